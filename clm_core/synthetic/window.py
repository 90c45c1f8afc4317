"""Synthetic sleeper soil forces of a moving window (free-field tests and benchmarks).

:func:`moving_window_forces` gives what the track node publishes, in the
layout of ``history.npz`` (window-relative): a window of ``n_window``
sleepers centred on a load moving along the track, the load shared between
the two sleepers beside it (hat functions), plus a small ripple on every
sleeper (a signal in the band of the receiver filters). Used by
``tests/freefield`` (stream = offline, figures, the demo's bag reader),
``tests/ros/test_receiver_node.py`` and ``benchmarks/freefield_rtf.py``.
"""

from __future__ import annotations

import numpy as np

from clm_core.arrays import Array, IntArray

__all__ = ["moving_window_forces"]


def moving_window_forces(n: int, dt: float, speed: float = 60.0, n_window: int = 31, spacing: float = 0.6,
                         x0: float = -15.0, load: float = 85e3, ripple: float = 300.0,
                         ripple_hz: float = 30.0) -> tuple[Array, IntArray, Array]:
    """A window of sleepers following a moving load.

    Parameters
    ----------
    n : int
        Frames.
    dt : float
        Frame interval [s].
    speed : float
        Load speed [m/s].
    n_window : int
        Sleepers in the window (centred on the load: first = floor(x / d) - n_window // 2).
    spacing : float
        Sleeper spacing d [m] (sleeper j at x = j d).
    x0 : float
        Load position at t = 0 [m].
    load : float
        Moving load [N], shared between the sleepers beside it: F_j = load max(0, 1 - |x_j - x| / d).
    ripple, ripple_hz : float
        Amplitude [N] and frequency [Hz] of a sine added to every window sleeper.

    Returns
    -------
    t : (n,) array
        Times [s].
    first_sleeper : (n,) int array
        Global index of the window's first sleeper.
    soil_force : (n, n_window) array
        Forces on the window sleepers [N].
    """
    t = np.arange(n) * dt
    xw = x0 + speed * t
    first = np.floor(xw / spacing).astype(np.int64) - n_window // 2
    xs = (first[:, None] + np.arange(n_window)[None, :]) * spacing
    F = load * np.maximum(0.0, 1.0 - np.abs(xs - xw[:, None]) / spacing) + ripple * np.sin(2 * np.pi * ripple_hz * t)[
        :, None]
    return np.asarray(t, dtype=np.float64), first, np.asarray(F, dtype=np.float64)
