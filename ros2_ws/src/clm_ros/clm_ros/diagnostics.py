"""Diagnostics of the nodes: the /diagnostics message of all three (:func:`diagnostic_array`); the track node's
counters, answer lag on the stamps' clock and publishing thread.

Three pieces, independent of the node class so that they can be tested and
reused:

- :class:`Counters`: what happened to every wheel-load message, monotonic for
  the life of the node (a parameter update, a lifecycle transition or a new
  model never resets them).
- :class:`LagMonitor`: the lag of each answer, publish time minus the
  wheel-load stamp, measured on the clock the stamps use (sim time with
  ``/clock``, ROS time otherwise). Frames waiting to be answered count too
  (the lag of the oldest one grows while a backlog is worked off). A lag that
  cannot be measured (``use_sim_time`` without ``/clock``, or sim-time stamps
  read on the wall clock: 1.8e9 s) is reported as unavailable, never as a
  number.
- :class:`DiagnosticsThread`: publishes ``/diagnostics`` on its own thread, so
  that they arrive on time while the executor thread works off a backlog.

Levels (:func:`lag_level`): WARN when the largest lag of the period exceeds
``lag_budget``; ERROR when more than 1 % of the period's answers (or the
oldest frame still waiting) are older than ``max_feedback_delay``, i.e. too
late to be used as feedback by the vehicle.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.publisher import Publisher

from clm_core.io.timebase import NS, lag_figures
from clm_core.online import OnlineStats

OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR
STALE = DiagnosticStatus.STALE

#: A lag larger than this [s] (either sign) means the stamps are not on the node's clock.
CLOCK_MISMATCH_S = 86400.0

@dataclass
class Counters:
    """What the node did with the wheel-load messages; every field only grows.

    The model's own counters (:class:`clm_core.online.OnlineStats`: accepted,
    rejected per cause, resyncs, simulated time) are carried from model to
    model for the node's life; these are the node's. Once nothing is in
    flight, ``received = accepted + rejected + not_accepted``: every message
    taken from the middleware is accepted (and answered), rejected (counted
    per cause, ``malformed`` for undecodable bytes, the state untouched) or
    not accepted because the node was no longer active (no answer owed).
    """

    received: int = 0
    published: int = 0
    """Answers (pairs of SleeperResponse and WheelRailResponse) handed to the middleware."""
    not_accepted: int = 0
    """Taken while deactivating or after shutdown: discarded unprocessed, no answer owed."""
    internal_errors: int = 0
    """Messages lost to a defect of the node or the model (logged; should stay 0)."""
    publish_failed: int = 0
    """Answers the middleware refused."""
    lost: int = 0
    """Wheel loads the middleware reports lost (best-effort transport)."""
    batches: int = 0
    largest_batch: int = 0

    def values(self, stats: OnlineStats) -> dict[str, Any]:
        """The counters with the model's (``stats``) as diagnostics key-values."""
        rejected = Counter(stats.rejected)
        if self.internal_errors:
            rejected["internal_error"] += self.internal_errors
        return {
            "received": self.received,
            "accepted": stats.accepted,
            "published": self.published,
            "rejected": sum(rejected.values()),
            **{f"rejected.{k}": v for k, v in sorted(rejected.items())},
            "not_accepted": self.not_accepted,
            "resyncs": stats.resyncs,
            "publish_failed": self.publish_failed,
            "lost": self.lost,
            "batches": self.batches,
            "largest_batch": self.largest_batch,
        }


@dataclass(frozen=True)
class LagSummary:
    """Lag figures of one diagnostics period [s]; NaN when not available (``reason`` says why)."""

    answers: int
    median: float
    p99: float
    max: float
    late_fraction: float
    """Fraction of the period's answers older than ``max_feedback_delay``."""
    waiting: int
    """Most frames taken but not yet answered at one time in the period (a state of the period, not a sample of
    the instant the status is made: a backlog worked off in chunks shows even when the status is made between
    two chunks)."""
    oldest_waiting: float
    """Age of the oldest frame waiting now [s] (NaN: none)."""
    reason: str = ""
    """Why the lag is not available ('' when it is)."""
    min: float = float("nan")
    """Smallest lag of the period [s]: negative when the node's clock is behind the stamps."""

    @property
    def available(self) -> bool:
        """Whether the lag could be measured."""
        return not self.reason


