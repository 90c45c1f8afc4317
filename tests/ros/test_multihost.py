"""A fleet across two hosts: two network namespaces joined by a veth pair, one train in each, a listener across.

The test makes the two "hosts" itself (``ip netns``, a veth pair with
addresses of a private /24 that exist only inside the two namespaces) and
removes them at the end; it is skipped, saying why, where ``ip netns`` is
refused (no root, no CAP_NET_ADMIN, a container without it). In each
namespace ``clm fleet`` runs one train with discovery on the subnet
(``--discovery-range SUBNET``): ``/train_0`` on host A, ``/train_1`` on
host B, both joining one ROS graph in one domain (``--join-domain``: the
domain lock is a choice; the test holds the domain with its fixture). On
each host a listener also subscribes to the *other* host's wheel loads:
before issue 21 such a reader let a vehicle start before its own track node
had matched it (in != out). Checked: both fleets exit 0 with in = out and
answers equal to the offline replay, each trains's vehicle waited for its own
track node, and each listener received the other host's wheel loads over the
veth.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from tests.clitools import CLM

DURATION = 1.0
N_MSG = round(DURATION * 1000) + 1
#: The two hosts' addresses on the veth (a private /24 that exists only inside the test's namespaces).
ADDRESSES = ("10.231.21.1", "10.231.21.2")

#: Counts the wheel loads of ``sys.argv[1]`` until SIGINT, then prints the count (a tool on the other host).
LISTENER = """
import signal, sys
import rclpy
from clm_msgs.msg import WheelLoads
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
rclpy.init()
node = rclpy.create_node("clm_test_listener")
count = [0]
node.create_subscription(WheelLoads, sys.argv[1], lambda _m: count.__setitem__(0, count[0] + 1),
                         QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                                    reliability=ReliabilityPolicy.RELIABLE), raw=True)
stop = []
signal.signal(signal.SIGINT, lambda *_: stop.append(1))
print("listening", flush=True)
while not stop:
    rclpy.spin_once(node, timeout_sec=0.05)
print(f"count {count[0]}", flush=True)
"""


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)


@pytest.fixture
def two_hosts() -> Iterator[tuple[str, str]]:
    """Two network namespaces joined by a veth pair (created here, removed at teardown): their names."""
    tag = f"{os.getpid() % 100000}"
    hosts = (f"clm_a{tag}", f"clm_b{tag}")
    made: list[str] = []
    try:
        for h in hosts:
            r = _ip("netns", "add", h)
            if r.returncode != 0:
                pytest.skip(f"ip netns refused here ({r.stderr.strip()}): the multi-host test needs root or "
                            "CAP_NET_ADMIN")
            made.append(h)
        links = (f"clmva{tag}", f"clmvb{tag}")
        steps = [("link", "add", links[0], "type", "veth", "peer", "name", links[1])]
        for h, link, addr in zip(hosts, links, ADDRESSES):
            steps += [("link", "set", link, "netns", h), ("-n", h, "addr", "add", f"{addr}/24", "dev", link),
                      ("-n", h, "link", "set", link, "up"), ("-n", h, "link", "set", "lo", "up"),
                      ("-n", h, "route", "add", "224.0.0.0/4", "dev", link)]  # DDS discovery's multicast
        for step in steps:
            r = _ip(*step)
            assert r.returncode == 0, f"ip {' '.join(step)}: {r.stderr}"
        yield hosts
    finally:
        for h in made:
            _ip("netns", "del", h)  # removes the veth pair with it


def test_fleet_across_two_hosts_in_equals_out(two_hosts: tuple[str, str], ros_domain_id: int,
                                              ros_env: dict[str, str], tmp_path: Path) -> None:
    env = {**ros_env, "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}
    procs: list[subprocess.Popen[str]] = []
    try:
        listeners = []
        for host, other in zip(two_hosts, ("/train_1", "/train_0")):
            p = subprocess.Popen(["ip", "netns", "exec", host, sys.executable, "-c", LISTENER,
                                  f"{other}/wheel_loads"], env=env, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
            procs.append(p)
            listeners.append(p)
        for p in listeners:
            assert p.stdout is not None and p.stdout.readline().strip() == "listening", p.communicate()
        fleets = []
        for i, host in enumerate(two_hosts):
            p = subprocess.Popen(
                ["ip", "netns", "exec", host, *CLM, "fleet", "--trains", "1", "--first-index", str(i),
                 "--duration", str(DURATION), "--domain", str(ros_domain_id), "--join-domain",
                 "--discovery-range", "SUBNET", "--out", str(tmp_path / f"host{i}")],
                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            procs.append(p)
            fleets.append(p)
        results = [p.communicate(timeout=400) for p in fleets]
        for p in listeners:
            p.send_signal(signal.SIGINT)
        heard = [p.communicate(timeout=60)[0] for p in listeners]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    for i, (p, (out, err)) in enumerate(zip(fleets, results)):
        assert p.returncode == 0, f"host {i}: exit {p.returncode}\n{out}\n{err}"
        s = json.loads((tmp_path / f"host{i}" / "summary.json").read_text())
        t = s["trains"][f"train_{i}"]
        assert s["discovery_range"] == "SUBNET" and t["status"] == "ok" and s["supervisor_transport"] == "UDP"
        assert t["messages_in"] == t["messages_out"] == t["wheel_rail_responses"] == N_MSG and t["in_equals_out"]
        assert t["offline_equal"] and t["vehicle_node"]["published"] == t["vehicle_node"]["answered"] == N_MSG
        log = (tmp_path / f"host{i}" / f"train_{i}_vehicle_node.log").read_text()
        assert "train 1 starts" in log
    # each host's listener heard the other host's train over the veth (it joined the graph across hosts)
    for text in heard:
        count = int(text.strip().splitlines()[-1].split()[1])
        assert 0 < count <= N_MSG, text
