"""``clm view``: a real WebSocket client against the relay process, fed by a real publisher process over DDS.

The publisher sends ``clm_msgs/SleeperResponse`` at ~1 kHz on
``/sleeper_response`` with content that is a function of the stamp; ``clm view``
runs as its own process (``python -m clm_core.cli view``, port 0, 100 Hz);
the test speaks the Foxglove WebSocket protocol with the ``websockets``
package, decodes the relayed bytes from the advertised schema alone (a
rosbags type store that starts empty) and checks every value. An rclpy
observer in the test's domain checks the on-demand subscriptions: none on
``/sleeper_response`` before the client subscribes (checked once the relay's
subscription of another channel, made later, has been discovered), one while
it watches, none after it unsubscribes.
"""

from __future__ import annotations

import json
import os
import select
import signal
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("clm_msgs.msg", reason="clm_msgs is not importable from this python; run scripts/bootstrap.sh")
pytest.importorskip("foxglove", reason="foxglove-sdk is not installed (scripts/ros-requirements.txt)")
websockets_sync = pytest.importorskip("websockets.sync.client", reason="websockets is not installed")

from clm_ros.errors import ClmRosError  # noqa: E402
from clm_ros.view import Handoff, Thinner, check_rate, parse_topics  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
TOPIC = "/sleeper_response"
#: What the client offers (the foxglove-sdk server speaks foxglove.sdk.v1; foxglove_bridge foxglove.websocket.v1).
SUBPROTOCOLS: list[Any] = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
RATE = 100.0
N_SLEEPERS = 5
#: Stamp of message k [ns]: 1 ms apart from t = 2 s.
T0_NS = 2_000_000_000

PUBLISHER = """
import sys, time
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from clm_msgs.msg import SleeperResponse

T0_NS, N = int(sys.argv[1]), int(sys.argv[2])
rclpy.init()
node = rclpy.create_node('clm_test_view_publisher')
pub = node.create_publisher(SleeperResponse, '/sleeper_response',
                            QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                                       reliability=ReliabilityPolicy.RELIABLE))
k = 0
def tick():
    global k
    t = T0_NS + k * 1_000_000
    m = SleeperResponse()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(t, 1_000_000_000)
    m.header.frame_id = 'line'
    m.sleeper_index = [k + i for i in range(N)]
    m.position = [0.6 * (k + i) for i in range(N)]
    m.soil_force = [1000.0 * k + i for i in range(N)]
    m.rail_deflection = [1e-6 * k + 1e-9 * i for i in range(N)]
    m.sleeper_displacement = [-float(i) for i in range(N)]
    m.area_displacement = [float(k % 7) for i in range(N)]
    pub.publish(m)
    k += 1
node.create_timer(0.001, tick)
print('publishing', flush=True)
rclpy.spin(node)
"""


def test_parse_topics_and_rate() -> None:
    """Defaults, a typed extra topic, and refusals with the option and the value."""
    assert list(parse_topics(None))[:3] == ["/wheel_loads", "/sleeper_response", "/wheel_rail_response"]
    assert parse_topics(["sleeper_response", "/clock:rosgraph_msgs/msg/Clock"]) == {
        "/sleeper_response": "clm_msgs/msg/SleeperResponse", "/clock": "rosgraph_msgs/msg/Clock"}
    with pytest.raises(ClmRosError, match="'/foo'.*give its type"):
        parse_topics(["/foo"])
    with pytest.raises(ClmRosError, match="not of the form"):
        parse_topics(["/foo:Bar"])
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ClmRosError, match="--rate"):
            check_rate(bad)


def test_layout_topics_are_offered() -> None:
    """Every topic a panel of the shipped layout (config/foxglove_demo.json) shows is a channel of clm view."""
    from clm_ros.view import DEFAULT_TOPICS

    layout = json.loads((REPO / "ros2_ws" / "src" / "clm_ros" / "config" / "foxglove_demo.json").read_text())
    shown: set[str] = set()
    for cfg in layout["configById"].values():
        shown |= {p["value"].partition(".")[0] for p in cfg.get("paths", [])}
        shown |= set(cfg.get("topics", {}))
        shown |= {cfg[k] for k in ("topicToRender", "topicPath") if k in cfg}
    assert shown and shown <= set(DEFAULT_TOPICS), shown - set(DEFAULT_TOPICS)
    assert "/sleeper_response" in DEFAULT_TOPICS and len(DEFAULT_TOPICS) == 6


