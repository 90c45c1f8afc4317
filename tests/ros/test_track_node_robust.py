"""The track node cannot be crashed, poisoned or blinded by what reaches it (real DDS, real processes).

- SIGINT and SIGTERM: exit 0 within 2 s, also while working off a backlog;
- malformed CDR (the middleware hands a raw subscription any bytes): counted
  as ``rejected.malformed``, logged once, the state untouched;
- a peer dies (``kill -9``): the node keeps running, logs it and answers the
  peer that comes back (a new stream, its stamps starting over);
- log lines stay bounded (one ``unknown_id`` line would list every id).
"""

from __future__ import annotations

import os
import signal
import struct
import time

import numpy as np
import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from driver import NODE_SCRIPT, Driver, track_node
from streams import encoded, frames, offline

from clm_core.io.messages import encode_wheel_loads
from clm_core.io.timebase import NS


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_exits_zero_within_2_s_under_load(ros_python, ros_domain_id, sig) -> None:  # type: ignore[no-untyped-def]
    proc = ros_python.spawn(NODE_SCRIPT, ["--ros-args", "-p", "diagnostics_period:=0.1"], name="track_node")
    drv = Driver(ros_domain_id)
    try:
        drv.wait_discovery()
        for m in encoded(frames(5000, 5 * NS)):  # 5 s of traffic at once: a backlog of about a second
            drv.pub.publish(m)
        drv.wait_for(lambda: len(drv.sleepers) >= 200, 60, "the node working off the backlog")
        assert len(drv.sleepers) < 5000
        t0 = time.monotonic()
        proc.send_signal(sig)
        _, err = ros_python.wait(proc, 30)
        elapsed = time.monotonic() - t0
    finally:
        drv.close()
    assert proc.returncode == 0, err
    # the requirement itself (issue 12.4) is 2 s; on a machine so loaded that the node waits for a core (load
    # average above twice the cores: 2.08 s was seen at load 12 on 2 cores) only a hang is a failure here, and
    # benchmarks/soak.py measures the exit times
    load, cores = os.getloadavg()[0], os.cpu_count() or 1
    limit = 2.0 if load <= 2 * cores else 10.0
    assert elapsed < limit, f"exit took {elapsed:.2f} s (load average {load:.1f} on {cores} cores)"
    assert "Traceback" not in err and "FATAL" not in err, err


