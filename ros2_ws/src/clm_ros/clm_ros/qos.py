"""QoS of the track node's topics (REP 2003), exposed through rclpy's standard QoS overrides.

Every data topic is created with ``QoSOverridingOptions.with_default_policies()``,
so a user sets its history, depth and reliability the ROS way, read-only at
start (``--ros-args -p qos_overrides./wheel_loads.subscription.reliability:=reliable``
or in a parameter file), and ``ros2 param list`` shows them. Defaults:

- ``wheel_loads`` (subscription): keep all, reliability **best available**.
  A reliable publisher (the vehicle node) is served reliably, so nothing it
  sends is lost; a sensor-data (best-effort) publisher is accepted too. The
  node resolves "best available" itself each time it creates the
  subscription: best effort if a best-effort publisher is on the topic,
  reliable otherwise (rmw's rule), and re-creates the subscription when the
  resolution changes (a best-effort publisher appears, detected by the
  incompatible-QoS event or the publisher list, or the last one leaves).
  With an explicit ``reliable`` or ``best_effort`` override the node never
  changes it (an incompatible publisher is then logged and counted, not
  served).
- answers (``sleeper_response``, ``wheel_rail_response``): reliable, keep
  last :data:`ANSWERS_DEPTH` (5000). A reader acknowledges a sample once its
  middleware holds it (not when its application takes it), so a live reader
  loses nothing unless its middleware falls 5000 answers (5 s at 1 kHz)
  behind; a reader that
  died without saying so (``kill -9``: the middleware notices only after its
  lease, ~20 s) never blocks the node. With keep-all, each publish would
  block for the middleware's blocking time once that reader's unacknowledged
  samples fill the history, and fail: the node would fall seconds behind
  for every live reader. (A failed publish is counted, ``publish_failed``,
  never fatal.)
- live views (``monitored_sleepers``, ``track_markers``): reliable, keep last
  100 / 1 (compatible with best-effort and reliable readers: PlotJuggler,
  Foxglove, RViz).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions

__all__ = ["ANSWERS_DEPTH", "answers_qos", "overrides", "resolve_reliability", "view_qos", "wheel_loads_qos"]


def wheel_loads_qos() -> QoSProfile:
    """Default QoS of the ``wheel_loads`` subscription: keep all, best available."""
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1000, reliability=ReliabilityPolicy.BEST_AVAILABLE)


#: History depth of the answers: a reader may fall this many answers behind (5 s at 1 kHz) and still get every
#: one. With 1000, a 2000-message backlog answered by a track node under SCHED_FIFO (clm_ros.realtime) outran a
#: reader at normal priority by more than the history (1 905-1 937 of 2 000 answers arrived, 3 runs of 3); with
#: 5000, 3 of 3 runs got every answer. Memory only when a reader lags: ~3 KB per 61-sleeper answer.
ANSWERS_DEPTH = 5000


def answers_qos() -> QoSProfile:
    """Default QoS of the answers: reliable, keep last :data:`ANSWERS_DEPTH` (a dead reader never blocks the
    node)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=ANSWERS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)


def view_qos(depth: int) -> QoSProfile:
    """Default QoS of the live views: reliable, keep last ``depth``."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE)


def overrides(callback: Callable[[QoSProfile], Any] | None = None) -> QoSOverridingOptions:
    """rclpy's standard QoS override parameters (history, depth, reliability) for a topic; ``callback``
    receives the profile after the overrides (before the entity is created)."""
    return QoSOverridingOptions.with_default_policies(callback=callback)


def resolve_reliability(requested: ReliabilityPolicy, publishers: Iterable[Any]) -> ReliabilityPolicy:
    """The reliability a subscription gets: ``requested``, or for ``BEST_AVAILABLE`` best effort when any of
    ``publishers`` (``TopicEndpointInfo``) is best effort, reliable otherwise."""
    if requested != ReliabilityPolicy.BEST_AVAILABLE:
        return requested
    if any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in publishers):
        return ReliabilityPolicy.BEST_EFFORT
    return ReliabilityPolicy.RELIABLE
