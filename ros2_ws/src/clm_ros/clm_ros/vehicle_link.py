"""The vehicle node's link to its track node: the answers' subscription, and when a train may start.

:class:`TrackLink` owns a helper node (``<vehicle>_answers``, same namespace)
that no executor spins: the vehicle node takes the answers itself when it
serves its timetable (one wake-up per message instead of two), with the
middleware's reception times; and the latched ``track_status`` of its track
node and the supervisor's latched ``start_at``, taken while a train waits.

A train starts when its own track node is active and subscribed
(:meth:`TrackLink.track_ready`): its endpoints in this namespace
(:func:`clm_ros.readiness.owned`), every known reader matched
(:func:`clm_ros.readiness.all_matched`), its latched ``track_status`` saying
its subscription matched this node's publisher (discovery is two-sided:
wheel loads published before it may never reach a volatile reader), plus
``wait_for_subscribers`` matched readers; with ``start_signal``, at the
supervisor's start time (:meth:`TrackLink.start_due`).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import rclpy
from clm_msgs.msg import WheelRailResponse
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message
from std_msgs.msg import Int64

from clm_core.io.timebase import NS
from clm_ros.bag_tools import take_raw
from clm_ros.latched import LATCHED_QOS, TRACK_STATUS
from clm_ros.readiness import START_AT, all_matched, owned

#: Data topics: reliable, keep-last 5000 (5 s at 1 kHz): nothing is lost for a reader that keeps up within
#: 5 s, and a reader that died never blocks publishing (keep-all would, then fail). Overridable through the
#: standard QoS parameters, e.g. ``qos_overrides./wheel_loads.publisher.depth``.
DATA_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000, reliability=ReliabilityPolicy.RELIABLE)

#: How long a train waits, once the track node is on the graph and matched, for the track node's own word that
#: its subscription has matched this node's publisher, when the track node has no latched status
#: (``track_status``, :mod:`clm_ros.latched`): not a clm track node; a clm track node's word is always awaited [ns].
HANDSHAKE_TIMEOUT_NS = 5 * NS


def _ignore(_raw: Any) -> None:
    """Callback of the helper node's subscriptions, never called: no executor spins that node."""


class TrackLink:
    """The vehicle node's answers and its wait for its track node (see the module docstring).

    Parameters
    ----------
    node : rclpy.node.Node
        The vehicle node (its name, namespace, context and graph).
    pub : Publisher
        Its ``wheel_loads`` publisher.
    track_node : str
        The track node's name ('': any ``wait_for_subscribers`` readers will do).
    wait_for_subscribers : int
        Matched readers of ``wheel_loads`` needed.
    start_signal : bool
        Wait for the supervisor's latched ``start_at`` before the activation's first train.
    """

    def __init__(self, node: Any, pub: Any, track_node: str, wait_for_subscribers: int, start_signal: bool) -> None:
        self.node, self.pub, self.track_node, self.readers = node, pub, track_node, wait_for_subscribers
        self.helper = rclpy.create_node(f"{node.get_name()}_answers", namespace=node.get_namespace(),
                                        context=node.context)
        qos = QoSOverridingOptions.with_default_policies()
        self.answers = self.helper.create_subscription(WheelRailResponse, "wheel_rail_response", _ignore, DATA_QOS,
                                                       qos_overriding_options=qos, raw=True)
        self._status = self._status_reader()
        self._start = self.helper.create_subscription(Int64, START_AT, _ignore, LATCHED_QOS) if start_signal else None
        self.start_at: int | None = None  # the supervisor's start time [ns, system clock] (start_signal)
        self._handshake: int | None = None  # the track node's matched wheel-load publishers (None: not said)
        self._graph_ready_since = 0  # monotonic ns since the track node is on the graph and matched (0: not)

    def destroy(self) -> None:
        """Drop the helper node and its subscriptions."""
        self.helper.destroy_node()

    def take_answers(self) -> Iterator[tuple[bytes, int]]:
        """Every answer that has arrived, with its reception time [monotonic ns]."""
        offset = time.time_ns() - time.monotonic_ns()  # system clock -> monotonic
        for raw, received in take_raw(self.answers):
            yield raw, (received - offset if received else time.monotonic_ns())

    def track_ready(self) -> bool:
        """The track node is active and subscribed: its subscription and answering publisher matched, on this
        node's side and on its own (:meth:`_track_subscribed`)."""
        pub, sub = self.pub, self.answers
        if pub.get_subscription_count() < self.readers:
            return False
        if not self.track_node:
            return True
        readers = self.node.get_subscriptions_info_by_topic(pub.topic_name)
        writers = self.node.get_publishers_info_by_topic(sub.topic_name)
        ns, name = self.node.get_namespace(), self.track_node
        if not (sub.get_publisher_count() >= 1 and any(owned(r, name, ns) for r in readers)
                and any(owned(w, name, ns) for w in writers) and all_matched(pub, readers)):
            # not there yet: its word, latched and sent once, stays queued for when it is; gone after it was
            # there: forget what it said through a new reader, which gets the latched word of whichever track
            # node is there next (draining the queue instead lost a word that came while the graph lagged)
            if self._graph_ready_since:
                self._renew_status()
            self._graph_ready_since, self._handshake = 0, None
            return False
        return self._track_subscribed()

    def _status_reader(self) -> Any:
        """A reader of the track node's latched ``track_status`` (its current word is sent to it on matching)."""
        return self.helper.create_subscription(DiagnosticArray, TRACK_STATUS, _ignore, LATCHED_QOS)

    def _renew_status(self) -> None:
        """A new ``track_status`` reader: what a former track node said is dropped, the current word re-sent."""
        self.helper.destroy_subscription(self._status)
        self._status = self._status_reader()

    def _track_subscribed(self) -> bool:
        """The track node says (``wheel_load_publishers_matched`` >= 1 in its latched ``track_status``) that its
        subscription has matched this node's publisher. A track node without that status (not a clm one) is
        taken at its graph entry after :data:`HANDSHAKE_TIMEOUT_NS`.
        """
        status = f"{self.node.get_namespace().rstrip('/')}/{self.track_node}: "
        for raw, _ in take_raw(self._status):
            for st in deserialize_message(raw, DiagnosticArray).status:
                if st.name.startswith(status):
                    said = next((kv.value for kv in st.values if kv.key == "wheel_load_publishers_matched"), "")
                    self._handshake = int(said) if said.isdigit() else -1
        now = time.monotonic_ns()
        if not self._graph_ready_since:
            self._graph_ready_since = now
        if self._handshake is not None:
            return self._handshake != 0
        if self._status.get_publisher_count():  # a clm track node: its latched word comes, however late
            return False
        return now - self._graph_ready_since > HANDSHAKE_TIMEOUT_NS

    def start_due(self) -> bool | None:
        """With ``start_signal``: True once the supervisor's start time has come, None while it has not said it
        (the caller says it is ready); without: True."""
        if self._start is None:
            return True
        for raw, _ in take_raw(self._start):
            self.start_at = int(deserialize_message(raw, Int64).data)
        if self.start_at is None:
            return None
        return time.time_ns() >= self.start_at
