"""A study on a scheduler and workers in another network namespace (another host, as far as the network goes):
the client reaches them only through a veth pair created by this test, and gets results identical to a local
cluster's. Skipped, with the reason, where ``ip netns`` is refused (no CAP_NET_ADMIN, no iproute2).

Only addresses of the namespace and its veth pair are used (10.231.<n>.1 and .2/30, checked unused first);
the test removes the namespace and the pair whatever happens.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from clm_core.studies import load_study, run_study
from clm_core.studies.runner import SUMMARY_METRICS
from clm_core.studies.store import read_table
from tests.clitools import run_clm
from tests.studies.cluster import ENV, dask_processes

ROOT = Path(__file__).resolve().parents[2]
SOFT = ROOT / "clm_core" / "presets" / "soils" / "soft.yaml"


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)


@pytest.fixture
def namespace() -> Iterator[tuple[str, str]]:
    """(namespace name, its address) joined to this namespace by a veth pair; removed afterwards."""
    if shutil.which("ip") is None:
        pytest.skip("ip (iproute2) is not installed: cannot create a network namespace")
    n = os.getpid() % 250 + 1
    net = f"10.231.{n}."
    if net in _ip("-o", "addr").stdout:
        pytest.skip(f"{net}0/30 is already in use on this machine")
    ns, host_if, ns_if = f"clmstudy{os.getpid()}", f"vcs{os.getpid()}h", f"vcs{os.getpid()}n"
    made = _ip("netns", "add", ns)
    if made.returncode != 0:
        pytest.skip(f"`ip netns add` refused here: {made.stderr.strip()}")
    try:
        for cmd in (["link", "add", host_if, "type", "veth", "peer", "name", ns_if],
                    ["link", "set", ns_if, "netns", ns],
                    ["addr", "add", f"{net}1/30", "dev", host_if],
                    ["link", "set", host_if, "up"],
                    ["netns", "exec", ns, "ip", "addr", "add", f"{net}2/30", "dev", ns_if],
                    ["netns", "exec", ns, "ip", "link", "set", ns_if, "up"],
                    ["netns", "exec", ns, "ip", "link", "set", "lo", "up"]):
            r = _ip(*cmd)
            assert r.returncode == 0, f"ip {' '.join(cmd)}: {r.stderr}"
        yield ns, f"{net}2"
    finally:
        _ip("netns", "del", ns)  # takes its end of the pair, and so the pair, with it
        if _ip("link", "show", host_if).returncode == 0:
            _ip("link", "del", host_if)


def test_study_on_a_scheduler_and_workers_in_another_namespace(namespace: tuple[str, str], tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    ns, address = namespace
    client = tmp_path / "client"
    client.mkdir()
    data = yaml.safe_load(SOFT.read_text())
    data["clm"]["kf"] = 4.0e6
    (client / "site.yaml").write_text(yaml.safe_dump(data))  # a relative soil file, on the client only
    study = client / "study.yaml"
    study.write_text(yaml.safe_dump({
        "name": "netns",
        "settings": {"track": "soil-study", "duration": 0.2, "dt": 1.0e-4, "irregularity": "german-low"},
        "grid": {"speed": [40.0, 80.0], "soil": ["site.yaml", "stiff"], "seed": [1, 2]},
    }, sort_keys=False))
    far = tmp_path / "far"  # the namespace's processes run in another folder
    far.mkdir()
    with dask_processes(tmp_path / "dask", host=address, workers=2, prefix=["ip", "netns", "exec", ns],
                        worker_cwd=far) as scheduler:
        assert scheduler.startswith(f"tcp://{address}:")
        res = run_clm(["study", "study.yaml", "--out", "remote", "--scheduler", scheduler, "--workers", "2"],
                      env=ENV, cwd=str(client))
    assert res.returncode == 0, res.stderr
    assert f"8 cases (8 run, 0 reused) on the scheduler {scheduler} of 2 workers" in res.stdout
    remote = read_table(client / "remote" / "results.parquet")
    # the same study on a local cluster in this namespace: identical rows (numbers and keys)
    monkeypatch.chdir(client)
    local = run_study(load_study(study), client / "local", workers=2).rows
    assert len(remote) == len(local) == 8
    for r, lo in zip(remote, local):
        assert r["status"] == lo["status"] == "ok"
        assert r["case_key"] == lo["case_key"]
        assert [r[m] for m in SUMMARY_METRICS] == [lo[m] for m in SUMMARY_METRICS], r["case"]
    assert not any(far.iterdir())  # nothing written where the namespace's processes run
