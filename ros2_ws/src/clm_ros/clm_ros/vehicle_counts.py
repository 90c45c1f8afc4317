"""What happened in one train of the vehicle node (or, summed, in its life), and how it is reported.

Plain Python (no ROS): :class:`Counts` (the counters and answer lags of a
train), :meth:`Counts.report` (the log line at a train's end) and
:func:`diagnostics_values` (the key-value pairs of the node's
``/diagnostics``). Lag figures through :func:`clm_core.io.timebase.lag_figures`,
the project's one lag-statistics helper.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterable
from dataclasses import dataclass, field, fields
from typing import Any

from clm_core.io.timebase import LagFigures, lag_figures


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
