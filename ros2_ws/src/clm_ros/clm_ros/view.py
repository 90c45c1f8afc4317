"""``clm view``: a live view of the demo's topics in Foxglove without a ROS install (foxglove-sdk WebSocket server).

A Foxglove WebSocket server (PyPI ``foxglove-sdk``; the app connects to
``ws://HOST:PORT``) that advertises one channel per topic of
:data:`DEFAULT_TOPICS` (or ``--topics``), each with its type's ``ros2msg``
schema (:func:`clm_core.io.messages.message_definition`: the ``.msg`` text
with its dependencies, as rosbag2 embeds it) and message encoding ``cdr``: the
bytes relayed are the middleware's own, so the app decodes them as it decodes
a bag.

- **On demand.** A ROS subscription of a topic exists only while at least one
  client subscribes to its channel (the server's ``on_subscribe`` /
  ``on_unsubscribe``, also called when a client goes); nothing is taken from
  DDS for a channel nobody watches.
- **Thinning without blocking the ROS side.** The ROS thread takes what has
  arrived every :data:`POLL` s (raw subscriptions that no executor spins: no
  wake-up per message, :func:`clm_ros.bag_tools.take_raw`), keeps of each
  topic the first message of every period ``1/rate`` (by the header stamp when
  the type starts with a ``std_msgs/Header``, else by the reception time) and
  hands it to the sender thread through a bounded queue
  (:class:`Handoff`, :data:`HANDOFF_SIZE` messages): when the sender falls
  behind, the oldest waiting message is dropped and counted, the ROS thread
  never waits. The sender logs to the server, which queues per client
  (``message_backlog_size``).
- **Second place on the CPU.** ``clm view`` runs niced (:data:`DEFAULT_NICE`)
  and wakes up every :data:`POLL` s: on a 2-core machine shared with the
  demo, the relay at normal priority waking every 5 ms raised the demo's lag
  p99 (its recorder's reception time) from 2.7 ms to 18-40 ms in 2 of 3 runs.
- **Counts.** Per topic: taken from DDS, relayed, thinned (skipped by the
  rate), dropped (the handoff was full); logged every ``log_period`` s while
  any count changes and printed at exit (:meth:`Relay.report`).

The subscriptions are volatile (a transient-local reader would not match
the suite's volatile writers), keep last :data:`SUBSCRIPTION_DEPTH`, and
reliable unless a publisher of the topic is best effort
(:func:`clm_ros.qos.resolve_reliability`, rmw's "best available" rule,
resolved anew every :data:`GRAPH_PERIOD` s: a best-effort publisher that
appears later gets the subscription re-created). A viewer that falls behind
loses the oldest samples in its own middleware and never slows a publisher
(whose answers are keep-last, :mod:`clm_ros.qos`). rmw's own
``BEST_AVAILABLE`` is not used: resolved before any publisher is
discovered it picks transient local and reliable, and then matches none of
the suite's volatile writers. Best-effort subscriptions were tried instead
(benchmarks/view_relay.py, 3 runs): no less CPU per message (111-133 us vs
100-115 us), and in a run where the machine stalled the demo for a second
the relay took 1490 of 3001 answers (54 % of the thinned stream), where the
reliable ones delivered 100 % in 6 of 6 runs at the same load.
"""

from __future__ import annotations

import collections
import json
import struct
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from clm_ros.errors import ClmRosError
from clm_ros.launch_common import LIVE_VIEWS
from clm_ros.launcher import TOPICS as RECORDED

#: The demo's topics and their types: what ``clm view`` relays by default, those the demo records and its live
#: views (config/foxglove_demo.json shows them).
DEFAULT_TOPICS: dict[str, str] = {**RECORDED, **{f"/{t}": msgtype for t, msgtype in LIVE_VIEWS.items()}}

