"""``clm record`` / ``clm play`` over real DDS: recorded QoS profiles, damaged bags, a topic of the wrong type.

- the recorder stores what each topic's publishers offer (as ``ros2 bag
  record`` does) and the bag appears only when recording stops;
- ``clm play`` of a damaged bag fails before publishing anything and names
  the damaged chunk; with ``--allow-partial`` it publishes what is readable;
- a bag whose ``/wheel_loads`` is ``std_msgs/String`` against a WheelLoads
  subscriber fails at once naming both types (it used to wait 20 s for a
  subscriber that can never match).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clm_core.io import messages as msgs  # noqa: E402
from clm_core.io.bags import BagReader, BagWriter  # noqa: E402
from clm_core.io.timebase import NS  # noqa: E402

T0 = 1_700_000_000 * NS


def _wheel_bag(path: Path, n: int) -> Path:
    import numpy as np

    with BagWriter(path) as w:
        c = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
        c_s = w.add_topic("/sleeper_response", msgs.SLEEPER_RESPONSE)
        for k in range(n):
            t = T0 + k * 1_000_000
            w.write(c, t, msgs.encode_wheel_loads(t, "track", [0, 1], [1.0 + k, k], [8e4, 8e4]))
            w.write(c_s, t, msgs.encode_sleeper_response(t, "track", np.arange(61), *[np.zeros(61)] * 5))
    return path


def _zero_middle(bag: Path) -> None:
    f = next(bag.glob("*.mcap"))
    data = bytearray(f.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 4096] = bytes(4096)
    f.write_bytes(bytes(data))


def _node(domain_id: int, name: str) -> tuple[Any, Any]:
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    return ctx, rclpy.create_node(name, context=ctx)


def _spin_until(node: Any, done: Any, timeout: float) -> None:
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    t0 = time.monotonic()
    try:
        while not done() and time.monotonic() - t0 < timeout:
            ex.spin_once(timeout_sec=0.05)
    finally:
        ex.remove_node(node)
        ex.shutdown()


def test_recorder_stores_the_offered_qos(ros_domain_id: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import rclpy
    from clm_msgs.msg import WheelLoads
    from clm_ros.bag_tools import BagRecorder
    from rclpy.qos import DurabilityPolicy, QoSProfile

    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    ctx, node = _node(ros_domain_id, "qos_recorder")
    try:
        pub = node.create_publisher(WheelLoads, "/wheel_loads", QoSProfile(depth=5,
                                                                         durability=DurabilityPolicy.TRANSIENT_LOCAL))
        rec = BagRecorder(node, tmp_path / "rec", {"/wheel_loads": msgs.WHEEL_LOADS,
                                                   "/sleeper_response": msgs.SLEEPER_RESPONSE})
        _spin_until(node, lambda: pub.get_subscription_count() > 0, 20)
        for k in range(5):
            m = WheelLoads()
            m.header.stamp.sec = k
            pub.publish(m)
        _spin_until(node, lambda: rec.counts["/wheel_loads"] >= 5, 20)
        assert not (tmp_path / "rec").exists()  # not before it is complete
        assert rec.close() == {"/wheel_loads": 5, "/sleeper_response": 0}
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    text = (tmp_path / "rec" / "metadata.yaml").read_text()
    assert "ros_distro: jazzy" in text and "version: 9" in text
    with BagReader(tmp_path / "rec") as r:
        (q,) = r.topics["/wheel_loads"].qos
        assert (q.history.name, q.depth, q.reliability.name, q.durability.name) == (
            "UNKNOWN", 0, "RELIABLE", "TRANSIENT_LOCAL")  # what discovery reports, as ros2 bag records it
        assert r.topics["/sleeper_response"].qos == ()  # nobody offered it
        assert [msgs.decode_wheel_loads(m.data).stamp_ns for m in r.messages(["/wheel_loads"])] == [
            k * NS for k in range(5)]


def _play(env: dict[str, str], *args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "clm_core.cli", "play", *args], capture_output=True, text=True,
                          env=env, timeout=timeout)


def test_play_refuses_a_damaged_bag_before_publishing(ros_env: dict[str, str], tmp_path: Path) -> None:
    bag = _wheel_bag(tmp_path / "bag", 3000)
    _zero_middle(bag)
    p = _play(ros_env, str(bag), "--topics", "/wheel_loads", "--rate", "0")
    assert p.returncode == 2 and "is damaged: chunk" in p.stderr and "--allow-partial" in p.stderr, p.stderr
    assert "no subscriber" not in p.stderr  # refused before any discovery wait


def test_play_allow_partial_publishes_what_is_readable(ros_domain_id: int, ros_env: dict[str, str], tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    import rclpy
    from clm_msgs.msg import WheelLoads
    from clm_ros.bag_tools import data_qos

    bag = _wheel_bag(tmp_path / "bag", 3000)
    _zero_middle(bag)
    with BagReader(bag, allow_partial=True) as r:
        readable = sum(1 for _ in r.messages(["/wheel_loads"]))
    assert 0 < readable < 3000
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    ctx, node = _node(ros_domain_id, "partial_listener")
    got: list[int] = []
    try:
        node.create_subscription(WheelLoads, "/wheel_loads", lambda m: got.append(m.header.stamp.sec), data_qos())
        proc = subprocess.Popen([sys.executable, "-m", "clm_core.cli", "play", str(bag), "--topics", "/wheel_loads",
                                 "--rate", "100", "--allow-partial"], env=ros_env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        _spin_until(node, lambda: proc.poll() is not None and len(got) >= readable, 120)
        out, err = proc.communicate(timeout=30)
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert proc.returncode == 0, err
    assert out.strip() == f'{{"/wheel_loads": {readable}}}' and len(got) == readable


def test_play_names_a_topic_of_the_wrong_type(ros_domain_id: int, ros_env: dict[str, str], tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    import rclpy
    from clm_msgs.msg import WheelLoads
    from clm_ros.bag_tools import data_qos

    with BagWriter(tmp_path / "strings") as w:
        c = w.add_topic("/wheel_loads", "std_msgs/msg/String")
        w.write_msg(c, T0, w.typestore.types["std_msgs/msg/String"](data="not a wheel"))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    ctx, node = _node(ros_domain_id, "wheel_listener")
    try:
        node.create_subscription(WheelLoads, "/wheel_loads", lambda m: None, data_qos())
        proc = subprocess.Popen([sys.executable, "-m", "clm_core.cli", "play", str(tmp_path / "strings")],
                                env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _spin_until(node, lambda: proc.poll() is not None, 60)
        _out, err = proc.communicate(timeout=30)
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert proc.returncode == 2, err
    assert ("topic /wheel_loads: the subscribers on the graph use clm_msgs/msg/WheelLoads, not std_msgs/msg/String"
            in err), err
    assert "after 20 s" not in err


def test_record_and_play_agree_on_what_a_bag_is(ros_env: dict[str, str], tmp_path: Path) -> None:
    """A bag directory without metadata.yaml is a bag for play as for replay and calibrate (its one file)."""
    bag = _wheel_bag(tmp_path / "bag", 5)
    (bag / "metadata.yaml").unlink()
    p = _play(ros_env, str(bag), "--topics", "/nothing")
    assert p.returncode == 2 and "none of the topics ['/nothing'] are in it" in p.stderr, p.stderr
    shutil.rmtree(bag)
    p = _play(ros_env, str(bag))
    assert p.returncode == 2 and "not found: the path does not exist" in p.stderr, p.stderr


PUBLISH_BIG = """
import sys, time
import rclpy
from std_msgs.msg import String
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
rclpy.init()
node = rclpy.create_node("big_publisher")
pub = node.create_publisher(String, "/big", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                                                       history=HistoryPolicy.KEEP_LAST))
msg = String(data="x" * 65536)
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    pub.publish(msg)
    rclpy.spin_once(node, timeout_sec=0.005)
"""


@pytest.fixture
def small_disk(tmp_path: Path) -> Any:
    """A 2 MB tmpfs mounted by the test under ``tmp_path`` (skipped where mounting is refused); unmounted after."""
    mnt = tmp_path / "small_disk"
    mnt.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)], capture_output=True,
                          text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs CAP_SYS_ADMIN): {proc.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_record_on_a_full_disk(ros_python, small_disk, storage) -> None:  # type: ignore[no-untyped-def]
    """``clm record`` filling its disk: one line, exit 1, nothing left that looks like a bag (issue 26.5)."""
    ros_python.spawn(PUBLISH_BIG, ["120"], name="big_publisher")
    out = small_disk / "bag"
    proc = subprocess.run([sys.executable, "-m", "clm_core.cli", "record", "/big:std_msgs/msg/String", "--out",
                           str(out), "--storage", storage, "--duration", "90"], env=ros_python.env,
                          capture_output=True, text=True, timeout=300)
    print(proc.stderr.strip()[-400:])
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"clm record: error: writing '{out}' failed after ") and "partial bag was removed" \
        in lines[0], lines
    assert "Traceback" not in proc.stderr and list(small_disk.iterdir()) == [], list(small_disk.iterdir())
