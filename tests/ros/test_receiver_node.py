"""The receiver node over real DDS: its published velocities equal the offline computation on the same forces.

Two real processes in this test's own domain (tests/ros/conftest.py): the
receiver node (console entry ``clm_ros.receiver_node``) and a snippet that
publishes ``sleeper_response`` frames (a moving 61-sleeper window with an
85 kN moving load, 500 Hz, paced) and records ``receiver_velocities``. The
test computes :func:`clm_core.freefield.receiver_velocity` on the same frames
and compares every published sample (<= 1e-9 of the peak) and its stamp.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from clm_core.freefield import FreeFieldModel, receiver_velocity
from clm_core.params import model_from_settings
from clm_core.profile import load_profile
from clm_core.synthetic.window import moving_window_forces
from tests.ros.conftest import RosPython

N_FRAMES, DT, N_WIN = 600, 0.002, 61

PUBLISHER = r'''
import json, sys, time
import numpy as np
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from builtin_interfaces.msg import Time
from clm_msgs.msg import ReceiverVelocities, SleeperResponse
from clm_core.synthetic.window import moving_window_forces

n, dt, N = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
rclpy.init()
node = rclpy.create_node("receiver_test_driver")
qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
got = []
node.create_subscription(ReceiverVelocities, "receiver_velocities",
                         lambda m: got.append([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec,
                                               list(m.velocity), list(m.y)]), qos)
pub = node.create_publisher(SleeperResponse, "sleeper_response", qos)
deadline = time.monotonic() + 60
while (pub.get_subscription_count() == 0 or node.count_publishers("receiver_velocities") == 0):
    rclpy.spin_once(node, timeout_sec=0.1)
    if time.monotonic() > deadline:
        sys.exit("no receiver node")
time.sleep(1.0)
ts, firsts, Fs = moving_window_forces(n, dt, 40.0, N, 0.6, -6.0)
for i in range(n):
    t, first, F = float(ts[i]), int(firsts[i]), Fs[i]
    xs = (first + np.arange(N)) * 0.6
    m = SleeperResponse()
    ns = int(round(t * 1e9))
    m.header.stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
    m.sleeper_index = [int(j) for j in first + np.arange(N)]
    m.position = [float(v) for v in xs]
    m.soil_force = [float(v) for v in F]
    for name in ("rail_deflection", "sleeper_displacement", "area_displacement"):
        setattr(m, name, [0.0] * N)
    pub.publish(m)
    rclpy.spin_once(node, timeout_sec=0.0)
    time.sleep(dt)
expected = int(sys.argv[4])
deadline = time.monotonic() + 60
while len(got) < expected and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
print(json.dumps(got))
node.destroy_node()
rclpy.shutdown()
'''


def _frames() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return moving_window_forces(N_FRAMES, DT, 40.0, N_WIN, 0.6, -6.0)


def test_receiver_node_equals_offline(ros_python: RosPython) -> None:
    params = model_from_settings("mevergnies", "mevergnies", "clm", None, {})
    model = FreeFieldModel(load_profile("mevergnies"), [[0.0, 8.0], [0.0, 16.0]], params.track.spacing, DT,
                           contact_length=params.track.contact_length, contact_width=params.track.contact_width,
                           influence_length=12.0)
    t, first, F = _frames()
    off = receiver_velocity(model, t, first, F)
    node = subprocess.Popen(
        [sys.executable, "-m", "clm_ros.receiver_node", "--ros-args", "-p", "receivers:=8,16", "-p",
         "receiver_influence:=12.0", "-p", "rate:=500.0"],
        env=ros_python.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ros_python.procs.append(node)  # killed at teardown if still running
    res = ros_python.run(PUBLISHER, [str(N_FRAMES), str(DT), str(N_WIN), str(off.t.size)], name="driver",
                         timeout=300.0)
    got = json.loads(res.stdout.strip().splitlines()[-1])
    node.terminate()
    out, err = node.communicate(timeout=30)
    assert node.returncode == 0, err
    assert len(got) == off.t.size, f"{len(got)} samples published, {off.t.size} expected\n{err}"
    ts = np.array([g[0] for g in got])
    v = np.array([g[1] for g in got]).T
    np.testing.assert_allclose(ts, off.t, rtol=0, atol=1e-9)
    assert all(g[2] == [8.0, 16.0] for g in got)
    peak = float(np.max(np.abs(off.velocity)))
    assert peak > 1e-5
    assert float(np.max(np.abs(v - off.velocity))) <= 1e-9 * peak
    assert "restart" not in err  # no frame was lost or refused
