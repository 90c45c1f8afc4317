"""Reference impact responses from the rigorous frequency-domain flexibility.

The paper checks its CLM chain against time histories of the contact areas
under the decay pulse of Eq. (1) (A = 1 N, t0 = 0.05 s, td = 0.001 s),
Fig. 7. Here the same histories are synthesised from the rigorous
flexibility H(f) of the row (:mod:`clm_core.halfspace.bem`) by inverse FFT.

Conventions and choices
-----------------------
- Fourier pair: F(w) = int f(t) e^{-i w t} dt, f(t) = (1/2 pi) int F(w)
  e^{+i w t} dw (time convention exp(+i w t), as everywhere in the suite);
  the pulse spectrum is A td e^{-i w t0} / (1 + i w td).
- Band limit: H is known only up to f_max (150 Hz by default), while the
  pulse with td = 1 ms still has 73 % of its static spectral level at
  150 Hz. Rather than invent H beyond f_max, the pulse itself is low-passed
  by a causal analog Butterworth filter (order ``order``, cut-off
  ``cutoff`` x f_max; default 8th order at f_max / 2, i.e. -48 dB at f_max)
  and the spectrum is cut at f_max. The returned ``force`` is that
  band-limited pulse, so force and responses form an exact input–output
  pair of the rigorous model: feed the same ``force`` to a CLM simulation
  to compare. Being causal, the filter adds no precursor before t0 (a
  zero-phase taper would). ``pulse_exact`` holds Eq. (1) for reference.
- Zero frequency: H(0) is the static flexibility (the BEM solves w = 0
  directly), so the displacement has the correct static level and there is
  no 0/0 at w = 0. The frequency grid must start at 0 and be uniform.
- Causality: the record length is T = 1 / df (1 s for 1 Hz steps); the
  response must have decayed within T - t0 (the soil's radiation damping
  ensures it for the paper's soils; the wrap-around residue is reported as
  ``wrap_residual``). The cut at f_max leaves a small non-causal residue
  before t0, reported as ``precursor`` (~1e-3 of the peak).
- The time step is 1 / (2 f_pad) with f_pad = ``oversample`` x f_max
  (zero padding of the spectrum above f_max).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

from clm_core.errors import InputError, ParameterError

__all__ = ["ImpactResponse", "impact_response", "save_impact_npz"]


@dataclass(frozen=True)
class ImpactResponse:
    """Time histories of the areas of a row under the Eq. (1) pulse on the centre area.

    Attributes
    ----------
    time : ndarray, shape (nt,)
        Time [s], from 0 with step ``dt``.
    force : ndarray, shape (nt,)
        Band-limited pulse actually applied [N] (see the module docstring).
    pulse_exact : ndarray, shape (nt,)
        Eq. (1) without band limit [N].
    displacement : ndarray, shape (n_areas, nt)
        Vertical displacement of each area [m], downwards positive.
    velocity : ndarray, shape (n_areas, nt)
        Vertical velocity [m/s].
    positions : ndarray, shape (n_areas,)
        Area positions along the track [m] (0 at the loaded area).
    f_max : float
        Band limit [Hz].
    precursor : float
        max |x(t)| for t < t0 - 5 ms over max |x| (non-causal leakage) [-].
    wrap_residual : float
        max |x| over the last 5 % of the record over max |x| [-].
    """

    time: NDArray[np.float64]
    force: NDArray[np.float64]
    pulse_exact: NDArray[np.float64]
    displacement: NDArray[np.float64]
    velocity: NDArray[np.float64]
    positions: NDArray[np.float64]
    f_max: float
    amplitude: float
    t0: float
    td: float
    precursor: float
    wrap_residual: float


def impact_response(
    freqs: ArrayLike,
    flexibility: ArrayLike,
    *,
    positions: ArrayLike | None = None,
    amplitude: float = 1.0,
    t0: float = 0.05,
    td: float = 0.001,
    cutoff: float = 0.5,
    order: int = 8,
    oversample: float = 4.0,
) -> ImpactResponse:
    """Time responses of the areas to the Eq. (1) pulse on the loaded area.

    Parameters
    ----------
    freqs : array_like, shape (nf,)
        Uniform frequency grid from 0 [Hz] (e.g. 0..150 Hz by 1 Hz).
    flexibility : array_like of complex, shape (nf, n_areas)
        X_j(f) / F for a unit force on the loaded area [m/N], e.g.
        :attr:`clm_core.halfspace.bem.RowResult.centre_column`.
    positions : array_like, optional
        Area positions [m] (stored only).
    amplitude : float
        Pulse amplitude A [N] (the paper: 1 N).
    t0 : float
        Pulse onset [s] (0.05 s).
    td : float
        Decay time [s] (0.001 s).
    cutoff : float
        Cut-off of the Butterworth low-pass as a fraction of f_max (0 < . <= 1).
    order : int
        Order of the Butterworth low-pass (>= 1).
    oversample : float
        Time step 1 / (2 oversample f_max) [s].

    Returns
    -------
    ImpactResponse
    """
    f = np.asarray(freqs, dtype=float)
    H = np.asarray(flexibility, dtype=np.complex128)
    if H.ndim == 1:
        H = H[:, None]
    if f.ndim != 1 or f.size < 8:
        raise InputError(f"freqs: need a 1-D grid of >= 8 frequencies, got shape {f.shape}")
    if H.shape[0] != f.size:
        raise InputError(f"flexibility: first axis {H.shape[0]} differs from len(freqs) = {f.size}")
    if f[0] != 0.0:
        raise InputError(f"freqs[0] = {f[0]:g} Hz: the grid must start at 0 Hz (static value)")
    df = float(f[1] - f[0])
    if df <= 0 or not np.allclose(np.diff(f), df, rtol=1e-9, atol=1e-12):
        raise InputError("freqs: must be uniformly spaced")
    if not np.all(np.isfinite(H)):
        raise InputError("flexibility: contains non-finite values")
    if td <= 0:
        raise ParameterError(f"td = {td:g} s: decay time must be > 0")
    if not 0.0 < cutoff <= 1.0:
        raise ParameterError(f"cutoff = {cutoff:g}: must lie in (0, 1] (fraction of f_max)")
    if order < 1:
        raise ParameterError(f"order = {order}: must be >= 1")
    if oversample < 1.0:
        raise ParameterError(f"oversample = {oversample:g}: must be >= 1")
    T = 1.0 / df
    if not 0.0 <= t0 < 0.5 * T:
        raise ParameterError(f"t0 = {t0:g} s: must lie in [0, T/2) with T = 1/df = {T:g} s")
    f_max = float(f[-1])
    n_half = int(math.ceil(oversample * f_max / df)) + 1
    nt = 2 * (n_half - 1)
    fg = np.arange(n_half) * df
    w = 2.0 * math.pi * fg
    P = amplitude * td * np.exp(-1j * w * t0) / (1.0 + 1j * w * td)
    b, a = signal.butter(order, 2.0 * math.pi * cutoff * f_max, analog=True)
    _, lp = signal.freqs(b, a, worN=w)
    lp = np.where(fg <= f_max * (1 + 1e-12), lp, 0.0)
    Pt = P * lp
    Hg = np.zeros((n_half, H.shape[1]), dtype=np.complex128)
    Hg[: f.size] = H
    dt = 1.0 / (nt * df)
    # continuous inverse transform: x(t) = (1/2 pi) int X e^{i w t} dw ~ irfft(X) / dt
    force = np.fft.irfft(Pt, n=nt) / dt
    X = Hg * Pt[:, None]
    disp = np.fft.irfft(X, n=nt, axis=0).T / dt
    vel = np.fft.irfft(1j * w[:, None] * X, n=nt, axis=0).T / dt
    t = np.arange(nt, dtype=np.float64) * dt
    exact = np.where(t >= t0, amplitude * np.exp(-(np.maximum(t - t0, 0.0)) / td), 0.0)
    peak = float(np.max(np.abs(disp))) or 1.0
    pre = t < t0 - 0.005
    precursor = float(np.max(np.abs(disp[:, pre]))) / peak if pre.any() else 0.0
    tail = t >= 0.95 * T
    wrap = float(np.max(np.abs(disp[:, tail]))) / peak
    pos = np.zeros(H.shape[1]) if positions is None else np.asarray(positions, dtype=float)
    if pos.shape != (H.shape[1],):
        raise InputError(f"positions: shape {pos.shape} differs from the {H.shape[1]} areas")
    return ImpactResponse(
        time=t,
        force=force,
        pulse_exact=exact,
        displacement=disp,
        velocity=vel,
        positions=pos,
        f_max=f_max,
        amplitude=amplitude,
        t0=t0,
        td=td,
        precursor=precursor,
        wrap_residual=wrap,
    )


def save_impact_npz(response: ImpactResponse, path: str | Path) -> Path:
    """Save an :class:`ImpactResponse` as a NumPy ``.npz`` archive; returns the path.

    Arrays: ``time`` [s], ``force`` [N], ``pulse_exact`` [N],
    ``displacement`` [m] (n_areas, nt), ``velocity`` [m/s], ``positions`` [m];
    scalars ``f_max`` [Hz], ``amplitude`` [N], ``t0`` [s], ``td`` [s],
    ``precursor``, ``wrap_residual``.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        p,
        time=response.time,
        force=response.force,
        pulse_exact=response.pulse_exact,
        displacement=response.displacement,
        velocity=response.velocity,
        positions=response.positions,
        f_max=response.f_max,
        amplitude=response.amplitude,
        t0=response.t0,
        td=response.td,
        precursor=response.precursor,
        wrap_residual=response.wrap_residual,
    )
    return p
