"""The ROS layer's ``clm`` commands as a user runs them (issue 13 item 7).

``clm replay`` crashed in a terminal (``TypeError: bool() undefined`` on a
progress bar without a total): it runs here in a pseudo-terminal. The output
rules are the core's: an existing output is refused unless ``--overwrite``.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from tests.clitools import CLM, run_clm, run_in_pty

REPO = Path(__file__).resolve().parents[2]
DEMO_BAG = REPO / "bags" / "demo" / "demo_bag"


def test_ros_commands_register_through_the_entry_point() -> None:
    from clm_core.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices  # type: ignore[attr-defined]
    assert {"replay", "record", "play", "demo"} <= set(sub)
    assert "--ros-args" not in sub["play"].format_help()
    assert sub["play"].description and sub["replay"].description and sub["demo"].description


def test_replay_in_a_terminal(tmp_path: Path) -> None:
    out = tmp_path / "replayed"
    code, text = run_in_pty([*CLM, "replay", str(DEMO_BAG), "--out", str(out)])
    assert code == 0, text
    assert "Traceback" not in text and "bool() undefined" not in text
    assert re.search(r"clm replay: +\d+%\|.*msg", text), text  # a bar with the bag's message count as total
    assert re.search(r"replay: 1001 wheel-load messages read, 1001 accepted, rejected: none; \d+\.?\d* m?s "
                     r"simulated in \d+\.?\d* m?s", text), text
    assert (out / "metadata.yaml").is_file()
    # the same run without a terminal: quiet stderr, and the existing output is refused unless --overwrite
    proc = run_clm(["replay", str(DEMO_BAG), "--out", str(out)])
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"clm replay: error: --out {out}: exists; choose a new path or pass --overwrite"
    proc = run_clm(["replay", str(DEMO_BAG), "--out", str(out), "--overwrite"])
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    # --overwrite removes bags only
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("x")
    proc = run_clm(["replay", str(DEMO_BAG), "--out", str(other), "--overwrite"])
    assert proc.returncode == 2 and "is not a rosbag2 bag" in proc.stderr and (other / "notes.txt").exists()


def test_replay_bad_option(tmp_path: Path) -> None:
    proc = run_clm(["replay", str(DEMO_BAG), "--out", str(tmp_path / "o"), "--max-gap", "0"])
    assert proc.returncode == 2
    assert proc.stderr.strip() == "clm replay: error: --max-gap = 0: must be 0.0001 to 1e+06 s"
    assert not (tmp_path / "o").exists()


def test_demo_refuses_an_existing_output(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    (out / "demo_bag").mkdir(parents=True)
    (out / "demo_bag" / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    proc = run_clm(["demo", "--out", str(out), "--duration", "0.1"], timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip() == (f"clm demo: error: --out {out}: exists and is not empty; choose another directory "
                                   "or pass --overwrite")
    assert (out / "demo_bag" / "metadata.yaml").is_file()  # untouched
    # the launcher itself refuses the existing bag unless told to overwrite it
    from clm_ros.errors import ClmRosError
    from clm_ros.launcher import run_demo
    from clm_ros.run_settings import RunSettings

    with pytest.raises(ClmRosError, match="demo_bag: exists"):
        run_demo(out, RunSettings(duration=0.1))


def test_simulate_bag_storage_is_one_option(tmp_path: Path) -> None:
    from clm_core.cli import build_parser

    args = build_parser().parse_args(["simulate", "--bag", "--storage", "sqlite3", "--out", "x"])
    assert args.bag is True and args.storage == "sqlite3"
    for cmd in (["replay", "b"], ["demo"], ["soil-calibrate", "--profile", "soft"]):
        assert build_parser().parse_args([*cmd, "--out", "x", "--storage", "sqlite3"]).storage == "sqlite3"
