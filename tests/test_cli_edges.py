"""The ``clm`` command at its edges (issue 13 item 7): ranges, outputs, progress, final lines, help.

Subprocesses as a user runs them; a pseudo-terminal where the behaviour
depends on a terminal (progress bars).
"""

from __future__ import annotations

import inspect
import json
import re
import sys
from pathlib import Path
from typing import Any

import pytest

from clm_core.cli import build_parser, main
from clm_core.settings import SETTINGS
from tests.clitools import CLM, input_error, run_clm, run_in_pty

#: A number printed with more than 6 significant digits (what "16-digit floats" look like).
LONG_NUMBER = re.compile(r"\d\.\d{6,}|\d{7,}\.\d")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "--speed", "-5"], "--speed = -5: must be 0 to 150 m/s"),
        (["simulate", "--speed", "fast"], "--speed = 'fast': must be a real number"),
        (["simulate", "--dt", "-1"], "--dt = -1: must be 1e-06 to 0.01 s"),
        (["simulate", "--model", "elastic"], "--model = 'elastic': must be one of rigid, winkler, lysmer, clm"),
        (["simulate", "--vehicle", "--wavelength-band", "50,1"], "--wavelength-band = '50,1': need 0 < LMIN < LMAX"),
        (["simulate", "--sleepers", "5"], "--sleepers = 5: must be 11 to 4001"),
        (["simulate", "--seed", "-1"], "--seed = -1: must be 0 to 2147483647"),
        (["simulate"], "the following arguments are required: --out"),
        (["receptance", "--soil", "clay"], "unknown soil preset 'clay'"),
        (["receptance", "--track", "tgv"], "unknown track preset 'tgv'"),
        (["receptance", "--set", "foo=1"], "unknown parameter 'foo'"),
        (["receptance", "--set", "kb=-4"], "track.kb = -4: must be > 0"),
        (["receptance", "--set", "kb=nan"], "kb = nan"),
        (["receptance", "--set", "dc=-400e3"], "not positive semi-definite"),
        (["receptance", "--sleepers", "9"], "--sleepers 9"),
        (["soil-chain", "--areas", "40"], "--areas 40"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path: Path, argv: list[str], message: str) -> None:
    out = tmp_path / "never"
    line = input_error(run_clm([*argv, *(["--out", str(out)] if argv != ["simulate"] else [])]))
    assert line.startswith(f"clm {argv[0]}: error: ") and message in line
    assert not out.exists()


def test_bad_option_in_process_returns_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--speed", "-5", "--out", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err.strip() == "clm simulate: error: --speed = -5: must be 0 to 150 m/s"


def test_help_and_defaults_come_from_the_schema() -> None:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices  # type: ignore[attr-defined]
    sim = sub["simulate"]
    by_dest = {a.dest: a for a in sim._actions}
    for name, s in SETTINGS.items():
        if name not in by_dest:
            continue
        a = by_dest[name]
        assert s.description.replace("%", "%%") in (a.help or ""), name
        assert set(a.option_strings) >= set(s.option_strings), name
    # the vehicle run's defaults are the schema's: the demo's train, speed and rail
    args = parser.parse_args(["simulate", "--vehicle", "--out", "x"])
    assert args.vehicle == "thalys"
    for name in ("speed", "irregularity", "seed", "wavelength_band", "dt", "start", "lead_in", "track_engine"):
        assert getattr(args, name) == SETTINGS[name].default, name
    assert (args.speed, args.irregularity) == (83.33, "german-low")
    assert parser.parse_args(["simulate", "--out", "x"]).vehicle is None  # no --vehicle: constant moving loads
    assert "[m/s]; 0 to 150 m/s; default 83.33 m/s" in " ".join(sim.format_help().split())


def test_every_command_has_a_description() -> None:
    action: Any = next(a for a in build_parser()._actions if a.dest == "command")
    sub = action.choices
    helps = {c.dest: c.help for c in action._choices_actions}
    for name, p in sub.items():
        assert p.description and len(p.description) > 40, name
        # both from the docstring of the function that runs the command (add_command)
        doc = " ".join((inspect.getdoc(p.get_default("func")) or "").split())
        assert helps[name] and doc.lower().startswith(helps[name].lower() + ".") and doc.endswith(p.description), name
    assert {"report", "simulate", "receptance", "soil-chain", "calibrate", "soil-calibrate"} <= set(sub)


