"""Streams of wheel-load frames and exact comparisons of online models.

Helpers of tests/online and tests/ros/test_replay_online.py.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from clm_core.online import OnlineTrackModel, Rejected, ResponseFrame, WheelFrame

MS = 1_000_000  # one millisecond [ns]
WALL = 1_796_150_165_843_913_423  # a wall-clock stamp [ns] (the demo bag's first)
OFF = np.array([0.0, 3.0])  # two wheels, 3 m apart
FIELDS = ("sleeper_index", "sleeper_x", "soil_force", "rail_deflection", "sleeper_displacement", "area_displacement",
          "wheel_ids", "wheel_positions", "wheel_deflection", "wheel_velocity")


def stream(n: int, t0: int = 0, period: int = MS, v: float = 30.0, x0: float = 30.0, force: float = 85e3,
           ids: tuple[int, ...] = (0, 1)) -> list[WheelFrame]:
    """``n`` frames every ``period`` ns from ``t0``: wheels 3 m apart moving at ``v`` m/s, forces varying a little."""
    out = []
    for k in range(n):
        t = k * period / 1e9
        pos = x0 - np.arange(len(ids)) * 3.0 + v * t
        f = force * (1.0 + 0.05 * np.sin(2 * np.pi * 9.0 * t + np.arange(len(ids))))
        out.append(WheelFrame.of(t0 + k * period, list(ids), pos, f))
    return out


def same(a: ResponseFrame | Rejected, b: ResponseFrame | Rejected) -> bool:
    """Bit for bit the same answer (arrays compared as bytes: -0.0 and NaN patterns too)."""
    if isinstance(a, Rejected) or isinstance(b, Rejected):
        return isinstance(a, Rejected) and isinstance(b, Rejected) and a.reason == b.reason and str(a) == str(b)
    return (a.stamp_ns == b.stamp_ns and a.resynced == b.resynced
            and all(np.asarray(getattr(a, f)).tobytes() == np.asarray(getattr(b, f)).tobytes() for f in FIELDS))


def state(m: OnlineTrackModel) -> tuple[Any, ...]:
    """Everything a refused frame must leave unchanged: the simulator's state, wheel set, timeline, counters.

    (The candidate new timeline and the rejection counts are not in it: a stamp refusal updates the first, every
    refusal the second.)
    """
    s = m.sim._s
    W = len(m._slot_ids)
    # (the wheels at the last step: as many slots as the wheel set; a batch may have run with more, absent ones)
    arrays = (s.u, s.v, s.pk_force, s.pk_rail, s.prev_dofs, s.prev_vals, s.pos[:W], s.F[:W], m._pos[:W], m._F[:W])
    st = m.stats
    return (tuple(np.asarray(a).tobytes() for a in arrays), s.placement, s.op.orientation, s.k, s.t0,
            dict(m._slot), list(m._slot_ids), m.timeline.last, m.epoch_ns, m._prev_tick,
            st.accepted, st.resyncs, st.steps, st.simulated_ns)


def answers(m: OnlineTrackModel, frames: list[WheelFrame]) -> list[ResponseFrame | Rejected]:
    """``process`` of each frame in turn, refusals returned rather than raised."""
    out: list[ResponseFrame | Rejected] = []
    for f in frames:
        try:
            out.append(m.process(f))
        except Rejected as exc:
            out.append(exc)
    return out
