"""Stale Fast DDS shared-memory ports after a kill -9, removed at start (issue 26, item 3).

A process killed with SIGKILL could leave a shared-memory port of its domain
locked (``/dev/shm/fastrtps_port<N>``): afterwards every 4th new process of
that domain hung at start. Each node removes, before its participant exists,
the ports of its own domain that no live process maps (:mod:`clm_ros.shm`):

- in ``/dev/shm``, planted files: the stale port of the domain is removed,
  a port of another domain, a port a live process maps and a port just
  created are kept;
- over DDS: a node killed with SIGKILL leaves its ports behind; 8 node
  processes started at once in that domain remove them, every one comes up
  (seen in the graph) and exits 0 on SIGTERM.
"""

from __future__ import annotations

import mmap
import os
import signal
import time
from pathlib import Path

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clientnode import ClientNode
from clm_ros.shm import DOMAIN_GAIN, PORT_BASE, SHM_DIR, STALE_AGE, clean_stale_ports, port_files

from tests.clitools import wait_or_stacks

TRACK_NODE = "import sys\nfrom clm_ros.track_node import main\nsys.exit(main(sys.argv))\n"
STARTS = 8
START_TIMEOUT = 240.0  # 8 node processes starting at once on a loaded 2-core machine [s]

pytestmark = pytest.mark.skipif(not SHM_DIR.is_dir(), reason="no /dev/shm on this machine")


def _plant(port: int, age: float) -> list[Path]:
    files = [SHM_DIR / f"fastrtps_port{port}", SHM_DIR / f"fastrtps_port{port}_el",
             SHM_DIR / f"sem.fastrtps_port{port}_mutex"]
    for f in files:
        f.write_bytes(b"\0" * 4096)
        os.utime(f, (time.time() - age, time.time() - age))  # (ctime cannot be set: age checked below)
    return files


def test_only_stale_ports_of_the_domain_are_removed(ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    base = PORT_BASE + DOMAIN_GAIN * ros_domain_id
    other_domain = (ros_domain_id + 1) % 233
    time.sleep(STALE_AGE)
    clean_stale_ports(ros_domain_id)  # what earlier processes of this domain left (stale: removed, never ours)
    stale = _plant(base + 201, 0)
    mapped = _plant(base + 203, 0)
    foreign = _plant(PORT_BASE + DOMAIN_GAIN * other_domain + 205, 0)
    try:
        assert clean_stale_ports(ros_domain_id) == []  # just created: never taken for stale
        time.sleep(STALE_AGE + 0.1)
        fresh = _plant(base + 207, 0)
        with open(mapped[0], "r+b") as fh, mmap.mmap(fh.fileno(), 4096):
            removed = clean_stale_ports(ros_domain_id)
        assert removed == sorted(f.name for f in stale), removed
        assert all(f.exists() for f in mapped + foreign + fresh) and not any(f.exists() for f in stale)
        assert set(port_files(ros_domain_id)) >= {base + 203, base + 207}
    finally:
        for f in stale + mapped + foreign + locals().get("fresh", []):
            f.unlink(missing_ok=True)


def _identities(domain_id: int) -> set[tuple[str, int]]:
    """(name, inode) of the domain's port files now: a file removed and created anew is another one."""
    out = set()
    for files in port_files(domain_id).values():
        for f in files:
            try:
                out.add((f.name, f.stat().st_ino))
            except OSError:  # removed meanwhile
                continue
    return out


def test_kill9_then_8_starts_none_hangs(ros_python, ros_domain_id, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    victim = ros_python.spawn(TRACK_NODE, ["--ros-args", "-r", "__node:=victim"], name="victim")
    deadline = time.monotonic() + START_TIMEOUT
    while not port_files(ros_domain_id) and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(2.0)  # the victim in its stride: discovery and diagnostics on its ports
    victim.kill()
    victim.wait(10)
    left = _identities(ros_domain_id)
    print(f"left behind by the kill -9: {sorted(name for name, _ in left)}")
    assert left, "the killed node left no shared-memory port (nothing to test)"
    procs = [ros_python.spawn(TRACK_NODE, ["--ros-args", "-r", f"__node:=n{k}", "-p", "autostart:=false"],
                              name=f"node{k}") for k in range(STARTS)]
    # the new nodes remove the stale files before they open the domain's ports (the test's participant joins after)
    while left & _identities(ros_domain_id):  # (a new node may create a port of the same name: a new file)
        assert time.monotonic() < deadline + START_TIMEOUT, "the stale files were never removed"
        assert all(p.poll() is None for p in procs), [p.communicate() for p in procs if p.poll() is not None]
        time.sleep(0.2)
    client = ClientNode(ros_domain_id, procs, "clm_test_shm_client", timeout=START_TIMEOUT)
    try:
        names = {f"n{k}" for k in range(STARTS)}
        t0 = time.monotonic()
        client.wait_for(lambda: names <= set(client.node.get_node_names()), f"all {STARTS} nodes in the graph")
        print(f"{STARTS} nodes up {time.monotonic() - t0:.1f} s after the stale files went")
    finally:
        client.close()
    errs = []
    for p in procs:
        p.send_signal(signal.SIGTERM)
    for k, p in enumerate(procs):
        _, err = wait_or_stacks(p, 60, f"node {k} after SIGTERM")  # hung: its threads' stacks in the failure
        assert p.returncode == 0, err
        errs.append(err)
    assert any("stale Fast DDS shared-memory file(s) of domain" in e for e in errs)