def test_existing_output_refused_unless_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    args = ["soil-chain", "--areas", "11", "--fmax", "20", "--out", str(out)]
    proc = run_clm(args)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"clm soil-chain: error: --out {out}: exists and is not empty; choose another " \
        "directory or pass --overwrite"
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    proc = run_clm([*args, "--overwrite"])
    assert proc.returncode == 0, proc.stderr
    assert (out / "summary.json").is_file() and (out / "notes.txt").read_text() == "mine\n"
    # an empty directory is no output: taken without --overwrite
    empty = tmp_path / "empty"
    empty.mkdir()
    assert run_clm(["soil-chain", "--areas", "11", "--fmax", "20", "--out", str(empty)]).returncode == 0


def test_failed_run_leaves_no_output_directory(tmp_path: Path) -> None:
    bad = tmp_path / "loads.csv"
    bad.write_text("t,x1,F1\n0.0,0.0,80e3\n0.0,1.0,80e3\n")  # times not increasing: refused while running
    out = tmp_path / "a" / "b" / "run"
    input_error(run_clm(["simulate", "--loads-file", str(bad), "--out", str(out)]))
    assert not (tmp_path / "a").exists()
    proc = run_clm(["simulate", "--params", str(tmp_path / "missing.yaml"), "--out", str(out)])
    assert proc.returncode == 2 and "missing.yaml" in proc.stderr
    assert not (tmp_path / "a").exists()


def test_final_lines_have_units_and_sensible_digits(tmp_path: Path) -> None:
    proc = run_clm(["simulate", "--speed", "30", "--duration", "0.2", "--out", str(tmp_path / "s")])
    assert proc.returncode == 0, proc.stderr
    line = proc.stdout.strip().splitlines()[-1]
    assert re.search(r"peak sleeper soil force \d+\.\d+ kN \(sleeper \d+\), max rail deflection \d\.\d+ mm", line), line
    assert not LONG_NUMBER.search(line), line
    assert proc.stderr == ""  # no terminal: no progress bar
    proc = run_clm(["soil-chain", "--areas", "11", "--fmax", "20", "--out", str(tmp_path / "c")])
    line = proc.stdout.strip().splitlines()[-1]
    assert re.search(r"delays \d+\.?\d* ms, \d+\.?\d* ms", line) and not LONG_NUMBER.search(line), line


def test_progress_shown_in_a_terminal(tmp_path: Path) -> None:
    code, text = run_in_pty([*CLM, "simulate", "--vehicle", "thalys", "--duration", "0.3", "--no-csv",
                             "--out", str(tmp_path / "v")])
    assert code == 0, text
    assert "Traceback" not in text
    assert re.search(r"clm simulate --vehicle: +\d+%\|", text), text  # the tqdm bar
    assert re.search(r"simulate --vehicle: peak wheel load \d+\.?\d* kN", text), text
    code, text = run_in_pty([*CLM, "simulate", "--speed", "30", "--duration", "0.3", "--out", str(tmp_path / "m")])
    assert code == 0 and re.search(r"clm simulate: +\d+%\|", text), text


def test_report_calls_the_core_not_the_cli(tmp_path: Path) -> None:
    """``clm report`` computes every report in-process from the core functions (no second CLI run)."""
    code = (
        "import sys\n"
        "from clm_core.commands import report\n"
        "import clm_core.params as p\n"
        "p.list_presets = lambda kind: {'tracks': ['mevergnies'], 'soils': ['mevergnies', 'soft']}[kind]\n"
        "import argparse\n"
        f"rc = report.run(argparse.Namespace(out={str(tmp_path / 'r')!r}, overwrite=False))\n"
        "assert 'clm_core.cli' not in sys.modules, 'report imported the CLI'\n"
        "sys.exit(rc)\n"
    )
    import subprocess

    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    index = json.loads((tmp_path / "r" / "index.json").read_text())
    assert sorted(index) == ["receptance_mevergnies_mevergnies_clm", "receptance_mevergnies_mevergnies_lysmer",
                             "receptance_mevergnies_rigid_rigid", "receptance_mevergnies_soft_clm",
                             "receptance_mevergnies_soft_lysmer", "soil-chain_mevergnies", "soil-chain_soft"]
    rigid = json.loads((tmp_path / "r" / "receptance_mevergnies_rigid_rigid" / "summary.json").read_text())
    assert index["receptance_mevergnies_rigid_rigid"] == rigid["peaks_hz"]
    assert rigid["peaks_hz"][0] == pytest.approx(63.7, abs=1.0)  # the rigid-ground track's first resonance
