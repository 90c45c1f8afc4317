"""Excitation signals of the paper.

Eq. (1): f(t) = 0 for t < t0, A exp(-(t - t0)/t_d) for t >= t0.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.checks import finite, positive
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

    Raises
    ------
    ParameterError
        ``A``, ``t0`` or a time not a finite number, or ``td`` not > 0.
    """
    A, t0, td = _pulse(A, t0, td)
    try:
        t = np.asarray(t, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"t = {t!r}: times must be real numbers [s]") from None
    if not np.all(np.isfinite(t)):
        raise ParameterError(f"t = {t[~np.isfinite(t)][0]} s: times must be finite")
    out = np.zeros_like(t)
    on = t >= t0
    out[on] = A * np.exp(-(t[on] - t0) / td)
    return out


def decay_pulse_spectrum(f: ArrayLike, A: float = 1.0, t0: float = 0.05, td: float = 0.001) -> NDArray[np.complex128]:
    """Continuous Fourier transform of Eq. (1), convention exp(-j w t): A td e^{-j w t0} / (1 + j w td) [N s].

    Raises
    ------
    ParameterError
        As :func:`decay_pulse` (a frequency [Hz] in place of a time).
    """
    A, t0, td = _pulse(A, t0, td)
    w = 2 * np.pi * np.asarray(f, dtype=float)
    if not np.all(np.isfinite(w)):
        raise ParameterError(f"f = {w[~np.isfinite(w)][0] / (2 * np.pi)} Hz: frequencies must be finite")
    return np.asarray(A * td * np.exp(-1j * w * t0) / (1 + 1j * w * td), dtype=np.complex128)


def _pulse(A: float, t0: float, td: float) -> tuple[float, float, float]:
    """The pulse parameters of Eq. (1), checked: A [N] and t0 [s] finite, td [s] > 0."""
    return finite("A", A), finite("t0", t0), positive("td", td, unit="s")
