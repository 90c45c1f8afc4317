"""Bag record and play over DDS with ``rosbags`` (``ros2 bag`` is not available here).

- :class:`BagRecorder`: raw (serialized) subscriptions written as they arrive
  to a rosbag2 bag (mcap by default, sqlite3 as an option), reliable
  keep-all QoS so that nothing the publisher sends reliably is lost; the
  bytes are the middleware's own, so the bag plays in a real ``ros2 bag``.
- :func:`play_bag`: publishes a bag's messages (raw bytes) on their topics at
  real time, a scaled rate, or as fast as a subscriber takes them
  (``rate=0``: at most ``max_in_flight`` messages ahead of the responses seen
  on ``ack_topic``).

Console commands: ``clm record`` and ``clm play`` (:mod:`clm_ros.commands`).
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Writer

from clm_ros.errors import ClmRosError
from clm_ros.msg_types import typestore
from clm_ros.replay import open_reader, storage_plugin


def message_class(msgtype: str) -> Any:
    """rclpy class of a type name such as ``clm_msgs/msg/WheelLoads``."""
    try:
        pkg, kind, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        raise ClmRosError(f"message type {msgtype!r} is not importable in this Python") from None


def data_qos(depth: int = 0) -> Any:
    """Reliable QoS; keep-all when ``depth`` is 0."""
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    if depth <= 0:
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE)


class BagRecorder:
    """Record topics of a running ROS graph to a rosbag2 bag.

    Parameters
    ----------
    node : rclpy.node.Node
        Node that owns the subscriptions (spun by the caller).
    path : path
        Output bag directory (must not exist).
    topics : mapping topic -> message type name
        What to record, e.g. ``{'/wheel_loads': 'clm_msgs/msg/WheelLoads'}``.
    storage : {'mcap', 'sqlite3'}
    """

    def __init__(self, node: Any, path: str | Path, topics: dict[str, str], storage: str = "mcap") -> None:
        out = Path(path)
        if out.exists():
            raise ClmRosError(f"output bag {str(out)!r} exists; choose a new path")
        self.ts = typestore()
        self.writer = Writer(out, version=8, storage_plugin=storage_plugin(storage))
        self.writer.open()
        self.counts: dict[str, int] = {}
        self._subs = []
        self._node = node
        for topic, msgtype in topics.items():
            if msgtype not in self.ts.types:
                raise ClmRosError(f"topic {topic}: type {msgtype!r} unknown to the bag type store")
            conn = self.writer.add_connection(topic, msgtype, typestore=self.ts)
            self.counts[topic] = 0
            self._subs.append(
                node.create_subscription(
                    message_class(msgtype), topic, self._callback(topic, conn), data_qos(), raw=True
                )
            )
        self.closed = False

    def _callback(self, topic: str, conn: Any) -> Any:
        def cb(raw: bytes) -> None:
            if self.closed:
                return
            self.writer.write(conn, self._node.get_clock().now().nanoseconds, bytes(raw))
            self.counts[topic] += 1

        return cb

    def close(self) -> dict[str, int]:
        """Stop recording and close the bag; return the message counts per topic."""
        if not self.closed:
            self.closed = True
            for s in self._subs:
                self._node.destroy_subscription(s)
            self.writer.close()
        return dict(self.counts)


def play_bag(
    node: Any,
    path: str | Path,
    topics: Sequence[str] | None = None,
    rate: float = 1.0,
    ack_topic: str | None = None,
    ack_type: str = "clm_msgs/msg/SleeperResponse",
    max_in_flight: int = 20,
    discovery_timeout: float = 20.0,
    idle_timeout: float = 30.0,
    min_subscribers: int = 1,
) -> dict[str, int]:
    """Publish a bag's messages on their topics.

    Parameters
    ----------
    node : rclpy.node.Node
        Node that owns the publishers (this function spins it).
    path : path
        Bag (mcap or sqlite3).
    topics : sequence of str, optional
        Topics to play (default all).
    rate : float
        Speed factor against the bag's timestamps (1: real time); 0: as fast
        as the subscriber takes them (flow control on ``ack_topic``).
    ack_topic : str, optional
        With ``rate=0``: topic on which every played message is answered (the
        track node's ``sleeper_response``); at most ``max_in_flight``
        messages are sent ahead of the answers.
    discovery_timeout : float
        Wait this long for at least one subscriber per topic [s].
    idle_timeout : float
        With flow control: give up when no answer came for this long [s].
    min_subscribers : int
        Subscribers each topic must have before playing starts (count a
        recorder in the same graph too).

    Returns
    -------
    dict topic -> messages published
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    if rate < 0:
        raise ClmRosError(f"rate = {rate}: must be >= 0 (0: as fast as the subscriber takes them)")
    if rate == 0 and not ack_topic:
        raise ClmRosError("rate = 0 needs ack_topic (the topic that answers each message) for flow control")
    acked = [0]
    ack_sub = None
    if rate == 0:
        ack_sub = node.create_subscription(
            message_class(ack_type), ack_topic, lambda _m: acked.__setitem__(0, acked[0] + 1), data_qos()
        )
    sent: dict[str, int] = {}
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    spin = executor.spin_once
    reader = open_reader(path)
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        if not conns:
            raise ClmRosError(f"bag {str(path)!r}: none of the topics {list(topics or [])} are in it")
        pubs = {}
        for c in conns:
            if c.topic not in pubs:
                pubs[c.topic] = node.create_publisher(message_class(c.msgtype), c.topic, data_qos())
                sent[c.topic] = 0
        t0 = time.monotonic()
        while any(p.get_subscription_count() < min_subscribers for p in pubs.values()) or (
            ack_sub is not None and ack_sub.get_publisher_count() < 1
        ):
            if time.monotonic() - t0 > discovery_timeout:
                missing = [t for t, p in pubs.items() if p.get_subscription_count() < min_subscribers]
                if ack_sub is not None and ack_sub.get_publisher_count() < 1:
                    missing.append(f"publisher of {ack_topic}")
                raise ClmRosError(f"no subscriber on {missing} after {discovery_timeout:g} s")
            spin(timeout_sec=0.02)
        start_wall = time.monotonic()
        start_bag: int | None = None
        total = 0
        for conn, bag_t, raw in reader.messages(connections=conns):
            if start_bag is None:
                start_bag = bag_t
            if rate > 0:
                due = start_wall + (bag_t - start_bag) / 1e9 / rate
                while (wait := due - time.monotonic()) > 0:
                    spin(timeout_sec=min(wait, 0.01))
            else:
                last = time.monotonic()
                while total - acked[0] >= max_in_flight:
                    before = acked[0]
                    spin(timeout_sec=0.01)
                    if acked[0] != before:
                        last = time.monotonic()
                    elif time.monotonic() - last > idle_timeout:
                        raise ClmRosError(f"no answer on {ack_topic} for {idle_timeout:g} s ({acked[0]} of {total})")
            pubs[conn.topic].publish(bytes(raw))
            sent[conn.topic] += 1
            total += 1
        for p in pubs.values():
            p.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
    finally:
        reader.close()
        if ack_sub is not None:
            node.destroy_subscription(ack_sub)
        executor.remove_node(node)
        executor.shutdown()
    return sent
