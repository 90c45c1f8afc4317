"""Wheel-load streams for the track-node tests and their offline answers (the reference).

Two wheels 3 m apart at 30 m/s, 85 kN each; the same frames go to the node over
DDS (serialized with the numpy CDR codec) and through
:class:`clm_core.online.OnlineTrackModel` in this process.
"""

from __future__ import annotations

import numpy as np

from clm_core.io.messages import encode_wheel_loads
from clm_core.io.timebase import NS
from clm_core.online import OnlineTrackModel, ResponseFrame, WheelFrame
from clm_core.params import load_model

OFF = np.array([0.0, 3.0])
Stream = list[tuple[int, np.ndarray, np.ndarray]]


def frames(n: int, t0_ns: int, period_ns: int = 10**6, v: float = 30.0) -> Stream:
    """``n`` frames ``(stamp_ns, positions, forces)``, one per ``period_ns``, the front wheel from 30 m."""
    return [(t0_ns + k * period_ns, 30.0 - OFF + v * k * period_ns / NS, np.array([85e3, 85e3])) for k in range(n)]


def encoded(stream: Stream) -> list[bytes]:
    """Serialized ``WheelLoads`` of the frames (wheel ids 0 and 1)."""
    return [encode_wheel_loads(t, "track", [0, 1], p, f) for t, p, f in stream]


def offline(stream: Stream, model: OnlineTrackModel | None = None) -> list[ResponseFrame]:
    """The answers of a fresh default model (Mevergnies, 61 sleepers, dt 1e-4 s) to the frames."""
    m = model or OnlineTrackModel(load_model("mevergnies", "mevergnies", "clm"), dt=1e-4, n_sleepers=61)
    return [m.process(WheelFrame.of(t, [0, 1], p, f)) for t, p, f in stream]
