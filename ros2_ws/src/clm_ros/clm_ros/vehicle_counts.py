"""What happened in one train of the vehicle node (or, summed, in its life), and how it is reported.

Plain Python (no ROS): :class:`Counts` (the counters and answer lags of a
train), :meth:`Counts.report` (the log line at a train's end) and
:func:`diagnostics_values` (the key-value pairs of the node's
``/diagnostics``), :class:`VehicleStatus` (its state, level and latched
status). Lag figures through :func:`clm_core.io.timebase.lag_figures`,
the project's one lag-statistics helper.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterable
from dataclasses import dataclass, field, fields
from typing import Any

from clm_core.io.timebase import LagFigures, lag_figures

#: ``diagnostic_msgs/DiagnosticStatus`` levels (a ``byte`` field: one byte; a Python int there is not converted).
#: Typed ``Any`` as rclpy's own constants are, for the diagnostics helpers that annotate the level ``int``.
OK: Any = b"\x00"
WARN: Any = b"\x01"
ERROR: Any = b"\x02"


@dataclass
class Counts:
    """What happened in one train (or, summed, in the node's life).

    Attributes
    ----------
    lags_ns : array of int
        Lag of every answer: its receive time - its message's due time [ns].
    """

    published: int = 0
    answered: int = 0
    used: int = 0
    stale: int = 0
    after_end: int = 0
    unmatched: int = 0
    malformed: int = 0
    late: int = 0
    publish_failed: int = 0
    contact_lost_steps: int = 0
    model_cpu_s: float = 0.0
    model_messages: int = 0
    lags_ns: array[int] = field(default_factory=lambda: array("q"))

    def __add__(self, other: Counts) -> Counts:
        out = Counts()
        for f in fields(self):
            if f.name != "lags_ns":
                setattr(out, f.name, getattr(self, f.name) + getattr(other, f.name))
        return out

    def lags(self) -> LagFigures:
        """Median, 99th percentile and maximum of the answer lags [s] (NaN without answers)."""
        return lag_figures(self.lags_ns)

    def model_us(self) -> float:
        """CPU time of the vehicle model per message [us]."""
        return 1e6 * self.model_cpu_s / self.model_messages if self.model_messages else float("nan")

    def report(self, number: int, rate: float, stopped: bool) -> str:
        """The log line of train ``number`` published at ``rate`` [Hz] (``stopped``: ended by a stop)."""
        lag = self.lags()
        used = 100.0 * self.used / self.published if self.published else 0.0
        return (
            f"train {number}{' (stopped)' if stopped else ''}: published {self.published} wheel-load messages at "
            f"{rate} Hz ({self.late} late by > 2 periods), {self.answered} answered ({self.used} used as "
            f"feedback, {self.stale} too late, {self.after_end} after the last step); contact lost in "
            f"{self.contact_lost_steps} wheel-steps; vehicle model {self.model_us():.0f} us per message; feedback "
            f"{used:.1f} %, "
            + (f"answer lag median {1e3 * lag.median_s:.2f} ms, p99 {1e3 * lag.p99_s:.2f} ms, max "
               f"{1e3 * lag.max_s:.2f} ms" if self.answered else "no answer")
        )


def diagnostics_values(train: Counts, life: Counts, recent_lags_ns: Iterable[int], contact_lost_steps: int,
                       final: bool) -> dict[str, Any]:
    """The vehicle node's ``/diagnostics`` key-value pairs (without its state, train number and scheduling).

    Parameters
    ----------
    train, life : Counts
        The current (or last) train; the node's life so far.
    recent_lags_ns : iterable of int
        The latest answer lags [ns] (``recent_lag_*``).
    contact_lost_steps : int
        The running train's wheel-steps without contact so far.
    final : bool
        At a train's end: also the train's lag figures (``train.lag_median_s``, ...).
    """
    c = train
    recent = lag_figures(list(recent_lags_ns))
    values: dict[str, Any] = {
        "train.published": c.published,
        "train.answered": c.answered,
        "train.feedback_used": c.used,
        "train.feedback_total": c.published,
        "train.too_late": c.stale,
        "train.after_last_step": c.after_end,
        "train.late_publishes": c.late,
        "train.contact_lost_steps": contact_lost_steps,
        "train.model_us_per_message": f"{c.model_us():.1f}",
        "recent_lag_median_s": f"{recent.median_s:.6f}",
        "recent_lag_p99_s": f"{recent.p99_s:.6f}",
        "published": life.published,
        "answered": life.answered,
        "feedback_used": life.used,
        "too_late": life.stale,
        "unmatched": life.unmatched,
        "malformed": life.malformed,
        "late_publishes": life.late,
        "publish_failed": life.publish_failed,
    }
    if final:
        values.update({f"train.{k}": f"{v:.6f}" for k, v in c.lags().named().items()})
    return values


class VehicleStatus:
    """The vehicle node's state as ``/diagnostics`` and its latched ``vehicle_status`` say it (levels :data:`OK`,
    :data:`WARN`, :data:`ERROR`).

    Examples
    --------
    >>> s = VehicleStatus()
    >>> s.set("train 1: running", OK)
    >>> level, message, _ = s.diagnostics(Counts(published=200, stale=5), Counts(), [], 0, True, {})
    >>> level == WARN, message
    (True, 'train 1: running (5 of the last 200 answers too late for the closed loop)')
    >>> s.failed("stopped: model diverged"); s.latched({"train": 1})[0] == ERROR
    True
    """

    def __init__(self) -> None:
        self.text, self.level, self.phase, self.model_error = "unconfigured", OK, "idle", ""
        self.train_times = (0, 0)  # system clock [ns] of the current / last train's start and end
        self._final: dict[str, Any] = {}  # the last finished train's figures, as reported at its end
        self._mark = (0, 0)  # (published, too late) of the train at the last diagnostics

    def set(self, text: str, level: Any) -> None:
        """The state's text and level."""
        self.text, self.level = text, level

    def failed(self, text: str) -> None:
        """The train failed (the schedule ends): ERROR with ``text``."""
        self.model_error, self.phase = text, "stopped"
        self.set(text, ERROR)

    def latched(self, values: dict[str, Any]) -> tuple[Any, str, dict[str, Any]]:
        """(level, text, values) of the latched status: ``values`` (train number, trains done) with the phase, the
        state, the current train's start and end and the last finished train's figures."""
        return (ERROR if self.model_error else self.level, self.text,
                {"phase": self.phase, "state": self.text, **values, "train.start_ns": self.train_times[0],
                 "train.end_ns": self.train_times[1], **self._final})

    def diagnostics(self, train: Counts, life: Counts, recent_lags_ns: Iterable[int], contact_lost_steps: int,
                    closed_loop: bool, head: dict[str, Any], final: int = 0) -> tuple[Any, str, dict[str, Any]]:
        """(level, message, values) of a ``/diagnostics`` status: ``head`` and :func:`diagnostics_values`; with
        ``final`` (a train's number, at its end) also kept for the latched status. WARN in closed loop when more than
        1 % of the messages published since the last diagnostics (100 at least) were answered too late."""
        values = {**head, **diagnostics_values(train, life, recent_lags_ns, contact_lost_steps, bool(final))}
        if final:
            values["final_train"] = final
            self._final = {k: v for k, v in values.items() if k.startswith("train.") or k in (
                "final_train", "scheduling")}
        level, message = (ERROR if self.model_error else self.level), self.text
        published, stale = train.published - self._mark[0], train.stale - self._mark[1]
        self._mark = (train.published, train.stale) if train.published >= self._mark[0] else (0, 0)
        if level == OK and closed_loop and published >= 100 and stale > 0.01 * published:
            level = WARN
            message += f" ({stale} of the last {published} answers too late for the closed loop)"
        return level, message, values
