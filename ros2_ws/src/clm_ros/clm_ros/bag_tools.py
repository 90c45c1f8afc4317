"""Bag record and play over DDS with the suite's bag reader and writer (``ros2 bag`` is not available here).

- :class:`BagRecorder`: raw (serialized) subscriptions written as they arrive
  to a rosbag2 bag (mcap by default, sqlite3 as an option) by
  :class:`clm_core.io.bags.BagWriter`, reliable keep-all QoS so that nothing
  the publisher sends reliably is lost; the bytes are the middleware's own and
  the metadata what ``ros2 bag record`` writes (offered QoS profiles, message
  definitions with comments, type hashes), so the bag plays in a real
  ``ros2 bag``.
- :func:`play_bag`: publishes a bag's messages (raw bytes) on their topics at
  real time, a scaled rate, or as fast as a subscriber takes them
  (``rate=0``: at most ``max_in_flight`` messages ahead of the responses seen
  on ``ack_topic``).

Console commands: ``clm record`` and ``clm play`` (:mod:`clm_ros.commands`).
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from clm_core.io.bags import BagReader, BagWriter
from clm_core.io.errors import BagError
from clm_core.io.timebase import NS
from clm_ros.errors import ClmRosError


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


def qos_from_rclpy(profile: Any) -> Any:
    """An rclpy QoS profile (as discovered for a publisher) as the bag writer records it (rosbags ``Qos``)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    def t(d: Any) -> QosTime:
        return QosTime(*divmod(int(d.nanoseconds), NS))

    def enum(kind: Any, policy: Any) -> Any:
        try:
            return kind(int(policy.value if hasattr(policy, "value") else policy))
        except ValueError:
            return kind.UNKNOWN

    return Qos(
        history=enum(QosHistory, profile.history),
        depth=int(profile.depth),
        reliability=enum(QosReliability, profile.reliability),
        durability=enum(QosDurability, profile.durability),
        deadline=t(profile.deadline),
        lifespan=t(profile.lifespan),
        liveliness=enum(QosLiveliness, profile.liveliness),
        liveliness_lease_duration=t(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def offered_qos(node: Any, topic: str) -> list[Any]:
    """The QoS profiles the publishers of ``topic`` offer, as ``ros2 bag record`` stores them."""
    return [qos_from_rclpy(info.qos_profile) for info in node.get_publishers_info_by_topic(topic)]


class BagRecorder:
    """Record topics of a running ROS graph to a rosbag2 bag, as ``ros2 bag record`` does.

    Raw (serialized) subscriptions, reliable keep-all, written by the one bag
    writer (:class:`clm_core.io.bags.BagWriter`: format 9, the message
    definitions with their comments, type hashes). A topic enters the bag with
    its first message, with the QoS profiles its publishers offer at that
    moment; topics without messages are added when recording stops. The bag is
    written under a temporary name and appears at ``path`` only when
    :meth:`close` has run.

    Two ways to take the messages:

    - callbacks (default): the caller spins ``node``; each message is written
      in its callback with the time it is taken as log time (system clock, or
      the node's clock with ``use_sim_time``);
    - ``polled``: ``node`` must not be spun by any executor; :meth:`poll`
      takes whatever has arrived on every topic and writes it with the time
      the middleware received it (rmw's reception timestamp, system clock) as
      log time. A recorder that polls every few milliseconds costs no executor
      wake-up per message (about half the CPU of the callbacks at the demo's
      3 messages per ms), and its log times do not depend on when it polls.

    Parameters
    ----------
    node : rclpy.node.Node
        Node that owns the subscriptions.
    path : path
        Output bag directory (must not exist).
    topics : mapping topic -> message type name
        What to record, e.g. ``{'/wheel_loads': 'clm_msgs/msg/WheelLoads'}``.
    storage : {'mcap', 'sqlite3'}
    polled : bool
        Take the messages with :meth:`poll` instead of callbacks.
    """

    def __init__(self, node: Any, path: str | Path, topics: dict[str, str], storage: str = "mcap",
                 polled: bool = False) -> None:
        try:
            self.writer = BagWriter(path, storage)
        except BagError as exc:
            raise ClmRosError(str(exc)) from None
        self.ts = self.writer.typestore
        self.topics = dict(topics)
        self.counts: dict[str, int] = {}
        self._conns: dict[str, Any] = {}
        self._subs: list[Any] = []
        self._node = node
        self.closed = False
        self.polled = polled
        try:
            for topic, msgtype in topics.items():
                if msgtype not in self.ts.types:
                    raise ClmRosError(f"topic {topic}: type {msgtype!r} unknown to the bag type store")
                self.counts[topic] = 0
                callback = (lambda _raw: None) if polled else self._callback(topic)
                self._subs.append(
                    node.create_subscription(message_class(msgtype), topic, callback, data_qos(), raw=True)
                )
        except BaseException:
            self.abort()
            raise

    def _connection(self, topic: str) -> Any:
        conn = self._conns.get(topic)
        if conn is None:
            qos = offered_qos(self._node, topic)
            conn = self._conns[topic] = self.writer.add_topic(topic, self.topics[topic], qos=qos)
        return conn

    def _callback(self, topic: str) -> Any:
        # the receive time on the system clock, as ros2 bag record logs it (the node's clock with use_sim_time);
        # the hot path is a few attribute lookups
        node_clock = self._node.get_clock() if self._node.get_parameter("use_sim_time").value else None
        now = time.time_ns if node_clock is None else (lambda: node_clock.now().nanoseconds)
        counts = self.counts
        write = self.writer.write
        conn: list[Any] = []

        def cb(raw: bytes) -> None:
            if self.closed:
                return
            if not conn:
                conn.append(self._connection(topic))
            write(conn[0], now(), raw)
            counts[topic] += 1

        return cb

    def matched(self, topics: Sequence[str]) -> bool:
        """Whether the subscription of each of ``topics`` has matched at least one publisher."""
        subs = dict(zip(self.topics, self._subs))
        return all(subs[t].get_publisher_count() >= 1 for t in topics)

    def poll(self) -> int:
        """``polled``: take and write every message that has arrived; return how many.

        The log time of a message is its reception time by the middleware
        (system clock; rmw's ``received_timestamp``, the time of taking where
        the middleware gives none).
        """
        if self.closed:
            return 0
        n = 0
        write = self.writer.write
        for topic, sub in zip(self.topics, self._subs):
            for raw, received in take_raw(sub):
                write(self._connection(topic), received or time.time_ns(), raw)
                self.counts[topic] += 1
                n += 1
        return n

    def _stop(self) -> None:
        self.closed = True
        for s in self._subs:
            self._node.destroy_subscription(s)
        self._subs = []

    def close(self) -> dict[str, int]:
        """Stop recording, finish the bag (it appears at its path); return the message counts per topic."""
        if not self.closed:
            if self.polled:
                self.poll()
            self._stop()
            for topic in self.topics:
                self._connection(topic)
            self.writer.close()
        return dict(self.counts)

    def abort(self) -> None:
        """Stop recording and drop the bag."""
        if not self.closed:
            self._stop()
        self.writer.abort()


#: The clm data types decoded by clm_core.io.messages (numpy, no rclpy) when a bag is read back: type -> decoder.
DECODERS = {"clm_msgs/msg/WheelLoads": "decode_wheel_loads",
            "clm_msgs/msg/SleeperResponse": "decode_sleeper_response",
            "clm_msgs/msg/WheelRailResponse": "decode_wheel_rail_response"}


def read_topics(bag: str | Path, topics: Sequence[str] | None = None) -> dict[str, list[tuple[int, Any]]]:
    """Every message of ``topics`` (default all; those not in the bag are left out) of a bag, decoded, with its
    log time: ``{topic: [(log_ns, message), ...]}`` in log-time order.

    The one reader of recorded runs (``clm demo``'s figures and plots, ``clm fleet``'s in = out, recorder lag and
    offline check): the clm data topics are decoded by :mod:`clm_core.io.messages` (``stamp_ns`` and numpy
    arrays), every other type by the bag's type store (rosbags). A damaged bag raises
    :class:`clm_core.io.errors.BagError`.
    """
    from clm_core.io import messages

    with BagReader(bag) as reader:
        wanted = [t for t in (reader.topics if topics is None else topics) if t in reader.topics]
        out: dict[str, list[tuple[int, Any]]] = {t: [] for t in wanted}
        decode = {t: getattr(messages, DECODERS[reader.topics[t].msgtype]) if reader.topics[t].msgtype in DECODERS
                  else (lambda data, mt=reader.topics[t].msgtype: reader.deserialize(data, mt)) for t in wanted}
        for bm in reader.messages(wanted):
            out[bm.topic].append((bm.log_ns, decode[bm.topic](bm.data)))
    return out


def take_raw(sub: Any) -> Iterator[tuple[bytes, int | None]]:
    """Take every message waiting in raw subscription ``sub`` (one no executor spins).

    Yields ``(serialized bytes, reception time [ns, system clock] or None)``;
    the reception time is the middleware's (rmw ``received_timestamp``).
    """
    handle, msg_type = sub.handle, sub.msg_type
    while True:
        with handle:
            taken = handle.take_message(msg_type, True)
        if taken is None:
            return
        raw, info = taken
        yield raw, info.get("received_timestamp") or None


def _type_clash(node: Any, topic: str, msgtype: str, publishers: bool) -> str | None:
    """What another endpoint on ``topic`` expects, if its type differs from ``msgtype``."""
    infos = node.get_publishers_info_by_topic(topic) if publishers else node.get_subscriptions_info_by_topic(topic)
    other = sorted({i.topic_type for i in infos if i.topic_type != msgtype})
    if not other:
        return None
    who = "publishers" if publishers else "subscribers"
    return f"topic {topic}: the {who} on the graph use {', '.join(other)}, not {msgtype}"


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
    allow_partial: bool = False,
) -> dict[str, int]:
    """Publish a bag's messages on their topics.

    The bag is read once before anything is published: a damaged bag (counts
    that disagree with its metadata, a damaged chunk) is refused before the
    first message goes out, unless ``allow_partial`` (then what is readable is
    played). A subscriber (or, with flow control, an answering publisher) of
    another message type on a played topic is reported at once, by name of
    the types, instead of waiting for a subscriber that can never match.

    Parameters
    ----------
    node : rclpy.node.Node
        Node that owns the publishers (this function spins it).
    path : path
        Bag (mcap or sqlite3; see :mod:`clm_core.io.bags` for what a bag is).
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
    allow_partial : bool
        Play what is left of a damaged bag.

    Returns
    -------
    dict topic -> messages published

    Raises
    ------
    ClmRosError
        Bad arguments, unreadable, empty or damaged bag, a type clash on the
        graph, no subscriber after ``discovery_timeout``, no answer for ``idle_timeout``.
    """
    if rate < 0:
        raise ClmRosError(f"rate = {rate}: must be >= 0 (0: as fast as the subscriber takes them)")
    if rate == 0 and not ack_topic:
        raise ClmRosError("rate = 0 needs ack_topic (the topic that answers each message) for flow control")
    try:
        reader = BagReader(path, allow_partial=allow_partial)
    except BagError as exc:
        raise ClmRosError(str(exc)) from None
    try:
        return _play(node, reader, topics, rate, ack_topic, ack_type, max_in_flight, discovery_timeout,
                     idle_timeout, min_subscribers)
    except BagError as exc:
        raise ClmRosError(str(exc)) from None
    finally:
        reader.close()


def _play(node: Any, reader: BagReader, topics: Sequence[str] | None, rate: float, ack_topic: str | None,
          ack_type: str, max_in_flight: int, discovery_timeout: float, idle_timeout: float,
          min_subscribers: int) -> dict[str, int]:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    play = [t for t in reader.topics if topics is None or t in topics]
    if not play:
        raise ClmRosError(f"bag {str(reader.path)!r}: none of the topics {list(topics or [])} are in it")
    for _ in reader.messages(play):  # the whole bag once: damage is found before anything is published
        pass
    acked = [0]
    ack_sub = None
    sent: dict[str, int] = {}
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    spin = executor.spin_once
    pubs: dict[str, Any] = {}
    try:
        if rate == 0:
            ack_sub = node.create_subscription(
                message_class(ack_type), ack_topic, lambda _m: acked.__setitem__(0, acked[0] + 1), data_qos()
            )
        for t in play:
            pubs[t] = node.create_publisher(message_class(reader.topics[t].msgtype), t, data_qos())
            sent[t] = 0
        t0 = time.monotonic()
        while any(p.get_subscription_count() < min_subscribers for p in pubs.values()) or (
            ack_sub is not None and ack_sub.get_publisher_count() < 1
        ):
            clash = [c for t in pubs if (c := _type_clash(node, t, reader.topics[t].msgtype, False))]
            if ack_sub is not None and ack_topic:
                clash += [c for c in [_type_clash(node, ack_topic, ack_type, True)] if c]
            if clash:
                raise ClmRosError(f"bag {str(reader.path)!r}: " + "; ".join(clash))
            if time.monotonic() - t0 > discovery_timeout:
                missing = [t for t, p in pubs.items() if p.get_subscription_count() < min_subscribers]
                if ack_sub is not None and ack_sub.get_publisher_count() < 1:
                    missing.append(f"publisher of {ack_topic}")
                raise ClmRosError(f"no subscriber on {missing} after {discovery_timeout:g} s")
            spin(timeout_sec=0.02)
        start_wall = time.monotonic()
        start_bag: int | None = None
        total = 0
        for m in reader.messages(play):
            if start_bag is None:
                start_bag = m.log_ns
            if rate > 0:
                due = start_wall + (m.log_ns - start_bag) / NS / rate
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
            pubs[m.topic].publish(m.data)
            sent[m.topic] += 1
            total += 1
        for p in pubs.values():
            p.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
    finally:
        for p in pubs.values():
            node.destroy_publisher(p)
        if ack_sub is not None:
            node.destroy_subscription(ack_sub)
        executor.remove_node(node)
        executor.shutdown()
    return sent