class LagMonitor:
    """Answer lag on the stamps' clock, collected by the data path and summarised per diagnostics period.

    Parameters
    ----------
    now_ns : callable
        The node's clock [ns] (sim time with ``/clock`` and ``use_sim_time``;
        ROS time = system time otherwise); returns 0 while ``use_sim_time`` is
        set and no ``/clock`` has arrived.
    """

    def __init__(self, now_ns: Callable[[], int]) -> None:
        self.now_ns = now_ns
        self._answers: list[tuple[int, list[int]]] = []  # (publish time, stamps) [ns]
        self._waiting = 0
        self._peak = 0  # most frames waiting at once since the last summary
        self._oldest_ns = 0
        self._reason = ""  # why the last answers' lag could not be measured (kept through idle periods)

    def waiting(self, count: int, oldest_stamp_ns: int) -> None:
        """The data path took ``count`` frames (0: none left), the oldest stamped ``oldest_stamp_ns``."""
        self._waiting = count
        self._oldest_ns = oldest_stamp_ns
        if count > self._peak:
            self._peak = count

    def answered(self, stamps_ns: list[int]) -> None:
        """Answers to frames stamped ``stamps_ns`` [ns] were just published (kept as they are: the per-message
        path does no arithmetic; :meth:`summary` does it once per period)."""
        if stamps_ns:
            self._answers.append((self.now_ns(), stamps_ns))  # list.append: atomic under the GIL

    def summary(self, max_feedback_delay: float) -> LagSummary:
        """Figures since the last call (and reset for the next period)."""
        parts, self._answers = self._answers, []
        now = self.now_ns()
        nan = float("nan")
        now_waiting, oldest = self._waiting, nan
        waiting, self._peak = max(self._peak, now_waiting), now_waiting
        if now_waiting and now > 0:
            oldest = (now - self._oldest_ns) * 1e-9
        if now <= 0:
            return LagSummary(0, nan, nan, nan, nan, waiting, nan,
                              "use_sim_time is set and no /clock has arrived")
        lag_ns = np.concatenate([t - np.asarray(st, dtype=np.int64) for t, st in parts if t > 0]
                                or [np.zeros(0, dtype=np.int64)])
        ok = np.abs(lag_ns) < CLOCK_MISMATCH_S * NS
        bad = int(lag_ns.size - ok.sum()) + sum(len(st) for t, st in parts if t <= 0)
        if abs(oldest) >= CLOCK_MISMATCH_S:
            oldest, bad = nan, bad + 1
        if bad and not ok.any():
            self._reason = ("stamps are not on the node's clock (sim-time stamps: set use_sim_time and publish "
                            "/clock)")
        elif ok.any():
            self._reason = ""
        good = lag_ns[ok]
        if not good.size:
            return LagSummary(0, nan, nan, nan, nan, waiting, oldest, self._reason)
        f = lag_figures(good)  # the one lag statistic (median, p99, max) of the suite
        return LagSummary(
            f.n, f.median_s, f.p99_s, f.max_s, float(np.mean(good > max_feedback_delay * NS)), waiting, oldest,
            min=float(good.min()) / NS,
        )


def lag_level(lag: LagSummary, lag_budget: float, max_feedback_delay: float) -> tuple[int, str]:
    """Level and message of an active node from its lag figures.

    ERROR: more than 1 % of the period's answers, or the oldest frame still
    waiting, older than ``max_feedback_delay`` [s] (too late to be feedback);
    WARN: the largest lag above ``lag_budget`` [s], or the smallest below
    ``-lag_budget`` (the node's clock behind the stamps: a ``/clock`` behind or
    stopped; issue 26.9: -10 s was reported OK); OK otherwise (also idle).
    """
    if not lag.available:
        return OK, f"running; lag unavailable: {lag.reason}"
    waiting = 0.0 if np.isnan(lag.oldest_waiting) else lag.oldest_waiting
    worst = max(lag.max if lag.answers else 0.0, waiting)
    if lag.answers and lag.late_fraction > 0.01:
        return ERROR, (f"answers too late for the closed loop: {100 * lag.late_fraction:.1f} % older than "
                       f"max_feedback_delay = {1e3 * max_feedback_delay:g} ms (largest lag {1e3 * worst:.1f} ms)")
    if waiting > max_feedback_delay:
        return ERROR, (f"backlog: {lag.waiting} frame(s) waiting, the oldest {1e3 * waiting:.1f} ms old "
                       f"(max_feedback_delay = {1e3 * max_feedback_delay:g} ms)")
    if worst > lag_budget:
        return WARN, f"lag {1e3 * worst:.2f} ms over lag_budget = {1e3 * lag_budget:g} ms"
    behind = clock_behind(lag, lag_budget)
    if behind:
        return WARN, behind
    return OK, "running" if lag.answers else "running; no wheel loads in the last period"


