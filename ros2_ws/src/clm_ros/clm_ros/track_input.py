"""The track node's input: the ``wheel_loads`` subscription, its QoS and peers, its sources, and the taking of messages.

The base class of :class:`clm_ros.track_node.TrackNode` (one node; split in
two modules to keep each readable): the subscription exists exactly while the
node is active (:meth:`TrackInput._subscribe`, :meth:`TrackInput._unsubscribe`);
its reliability is resolved against the publishers present ("best available",
:mod:`clm_ros.qos`) and followed every 0.25 s (:meth:`TrackInput._housekeeping`:
peers that come and go, a best-effort publisher appearing); its messages are
taken with their publisher's GID (:class:`clm_ros.sources.GidSubscription`):
the first publisher heard is the stream's source, a second one is refused
(``second_source``, counted) until the source leaves the graph or goes quiet
(:class:`clm_ros.sources.Sources`); what is taken goes to
:meth:`TrackInput._answer` (the track node's data path) in chunks of at most
:data:`CHUNK`.
"""

from __future__ import annotations

import traceback
from typing import Any

from clm_msgs.msg import WheelLoads
from rcl_interfaces.msg import SetParametersResult
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.qos import ReliabilityPolicy

from clm_core.online import OnlineTrackModel, Reason, Rejected
from clm_ros import qos
from clm_ros.diagnostics import Counters, bounded
from clm_ros.node_main import StopSignals
from clm_ros.sources import GidSubscription, Sources, gid_text

__all__ = ["CHUNK", "TrackInput"]

#: Frames processed in one go at most; between chunks the answers go out and a stop request is honoured.
CHUNK = 500


