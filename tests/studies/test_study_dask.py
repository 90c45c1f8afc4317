"""``clm study`` on a real dask.distributed cluster: equal rows, failures in their rows, resumption after a kill,
a remote scheduler, the progress bar.

Every cluster here is real: a :class:`distributed.LocalCluster` of 2 worker
processes (what ``clm study`` starts), or ``dask scheduler`` and ``dask
worker`` started as processes on loopback. Nothing asserts wall time.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from clm_core.studies import load_study, run_study
from clm_core.studies.runner import SUMMARY_METRICS, run_case
from clm_core.studies.store import read_table
from tests.clitools import CLM, run_clm, run_in_pty

ROOT = Path(__file__).resolve().parents[2]
SMOKE = ROOT / "examples" / "studies" / "smoke.yaml"
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


def _write(path: Path, data: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    """The smoke study on a local cluster of 2 worker processes, one failing case added."""
    d = tmp_path_factory.mktemp("smoke")
    data = yaml.safe_load(SMOKE.read_text())
    data["grid"]["n_sleepers"] = [61, 11]  # 11: too small a window for the power car -> fails when built
    data["grid"]["seed"] = [1]
    study = _write(d / "study.yaml", data)
    out = d / "out"
    outcome = run_study(load_study(study), out, workers=2, source_text=study.read_text())
    assert outcome.engine.kind == "local" and outcome.engine.workers == 2
    assert len(outcome.engine.worker_names) == 2  # two worker processes
    return out, read_table(out / "results.parquet")


def test_rows_equal_the_single_process_runs(smoke_run: tuple[Path, list[dict[str, Any]]]) -> None:
    out, rows = smoke_run
    spec = load_study(out / "study.yaml")
    cases = spec.cases()
    assert [r["case"] for r in rows] == list(range(len(cases)))
    ok = [(r, c) for r, c in zip(rows, cases) if c.values["n_sleepers"] == 61]
    assert len(ok) == 4
    for r, c in ok:
        assert r["status"] == "ok" and r["error"] == ""
        alone = run_case(c.settings)  # in this process, no dask
        for m in SUMMARY_METRICS:
            assert r[m] == alone[m], (c.values, m)  # identical, not close
        assert r["speed"] == c.values["speed"] and r["soil"] == c.values["soil"]
        assert r["wall_time_s"] > 0 and r["cpu_time_s"] > 0
    # the CSV holds the same numbers
    import csv

    with open(out / "results.csv", newline="") as fh:
        csv_rows = list(csv.DictReader(fh))
    for r, cr in zip(rows, csv_rows):
        for m in ("peak_sleeper_soil_force_N", "max_rail_deflection_m", "peak_wheel_load_N"):
            assert (cr[m] == "" and r[m] is None) or float(cr[m]) == r[m]


def test_a_failing_case_is_reported_in_its_row_and_the_study_goes_on(
        smoke_run: tuple[Path, list[dict[str, Any]]]) -> None:
    out, rows = smoke_run
    bad = [r for r in rows if r["n_sleepers"] == 11]
    assert len(bad) == 4
    for r in bad:
        assert r["status"] == "error"
        assert r["error"].startswith("ParameterError: n_sleepers = 11: the window must hold the wheelbase")
        assert r["peak_sleeper_soil_force_N"] is None
    summary = json.loads((out / "study.json").read_text())
    assert summary["ok"] == 4 and summary["failed"] == 4 and summary["computed"] == 8
    assert (out / "critical_speed.png").is_file()


def test_a_row_equals_clm_simulate_alone(smoke_run: tuple[Path, list[dict[str, Any]]], tmp_path: Path) -> None:
    out, rows = smoke_run
    row = next(r for r in rows if r["status"] == "ok" and r["soil"] == "soft" and r["speed"] == 80.0)
    rec = json.loads((out / "cases" / f"{row['case_key']}.json").read_text())
    cmd = rec["command"].split()
    assert cmd[:3] == ["clm", "simulate", "--vehicle"] and cmd[-2:] == ["--out", "OUT"]
    res = run_clm([*cmd[1:-1], str(tmp_path / "alone"), "--no-csv"], env=ENV)
    assert res.returncode == 0, res.stderr
    summary = json.loads((tmp_path / "alone" / "summary.json").read_text())
    for m in SUMMARY_METRICS:
        assert row[m] == summary[m], m
    assert "max_rail_deflection_m" in summary["peak_exclusion"]["applies_to"]


def _study_process(study: Path, out: Path, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen([*CLM, "study", str(study), "--out", str(out), *extra], env=ENV, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)


def test_resumes_after_the_process_is_killed(tmp_path: Path) -> None:
    # cases long enough (5 s simulated each) that the study is still running when it is killed
    study = _write(tmp_path / "long.yaml", {"settings": {"duration": 5.0, "irregularity": "german-low"},
                                            "grid": {"seed": list(range(1, 11))}})
    out = tmp_path / "out"
    proc = _study_process(study, out, "--workers", "2")
    store = out / "cases"
    try:
        deadline = time.monotonic() + 600
        while not (store.is_dir() and len(list(store.glob("*.json"))) >= 2):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no case finished"
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the study and its cluster: killed for real, no clean-up
        proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    done = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in store.glob("*.json")}
    assert 2 <= len(done) < 10, "the study finished before it was killed: nothing to resume"
    assert not (out / "results.parquet").exists()

    res = run_clm(["study", str(study), "--out", str(out), "--workers", "2"], env=ENV)
    assert res.returncode == 0, res.stderr
    assert f"resuming: {len(done)} of 10 cases already done" in res.stderr
    assert f"10 cases ({10 - len(done)} run, {len(done)} reused)" in res.stdout
    for name, (mtime, content) in done.items():  # the finished cases were not run again
        p = store / name
        assert p.stat().st_mtime_ns == mtime and p.read_bytes() == content
    rows = read_table(out / "results.parquet")
    assert len(rows) == 10 and all(r["status"] == "ok" for r in rows)
    stored = {json.loads(c)["key"]: json.loads(c)["row"] for _, c in done.values()}
    for r in rows:
        if r["case_key"] in stored:  # the reused rows are the stored ones, wall time included
            assert r["wall_time_s"] == stored[r["case_key"]]["wall_time_s"]
    summary = json.loads((out / "study.json").read_text())
    assert summary["reused"] == len(done) and summary["computed"] == 10 - len(done)


@pytest.fixture
def remote_scheduler(tmp_path: Path) -> Iterator[str]:
    """``dask scheduler`` and ``dask worker`` (2 processes, 1 thread each) on loopback, connected; their address."""
    from tests.studies.cluster import dask_processes

    with dask_processes(tmp_path / "dask", workers=2) as address:
        yield address


def test_remote_scheduler(remote_scheduler: str, tmp_path: Path,
                          smoke_run: tuple[Path, list[dict[str, Any]]]) -> None:
    out = tmp_path / "remote"
    res = run_clm(["study", str(SMOKE), "--out", str(out), "--scheduler", remote_scheduler, "--workers", "2"],
                  env=ENV)
    assert res.returncode == 0, res.stderr
    assert f"on the scheduler {remote_scheduler} of 2 workers" in res.stdout
    rows = read_table(out / "results.parquet")
    assert len(rows) == 8 and all(r["status"] == "ok" for r in rows)
    summary = json.loads((out / "study.json").read_text())
    assert summary["engine"]["kind"] == "remote" and len(summary["engine"]["worker_processes"]) == 2
    # the same cases as the local cluster's (smoke_run holds seed 1 of them): the same numbers
    local = {(r["speed"], r["soil"]): r for r in smoke_run[1] if r["status"] == "ok"}
    for r in rows:
        if r["seed"] == 1:
            for m in SUMMARY_METRICS:
                assert r[m] == local[(r["speed"], r["soil"])][m]


def test_unreachable_scheduler_is_one_clear_error(tmp_path: Path) -> None:
    res = run_clm(["study", str(SMOKE), "--out", str(tmp_path / "x"), "--scheduler", "tcp://127.0.0.1:9"], env=ENV)
    assert res.returncode == 2
    assert "--scheduler tcp://127.0.0.1:9: cannot connect" in res.stderr


def test_progress_bar_on_a_terminal(tmp_path: Path) -> None:
    code, text = run_in_pty([*CLM, "study", str(SMOKE), "--out", str(tmp_path / "tty"), "--workers", "2"], env=ENV)
    assert code == 0, text
    assert "clm study smoke:" in text and ("case/s" in text or "s/case" in text)
    assert "8/8" in text  # the final count is always drawn before the bar is removed
    assert "8 cases (8 run, 0 reused)" in text


def test_the_callers_environment_is_left_as_it_was(monkeypatch: pytest.MonkeyPatch) -> None:
    """A local cluster's nannies write their pre-spawn environment (NUMBA_NUM_THREADS=1, ...) into the calling
    process; the engine puts it back, or numba refuses to compile anything afterwards in this process."""
    from clm_core.studies.engine import WORKER_CONFIG, Engine

    names = list(WORKER_CONFIG["distributed.nanny.pre-spawn-environ"])
    monkeypatch.setenv(names[0], "7")
    monkeypatch.delenv(names[-1], raising=False)
    before = {k: os.environ.get(k) for k in names}
    with Engine(workers=1) as engine:
        assert engine.info.workers == 1
        assert {k: os.environ.get(k) for k in names} == before
    assert {k: os.environ.get(k) for k in names} == before
