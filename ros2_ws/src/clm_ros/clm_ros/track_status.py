"""The track node's ``/diagnostics`` status: level, message and key-values from what the node holds.

:class:`TrackStatus` is plain Python (the node publishes what it builds,
from its diagnostics thread): the lifecycle state, the counters of the node
and its model, the lag figures of the period
(:class:`clm_ros.diagnostics.LagMonitor`, :func:`clm_ros.diagnostics.lag_level`),
the sources and peers of the input (:class:`clm_ros.track_input.WheelLoadInput`),
the data path's time (:class:`clm_ros.track_answers.AnswerPath`).

A status is a state, not one sample: a clock found behind the stamps
(negative lags, :func:`~clm_ros.diagnostics.lag_level`) stays WARN through
periods without answers until an answer's lag shows the clock caught up;
rejections and second-source refusals turn a period WARN when they happened
since the previous status.
"""

from __future__ import annotations

from typing import Any

from clm_core.io.timebase import NS
from clm_ros.diagnostics import ERROR, OK, STALE, WARN, LagSummary, clock_behind, lag_level, lag_values
from clm_ros.track_answers import AnswerPath
from clm_ros.track_input import WheelLoadInput

__all__ = ["TrackStatus"]


class TrackStatus:
    """Builds the track node's status, period after period (one caller: the diagnostics thread).

    Parameters
    ----------
    input : WheelLoadInput
        The wheel-load input (sources, peers, reliability, the node's counters).
    """

    def __init__(self, input: WheelLoadInput) -> None:
        self.input = input
        self._mark = (0, 0.0, 0.0, 0)  # (simulated ns, busy s, CPU s, received) at the previous status
        self._rejected_seen = 0
        self._second_seen = 0
        self._clock_behind = ""  # the WARN message while the node's clock is found behind the stamps

    def build(self, state: str, configure_error: str, path: AnswerPath | None, lag: LagSummary, lag_budget: float,
              max_feedback_delay: float, scheduling: str) -> tuple[int, str, dict[str, Any]]:
        """Level, message and key-values now.

        Parameters
        ----------
        state : str
            The lifecycle state (``unconfigured``, ``inactive``, ``active``, ``finalized``).
        configure_error : str
            Why the last configure failed ('' if it did not).
        path : AnswerPath or None
            The data path (None while unconfigured).
        lag : LagSummary
            The lag figures of the period.
        lag_budget, max_feedback_delay : float
            The node's thresholds [s].
        scheduling : str
            How the process is scheduled (:class:`clm_ros.realtime.Scheduling` text).
        """
        inp = self.input
        counters, stats = inp.counters, inp.stats
        busy, cpu = (path.busy_s, path.cpu_s) if path is not None else (self._mark[1], self._mark[2])
        now = (stats.simulated_ns, busy, cpu, counters.received)
        d_sim, d_busy, d_cpu, d_msgs = (a - b for a, b in zip(now, self._mark))
        self._mark = now
        rejected = stats.rejected_total + counters.internal_errors
        new_rejections, self._rejected_seen = rejected - self._rejected_seen, rejected
        second = sum(inp.sources.refused.values())
        new_second, self._second_seen = second - self._second_seen, second
        if state == "active":
            level, message = self._lag_state(lag, lag_budget, max_feedback_delay)
            if new_second and level == OK:
                level, message = WARN, (f"second wheel-load source: {new_second} message(s) of "
                                        f"{len(inp.sources.refused)} other publisher(s) refused in the last period; "
                                        f"answering only {inp.sources.values()['wheel_load_source']}")
            elif level == OK and new_rejections:
                level, message = WARN, f"{new_rejections} wheel-load message(s) rejected in the last period"
        elif state == "finalized":
            level, message = STALE, "finalized: not answering"
        elif state == "unconfigured" and configure_error:
            level, message = ERROR, f"unconfigured: configure refused: {configure_error}"
        else:
            level, message = OK, f"{state}: not subscribed to wheel_loads"
        model = path.model if path is not None else None
        values = {
            "state": state,
            **counters.values(stats),
            **lag_values(lag),
            "lag_budget_s": f"{lag_budget:g}",
            "max_feedback_delay_s": f"{max_feedback_delay:g}",
            "real_time_factor": f"{d_sim * 1e-9 / d_busy:.3f}" if d_busy > 0 else "nan",
            "data_path_cpu_us_per_message": f"{1e6 * d_cpu / d_msgs:.1f}" if d_msgs else "nan",
            "clock_behind_stamps": "true" if self._clock_behind else "false",
            **inp.values(),
            "scheduling": scheduling,
            "sim_time_s": f"{model.time_ns / NS:.6f}" if model is not None and model.time_ns is not None else "nan",
        }
        return level, message, values

    def _lag_state(self, lag: LagSummary, lag_budget: float, max_feedback_delay: float) -> tuple[int, str]:
        """:func:`lag_level` of the period, the clock-behind WARN held while no answer shows it caught up."""
        level, message = lag_level(lag, lag_budget, max_feedback_delay)
        if lag.available and lag.answers:
            self._clock_behind = clock_behind(lag, lag_budget)
        if level == OK and self._clock_behind:
            return WARN, self._clock_behind
        return level, message
