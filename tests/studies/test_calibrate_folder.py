"""``clm calibrate FOLDER``: every bag of a folder on the study engine (a real 2-process LocalCluster), one row each,
equal to ``clm calibrate BAG`` alone; a bag that fails is reported in its row; resumable."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from clm_core.cli import main
from clm_core.studies.store import read_table
from clm_core.studies.study import find_bags, is_bag_folder
from tests.clitools import run_clm

ROOT = Path(__file__).resolve().parents[2]
BAGS = ROOT / "bags" / "calibration"
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("bags") / "site"
    d.mkdir()
    shutil.copytree(BAGS / "impact_mevergnies", d / "impact_a")
    shutil.copytree(BAGS / "receptance_mevergnies", d / "receptance_b")  # the wrong test for --method impact
    (d / "notes.txt").write_text("not a bag\n")
    return d


def test_folder_detection(folder: Path) -> None:
    assert is_bag_folder(folder)
    assert not is_bag_folder(folder / "impact_a")  # one bag
    assert [p.name for p in find_bags(folder)] == ["impact_a", "receptance_b"]


def test_calibrate_folder_rows_equal_single_runs(folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "cal"
    res = run_clm(["calibrate", str(folder), "--method", "impact", "--out", str(out), "--workers", "2", "--no-plots"],
                  env=ENV)
    assert res.returncode == 0, res.stderr
    assert "2 bags (2 run, 0 reused) on a local cluster of 2 workers" in res.stdout
    rows = read_table(out / "calibrations.parquet")
    assert [r["bag"] for r in rows] == ["impact_a", "receptance_b"]
    ok, bad = rows
    assert ok["status"] == "ok" and ok["model"] == "clm"
    assert bad["status"] == "error" and "is for the receptance test, not the impact test" in bad["error"]
    assert bad["misfit"] is None

    # the same bag alone, in this process: the same values and intervals, the same files
    assert main(["calibrate", str(folder / "impact_a"), "--method", "impact", "--out", str(tmp_path / "alone"),
                 "--no-plots", "--no-progress"]) == 0
    alone = json.loads((tmp_path / "alone" / "summary.json").read_text())
    in_folder = json.loads((out / "bags" / "impact_a" / "summary.json").read_text())
    for name, est in alone["parameters"].items():
        assert ok[name] == est["value"]
        assert [ok[f"{name}_ci95_low"], ok[f"{name}_ci95_high"]] == est["ci95"]
        assert in_folder["parameters"][name] == est
    assert ok["misfit"] == alone["fit"]["misfit"]
    assert (out / "bags" / "impact_a" / "params.yaml").read_text() == (tmp_path / "alone" / "params.yaml").read_text()

    # again: nothing is recomputed; --retry-failed runs the failed bag only
    again = run_clm(["calibrate", str(folder), "--method", "impact", "--out", str(out), "--workers", "1",
                     "--no-plots", "--retry-failed"], env=ENV)
    assert again.returncode == 0, again.stderr
    assert "2 bags (1 run, 1 reused)" in again.stdout


def test_engine_options_need_a_folder(tmp_path: Path) -> None:
    res = run_clm(["calibrate", str(BAGS / "impact_mevergnies"), "--method", "impact", "--out", str(tmp_path / "o"),
                   "--workers", "2"], env=ENV)
    assert res.returncode == 2 and "for a folder of bags" in res.stderr
