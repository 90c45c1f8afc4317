"""A case's identity is a content hash (settings, file contents, parameter values, code revision): resuming after
a soil file is edited recomputes exactly the cases that read it, on a real 2-process LocalCluster; a worker
running other clm_core code refuses the case.

Nothing asserts wall time; the counts are of cases recomputed and reused.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from clm_core.studies import load_study, run_study
from clm_core.studies.inputs import CaseResolver, code_files, code_revision, ship
from clm_core.studies.runner import SUMMARY_METRICS, run_case
from clm_core.studies.spec import case_key

PRESETS = Path(__file__).resolve().parents[2] / "clm_core" / "presets" / "soils"


def _soil(path: Path, kf: float) -> Path:
    """A soil file in the preset format: the soft soil with its k_f set to ``kf`` [N/m]."""
    data = yaml.safe_load((PRESETS / "soft.yaml").read_text())
    data["clm"]["kf"] = kf
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _study(path: Path) -> Path:
    path.write_text(yaml.safe_dump({
        "name": "edit",
        "settings": {"track": "soil-study", "duration": 0.2, "dt": 1.0e-4, "irregularity": "german-low"},
        # relative paths: read from the working directory of the client
        "grid": {"soil": ["soils/a.yaml", "soils/b.yaml", "stiff"], "speed": [40.0, 80.0]},
    }, sort_keys=False))
    return path


def test_resume_after_editing_a_soil_file_recomputes_exactly_the_affected_cases(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "soils").mkdir()
    _soil(tmp_path / "soils" / "a.yaml", 5.0e6)
    _soil(tmp_path / "soils" / "b.yaml", 8.0e6)
    study = _study(tmp_path / "study.yaml")
    out = tmp_path / "out"

    first = run_study(load_study(study), out, workers=2)
    assert (first.computed, first.reused, first.failed) == (6, 0, 0)
    stored = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in (out / "cases").glob("*.json")}
    assert len(stored) == 6
    before = {(r["soil"], r["speed"]): r for r in first.rows}

    # edit one soil file: the two cases that read it are recomputed, the four others reused
    _soil(tmp_path / "soils" / "a.yaml", 2.5e6)
    second = run_study(load_study(study), out, workers=2)
    assert (second.computed, second.reused, second.failed) == (2, 4, 0)
    after = {(r["soil"], r["speed"]): r for r in second.rows}
    for (soil, speed), r in after.items():
        if soil == "soils/a.yaml":
            assert r["case_key"] != before[(soil, speed)]["case_key"]
            # the new numbers are those of the edited file (run here, in this process, without dask)
            alone = run_case({"track": "soil-study", "duration": 0.2, "dt": 1.0e-4, "irregularity": "german-low",
                              "soil": "soils/a.yaml", "speed": speed})
            assert [r[m] for m in SUMMARY_METRICS] == [alone[m] for m in SUMMARY_METRICS]
            assert r["peak_sleeper_soil_force_N"] != before[(soil, speed)]["peak_sleeper_soil_force_N"]
        else:  # reused: same key, same stored record, untouched on disk
            assert r["case_key"] == before[(soil, speed)]["case_key"]
            assert r["wall_time_s"] == before[(soil, speed)]["wall_time_s"]
            p = out / "cases" / f"{r['case_key']}.json"
            assert (p.stat().st_mtime_ns, p.read_bytes()) == stored[p.name]
    summary = json.loads((out / "study.json").read_text())
    assert (summary["computed"], summary["reused"]) == (2, 4)

    # the same content again (the edit undone): the first run's records are found again, nothing recomputed
    _soil(tmp_path / "soils" / "a.yaml", 5.0e6)
    third = run_study(load_study(study), out, workers=2)
    assert (third.computed, third.reused) == (0, 6)
    assert {r["case_key"] for r in third.rows} == {r["case_key"] for r in first.rows}


def test_the_key_follows_content_and_values_not_names(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    a = _soil(tmp_path / "a.yaml", 5.0e6)
    same = tmp_path / "renamed.yaml"
    same.write_bytes(a.read_bytes())
    base = {"track": "soil-study", "speed": 40.0}
    key_a = case_key({**base, "soil": "a.yaml"})
    assert case_key({**base, "soil": str(same)}) == key_a  # another name, same content: the same case
    # a value written differently in the file (5.0e6 as 5000000.0 with a comment): other bytes, so another key,
    # but the parameter values are equal: the key holds both
    text = a.read_text().replace("5000000.0", "5000000.0  # N/m")
    (tmp_path / "c.yaml").write_text(text)
    assert case_key({**base, "soil": "c.yaml"}) != key_a
    # an override that reaches the same value as the file: the parameter values are in the identity
    r = CaseResolver()
    with_override = r.resolve({**base, "soil": "a.yaml", "soil.kf": 5.0e6})
    assert r.parameters({**base, "soil": "a.yaml", "soil.kf": 5.0e6}, with_override.files) == \
        r.parameters({**base, "soil": "a.yaml"}, r.resolve({**base, "soil": "a.yaml"}).files)
    # a missing file is one clear error naming the setting and the folder
    with pytest.raises(Exception, match=r"soil = 'missing.yaml': no such file \(relative paths are read from"):
        case_key({**base, "soil": "missing.yaml"})


def test_the_code_revision_hashes_the_installed_files(tmp_path: Path) -> None:
    files = code_files()
    names = {p.name for p in files}
    assert "inputs.py" in names and "soft.yaml" in names  # sources and presets
    assert not any("__pycache__" in p.parts for p in files)
    rev = code_revision()
    assert len(rev) == 64 and rev == code_revision()
    # a copy of the package with one byte changed has another revision (hashed by the same rule)
    import shutil

    from clm_core.studies import inputs

    root = Path(inputs.__file__).resolve().parents[1]
    copy = tmp_path / "clm_core"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert [p.relative_to(copy) for p in code_files(copy)] == [p.relative_to(root) for p in files]
    (copy / "studies" / "runner.py").write_text((root / "studies" / "runner.py").read_text() + "\n# edited\n")
    edited = [p.relative_to(copy) for p in code_files(copy)
              if p.read_bytes() != (root / p.relative_to(copy)).read_bytes()]
    assert edited == [Path("studies/runner.py")]


def test_a_worker_with_other_code_refuses_the_case() -> None:
    row: dict[str, Any] = run_case({"duration": 1e-3, "irregularity": "none"}, {}, "0" * 64)
    assert row["status"] == "error"
    assert row["error"].startswith("CodeMismatch: this worker runs other clm_core code (revision ")
    assert "than the client (revision 000000000000)" in row["error"]
    assert row["peak_sleeper_soil_force_N"] is None


def test_shipped_content_is_rebuilt_without_the_clients_path(tmp_path: Path) -> None:
    from clm_core.studies.inputs import materialise

    d = tmp_path / "bag"
    (d / "sub").mkdir(parents=True)
    (d / "metadata.yaml").write_text("x: 1\n")
    (d / "sub" / "data.bin").write_bytes(bytes(range(256)))
    item = ship(d, "bag")
    assert item.name == "bag" and item.size == 5 + 256
    # the hash covers the content and the inner paths, not the top name
    other = tmp_path / "other"
    import shutil

    shutil.copytree(d, other)
    assert ship(other, "bag").sha256 == item.sha256
    (other / "sub" / "data.bin").write_bytes(b"changed")
    assert ship(other, "bag").sha256 != item.sha256
    shutil.rmtree(d)  # the client's copy is gone: the worker needs only the shipped content
    back = materialise(item, tmp_path / "worker")
    assert back.name == "bag" and (back / "sub" / "data.bin").read_bytes() == bytes(range(256))
    assert materialise(item, tmp_path / "worker") == back  # content-addressed: built once


def test_a_worker_of_other_code_is_refused_at_connect(tmp_path: Path) -> None:
    """A real ``dask worker`` importing a copy of clm_core with one edited file (same version string): the study
    is refused before anything runs, naming the worker, exit code 2."""
    import shutil
    import subprocess

    from clm_core.studies import inputs
    from tests.clitools import run_clm
    from tests.studies.cluster import DASK, ENV, dask_processes

    root = Path(inputs.__file__).resolve().parents[1]
    other = tmp_path / "other"
    shutil.copytree(root, other / "clm_core", ignore=shutil.ignore_patterns("__pycache__"))
    (other / "clm_core" / "peaks.py").write_text((root / "peaks.py").read_text() + "\n# another revision\n")
    study = _study(tmp_path / "study.yaml")
    (tmp_path / "soils").mkdir()
    _soil(tmp_path / "soils" / "a.yaml", 5.0e6)
    _soil(tmp_path / "soils" / "b.yaml", 8.0e6)
    with dask_processes(tmp_path / "dask", workers=1) as address:
        env = {**ENV, "PYTHONPATH": str(other)}  # this worker imports the edited copy
        worker = subprocess.Popen([DASK, "worker", address, "--nthreads", "1", "--host", "127.0.0.1",
                                   "--no-dashboard"], env=env, cwd=tmp_path, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        try:
            from distributed import Client

            with Client(address, timeout="120s") as c:  # both connected before the study's own 60-s wait
                c.wait_for_workers(2, timeout=600)
            check = subprocess.run([sys.executable, "-c", "import clm_core, sys; print(clm_core.__file__)"],
                                   env=env, capture_output=True, text=True, cwd=tmp_path)
            assert check.stdout.strip() == str(other / "clm_core" / "__init__.py")
            res = run_clm(["study", str(study), "--out", str(tmp_path / "out"), "--scheduler", address,
                           "--workers", "2"], env=ENV, cwd=str(tmp_path))
        finally:
            worker.terminate()
            worker.wait(timeout=60)
    assert res.returncode == 2, res.stderr
    assert "1 worker(s) run other clm_core code than this client (revision" in res.stderr
    assert "install the same clm_core on every worker" in res.stderr
    assert not (tmp_path / "out" / "cases").exists() or not any((tmp_path / "out" / "cases").iterdir())


def test_a_file_read_by_many_cases_is_sent_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The engine scatters a shipped file that several tasks read once to every worker, and the tasks get its
    content (real 1-worker LocalCluster); a file read by one task travels inside it; equal content under
    another name is another input (the outputs name it)."""
    from clm_core.studies.engine import Engine, Task

    monkeypatch.chdir(tmp_path)
    _soil(tmp_path / "a.yaml", 4.0e6)
    (tmp_path / "b.yaml").write_bytes((tmp_path / "a.yaml").read_bytes())
    r = CaseResolver()
    cases = [r.resolve({"track": "soil-study", "soil": s, "duration": 0.05, "speed": v, "irregularity": "none"})
             for s, v in (("a.yaml", 30.0), ("a.yaml", 60.0), ("a.yaml", 90.0), ("b.yaml", 30.0))]
    tasks = [Task(c.key, run_case, (c.settings, c.files, c.code)) for c in cases]
    rows: dict[str, dict[str, Any]] = {}
    with Engine(workers=1) as engine:
        shared = engine._share_inputs(tasks)
        assert [k[1] for k in shared] == ["a.yaml"]  # read by 3 tasks: sent once; b.yaml (1 task): in its task
        engine.run(tasks, lambda t, row, _why: rows.update({t.key: dict(row or {})}))
    assert len(rows) == 3  # a.yaml at 30 m/s and b.yaml at 30 m/s: the same content, the same case key
    assert cases[0].key == cases[3].key
    for c in cases:
        alone = run_case(c.settings)
        assert [rows[c.key][m] for m in SUMMARY_METRICS] == [alone[m] for m in SUMMARY_METRICS]