def test_thinner_and_handoff() -> None:
    """The first message of each period is kept; a restart is kept; the handoff drops its oldest when full."""
    th = Thinner(100.0)
    kept = [t for t in range(0, 50_000_000, 1_000_000) if th.keep(t)]
    assert kept == [0, 10_000_000, 20_000_000, 30_000_000, 40_000_000]
    assert th.keep(5_000_000)  # back in time: a new stream
    assert not th.keep(6_000_000)
    assert all(Thinner(0.0).keep(t) for t in (5, 5, 5))
    h = Handoff(3)
    assert [h.put((i,)) for i in range(5)] == [None, None, None, (0,), (1,)]
    assert h.take(0.0) == [(2,), (3,), (4,)]
    assert h.take(0.0) == []


class _Observer:
    """An rclpy node of the test in the relay's domain: counts the subscriptions of a topic on the graph."""

    def __init__(self, domain_id: int) -> None:
        import rclpy
        from rclpy.context import Context

        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = rclpy.create_node("clm_test_view_observer", context=self.ctx)

    def subscriptions(self, topic: str) -> int:
        return int(self.node.count_subscribers(topic))

    def wait(self, what: str, cond: Callable[[], bool], timeout: float) -> None:
        end = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > end:
                pytest.fail(f"not within {timeout} s: {what}")
            time.sleep(0.02)

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def _read_line(proc: subprocess.Popen[str], timeout: float) -> str:
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    if not ready:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"clm view printed nothing within {timeout} s\n--- stdout\n{out}\n--- stderr\n{err}")
    return proc.stdout.readline()


def _recv_json(ws: Any, op: str, timeout: float) -> dict[str, Any]:
    """The next JSON message with ``op`` (other JSON and binary frames are skipped)."""
    end = time.monotonic() + timeout
    while True:
        left = end - time.monotonic()
        if left <= 0:
            pytest.fail(f"no {op!r} message from the server within {timeout} s")
        frame = ws.recv(timeout=left)
        if isinstance(frame, str):
            msg: dict[str, Any] = json.loads(frame)
            if msg.get("op") == op:
                return msg


def _fail(what: str, *procs: subprocess.Popen[str]) -> None:
    """Fail the test with the output of ``procs`` (killed first)."""
    text = [what]
    for p in procs:
        p.send_signal(signal.SIGINT)
        try:
            out, err = p.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            out, err = p.communicate()
        text.append(f"--- {p.args!r} exit {p.returncode}\n{out}\n{err}")
    pytest.fail("\n".join(text))