def clock_behind(lag: LagSummary, lag_budget: float) -> str:
    """The warning when the period's smallest lag is below ``-lag_budget`` [s] (an answer published before its
    stamp's time: the node's clock is behind the stamps); '' when not (or no answer to tell)."""
    if not (lag.available and lag.answers and lag.min < -lag_budget):
        return ""
    return (f"negative lag {1e3 * lag.min:.1f} ms: the node's clock is behind the wheel-load stamps (sim time: "
            "/clock behind or stopped; else the sender's clock is ahead); lags unreliable")


def lag_values(lag: LagSummary) -> dict[str, Any]:
    """Diagnostics key-values of the lag figures (``unavailable: <reason>`` instead of numbers)."""
    if not lag.available:
        text = f"unavailable: {lag.reason}"
        return {"lag_median_s": text, "lag_p99_s": text, "lag_max_s": text, "waiting": lag.waiting}
    def fmt(x: float) -> str:
        return "nan" if np.isnan(x) else f"{x:.6f}"

    return {
        "answers_in_period": lag.answers,
        "lag_median_s": fmt(lag.median),
        "lag_p99_s": fmt(lag.p99),
        "lag_max_s": fmt(lag.max),
        "lag_min_s": fmt(lag.min),
        "late_fraction": fmt(lag.late_fraction),
        "waiting": lag.waiting,
        "oldest_waiting_s": fmt(lag.oldest_waiting),
    }


#: Longest value of a diagnostics key-value [characters] (a one-line outcome, an error message).
VALUE_LIMIT = 500


def diagnostic_array(name: str, level: bytes | int, message: str, values: Mapping[str, Any],
                     stamp: Any) -> DiagnosticArray:
    """A ``DiagnosticArray`` with one status (the ``/diagnostics`` message of every clm node).

    Parameters
    ----------
    name : str
        Status name, ``<fully qualified node name>: <what>`` (the namespace tells a fleet's pairs apart).
    level : bytes or int
        ``DiagnosticStatus`` level (:data:`OK`, :data:`WARN`, :data:`ERROR`: one byte; the message also takes 0-3).
    message : str
        One-line summary.
    values : mapping
        Key-values; each value as ``str(v)``, cut to :data:`VALUE_LIMIT` characters.
    stamp : builtin_interfaces.msg.Time
        Header stamp (the node's clock).
    """
    status = DiagnosticStatus(
        level=level, name=name, message=message, hardware_id="clm_core",
        values=[KeyValue(key=k, value=str(v)[:VALUE_LIMIT]) for k, v in values.items()],
    )
    arr = DiagnosticArray(status=[status])
    arr.header.stamp = stamp
    return arr


def publish_status(node: Node, publisher: Publisher, name: str, level: bytes | int, message: str,
                   values: Mapping[str, Any]) -> None:
    """Publish :func:`diagnostic_array` on ``publisher``, stamped now on ``node``'s clock; best effort: a failure
    (the context is going down) is logged at debug level."""
    try:
        publisher.publish(diagnostic_array(name, level, message, values, node.get_clock().now().to_msg()))
    except Exception as exc:  # context shutting down: diagnostics are best effort
        node.get_logger().debug(f"diagnostics not published: {exc}")


class DiagnosticsThread:
    """Call ``publish`` every ``period`` seconds on a thread of its own until :meth:`stop`.

    The executor thread may be busy for a while (a backlog worked off in one
    go); diagnostics must not wait for it. ``publish`` only reads counters
    (integers and references swapped atomically under the GIL) and publishes.
    A failing ``publish`` is reported once through ``on_error`` and retried
    at the next period.
    """

    def __init__(self, publish: Callable[[], None], period: float, on_error: Callable[[BaseException], None]) -> None:
        self._publish = publish
        self._period = float(period)
        self._on_error = on_error
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="clm_diagnostics", daemon=True)
        self._failed = False

    def start(self) -> None:
        """Start publishing."""
        self._thread.start()

    def _run(self) -> None:
        next_t = time.monotonic() + self._period
        while not self._stop.wait(max(next_t - time.monotonic(), 0.0)):
            next_t += self._period
            if next_t < time.monotonic():  # fell behind (suspended): no burst of catch-up publications
                next_t = time.monotonic() + self._period
            try:
                self._publish()
                self._failed = False
            except Exception as exc:  # a diagnostics failure must not end the node
                if not self._failed:
                    self._on_error(exc)
                self._failed = True

    def stop(self, timeout: float = 2.0) -> None:
        """Stop and wait for the thread (at most ``timeout`` s)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)
