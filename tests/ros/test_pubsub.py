"""WheelLoads over DDS between two real processes (loopback, own domain).

A publisher process sends N messages at a few hundred Hz once it has
discovered the subscriber (``get_subscription_count()``, no fixed sleeps);
a subscriber process counts them and checks every field against the
deterministic content the publisher generates. Reliable, keep-all QoS:
every message sent must arrive, in order.
"""

from __future__ import annotations

import json
from typing import Any

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip(
    "clm_msgs.msg",
    reason="clm_msgs is not importable from this python; build it with "
    "`bash scripts/setup_ros.sh VENV` (ROS 2 Jazzy wheels + interface package)",
)

from typing import TYPE_CHECKING  # noqa: E402

if TYPE_CHECKING:
    from collections.abc import Callable

    from conftest import RosPython

N_MESSAGES = 600
RATE_HZ = 300.0
N_WHEELS = 4
TOPIC = "/clm_test/wheel_loads"

# Content of message k, wheel i (shared by both snippets). Speed of wheel 2
# is NaN ("unknown") to check that NaN survives the middleware.
CONTENT = """
import math

def expected(k, i):
    return dict(
        id=100 + i,
        position=10.0 + 0.01 * k + 2.5 * i,
        force=1.0e5 + k + 0.25 * i,
        speed=math.nan if i == 2 else 30.0 + 0.001 * k,
    )
"""

PUBLISHER = (
    CONTENT
    + """
import json, sys, time
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from clm_msgs.msg import WheelLoad, WheelLoads

topic, n, rate, n_wheels, discovery_timeout = (
    sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]))
rclpy.init()
try:
    node = rclpy.create_node('clm_test_publisher')
    qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(WheelLoads, topic, qos)

    # Wait for discovery of the subscriber: never a fixed sleep.
    t0 = time.monotonic()
    while pub.get_subscription_count() < 1:
        if time.monotonic() - t0 > discovery_timeout:
            print(json.dumps({'error': 'no subscriber discovered', 'after_s': discovery_timeout}))
            sys.exit(3)
        rclpy.spin_once(node, timeout_sec=0.01)
    discovery_s = time.monotonic() - t0

    sent = 0
    def publish():
        global sent
        if sent >= n:
            return
        msg = WheelLoads()
        msg.header.stamp.sec = sent
        msg.header.stamp.nanosec = 1000 * sent
        msg.header.frame_id = 'line_%d' % sent
        msg.wheels = [WheelLoad(**expected(sent, i)) for i in range(n_wheels)]
        pub.publish(msg)
        sent += 1

    timer = node.create_timer(1.0 / rate, publish)
    t1 = time.monotonic()
    while sent < n:
        rclpy.spin_once(node, timeout_sec=1.0)
    publish_s = time.monotonic() - t1
    all_acked = pub.wait_for_all_acked(rclpy.duration.Duration(seconds=20.0))
    print(json.dumps({'sent': sent, 'discovery_s': discovery_s, 'publish_s': publish_s,
                      'all_acked': all_acked}))
finally:
    rclpy.try_shutdown()
"""
)

SUBSCRIBER = (
    CONTENT
    + """
import json, math, sys, time
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from clm_msgs.msg import WheelLoads

topic, n, n_wheels, timeout = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
received = 0
errors = []

def same(a, b):
    return (math.isnan(a) and math.isnan(b)) or a == b

def on_msg(msg):
    global received
    k = received  # reliable keep-all: messages arrive in order
    if msg.header.stamp.sec != k or msg.header.stamp.nanosec != 1000 * k:
        errors.append('msg %d: stamp %d.%09d' % (k, msg.header.stamp.sec, msg.header.stamp.nanosec))
    if msg.header.frame_id != 'line_%d' % k:
        errors.append('msg %d: frame_id %r' % (k, msg.header.frame_id))
    if len(msg.wheels) != n_wheels:
        errors.append('msg %d: %d wheels' % (k, len(msg.wheels)))
    for i, w in enumerate(msg.wheels):
        want = expected(k, i)
        for field, value in want.items():
            if not same(getattr(w, field), value):
                got = getattr(w, field)
                errors.append('msg %d wheel %d: %s=%r, want %r' % (k, i, field, got, value))
    received += 1

rclpy.init()
try:
    node = rclpy.create_node('clm_test_subscriber')
    qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(WheelLoads, topic, on_msg, qos)
    print('READY', flush=True)
    deadline = time.monotonic() + timeout
    while received < n and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    # Anything beyond n would be a duplicate: give it a short chance to show.
    end = time.monotonic() + 0.2
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    print(json.dumps({'received': received, 'errors': errors[:20], 'n_errors': len(errors)}))
finally:
    rclpy.try_shutdown()
"""
)


def _last_json(out: str) -> dict[str, Any]:
    lines = [line for line in out.splitlines() if line.startswith("{")]
    assert lines, f"no JSON summary in output:\n{out}"
    result: dict[str, Any] = json.loads(lines[-1])
    return result


def test_wheel_loads_between_two_processes(ros_python: RosPython) -> None:
    discovery = ros_python.discovery_timeout
    timeout = discovery + N_MESSAGES / RATE_HZ + 30.0
    sub = ros_python.spawn(SUBSCRIBER, [TOPIC, str(N_MESSAGES), str(N_WHEELS), str(timeout)], name="subscriber")
    pub = ros_python.run(
        PUBLISHER,
        [TOPIC, str(N_MESSAGES), str(RATE_HZ), str(N_WHEELS), str(discovery)],
        name="publisher",
        timeout=timeout + 10.0,
        check=False,
    )
    sub_out, sub_err = ros_python.wait(sub, timeout + 10.0)
    report = (
        f"--- publisher (rc={pub.returncode})\n{pub.stdout}{pub.stderr}"
        f"--- subscriber (rc={sub.returncode})\n{sub_out}{sub_err}"
    )
    assert pub.returncode == 0, report
    assert sub.returncode == 0, report

    sent = _last_json(pub.stdout)
    got = _last_json(sub_out)
    assert sent["sent"] == N_MESSAGES, report
    assert sent["all_acked"], report
    assert got["n_errors"] == 0, report
    assert got["received"] == sent["sent"], report


def test_domains_are_isolated(ros_python: RosPython, new_ros_python: Callable[[], RosPython]) -> None:
    """A subscriber in another domain is not discovered and receives nothing."""
    other = new_ros_python()
    assert other.domain_id != ros_python.domain_id
    sub = other.spawn(SUBSCRIBER, [TOPIC, "1", str(N_WHEELS), "4.0"], name="foreign_subscriber")
    # The publisher must not discover the foreign subscriber: it gives up (exit 3).
    pub = ros_python.run(
        PUBLISHER,
        [TOPIC, "1", str(RATE_HZ), str(N_WHEELS), "3.0"],
        name="publisher",
        timeout=60.0,
        check=False,
    )
    assert pub.returncode == 3, pub.stdout + pub.stderr
    out, err = other.wait(sub, 60.0)
    assert sub.returncode == 0, out + err
    assert _last_json(out)["received"] == 0, out + err