class TrackInput(LifecycleNode):
    """The wheel-load input of the track node (see the module docstring); :meth:`_answer` is the node's."""

    _stop: StopSignals
    counters: Counters
    model: OnlineTrackModel | None
    _logged: set[str]
    _sub: GidSubscription | None
    _sources: Sources
    _accepting: bool
    _reliability: str
    _requested_reliability: Any
    _recreate: bool
    _peers: tuple[int, int]
    _matched_publishers: int
    _new_stream: bool
    _peer_lost: bool
    _pub_w: Any
    _pub_markers: Any
    _markers_watched: bool

    def _answer(self, raws: list[bytes]) -> None:
        """Decode, integrate and answer one chunk of messages, in order (the track node's data path)."""
        raise NotImplementedError

    def _log(self, level: str, text: str, once: str | None = None) -> None:
        """Log a bounded line (``once``: a key logged only the first time)."""
        if once is not None:
            if once in self._logged:
                return
            self._logged.add(once)
        logger, line = self.get_logger(), bounded(text)  # type: ignore[no-untyped-call]  # rclpy: unannotated
        # one call site per severity: rclpy's logger refuses another severity from the same line
        if level == "error":
            logger.error(line)
        elif level == "warning":
            logger.warning(line)
        else:
            logger.info(line)

    # ------------------------------------------------------------------ subscription (QoS, peers)

    def _capture_qos(self, profile: Any) -> SetParametersResult:
        self._requested_reliability = profile.reliability
        return SetParametersResult(successful=True)

    def _subscribe(self) -> None:
        """Subscribe to wheel_loads (raw bytes) with the QoS after the user's overrides (module clm_ros.qos)."""
        opts = qos.overrides(callback=self._capture_qos)
        events = SubscriptionEventCallbacks(incompatible_qos=self._on_incompatible_qos, message_lost=self._on_lost)
        sub = self.create_subscription(WheelLoads, "wheel_loads", lambda _raw: None, qos.wheel_loads_qos(),
                                       qos_overriding_options=opts, event_callbacks=events, raw=True)
        self._sub = GidSubscription(self, sub, self._on_wheel_loads)  # taken with the publisher's GID
        pubs = self.get_publishers_info_by_topic(self._sub.topic_name)
        self._reliability = qos.resolve_reliability(self._requested_reliability, pubs).name.lower()
        self._recreate = False

    def _unsubscribe(self) -> None:
        """Stop accepting; take and count what is queued (not accepted: no answer owed); destroy."""
        self._accepting = False
        sub, self._sub = self._sub, None
        if sub is None:
            return
        n = 0
        try:
            while sub.take() is not None:
                n += 1
        except Exception as exc:  # the subscription goes anyway
            self._log("warning", f"discarding queued wheel loads: {exc}")
        self.counters.received += n
        self.counters.not_accepted += n
        if n:
            self._log("info", f"{n} queued wheel-load message(s) not accepted (node no longer active)")
        sub.destroy()

    def _on_incompatible_qos(self, event: Any) -> None:
        self._log("warning", f"wheel_loads: a publisher offers an incompatible QoS (policy "
                  f"{event.last_policy_kind}); subscription reliability {self._reliability}", once="incompatible")
        self._recreate = True

    def _on_lost(self, event: Any) -> None:
        self.counters.lost += int(event.total_count_change)

    def _housekeeping(self) -> None:
        """Every 0.25 s on the executor thread: follow the publishers (QoS resolution, peers gone and back)."""
        markers = self._pub_markers
        self._markers_watched = markers is not None and markers.get_subscription_count() > 0
        sub = self._sub
        if sub is None:
            self._peers = (-1, -1)
            self._matched_publishers = 0
            return
        pubs = self.get_publishers_info_by_topic(sub.topic_name)
        self._matched_publishers = sub.get_publisher_count()
        if self._accepting:
            self._on_wheel_loads()  # (what arrived before the node had an executor to wake)
        if self._sources.graph(p.endpoint_gid for p in pubs):  # the stream's source left: the next one takes over
            self._new_stream = True
            self._log("info", "wheel_loads: the stream's source left the graph; the next publisher heard takes over")
        readers = self._pub_w.get_subscription_count() if self._pub_w is not None else 0
        peers = (len(pubs), readers)
        if peers != self._peers:
            self._peers_changed(self._peers, peers)
            self._peers = peers
        wanted = qos.resolve_reliability(self._requested_reliability, pubs).name.lower()
        if self._recreate or wanted != self._reliability:
            if self._requested_reliability != ReliabilityPolicy.BEST_AVAILABLE:
                self._recreate = False
                return
            old = self._reliability
            self._replace_subscription()
            self._log("info", f"wheel_loads: subscription re-created, reliability {old} -> {self._reliability}")

    def _peers_changed(self, old: tuple[int, int], new: tuple[int, int]) -> None:
        """Log who came and went (a peer that dies is seen when its middleware lease runs out)."""
        if old[0] > 0 and new[0] == 0:
            self._new_stream = self._peer_lost = True  # every source left: the next message starts a new stream
            self._log("warning", "wheel_loads: no publisher any more (peer gone); waiting for it to return")
        elif self._peer_lost and old[0] == 0 and new[0] > 0:
            self._peer_lost = False
            self._log("info", f"wheel_loads: {new[0]} publisher(s) back")
        elif old[0] >= 0 and new[0] != old[0]:
            self._log("info", f"wheel_loads: {old[0]} -> {new[0]} publisher(s)")
        if old[1] > 0 and new[1] == 0:
            self._log("warning", "wheel_rail_response: no reader any more (peer gone)")
        elif old[1] >= 0 and new[1] != old[1]:
            self._log("info", f"wheel_rail_response: {old[1]} -> {new[1]} reader(s)")

    def _replace_subscription(self) -> None:
        """A new subscription (QoS resolved anew); what the old one holds is answered first."""
        old = self._sub
        if old is None:
            return
        self._drain(old, [])
        self._subscribe()
        self._drain(old, [])
        old.destroy()

    def _on_wheel_loads(self) -> None:
        """Executor callback (messages have arrived): everything waiting, answered in order."""
        try:
            sub = self._sub
            if sub is None:
                return
            if not self._accepting:
                while sub.take() is not None:
                    self.counters.received += 1
                    self.counters.not_accepted += 1
                return
            self._drain(sub, [])
        except Exception as exc:  # never let one message end the node
            self.counters.internal_errors += 1
            tb = traceback.format_exc(limit=3).strip().splitlines()
            self._log("error", f"internal error on a wheel-load message (counted): {exc!r}; "
                      f"{' | '.join(tb[-4:])}", once="internal_error")

    def _drain(self, sub: Any, raws: list[bytes]) -> None:
        """Take everything waiting in ``sub`` after ``raws`` and answer it, in chunks of at most CHUNK."""
        take, sources = sub.take, self._sources
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
                self._new_stream = True
                self._log("info", f"wheel_loads: the stream's source went quiet; publisher {gid_text(got[1])} "
                          "takes over (a new stream)")
            raws.append(got[0])
            if len(raws) >= CHUNK:
                self._answer(raws)
                raws = []
                if self._stop.requested() or not self._accepting:
                    return
        if raws:
            self._answer(raws)

    def _second_source(self, gid: bytes) -> None:
        """A message of a publisher that is not the stream's source: refused (``second_source``), counted."""
        self.counters.received += 1
        src = self._sources.source
        if self.model is not None:
            self._reject(self.model.reject(Reason.SECOND_SOURCE, (
                f"publisher {gid_text(gid)} is a second source on wheel_loads (the stream's source is "
                f"{gid_text(src) if src else 'none'}): its messages are refused until the source leaves")))

    def _reject(self, exc: Rejected) -> None:
        cause = exc.reason.value
        self._log("warning", f"wheel loads rejected ({cause}; logged once per cause, counted in /diagnostics): "
                  f"{exc}", once=cause)
