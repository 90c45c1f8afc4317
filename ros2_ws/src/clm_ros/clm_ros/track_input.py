"""The track node's input: the ``wheel_loads`` subscription, its QoS and peers, its sources, and the taking of messages.

A collaborator of :class:`clm_ros.track_node.TrackNode` (the subscription
watch): the subscription exists exactly while the node is active
(:meth:`WheelLoadInput.subscribe`, :meth:`WheelLoadInput.unsubscribe`); its
reliability is resolved against the publishers present ("best available",
:mod:`clm_ros.qos`) and followed every 0.25 s
(:meth:`WheelLoadInput.housekeeping`: peers that come and go, a best-effort
publisher appearing); its messages are taken with their publisher's GID
(:class:`clm_ros.sources.GidSubscription`): the first publisher heard is the
stream's source, a second one is refused (``second_source``, counted) until
the source leaves the graph or goes quiet (:class:`clm_ros.sources.Sources`); what is taken
goes to the node's data path (``answer``, :class:`clm_ros.track_answers.AnswerPath`)
in chunks of at most :data:`CHUNK`.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable
from typing import Any

from clm_msgs.msg import WheelLoads
from rcl_interfaces.msg import SetParametersResult
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import ReliabilityPolicy

from clm_core.online import OnlineStats, Reason
from clm_ros import qos
from clm_ros.diagnostics import Counters
from clm_ros.node_log import NodeLog
from clm_ros.node_main import StopSignals
from clm_ros.sources import GidSubscription, Sources, gid_text

__all__ = ["CHUNK", "WheelLoadInput"]

#: Frames processed in one go at most; between chunks the answers go out and a stop request is honoured.
CHUNK = 500


class WheelLoadInput:
    """The wheel-load input of the track node (see the module docstring).

    Parameters
    ----------
    node : rclpy.node.Node
        The track node (its subscription, graph queries and executor).
    counters : Counters
        The node's counters (received, not accepted, lost, internal errors).
    stats : OnlineStats
        The model's counters (carried from model to model for the node's life).
    log : NodeLog
        The node's log.
    stop : StopSignals
        Stop requests, honoured between chunks of a backlog.
    answer : callable
        The data path: answers a chunk of serialized messages, in order.
    reject : callable
        Refuses a message (reason, text): counted by the model, logged once per cause (no model: ignored).
    """

    def __init__(self, node: Node, counters: Counters, stats: OnlineStats, log: NodeLog, stop: StopSignals,
                 answer: Callable[[list[bytes]], None], reject: Callable[[Reason, str], None],
                 doorbell: bool = True) -> None:
        self.node, self.counters, self.stats, self.log, self._stop = node, counters, stats, log, stop
        self._answer, self._reject = answer, reject
        self._doorbell = doorbell  # False: the process's loop waits on the arrival fd (arrival_fd, serve_arrivals)
        self.sub: GidSubscription | None = None
        self.sources = Sources()  # which publisher of wheel_loads is the stream (clm_ros.sources)
        self.accepting = False
        self.reliability = ""
        self._requested_reliability: Any = None
        self._recreate = False
        self.peers = (-1, -1)  # (wheel-load publishers, answer readers); -1: not followed
        self.matched_publishers = 0  # wheel-load writers the subscription has matched (its own side of discovery)
        self.new_stream = False  # every source left, or the source left the graph: the data path restarts the state
        self._peer_lost = False

    def arrival_fd(self) -> int:
        """The subscription's arrival fd when the process's loop waits on it (``doorbell`` false), else -1."""
        sub = self.sub
        return sub.fileno() if sub is not None and not self._doorbell else -1

    def serve_arrivals(self) -> None:
        """The arrival fd is readable: take and answer what has arrived."""
        sub = self.sub
        if sub is not None:
            sub.serve_arrivals()

    def values(self) -> dict[str, Any]:
        """The input's ``/diagnostics`` key-values."""
        return {
            "wheel_load_publishers": max(self.peers[0], 0),
            "wheel_load_publishers_matched": self.matched_publishers,
            **self.sources.values(),
            "answer_readers": max(self.peers[1], 0),
            "wheel_loads_reliability": self.reliability or "none",
        }

    # ------------------------------------------------------------------ subscription (QoS, peers)

    def _capture_qos(self, profile: Any) -> SetParametersResult:
        self._requested_reliability = profile.reliability
        return SetParametersResult(successful=True)

    def subscribe(self) -> None:
        """Subscribe to wheel_loads (raw bytes) with the QoS after the user's overrides (module clm_ros.qos)."""
        opts = qos.overrides(callback=self._capture_qos)
        events = SubscriptionEventCallbacks(incompatible_qos=self._on_incompatible_qos, message_lost=self._on_lost)
        sub = self.node.create_subscription(WheelLoads, "wheel_loads", lambda _raw: None, qos.wheel_loads_qos(),
                                            qos_overriding_options=opts, event_callbacks=events, raw=True)
        # taken with the publisher's GID
        self.sub = GidSubscription(self.node, sub, self._on_wheel_loads, doorbell=self._doorbell)
        # the new subscription's own count (0 until it matches): never the old one's, which a vehicle waiting for
        # this node's word would take for a match and publish into a reader not matched yet (stress run at
        # 8d15678: 36 of 50 wheel loads lost after a deactivate/activate, the node still saying 1)
        self.matched_publishers = self.sub.get_publisher_count()
        pubs = self.node.get_publishers_info_by_topic(self.sub.topic_name)
        self.reliability = qos.resolve_reliability(self._requested_reliability, pubs).name.lower()
        self._recreate = False

    def unsubscribe(self) -> None:
        """Stop accepting; take and count what is queued (not accepted: no answer owed); destroy."""
        self.accepting = False
        sub, self.sub = self.sub, None
        self.matched_publishers = 0  # no subscription, nothing matched (said at once, not at the next housekeeping)
        if sub is None:
            return
        n = 0
        try:
            while sub.take() is not None:
                n += 1
        except Exception as exc:  # the subscription goes anyway
            self.log.warning(f"discarding queued wheel loads: {exc}")
        self.counters.received += n
        self.counters.not_accepted += n
        if n:
            self.log.info(f"{n} queued wheel-load message(s) not accepted (node no longer active)")
        sub.destroy()

    def _on_incompatible_qos(self, event: Any) -> None:
        self.log.warning(f"wheel_loads: a publisher offers an incompatible QoS (policy {event.last_policy_kind}); "
                         f"subscription reliability {self.reliability}", key="incompatible")
        self._recreate = True

    def _on_lost(self, event: Any) -> None:
        self.counters.lost += int(event.total_count_change)

    def housekeeping(self, readers: int) -> None:
        """Every 0.25 s on the executor thread: follow the publishers (QoS resolution, peers gone and back);
        ``readers``: the answer readers now (the node's ``wheel_rail_response`` subscriptions)."""
        sub = self.sub
        if sub is None:
            self.peers = (-1, -1)
            self.matched_publishers = 0
            return
        pubs = self.node.get_publishers_info_by_topic(sub.topic_name)
        self.matched_publishers = sub.get_publisher_count()
        if self.accepting:
            self._on_wheel_loads()  # (what arrived before the node had an executor to wake)
        if self.sources.graph(p.endpoint_gid for p in pubs):  # the stream's source left: the next one takes over
            self.new_stream = True
            self.log.info("wheel_loads: the stream's source left the graph; the next publisher heard takes over")
        peers = (len(pubs), readers)
        if peers != self.peers:
            self._peers_changed(self.peers, peers)
            self.peers = peers
        wanted = qos.resolve_reliability(self._requested_reliability, pubs).name.lower()
        if self._recreate or wanted != self.reliability:
            if self._requested_reliability != ReliabilityPolicy.BEST_AVAILABLE:
                self._recreate = False
                return
            old = self.reliability
            self._replace_subscription()
            self.log.info(f"wheel_loads: subscription re-created, reliability {old} -> {self.reliability}")

    def _peers_changed(self, old: tuple[int, int], new: tuple[int, int]) -> None:
        """Log who came and went (a peer that dies is seen when its middleware lease runs out)."""
        if old[0] > 0 and new[0] == 0:
            self.new_stream = self._peer_lost = True  # every source left: the next message starts a new stream
            self.log.warning("wheel_loads: no publisher any more (peer gone); waiting for it to return")
        elif self._peer_lost and old[0] == 0 and new[0] > 0:
            self._peer_lost = False
            self.log.info(f"wheel_loads: {new[0]} publisher(s) back")
        elif old[0] >= 0 and new[0] != old[0]:
            self.log.info(f"wheel_loads: {old[0]} -> {new[0]} publisher(s)")
        if old[1] > 0 and new[1] == 0:
            self.log.warning("wheel_rail_response: no reader any more (peer gone)")
        elif old[1] >= 0 and new[1] != old[1]:
            self.log.info(f"wheel_rail_response: {old[1]} -> {new[1]} reader(s)")

    def _replace_subscription(self) -> None:
        """A new subscription (QoS resolved anew); what the old one holds is answered first."""
        old = self.sub
        if old is None:
            return
        self._drain(old, [])
        self.subscribe()
        self._drain(old, [])
        old.destroy()

    def _on_wheel_loads(self) -> None:
        """Executor callback (messages have arrived): everything waiting, answered in order."""
        try:
            sub = self.sub
            if sub is None:
                return
            if not self.accepting:
                while sub.take() is not None:
                    self.counters.received += 1
                    self.counters.not_accepted += 1
                return
            self._drain(sub, [])
        except Exception as exc:  # never let one message end the node
            self.counters.internal_errors += 1
            tb = traceback.format_exc(limit=3).strip().splitlines()
            self.log.error(f"internal error on a wheel-load message (counted): {exc!r}; {' | '.join(tb[-4:])}",
                           key="internal_error")

    def _drain(self, sub: Any, raws: list[bytes]) -> None:
        """Take everything waiting in ``sub`` after ``raws`` and answer it, in chunks of at most CHUNK."""
        take, sources = sub.take, self.sources
        while True:
            got = take()
            if got is None:
                break
            if not sources.admit(got[1], got[2]):
                self._second_source(got[1])
                continue
            if sources.fresh:  # the source went quiet and this publisher took over: its message starts a new stream
                sources.fresh = False
                if raws:
                    self._answer(raws)
                    raws = []
                self.new_stream = True
                self.log.info(f"wheel_loads: the stream's source went quiet; publisher {gid_text(got[1])} "
                              "takes over (a new stream)")
            raws.append(got[0])
            if len(raws) >= CHUNK:
                self._answer(raws)
                raws = []
                if self._stop.requested() or not self.accepting:
                    return
        if raws:
            self._answer(raws)

    def _second_source(self, gid: bytes) -> None:
        """A message of a publisher that is not the stream's source: refused (``second_source``), counted."""
        self.counters.received += 1
        src = self.sources.source
        self._reject(Reason.SECOND_SOURCE, (
            f"publisher {gid_text(gid)} is a second source on wheel_loads (the stream's source is "
            f"{gid_text(src) if src else 'none'}): its messages are refused until the source leaves"))