def _typestore_from_schema(name: str, text: str) -> Any:
    """A rosbags type store that knows only what the advertised schema text says."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.EMPTY)
    ts.register(get_types_from_msg(text, name))
    return ts


def test_view_relays_on_demand(ros_python: Any, ros_env: dict[str, str], ros_domain_id: int, tmp_path: Path) -> None:
    """Subscribe, receive thinned messages decoded from the schema alone, unsubscribe; subscriptions on demand."""
    import numpy as np

    publisher = ros_python.spawn(PUBLISHER, [str(T0_NS), str(N_SLEEPERS)], name="publisher")
    stats = tmp_path / "view_stats.json"
    view = subprocess.Popen(
        [sys.executable, "-m", "clm_core.cli", "view", "--domain", str(ros_domain_id), "--port", "0",
         "--rate", str(RATE), "--log-period", "0", "--stats", str(stats)],
        env=ros_env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ros_python.procs.append(view)
    first = _read_line(view, 60.0)
    assert "ws://127.0.0.1:" in first, first
    port = int(first.split("ws://127.0.0.1:")[1].split(" ")[0])
    obs = _Observer(ros_domain_id)
    received: list[tuple[int, Any]] = []
    try:
        with websockets_sync.connect(f"ws://127.0.0.1:{port}",
                                     subprotocols=SUBPROTOCOLS,
                                     max_size=None) as ws:
            assert ws.subprotocol == "foxglove.sdk.v1"  # the only one foxglove-sdk accepts (HTTP 400 for the other)
            channels: dict[str, dict[str, Any]] = {}
            end = time.monotonic() + 30
            while len(channels) < 6 and time.monotonic() < end:
                for ch in _recv_json(ws, "advertise", 30)["channels"]:
                    channels[ch["topic"]] = ch
            assert set(channels) == set(parse_topics(None))
            ch = channels[TOPIC]
            assert (ch["encoding"], ch["schemaEncoding"], ch["schemaName"]) == (
                "cdr", "ros2msg", "clm_msgs/msg/SleeperResponse")

            # another channel first: once its subscription is on the graph, one on TOPIC made before would be too
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 7, "channelId": channels["/diagnostics"]["id"]}]}))
            obs.wait("the relay's /diagnostics subscription", lambda: obs.subscriptions("/diagnostics") >= 1,
                     ros_python.discovery_timeout)
            assert obs.subscriptions(TOPIC) == 0, "a ROS subscription exists before any client watches"

            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": ch["id"]}]}))
            obs.wait("the relay's subscription of /sleeper_response", lambda: obs.subscriptions(TOPIC) == 1,
                     ros_python.discovery_timeout)
            ts = _typestore_from_schema(ch["schemaName"], ch["schema"])
            end = time.monotonic() + 60
            while len(received) < 30:
                if time.monotonic() > end or publisher.poll() is not None:
                    _fail(f"{len(received)} messages relayed", publisher, view)
                try:
                    frame = ws.recv(timeout=1.0)
                except TimeoutError:
                    continue
                if isinstance(frame, bytes):
                    assert frame[0] == 0x01  # MessageData
                    sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
                    assert sub_id == 1
                    received.append((log_time, ts.deserialize_cdr(frame[13:], ch["schemaName"])))

            ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [1]}))
            obs.wait("no subscription of /sleeper_response after the client left it",
                     lambda: obs.subscriptions(TOPIC) == 0, ros_python.discovery_timeout)
            assert obs.subscriptions("/diagnostics") >= 1  # the relay is alive: only the unwatched one went
    finally:
        obs.close()
    view.send_signal(signal.SIGINT)
    out, err = view.communicate(timeout=30)
    assert view.returncode == 0, f"--- stdout\n{out}\n--- stderr\n{err}"
    assert f"at exit: {TOPIC}:" in out, out

    periods = set()
    for _log_time, m in received:
        t = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        k, rest = divmod(t - T0_NS, 1_000_000)
        assert rest == 0 and k >= 0
        i = np.arange(N_SLEEPERS)
        assert m.header.frame_id == "line"
        np.testing.assert_array_equal(m.sleeper_index, k + i)
        np.testing.assert_array_equal(m.position, 0.6 * (k + i))
        np.testing.assert_array_equal(m.soil_force, 1000.0 * k + i)
        np.testing.assert_array_equal(m.rail_deflection, 1e-6 * k + 1e-9 * i)
        np.testing.assert_array_equal(m.sleeper_displacement, -i.astype(float))
        np.testing.assert_array_equal(m.area_displacement, np.full(N_SLEEPERS, float(k % 7)))
        period = t // int(1e9 / RATE)
        assert period not in periods, "two messages of one 10-ms period relayed"
        periods.add(period)

    counts = json.loads(stats.read_text())["counts"][TOPIC]
    assert counts["subscribed"] == 1
    assert counts["relayed"] >= len(received)
    assert counts["received"] == counts["relayed"] + counts["thinned"] + counts["dropped"]
    assert counts["thinned"] >= counts["relayed"]  # ~1 kHz taken, 100 Hz kept
    assert os.path.getsize(stats) > 0


def test_demo_with_view(tmp_path: Path) -> None:
    """``clm demo --view 0``: the viewer starts in the demo's domain, serves, and stops with the demo (exit 0)."""
    from clm_ros.processes import hold_domain_id, ros_env

    for attempt in range(3):  # a free domain for the demo to hold itself; taken by another run meanwhile: another
        with hold_domain_id() as dom:
            pass
        proc = subprocess.run(
            [sys.executable, "-m", "clm_core.cli", "demo", "--out", str(tmp_path / f"demo{attempt}"), "--duration",
             "0.2", "--domain", str(dom), "--view", "0"],
            env=ros_env(dom), stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
        if f"ROS domain {dom} is in use" not in proc.stderr:
            break
    assert proc.returncode == 0, f"--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}"
    assert "clm view: Foxglove WebSocket server on ws://127.0.0.1:" in proc.stdout
    assert f"(ROS domain {dom}," in proc.stdout
    assert "clm view: at exit:" in proc.stdout, proc.stdout
