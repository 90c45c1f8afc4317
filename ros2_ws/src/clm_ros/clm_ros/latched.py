"""A node's control-plane state as a latched status: one that a lost or late sample cannot make unknown.

``/diagnostics`` is periodic and volatile: a reader that is slow or joins
late misses samples, and a one-off message (a vehicle's "train done") can be
lost for good when the writer's keep-last history is overwritten under load
(issue 21: a fleet supervisor waited 600 s for a lost "final" diagnostics).
A :class:`LatchedStatus` publishes the node's state on a topic of its own
namespace (the vehicle's ``vehicle_status``, the track node's
``track_status``) with :data:`LATCHED_QOS`: reliable, transient local, keep
last 1. The middleware keeps the latest state and hands it to every reader
that matches, however late, and re-sends it until each matched reader has it;
a newer state replaces an older one that was not delivered yet. So a reader
always ends with the latest state: a *fact* (readiness, a train done and its
counts), not a message to catch.

The message is a ``diagnostic_msgs/DiagnosticArray`` with one status (as on
``/diagnostics``: :func:`clm_ros.diagnostics.diagnostic_array`); a reader
turns it into a ``{key: value}`` mapping with :func:`status_values`. A state
is published only when it differs from the last one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from clm_ros.diagnostics import diagnostic_array

#: QoS of a latched status: the last state, kept for late readers and re-sent until acknowledged.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: The vehicle node's latched status topic (relative: in the node's namespace).
VEHICLE_STATUS = "vehicle_status"
#: The track node's latched status topic (relative: in the node's namespace).
TRACK_STATUS = "track_status"
#: A fleet pair's own recorder's latched status topic (relative: in the pair's namespace; clm_ros.fleet_pair).
RECORDER_STATUS = "recorder_status"


class LatchedStatus:
    """Publish ``node``'s state on ``topic`` (latched, :data:`LATCHED_QOS`) whenever it changes.

    Parameters
    ----------
    node : rclpy.node.Node
        The publishing node; the status name is ``<fully qualified node name>: <what>``.
    topic : str
        Topic (relative names are in the node's namespace).
    what : str
        Second part of the status name (``vehicle simulator``, ``track-soil model``).
    """

    def __init__(self, node: Node, topic: str, what: str) -> None:
        self._node = node
        self._what = what
        self._pub = node.create_publisher(DiagnosticArray, topic, LATCHED_QOS)
        self._last: tuple[Any, ...] | None = None

    def update(self, level: bytes | int, message: str, values: Mapping[str, Any]) -> bool:
        """Publish the state when it differs from the last one published; whether it was published.

        Best effort on the way down: a failure (the context is shutting down) is logged at debug level.
        """
        key = (level, message, tuple((k, str(v)) for k, v in values.items()))
        if key == self._last:
            return False
        try:
            self._pub.publish(diagnostic_array(f"{self._node.get_fully_qualified_name()}: {self._what}", level,
                                               message, values, self._node.get_clock().now().to_msg()))
        except Exception as exc:  # context going down
            self._node.get_logger().debug(f"latched status not published: {exc}")
            return False
        self._last = key
        return True


def status_values(msg: Any) -> dict[str, str]:
    """``{key: value}`` of the (first) status of a latched status message, with its ``level`` and ``message``."""
    if not msg.status:
        return {}
    st = msg.status[0]
    return {"level": str(int.from_bytes(st.level, "little") if isinstance(st.level, bytes) else int(st.level)),
            "message": st.message, **{kv.key: kv.value for kv in st.values}}


def follow(node: Node, topic: str, what: str, state: Callable[[], tuple[int, str, Mapping[str, Any]]],
           period: float = 0.25) -> LatchedStatus:
    """A :class:`LatchedStatus` of ``node`` on ``topic`` updated from ``state()`` (level, message, values) every
    ``period`` s by a timer of the node (steady clock: also under sim time without ``/clock``).

    What the track node calls (one line): its state, its matched wheel-load publishers, its scheduling.
    """
    from rclpy.clock import Clock, ClockType

    status = LatchedStatus(node, topic, what)
    node.create_timer(period, lambda: status.update(*state()), clock=Clock(clock_type=ClockType.STEADY_TIME))
    return status


def matched_readers(**publishers: Any) -> dict[str, int]:
    """``{'<topic>_readers_matched': n}``: the readers each publisher (None: 0) has matched, for a latched status
    (a supervisor compares them with the readers it knows on the graph: discovery is two-sided)."""
    return {f"{name}_readers_matched": int(p.get_subscription_count()) if p is not None else 0
            for name, p in publishers.items()}
