"""Excitation signals of the paper.

Eq. (1): f(t) = 0 for t < t0, A exp(-(t - t0)/t_d) for t >= t0.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.errors import ParameterError


def decay_pulse(t: ArrayLike, A: float = 1.0, t0: float = 0.05, td: float = 0.001) -> NDArray[np.float64]:
    """The exponential decay pulse of Eq. (1) [N].

    Parameters
    ----------
    t : array_like
        Times [s].
    A : float
        Amplitude [N] (the paper uses 1).
    t0 : float
        Onset [s] (0.05 s in the paper, for checking causality).
    td : float
        Decay time [s]: 0.001 s covers 0–80 Hz, 0.0001 s higher frequencies.
    """
    if td <= 0:
        raise ParameterError(f"td = {td}: decay time must be > 0")
    t = np.asarray(t, dtype=float)
    out = np.zeros_like(t)
    on = t >= t0
    out[on] = A * np.exp(-(t[on] - t0) / td)
    return out


def decay_pulse_spectrum(f: ArrayLike, A: float = 1.0, t0: float = 0.05, td: float = 0.001) -> NDArray[np.complex128]:
    """Continuous Fourier transform of Eq. (1), convention exp(-j w t): A td e^{-j w t0} / (1 + j w td) [N s]."""
    w = 2 * np.pi * np.asarray(f, dtype=float)
    return np.asarray(A * td * np.exp(-1j * w * t0) / (1 + 1j * w * td), dtype=np.complex128)