#: How often the ROS thread takes what has arrived [s] (50 wake-ups per second; a view 20 ms late is live).
POLL = 0.02
#: Messages waiting between the ROS thread and the sender at most (all topics); beyond it the oldest is dropped.
HANDOFF_SIZE = 1000
#: History depth of the relay's subscriptions: samples its middleware keeps between two polls (1 s at 1 kHz, for a
#: relay that runs niced and waits for the CPU while the nodes have it).
SUBSCRIPTION_DEPTH = 1000
#: Niceness ``clm view`` gives itself (``--nice``): on a busy machine the nodes and their recorder get the CPU first.
DEFAULT_NICE = 10
#: How often the publishers of the watched topics are looked at (reliability of the subscriptions) [s].
GRAPH_PERIOD = 0.25
#: Default rate a topic is thinned to [Hz] (0: every message).
DEFAULT_RATE = 100.0
#: Messages the server buffers per client before dropping the oldest (foxglove-sdk ``message_backlog_size``).
BACKLOG = 4096

_HEADER = "std_msgs/msg/Header"


@dataclass
class TopicCounts:
    """What happened to one topic's messages (counts since the start)."""

    received: int = 0  #: taken from DDS
    relayed: int = 0  #: handed to the WebSocket server
    thinned: int = 0  #: skipped by the rate (another message of the same period was kept)
    dropped: int = 0  #: lost in the handoff (the sender was behind by HANDOFF_SIZE messages)
    subscribed: int = 0  #: times a ROS subscription was created (a client started watching)


def parse_topics(specs: Sequence[str] | None) -> dict[str, str]:
    """``--topics`` (``TOPIC`` of :data:`DEFAULT_TOPICS` or ``TOPIC:pkg/msg/Type``) -> topic -> type.

    Raises
    ------
    ClmRosError
        A topic not of the demo without a type, a type without the ``pkg/msg/Name`` form, a name not starting
        with ``/``.
    """
    if not specs:
        return dict(DEFAULT_TOPICS)
    out: dict[str, str] = {}
    for spec in specs:
        topic, _, msgtype = spec.partition(":")
        if not topic.startswith("/"):
            topic = "/" + topic
        if not msgtype:
            if topic not in DEFAULT_TOPICS:
                raise ClmRosError(f"--topics {spec!r}: not a topic of the demo ({', '.join(DEFAULT_TOPICS)}); "
                                  "give its type as TOPIC:pkg/msg/Type")
            msgtype = DEFAULT_TOPICS[topic]
        if msgtype.count("/") != 2:
            raise ClmRosError(f"--topics {spec!r}: type {msgtype!r} is not of the form pkg/msg/Type")
        out[topic] = msgtype
    return out


def check_rate(rate: float) -> float:
    """``--rate`` [Hz]: finite and >= 0 (0: no thinning); :class:`ClmRosError` otherwise."""
    if not rate >= 0.0 or rate == float("inf"):
        raise ClmRosError(f"--rate {rate!r}: must be a finite rate >= 0 Hz (0: relay every message)")
    return rate


def starts_with_header(msgtype: str) -> bool:
    """Whether the first field of ``msgtype`` is a ``std_msgs/Header`` (its stamp then leads the CDR bytes)."""
    from clm_core.io.messages import typestore

    ts = typestore()
    try:
        fields = ts.fielddefs[msgtype][1]
    except KeyError:
        raise ClmRosError(f"message type {msgtype!r} unknown to the type store") from None
    return bool(fields) and fields[0][1][1] == _HEADER


