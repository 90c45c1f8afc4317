"""``clm calibrate``: outputs that the CLI and the track node load back, and one-line errors."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import pytest

from clm_core.cli import main
from clm_core.params import load_params_file, load_soil, load_track
from clm_core.synthetic import add_noise, simulate_impact, write_bag

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "bags" / "calibration"


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rec = add_noise(simulate_impact(load_soil("mevergnies"), n_areas=11, duration=0.8), 30.0, seed=11)
    return write_bag(rec, tmp_path_factory.mktemp("cli") / "impact").path


def test_cli_impact_writes_loadable_outputs(
    small_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    code = main(["calibrate", str(small_bag), "--method", "impact", "--out", str(out), "--fmax", "120",
                 "--norm", "weighted", "--model", "clm"])
    assert code == 0
    text = capsys.readouterr().out
    assert "band 2-120 Hz, weighted norm" in text and "kc  =" in text
    for name in ("params.yaml", "soil.yaml", "summary.json", "report.md", "transfer_functions.png", "sums.png",
                 "time_histories.png"):
        assert (out / name).is_file(), name
    params = load_params_file(out / "params.yaml")
    soil = load_soil(out / "soil.yaml")
    assert params.soil == soil and soil.model == "clm"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["band_hz"] == [2.0, 120.0] and summary["norm"] == "weighted"
    assert set(summary["parameters"]) == {"mf", "kf", "df", "kc", "dc"}
    assert summary["parameters"]["kf"]["ci95"][0] < soil.kf < summary["parameters"]["kf"]["ci95"][1]
    assert set(summary["comparisons"]) == {"clm", "lysmer", "winkler"}
    report = (out / "report.md").read_text()
    assert "| kf |" in report and "band **2-120 Hz**" in report and "![sums.png](sums.png)" in report
    # the fitted soil feeds the other commands directly
    assert main(["receptance", "--params", str(out / "params.yaml"), "--out", str(tmp_path / "rec"),
                 "--fmax", "50", "--df", "5"]) == 0


def test_cli_lysmer_soil_preset(small_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "lys"
    assert main(["calibrate", str(small_bag), "--method", "impact", "--out", str(out), "--model", "lysmer",
                 "--no-plots"]) == 0
    assert load_soil(out / "soil.yaml", "lysmer").model == "lysmer"
    assert not (out / "transfer_functions.png").exists()


def test_cli_errors_are_one_line(small_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["calibrate", str(tmp_path / "missing"), "--method", "impact", "--out", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("clm calibrate: error: bag") and "does not exist" in err and "\n" not in err
    code = main(["calibrate", str(small_bag), "--method", "receptance", "--out", str(tmp_path / "o")])
    assert code == 2
    assert "is for the impact test, not the receptance test" in capsys.readouterr().err


@pytest.mark.skipif(not (SHIPPED / "receptance_mevergnies").is_dir(), reason="shipped bags not present")
def test_shipped_receptance_bag(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    assert main(["calibrate", str(SHIPPED / "receptance_mevergnies"), "--method", "receptance", "--out", str(out),
                 "--no-plots"]) == 0
    rail, track = load_track(out / "track.yaml")
    assert abs(track.kb / 47e6 - 1) < 0.05 and abs(track.kp / 120e6 - 1) < 0.05


def test_progress_reports_and_bar_on_a_terminal(small_bag: Path, tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    import io
    import sys

    from clm_core.calibration import calibrate

    seen: list[tuple[str, float]] = []
    calibrate(small_bag, "impact", {"compare": False}, progress=lambda s, f: seen.append((s, f)))
    fr = [f for _, f in seen]
    assert fr[0] == 0.0 and fr[-1] == 1.0 and fr == sorted(fr)

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    err = Tty()
    monkeypatch.setattr(sys, "stderr", err)
    assert main(["calibrate", str(small_bag), "--method", "impact", "--out", str(tmp_path / "o"), "--no-plots"]) == 0
    assert "calibrate:" in err.getvalue() and "%" in err.getvalue()


def _calibrate_parser() -> argparse.ArgumentParser:
    from clm_core.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices["calibrate"]  # type: ignore[no-any-return]


def test_every_calibration_setting_has_an_option_and_every_option_a_setting() -> None:
    """``clm calibrate``'s options are generated from CALIBRATION_SETTINGS: one option per setting (its flag, type,
    choices), no hand-written option for a calibration value beside them; the settings are the scalar fields of
    CalibrationOptions, with its defaults."""
    from clm_core.calibration.options import CALIBRATION_SETTINGS, CalibrationOptions

    p = _calibrate_parser()
    command = {"help", "bag", "method", "out", "options", "no_plots", "no_progress", "overwrite", "allow_partial",
               "scheduler", "workers", "retry_failed"}  # what to fit and where, not how: not calibration settings
    dests = {a.dest: a for a in p._actions}
    assert set(dests) - command == set(CALIBRATION_SETTINGS)
    for name, s in CALIBRATION_SETTINGS.items():
        a = dests[name]
        assert list(a.option_strings[:1]) == [s.option] and a.default is None, name
        assert s.description.replace("%", "%%") in (a.help or ""), name
    nested = {"window", "sampling", "initial"}  # sections only an options file sets
    fields = {f.name: f for f in dataclasses.fields(CalibrationOptions)}
    assert set(fields) - nested == set(CALIBRATION_SETTINGS)
    defaults = CalibrationOptions()
    assert all(getattr(defaults, n) == s.default for n, s in CALIBRATION_SETTINGS.items())


def test_an_option_overrides_the_options_file_and_is_checked_while_parsing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = _calibrate_parser()
    args = p.parse_args(["b", "--method", "impact", "--out", "o", "--n-areas", "9", "--no-compare"])
    assert (args.n_areas, args.compare, args.fmax, args.ident_rel) == (9, False, None, None)
    code = main(["calibrate", str(tmp_path), "--method", "impact", "--out", str(tmp_path / "o"), "--n-areas", "8"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "--n-areas = 8: must be odd" in err and "\n" not in err
    assert main(["calibrate", str(tmp_path), "--method", "impact", "--out", str(tmp_path / "o"),
                 "--interval", "bootstrap"]) == 2
    assert "--interval" in capsys.readouterr().err
