"""The ``clm`` command end to end (receptance, soil-chain) and its errors."""

import csv
import json
from pathlib import Path

import pytest

from clm_core.cli import main

HEADER = "frequency_hz,H11_re,H11_im,H21_re,H21_im,H31_re,H31_im,H41_re,H41_im,H51_re,H51_im"


@pytest.mark.parametrize("track", ["mevergnies", "soil-study"])
@pytest.mark.parametrize("soil", ["mevergnies", "soft", "medium", "stiff", "haren"])
def test_receptance_every_preset(tmp_path: Path, track: str, soil: str) -> None:
    out = tmp_path / "r"
    assert (
        main(
            [
                "receptance",
                "--track",
                track,
                "--soil",
                soil,
                "--model",
                "clm",
                "--fmin",
                "1",
                "--fmax",
                "400",
                "--df",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    with (out / "receptance.csv").open() as fh:
        rows = list(csv.reader(fh))
    assert ",".join(rows[0]) == HEADER
    assert len(rows) == 1 + 400
    summary = json.loads((out / "summary.json").read_text())
    assert summary["peaks_hz"] == sorted(summary["peaks_hz"]) and summary["peaks_hz"]
    assert summary["parameters"]["soil"]["model"] == "clm"
    png = (out / "receptance.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def test_receptance_models_and_set(tmp_path: Path) -> None:
    for model in ("rigid", "winkler", "lysmer"):
        assert main(["receptance", "--model", model, "--df", "2", "--out", str(tmp_path / model)]) == 0
    assert (
        main(
            [
                "receptance",
                "--set",
                "kb=50e6",
                "--set",
                "d=0.65",
                "--sleepers",
                "31",
                "--df",
                "2",
                "--out",
                str(tmp_path / "set"),
            ]
        )
        == 0
    )
    p = json.loads((tmp_path / "set" / "summary.json").read_text())["parameters"]
    assert p["track"]["kb"] == 50e6 and p["track"]["spacing"] == 0.65
    # the rigid-ground Mevergnies track resonates near 64 and 322 Hz
    peaks = json.loads((tmp_path / "rigid" / "summary.json").read_text())["peaks_hz"]
    assert peaks[0] == pytest.approx(63.7, abs=1.0) and peaks[-1] == pytest.approx(322.4, abs=1.0)


@pytest.mark.parametrize("soil", ["mevergnies", "soft", "medium", "stiff", "haren"])
def test_soil_chain_every_preset(tmp_path: Path, soil: str) -> None:
    assert main(["soil-chain", "--soil", soil, "--areas", "41", "--out", str(tmp_path)]) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert len(s["peak_displacement_m"]) == 3 and len(s["peak_time_s"]) == 3
    assert s["eq16_max_relative_error"] < 1e-9
    assert s["eq21_delay_s"] > 0 and s["eq23_delay_s"] > 0
    assert (tmp_path / "chain.png").stat().st_size > 20_000