def header_stamp_ns(raw: bytes) -> int | None:
    """The ``header.stamp`` [ns] of CDR bytes whose type starts with a header (None if too short)."""
    if len(raw) < 12:
        return None
    sec, nanosec = struct.unpack_from("<iI" if raw[1] == 1 else ">iI", raw, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


class Thinner:
    """Keep the first message of every period ``1 / rate`` (periods counted from t = 0 of the time base).

    A time that goes back to an earlier period (a restarted stream) is kept and starts over from there.
    ``rate`` 0 keeps everything.
    """

    def __init__(self, rate: float) -> None:
        self.period_ns = round(1e9 / rate) if rate > 0 else 0
        self.last: int | None = None

    def keep(self, t_ns: int) -> bool:
        """Whether the message of time ``t_ns`` [ns] is relayed."""
        if not self.period_ns:
            return True
        k = t_ns // self.period_ns
        if self.last is not None and k == self.last:
            return False
        self.last = k
        return True


class Handoff:
    """A bounded queue from the ROS thread to the sender: :meth:`put` never waits, the oldest item goes when full."""

    def __init__(self, size: int) -> None:
        self._items: collections.deque[tuple[Any, ...]] = collections.deque()
        self._size = size
        self._cond = threading.Condition()

    def put(self, item: tuple[Any, ...]) -> tuple[Any, ...] | None:
        """Queue ``item``; return the item dropped to make room, if any."""
        with self._cond:
            dropped = self._items.popleft() if len(self._items) >= self._size else None
            self._items.append(item)
            self._cond.notify()
        return dropped

    def take(self, timeout: float) -> list[tuple[Any, ...]]:
        """Everything queued (waits up to ``timeout`` s for something)."""
        with self._cond:
            if not self._items:
                self._cond.wait(timeout)
            items = list(self._items)
            self._items.clear()
        return items


class _Listener:
    """foxglove-sdk server listener: which clients watch which channel (called on the server's threads)."""

    def __init__(self, topics_by_channel: Mapping[int, str]) -> None:
        self._topics = dict(topics_by_channel)
        self._lock = threading.Lock()
        self.watchers: dict[str, set[int]] = {t: set() for t in self._topics.values()}

    def on_subscribe(self, client: Any, channel: Any) -> None:
        topic = self._topics.get(channel.id)
        if topic is not None:
            with self._lock:
                self.watchers[topic].add(client.id)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        topic = self._topics.get(channel.id)
        if topic is not None:
            with self._lock:
                self.watchers[topic].discard(client.id)

    def watched(self) -> set[str]:
        """The topics at least one client subscribes to."""
        with self._lock:
            return {t for t, c in self.watchers.items() if c}


class Relay:
    """The WebSocket server, its channels and the on-demand ROS subscriptions (see the module docstring).

    Parameters
    ----------
    topics : mapping topic -> type
        What to advertise (``pkg/msg/Type`` known to :func:`clm_core.io.messages.typestore`).
    domain_id : int
        ROS domain to watch.
    rate : float
        Thinning rate [Hz] of every topic (0: none).
    host, port : str, int
        Where the server listens (port 0: any free port, see :attr:`port`).
    log : callable
        Where the periodic counts go (one line each).
    log_period : float
        Seconds between two count lines (0: none).
    """

    def __init__(self, topics: Mapping[str, str], domain_id: int, rate: float = DEFAULT_RATE, *,
                 host: str = "127.0.0.1", port: int = 8765, log: Callable[[str], None] = print,
                 log_period: float = 10.0) -> None:
        import foxglove
        import rclpy
        from rclpy.context import Context

        from clm_core.io.messages import message_definition

        self.rate = check_rate(rate)
        self.topics = dict(topics)
        self.counts = {t: TopicCounts() for t in self.topics}
        self._stamped = {t: starts_with_header(m) for t, m in self.topics.items()}
        from clm_ros.bag_tools import message_class

        self._classes = {t: message_class(m) for t, m in self.topics.items()}  # refused now, not when watched
        self._thin = {t: Thinner(rate) for t in self.topics}
        self._log = log
        self._log_period = log_period
        self._handoff = Handoff(HANDOFF_SIZE)
        self._subs: dict[str, Any] = {}
        self._reliability: dict[str, Any] = {}
        self._graph_checked = 0.0
        self._cpu0: float | None = None  # CPU time of the process when the first subscription was made [s]
        self._stop = threading.Event()
        self._fg_context = foxglove.Context()
        self.channels: dict[str, Any] = {}
        for topic, msgtype in self.topics.items():
            schema = foxglove.Schema(name=msgtype, encoding="ros2msg",
                                     data=message_definition(msgtype).encode("utf-8"))
            self.channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding="cdr",
                                                    context=self._fg_context)
        self._listener = _Listener({c.id(): t for t, c in self.channels.items()})
        self._ctx = Context()
        rclpy.init(context=self._ctx, domain_id=domain_id)
        self._node = rclpy.create_node("clm_view", context=self._ctx)
        try:
            self.server = foxglove.start_server(name="clm view", host=host, port=port,
                                                server_listener=self._listener,  # type: ignore[arg-type]  # the 2 callbacks used
                                                context=self._fg_context,
                                                message_backlog_size=BACKLOG)
        except Exception as exc:  # the SDK raises its own error types (port in use, bad host)
            self._shutdown_ros()
            raise ClmRosError(f"cannot start the WebSocket server on {host}:{port}: {exc}") from None
        self.port = int(self.server.port)
        self._sender = threading.Thread(target=self._send_loop, name="clm-view-sender", daemon=True)
        self._sender.start()

    # ---------------------------------------------------------------- ROS side

    def _qos(self, topic: str) -> tuple[Any, Any]:
        """The subscription's QoS for the publishers of ``topic`` on the graph now, and its reliability."""
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        from clm_ros.qos import resolve_reliability

        reliability = resolve_reliability(ReliabilityPolicy.BEST_AVAILABLE,
                                          self._node.get_publishers_info_by_topic(topic))
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SUBSCRIPTION_DEPTH, reliability=reliability,
                          durability=DurabilityPolicy.VOLATILE), reliability

    def _reconcile(self) -> None:
        """Create the subscriptions of newly watched topics, destroy those nobody watches any more; every
        :data:`GRAPH_PERIOD` s re-create one whose reliability no longer suits its publishers."""
        watched = self._listener.watched()
        for topic in [t for t in self._subs if t not in watched]:
            self._node.destroy_subscription(self._subs.pop(topic))
        now = time.monotonic()
        if now - self._graph_checked >= GRAPH_PERIOD:
            self._graph_checked = now
            for topic in list(self._subs):
                if self._qos(topic)[1] != self._reliability[topic]:
                    self._take(topic, self._subs[topic])
                    self._node.destroy_subscription(self._subs.pop(topic))
        for topic in sorted(watched - set(self._subs)):
            if self._cpu0 is None:
                self._cpu0 = time.process_time()
            profile, self._reliability[topic] = self._qos(topic)
            self._subs[topic] = self._node.create_subscription(
                self._classes[topic], topic, lambda _raw: None, profile, raw=True)
            if topic not in self._thin:
                self._thin[topic] = Thinner(self.rate)
            self.counts[topic].subscribed += 1

    def poll(self) -> int:
        """One pass of the ROS thread: follow the watchers, take what has arrived, thin, hand over."""
        self._reconcile()
        return sum(self._take(topic, sub) for topic, sub in self._subs.items())

    def _take(self, topic: str, sub: Any) -> int:
        from clm_ros.bag_tools import take_raw

        n = 0
        c, thin, stamped = self.counts[topic], self._thin[topic], self._stamped[topic]
        for raw, received in take_raw(sub):
            n += 1
            c.received += 1
            t_recv = received or time.time_ns()
            t = header_stamp_ns(raw) if stamped else None
            if not thin.keep(t_recv if t is None else t):
                c.thinned += 1
                continue
            lost = self._handoff.put((topic, bytes(raw), t_recv))
            if lost is not None:
                self.counts[lost[0]].dropped += 1
        return n

    def subscribed_topics(self) -> list[str]:
        """The topics with a ROS subscription right now."""
        return sorted(self._subs)

    def run(self, stop: threading.Event | None = None) -> None:
        """Poll until ``stop`` (or :meth:`stop`) is set; logs the counts every ``log_period`` s."""
        stop = stop or self._stop
        last_log = time.monotonic()
        last_counts = self._snapshot()
        while not stop.is_set() and not self._stop.is_set():
            t0 = time.monotonic()
            self.poll()
            if self._log_period > 0 and t0 - last_log >= self._log_period:
                last_log = t0
                now = self._snapshot()
                if now != last_counts:
                    self._log(self.report(prefix="clm view: "))
                    last_counts = now
            stop.wait(max(0.0, POLL - (time.monotonic() - t0)))

    def stop(self) -> None:
        """Make :meth:`run` return."""
        self._stop.set()

    # ---------------------------------------------------------------- server side

    def _send_loop(self) -> None:
        channels = self.channels
        while not self._stop.is_set():
            for topic, raw, t_recv in self._handoff.take(0.1):
                channels[topic].log(raw, log_time=t_recv)
                self.counts[topic].relayed += 1

    # ---------------------------------------------------------------- counts, end

    def _snapshot(self) -> dict[str, dict[str, int]]:
        return {t: asdict(c) for t, c in self.counts.items()}

    def report(self, prefix: str = "") -> str:
        """The counts of every topic that had messages, one line each (a line saying so if none had)."""
        lines = [f"{prefix}{t}: {c.received} taken, {c.relayed} relayed, {c.thinned} thinned (rate "
                 f"{self.rate:g} Hz), {c.dropped} dropped" for t, c in self.counts.items() if c.received]
        return "\n".join(lines) if lines else f"{prefix}no messages taken (no client watched a topic with data)"

    def summary(self) -> dict[str, Any]:
        """Counts per topic and the settings, for ``--stats`` (JSON)."""
        return {"rate_hz": self.rate, "port": self.port, "topics": self.topics, "counts": self._snapshot(),
                "cpu_s_watching": time.process_time() - self._cpu0 if self._cpu0 is not None else 0.0}

    def close(self) -> None:
        """Stop the server, hand over what is left, drop the subscriptions and the ROS context."""
        self._stop.set()
        self._sender.join(timeout=5)
        for topic, raw, t_recv in self._handoff.take(0.0):  # what the sender had not taken: still relayed
            self.channels[topic].log(raw, log_time=t_recv)
            self.counts[topic].relayed += 1
        self.server.stop()
        self._shutdown_ros()

    def _shutdown_ros(self) -> None:
        import rclpy

        for s in self._subs.values():
            self._node.destroy_subscription(s)
        self._subs = {}
        self._node.destroy_node()
        rclpy.try_shutdown(context=self._ctx)


