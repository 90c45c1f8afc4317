"""Workers never read the client's paths: a ``dask worker`` started in another folder, holding *other* files under
the same relative names, gives the client the numbers of the client's files, and every output of ``clm calibrate
FOLDER`` (table, summaries, parameter files, reports, figures) lands in the client's ``--out``, written by the client.

Real processes: ``dask scheduler`` and ``dask worker`` (:mod:`tests.studies.cluster`), ``clm`` as a subprocess
in the client's folder.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml

from clm_core.cli import main
from clm_core.studies.runner import SUMMARY_METRICS, run_case
from clm_core.studies.store import read_table
from tests.clitools import run_clm
from tests.studies.cluster import ENV, dask_processes

ROOT = Path(__file__).resolve().parents[2]
SOFT = ROOT / "clm_core" / "presets" / "soils" / "soft.yaml"
IMPACT = ROOT / "bags" / "calibration" / "impact_mevergnies"


def _soil(path: Path, kf: float) -> None:
    data = yaml.safe_load(SOFT.read_text())
    data["clm"]["kf"] = kf
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def _profile(path: Path, amplitude: float) -> None:
    lines = ["# position [m], elevation [m]"]
    lines += [f"{x:.2f},{amplitude * ((-1) ** int(x)):.6g}" for x in [i * 0.5 for i in range(-40, 200)]]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def folders(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(client folder, worker folder): the same relative names, other contents."""
    root = tmp_path_factory.mktemp("folders")
    client, worker = root / "client", root / "worker"
    _soil(client / "soils" / "site.yaml", 3.0e6)
    _profile(client / "profiles" / "measured.csv", 1.0e-4)
    _soil(worker / "soils" / "site.yaml", 9.0e6)  # a trap: a worker that read its own relative path gets these
    _profile(worker / "profiles" / "measured.csv", 5.0e-3)
    (client / "study.yaml").write_text(yaml.safe_dump({
        "name": "folders",
        "settings": {"track": "soil-study", "soil": "soils/site.yaml", "irregularity": "profiles/measured.csv",
                     "duration": 0.2, "dt": 1.0e-4},
        "grid": {"speed": [40.0, 80.0]},
    }, sort_keys=False))
    site = client / "site"
    shutil.copytree(IMPACT, site / "impact_a")  # a bag directory, its channel map inside
    site.joinpath("impact_b.mcap").write_bytes((IMPACT / "impact_mevergnies.mcap").read_bytes())  # a bag file,
    site.joinpath("impact_b.channels.yaml").write_bytes((IMPACT / "channels.yaml").read_bytes())  # its map beside
    site.joinpath("impact_c.mcap").write_bytes((IMPACT / "impact_mevergnies.mcap").read_bytes())  # the folder's map
    site.joinpath("channels.yaml").write_bytes((IMPACT / "channels.yaml").read_bytes())
    return client, worker


@pytest.fixture(scope="module")
def scheduler(folders: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> str:
    _, worker = folders
    with dask_processes(tmp_path_factory.mktemp("dask"), workers=2, worker_cwd=worker) as address:
        yield address  # type: ignore[misc]


def _listing(d: Path) -> dict[str, bytes]:
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_study_files_come_from_the_client(folders: tuple[Path, Path], scheduler: str,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    client, worker = folders
    before = _listing(worker)
    res = run_clm(["study", "study.yaml", "--out", "results", "--scheduler", scheduler, "--workers", "2"], env=ENV,
                  cwd=str(client))
    assert res.returncode == 0, res.stderr
    assert "2 cases (2 run, 0 reused)" in res.stdout
    rows = read_table(client / "results" / "results.parquet")
    monkeypatch.chdir(client)  # the same cases here, reading the client's files
    for r in rows:
        assert r["status"] == "ok", r["error"]
        alone = run_case({"track": "soil-study", "soil": "soils/site.yaml", "irregularity": "profiles/measured.csv",
                          "duration": 0.2, "dt": 1.0e-4, "speed": r["speed"]})
        assert [r[m] for m in SUMMARY_METRICS] == [alone[m] for m in SUMMARY_METRICS]
    monkeypatch.chdir(worker)  # and not those of the worker's files of the same names
    other = run_case({"track": "soil-study", "soil": "soils/site.yaml", "irregularity": "profiles/measured.csv",
                      "duration": 0.2, "dt": 1.0e-4, "speed": rows[0]["speed"]})
    assert other["peak_sleeper_soil_force_N"] != rows[0]["peak_sleeper_soil_force_N"]
    assert _listing(worker) == before  # the worker wrote nothing in its folder
    assert (client / "results" / "critical_speed.png").is_file()


def test_calibrate_folder_outputs_come_back_to_the_client(folders: tuple[Path, Path], scheduler: str,
                                                          tmp_path: Path) -> None:
    client, worker = folders
    before = _listing(worker)
    res = run_clm(["calibrate", "site", "--method", "impact", "--out", "cal", "--scheduler", scheduler,
                   "--workers", "2"], env=ENV, cwd=str(client))
    assert res.returncode == 0, res.stderr
    assert "3 bags (3 run, 0 reused)" in res.stdout
    rows = read_table(client / "cal" / "calibrations.parquet")
    assert [r["bag"] for r in rows] == ["impact_a", "impact_b", "impact_c"]
    assert all(r["status"] == "ok" for r in rows), rows
    # the same bag alone, in this process
    assert main(["calibrate", str(IMPACT), "--method", "impact", "--out", str(tmp_path / "alone"),
                 "--no-progress"]) == 0
    alone = _listing(tmp_path / "alone")
    for name in ("impact_a", "impact_b", "impact_c"):
        got = _listing(client / "cal" / "bags" / name)
        assert set(got) == set(alone), name  # every output: params, soil, summary, report, figures
        assert any(f.endswith(".png") for f in got)
        assert yaml.safe_load(got["params.yaml"]) == yaml.safe_load(alone["params.yaml"])  # the header names the bag
        assert not any(b"clm-bag-" in data for data in got.values())  # nothing names the worker's temporary copy
        summary = json.loads(got["summary.json"])
        assert summary["parameters"] == json.loads(alone["summary.json"])["parameters"]
        # the outputs name the client's bag, not the worker's temporary copy
        assert summary["bag"] == str((client / "site" / (name if name == "impact_a" else f"{name}.mcap")).resolve())
        rec = next(json.loads(p.read_text()) for p in (client / "cal" / "cases").glob("*.json")
                   if json.loads(p.read_text())["columns"]["bag"] == name)
        assert sorted(rec["row"]["outputs"]) == sorted(got)
    assert _listing(worker) == before  # nothing written in the worker's folder
