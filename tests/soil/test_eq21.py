"""Eq. (21) in the reports uses the sleeper spacing of the track the soil goes with (issue 14, item 6)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from clm_core.cli import main
from clm_core.errors import PresetError
from clm_core.params import load_track, soil_track
from clm_core.profile import load_profile
from clm_core.soil.formulas import time_lag_mulliken

FAST = ["--areas", "11", "--dt", "1e-4", "--fmax", "20", "--df", "5"]


def test_soil_presets_name_their_track() -> None:
    assert {s: soil_track(s) for s in ("mevergnies", "soft", "medium", "stiff", "haren")} == {
        "mevergnies": "mevergnies",
        "soft": "soil-study",
        "medium": "soil-study",
        "stiff": "soil-study",
        "haren": "mevergnies",
    }
    assert load_track("soil-study")[1].spacing == 0.72  # Sec. 5.2


def test_soil_track_refuses_an_unknown_track(tmp_path: Path) -> None:
    p = tmp_path / "s.yaml"
    p.write_text("clm: {mf: 1, kf: 1, df: 1, kc: 1, dc: 0}\ntrack: tgv\n")
    with pytest.raises(PresetError, match="track = 'tgv' is not a track preset"):
        soil_track(p)
    p.write_text("clm: {mf: 1, kf: 1, df: 1, kc: 1, dc: 0}\n")
    assert soil_track(p) is None


@pytest.mark.parametrize("soil", ["soft", "stiff"])
def test_soil_chain_eq21_uses_the_track_spacing(tmp_path: Path, soil: str) -> None:
    cs = load_profile(soil).layers[0].cs
    assert main(["soil-chain", "--soil", soil, "--track", "soil-study", *FAST, "--out", str(tmp_path / "t")]) == 0
    s = json.loads((tmp_path / "t" / "summary.json").read_text())
    assert s["eq21_inputs"] == {"spacing_m": 0.72, "width_m": 0.285, "cs_m_s": cs, "from": "track soil-study"}
    assert s["eq21_delay_s"] == pytest.approx(time_lag_mulliken(0.72, 0.285, cs), rel=1e-12)
    # without a track the old default d = 0.6 m is used, and said so
    assert main(["soil-chain", "--soil", soil, *FAST, "--out", str(tmp_path / "d")]) == 0
    d = json.loads((tmp_path / "d" / "summary.json").read_text())
    assert d["eq21_inputs"]["spacing_m"] == 0.6 and d["eq21_inputs"]["from"] == "default (no --track)"
    # 3 (d + b/2) / (4 c_s): 0.12 m more spacing lengthens the lag by 0.09 / c_s
    assert s["eq21_delay_s"] - d["eq21_delay_s"] == pytest.approx(0.09 / cs, rel=1e-9)


def test_soil_chain_refuses_a_spacing_other_than_the_track(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["soil-chain", "--soil", "soft", "--track", "soil-study", "--spacing", "0.6", *FAST, "--out", str(tmp_path)]
    assert main(argv) == 2
    assert "--spacing = 0.6 m differs from the value 0.72 m of --track soil-study" in capsys.readouterr().err


@pytest.mark.slow
def test_report_eq21_uses_each_soil_track(tmp_path: Path) -> None:
    """``clm report`` (about 30 s): the soil-chain Eq. (21) lags use d = 0.72 m for the Sec. 5.2 soils."""
    assert main(["report", "--out", str(tmp_path)]) == 0
    index = json.loads((tmp_path / "index.json").read_text())
    for soil, spacing in (("soft", 0.72), ("medium", 0.72), ("stiff", 0.72), ("mevergnies", 0.6), ("haren", 0.6)):
        entry = index[f"soil-chain_{soil}"]
        cs = load_profile(soil).layers[0].cs
        assert entry["eq21_inputs"]["spacing_m"] == spacing
        assert entry["eq21_delay_s"] == pytest.approx(time_lag_mulliken(spacing, 0.285, cs), rel=1e-12)