def run_view(topics: Mapping[str, str], domain_id: int, rate: float, *, host: str = "127.0.0.1", port: int = 8765,
             log_period: float = 10.0, stats: str | Path | None = None, nice: int = DEFAULT_NICE) -> dict[str, Any]:
    """``clm view``: serve until SIGINT/SIGTERM, then print the counts (and write them to ``stats``, JSON).

    The process first adds ``nice`` to its niceness (0: none): the viewer, not the nodes, waits when the CPU is
    short (what it falls behind is kept by its middleware, :data:`SUBSCRIPTION_DEPTH`).
    """
    import os
    import signal

    if not 0 <= nice <= 19:
        raise ClmRosError(f"--nice {nice}: must be 0 to 19")
    if nice:
        os.nice(nice)
    stop = threading.Event()
    relay = Relay(topics, domain_id, rate, host=host, port=port, log_period=log_period,
                  log=lambda line: print(line, flush=True))
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        print(f"clm view: Foxglove WebSocket server on ws://{host}:{relay.port} (ROS domain {domain_id}, "
              f"{', '.join(relay.topics)}; thinned to {rate:g} Hz); in Foxglove: Open connection -> Foxglove "
              "WebSocket, then import the layout config/foxglove_demo.json", flush=True)
        relay.run(stop)
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        relay.close()
    print(relay.report(prefix="clm view: at exit: "), flush=True)
    out = relay.summary()
    if stats is not None:
        Path(stats).write_text(json.dumps(out, indent=1), encoding="utf-8")
    return out