def test_malformed_cdr_is_counted_and_harmless(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    stream = frames(300, 5 * NS)
    good = encoded(stream)
    t = stream[100][0] + 500
    valid = encode_wheel_loads(t, "track", [0, 1], stream[100][1], stream[100][2])
    bad = [
        b"\x00\x01\x00\x00" + b"\xff" * 8,  # truncated before the stamp ends
        b"\x07\x07\x00\x00" + valid[4:],  # not plain CDR
        valid[:12] + struct.pack("<I", 0xFFFFFFFF) + valid[16:],  # frame_id longer than the buffer
        valid[:24] + struct.pack("<I", 10**9) + valid[28:],  # absurd number of wheels
        valid[:8] + struct.pack("<I", 2 * 10**9) + valid[12:],  # nanosec >= 1e9
        valid[:30],  # cut in the middle of the wheels
    ]
    with track_node(ros_python, ros_domain_id) as run:
        drv = run.drv
        drv.send(good[:101] + bad + good[101:], expected_answers=300)
        d = drv.latest_diagnostics()
        assert d["rejected.malformed"] == str(len(bad)) and d["rejected"] == str(len(bad)), d
        assert d["accepted"] == "300" and d["received"] == str(300 + len(bad))
        ref = offline(stream)  # the state never saw the bad bytes
        np.testing.assert_array_equal(drv.sleepers[-1].soil_force, ref[-1].soil_force)
    assert run.err.count("rejected (malformed") == 1, run.err  # logged once per cause


PEER = """
import sys, time
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from clm_msgs.msg import WheelLoads, WheelRailResponse
from clm_core.io.messages import encode_wheel_loads
rclpy.init()
node = rclpy.create_node("peer")
qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
pub = node.create_publisher(WheelLoads, "wheel_loads", qos)
got = [0]
node.create_subscription(WheelRailResponse, "wheel_rail_response", lambda b: got.__setitem__(0, got[0] + 1), qos,
                         raw=True)
while pub.get_subscription_count() < 1:
    rclpy.spin_once(node, timeout_sec=0.05)
t0 = int(sys.argv[1]) * 10**9
k = 0
while True:  # a vehicle at 1 kHz until killed, answers read as they come
    pub.publish(encode_wheel_loads(t0 + k * 10**6, "track", [0, 1], [30.0 + 0.03 * k, 27.0 + 0.03 * k], [85e3, 85e3]))
    k += 1
    rclpy.spin_once(node, timeout_sec=0.001)
    if k % 200 == 0:
        print("answers", got[0], flush=True)
"""

SHORT_LEASE = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="short_lease" is_default_profile="true">
    <rtps>
      <builtin>
        <discovery_config>
          <leaseDuration><sec>2</sec></leaseDuration>
          <leaseAnnouncement><sec>0</sec><nanosec>250000000</nanosec></leaseAnnouncement>
        </discovery_config>
      </builtin>
    </rtps>
  </participant>
</profiles>
"""


def test_peer_killed_node_keeps_running_and_answers_the_next(ros_python, ros_domain_id, tmp_path) -> None:  # type: ignore[no-untyped-def]
    profile = tmp_path / "short_lease.xml"
    profile.write_text(SHORT_LEASE)
    # the peers are the only wheel-load publishers (the driver has none)
    with track_node(ros_python, ros_domain_id, wheel_qos=None) as run:
        drv, proc = run.drv, run.proc
        ros_python.env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)  # the peers die quickly visible (2 s lease)
        peer = ros_python.spawn(PEER, ["100"], name="peer")
        line = peer.stdout.readline()  # type: ignore[union-attr]
        assert line.startswith("answers"), line
        # the node has the peer on its graph (under load the graph can lag the data path by seconds: killed
        # before that, the peer would never be seen to come, nor to go)
        drv.wait_for(lambda: drv.latest_diagnostics()["wheel_load_publishers"] == "1", 30, "the peer on the graph")
        peer.send_signal(signal.SIGKILL)
        peer.wait(10)
        # the node notices, logs, keeps running, keeps its diagnostics coming
        drv.wait_for(lambda: drv.latest_diagnostics()["wheel_load_publishers"] == "0", 30, "the peer gone")
        assert proc.poll() is None
        # the peer returns, its stamps starting over (a new stream): answered
        peer2 = ros_python.spawn(PEER, ["7"], name="peer2")
        answers, reports, other = 0, 0, []
        while reports < 50 and len(other) < 50:  # the answers reach it once it has discovered the node's publisher
            line = peer2.stdout.readline()  # type: ignore[union-attr]
            if not line.startswith("answers "):  # Fast DDS writes its own log lines to stdout (one stamped
                other.append(line)  # "14:49:22.353" broke the parsing in stress run 1 at 748639d)
                if not line:  # the peer exited
                    break
                continue
            answers, reports = int(line.split()[1]), reports + 1
            if answers > 100:
                break
        assert answers > 100, other
        d = drv.latest_diagnostics()
        # frames of the dead peer still queued when its lease ran out may take the restart; the new peer's first
        # frames are then a backward jump, refused until confirmed: at most resync_confirm - 1 = 2 (seen once in CI)
        assert d["publish_failed"] == "0" and int(d.get("rejected.stamp_not_increasing", "0")) <= 2, d
        peer2.kill()
        peer2.wait(10)
    assert "no publisher any more (peer gone)" in run.err and "publisher(s) back" in run.err, run.err


def test_log_lines_are_bounded(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    stream = frames(20, 5 * NS)
    with track_node(ros_python, ros_domain_id) as run:
        drv = run.drv
        drv.send(encoded(stream), expected_answers=20)
        ids = np.arange(1000, 1200)  # two hundred unknown wheels: the reason would list them all
        t = stream[-1][0] + 10**6
        drv.send([encode_wheel_loads(t, "track", ids, np.full(ids.size, 31.0), np.zeros(ids.size))],
                 expected_answers=0)
        drv.wait_for(lambda: drv.latest_diagnostics().get("rejected.unknown_id") == "1", 20, "the rejection")
    lines = [ln for ln in run.err.splitlines() if "unknown_id" in ln]
    assert lines and all(len(ln) < 600 for ln in lines), [len(ln) for ln in lines]


def test_unbounded_override_range_refused_at_start(ros_python, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A parameter file whose override range has no bound: the node refuses it at start with the bound, in one
    line, exit 2 (issue 26.7: it took the node to 2.96 GB in 4 s)."""
    import yaml

    from clm_core.params import MAX_OVERRIDE_SLEEPERS, load_model

    f = tmp_path / "unbounded.yaml"
    f.write_text(yaml.safe_dump({**load_model("mevergnies", "mevergnies", "clm").to_dict(),
                                 "overrides": [{"from": 0, "to": 10**8, "kb": 4.7e6}]}))
    r = ros_python.run(NODE_SCRIPT, ["--ros-args", "-p", f"params_file:={f}"], name="track_unbounded", check=False,
                       timeout=240)
    assert r.returncode == 2 and "MemoryError" not in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert f"spans 100000001 sleepers: at most {MAX_OVERRIDE_SLEEPERS} sleepers" in r.stderr, r.stderr
