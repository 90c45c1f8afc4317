"""``clm study`` as a command: quick help without dask, dry run, one-line errors, output-directory rules; figures."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from clm_core.cli import main
from clm_core.outputs.plots import plot_study
from clm_core.studies.study import prepare_dir

ROOT = Path(__file__).resolve().parents[2]
SMOKE = ROOT / "examples" / "studies" / "smoke.yaml"


def test_help_imports_neither_dask_nor_pyarrow() -> None:
    code = (
        "import sys, json\n"
        "from clm_core.cli import build_parser\n"
        "build_parser()\n"
        "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules} & {'dask', 'distributed', 'pyarrow'})))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == []


def test_dry_run_lists_the_cases(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["study", str(SMOKE), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "study smoke: 8 cases; varied: speed, soil, seed" in out
    assert "case 7: speed = 80.0, soil = 'stiff', seed = 2" in out


def test_bad_file_is_one_line_naming_key_value_rule(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("settings:\n  duration: 0.2\ngrid:\n  speed: [40, 400]\n")
    assert main(["study", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"clm study: error: {bad}: grid.speed[1] = 400: must be 0 to 150 m/s"
    assert not (tmp_path / "o").exists()
    assert main(["study", str(tmp_path / "missing.yaml"), "--dry-run"]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["study", str(SMOKE), "--out", str(tmp_path / "o"), "--workers", "0"]) == 2
    assert "--workers 0: must be an integer >= 1" in capsys.readouterr().err


def test_output_directory_rules(tmp_path: Path) -> None:
    from clm_core.errors import InputError

    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="holds no earlier study"):
        prepare_dir(other, overwrite=False)
    assert prepare_dir(other, overwrite=True) == (other, False)
    study = tmp_path / "study"
    (study / "cases").mkdir(parents=True)
    (study / "cases" / "abc.json").write_text("{}")
    assert prepare_dir(study, overwrite=False) == (study, True)  # resumed
    assert prepare_dir(study, overwrite=True) == (study, False)  # results discarded
    assert not any((study / "cases").iterdir())


def test_study_figures(tmp_path: Path) -> None:
    rows = []
    for soil, base in (("soft", 30e3), ("stiff", 40e3)):
        for speed in (20.0, 60.0, 100.0, 140.0):
            for seed in range(1, 6):
                rows.append({"speed": speed, "soil": soil, "seed": seed, "status": "ok",
                             "peak_sleeper_soil_force_N": base * (1 + speed / 400) + 100 * seed,
                             "max_rail_deflection_m": 1e-3 * (1 + speed / 300),
                             "peak_wheel_load_N": 90e3 + 500 * seed + speed * 10})
    rows.append({"speed": 60.0, "soil": "soft", "seed": 9, "status": "error", "peak_sleeper_soil_force_N": None})
    files = plot_study(rows, ["speed", "soil", "seed"], tmp_path, title="test")
    assert [f.name for f in files] == ["critical_speed.png", "exceedance.png"]
    # nothing to draw without speed or seed
    assert plot_study(rows, ["soil"], tmp_path / "none") == []
