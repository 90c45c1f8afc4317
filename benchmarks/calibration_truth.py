"""Impact records of a CLM chain made without the calibration's own machinery (issue 14).

The calibration fits the chain of :func:`clm_core.soil.chain.chain_response`
(banded solve at s = sigma + j w) to transfer functions estimated from sampled
records. Coverage measured on records made by the same discretisation as the
fit, or by the project's own generator (:mod:`clm_core.synthetic`:
Newmark, ``resample_poly``), could hide errors they share. This module makes
the records by another route, as an independent CLM-chain integrator would:

- **exact continuous-time response**: the chain of Eq. (7)-(8) (free ends,
  ``n_true`` areas, by default 40 more than the geophones span: the soil goes
  on beyond the last sensor) is written in first-order form
  x' = A x + b f(t) and diagonalised, A = V diag(lambda) V^-1; the response
  of each mode to a half-sine hammer pulse f = F0 sin(pi (t - t_h) / T_c),
  t_h <= t <= t_h + T_c, is integrated in closed form

      q(t) = g F0 [w0 e^{lambda t'} - e^{lambda (t' - a)} (lambda sin w0 a + w0 cos w0 a)] / (lambda^2 + w0^2)

  with t' = t - t_h, a = min(t', T_c), w0 = pi / T_c (no time step at all);
- **acquisition**: the force and the responses are evaluated at ``oversample``
  times the output rate and brought to it by a zero-phase Chebyshev type I
  IIR anti-alias filter in two stages (:func:`scipy.signal.decimate`, not the
  Kaiser FIR of ``resample_poly``), identical on every channel;
- **noise models** (:func:`add_noise`), the level being a fraction of a
  channel's rms over the 0.1 s after each hit (the project's SNR definition,
  :func:`clm_core.synthetic.add_noise`: "2 % noise" is an SNR of
  34 dB): ``proportional`` (white, a fraction of each channel's own rms),
  ``floor`` (white, the same standard deviation on every geophone: a
  fraction of the loaded area's rms), ``coloured`` (first-order
  autoregressive noise, coefficient 0.8, 36 % of its variance common to all
  geophones, standard deviation a fraction of each channel's own rms). The
  force channel gets white noise at ``force_noise`` times the level (of its
  own rms over the same window).

Used by ``benchmarks/calibration_coverage.py`` and the tests of issue 14
(``tests/calibration/test_trust.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import decimate, firwin, lfilter

from clm_core.arrays import Array
from clm_core.calibration.channels import ChannelSpec, unit_factor
from clm_core.calibration.signals import Recording
from clm_core.params import SoilParams
from clm_core.soil.chain import chain_matrices

NOISE_MODELS: tuple[str, ...] = ("proportional", "floor", "coloured")


@dataclass(frozen=True)
class CleanRecord:
    """Noise-free record on the output grid.

    Attributes
    ----------
    t : (n,) array [s]
    fs : float [Hz]
    force : (n,) array [N]
    responses : (n, n_ch) array, in each channel's quantity [SI]
    channels : tuple of ChannelSpec
    hit_times : tuple of float [s]
    soil : SoilParams
        Truth.
    n_true : int
        Areas of the simulated chain.
    """

    t: Array
    fs: float
    force: Array
    responses: Array
    channels: tuple[ChannelSpec, ...]
    hit_times: tuple[float, ...]
    soil: SoilParams
    n_true: int


def _modal_half_sine(lam: NDArray[np.complex128], t: Array, t_hit: float, t_c: float) -> NDArray[np.complex128]:
    """Closed-form integral of e^{lambda (t - tau)} sin(w0 (tau - t_hit)) over the pulse, (n_t, n_modes)."""
    w0 = math.pi / t_c
    tp = t - t_hit
    out = np.zeros((t.size, lam.size), dtype=complex)
    on = tp > 0
    tt = tp[on][:, None]
    a = np.minimum(tt, t_c)
    L = lam[None, :]
    out[on] = (w0 * np.exp(L * tt) - np.exp(L * (tt - a)) * (L * np.sin(w0 * a) + w0 * np.cos(w0 * a))) / (
        L * L + w0 * w0
    )
    return out


def _spec(topic: str, quantity: str, index: int) -> ChannelSpec:
    units = {"force": "N", "displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}[quantity]
    return ChannelSpec(
        name=topic,
        topic=topic,
        quantity=quantity,  # type: ignore[arg-type]
        units=units,
        factor=unit_factor(quantity, units, topic),
        location="area",
        index=index,
    )


def exact_impact(
    soil: SoilParams,
    measured: Sequence[int],
    fs: float = 1000.0,
    duration: float = 1.0,
    hit_times: Sequence[float] = (0.2,),
    pulse_duration: float = 0.003,
    amplitude: float = 10e3,
    quantity: str = "velocity",
    n_true: int | None = None,
    oversample: int = 16,
    anti_alias: str = "iir",
    coupling2: float = 0.0,
    skew: float = 0.0,
) -> CleanRecord:
    """Exact response of a free-ended CLM chain (Eq. 7-8) to half-sine hits on its centre area.

    Parameters
    ----------
    soil : SoilParams
        Truth (CLM, admissible).
    measured : sequence of int
        Area indices with a sensor (0 = hit area).
    fs : float
        Output sample rate [Hz].
    duration : float
        Record length [s].
    hit_times : sequence of float
        Pulse onsets [s].
    pulse_duration : float
        Half-sine contact time T_c [s].
    amplitude : float
        Peak force F0 [N].
    quantity : {'displacement', 'velocity', 'acceleration'}
        What the sensors measure.
    n_true : int, optional
        Areas of the simulated chain (odd); default 2 max|measured| + 41.
    oversample : int
        Evaluation points per output sample before the anti-alias filter
        (a product of factors <= 13; two stages of sqrt(oversample) when square).
    anti_alias : {'iir', 'fir'}
        ``iir``: zero-phase Chebyshev I, two stages (:func:`scipy.signal.decimate`);
        ``fir``: a **causal** linear-phase FIR (Kaiser, 24 output samples
        long, cut-off 0.8 x the output Nyquist frequency) in one stage, as a
        sigma-delta data logger does: every channel delayed alike by 12
        output samples.
    coupling2 : float
        Second-neighbour coupling, a fraction of k_c and d_c between areas
        i and i +- 2 (springs and dampers, like the first-neighbour ones):
        a truth outside the CLM family (issue 24) [-]; 0 = the CLM chain.
    skew : float
        The responses are sampled ``skew`` seconds late against the force
        (exactly: the modal solution at t - skew) [s].

    Returns
    -------
    CleanRecord
    """
    reach = max(abs(j) for j in measured)
    n_true = n_true or 2 * reach + 41
    c = n_true // 2
    M, C, K = (m.toarray() for m in chain_matrices(soil, n_true))
    if coupling2:
        for i in range(n_true - 2):
            for A_, v in ((K, coupling2 * soil.kc), (C, coupling2 * soil.dc)):
                A_[i, i] += v
                A_[i + 2, i + 2] += v
                A_[i, i + 2] -= v
                A_[i + 2, i] -= v
    Minv = np.diag(1.0 / np.diag(M))
    A = np.block([[np.zeros((n_true, n_true)), np.eye(n_true)], [-Minv @ K, -Minv @ C]])
    b = np.zeros(2 * n_true)
    b[n_true + c] = 1.0 / M[c, c]
    lam, V = np.linalg.eig(A)
    if np.max(lam.real) >= 0:
        raise ValueError(f"soil {soil}: the chain has a non-decaying mode (max Re lambda = {lam.real.max():g})")
    g = np.linalg.solve(V, b)
    n_out = int(round(duration * fs))
    dt = 1.0 / (fs * oversample)
    t = np.arange(n_out * oversample) * dt
    cols = [c + j for j in measured]
    Vu, Vv = V[cols], V[[n_true + k for k in cols]]
    f = np.zeros_like(t)
    u = np.zeros((t.size, len(cols)))
    v = np.zeros_like(u)
    w0 = math.pi / pulse_duration
    for th in hit_times:
        # the force record: the pulse averaged over each fine step (its point samples would hold
        # 1 - (pi dt / 2 T_c)^2 / 3 of its impulse, -0.036 % at 1 kHz x 16, and bias every fitted parameter alike)
        a = np.clip(t - dt / 2 - th, 0.0, pulse_duration)
        b = np.clip(t + dt / 2 - th, 0.0, pulse_duration)
        f += amplitude * (np.cos(w0 * a) - np.cos(w0 * b)) / (w0 * dt)
        q = _modal_half_sine(lam, t - skew, th, pulse_duration) * (amplitude * g)[None, :]
        u += np.real(q @ Vu.T)
        v += np.real(q @ Vv.T)
    if quantity == "displacement":
        y = u
    elif quantity == "velocity":
        y = v
    else:
        # a = M^-1 (f e_c - C v - K u) on the measured rows needs all areas: from the full state
        raise ValueError("exact_impact: quantity must be displacement or velocity")
    data = np.column_stack([f, y])
    if anti_alias == "fir":
        taps = firwin(24 * oversample + 1, 0.8 / oversample, window=("kaiser", 8.0))
        data = lfilter(taps, [1.0], data, axis=0)[::oversample]
    else:
        for q_ in _stages(oversample):
            data = decimate(data, q_, n=8, ftype="iir", axis=0, zero_phase=True)
    n = data.shape[0]
    ts = np.arange(n) / fs
    chans = tuple(_spec(f"/geo/{'p' if j >= 0 else 'm'}{abs(j):02d}", quantity, j) for j in measured)
    return CleanRecord(ts, fs, data[:, 0].copy(), np.ascontiguousarray(data[:, 1:]), chans, tuple(hit_times), soil,
                       n_true)


def _stages(q: int) -> list[int]:
    r = int(round(math.sqrt(q)))
    if r * r == q and r <= 13:
        return [r, r]
    if q <= 13:
        return [q]
    raise ValueError(f"oversample = {q}: use a square of an integer <= 13 or a value <= 13")


def add_noise(
    rec: CleanRecord, model: str, level: float, seed: int, force_noise: float = 1.0, window: float = 0.1
) -> Recording:
    """A noisy :class:`~clm_core.calibration.signals.Recording` of a clean record.

    Parameters
    ----------
    rec : CleanRecord
    model : {'proportional', 'floor', 'coloured'}
        Noise model (module docstring).
    level : float
        Noise standard deviation as a fraction of the channel's rms over
        ``window`` seconds from each hit (``floor``: of the loaded area's) [-],
        e.g. 0.02 for "2 % noise" (SNR 34 dB).
    seed : int
        Random seed.
    force_noise : float
        Force-channel noise level relative to ``level`` [-].
    window : float
        Length of the rms window after each hit [s].
    """
    if model not in NOISE_MODELS:
        raise ValueError(f"noise model {model!r}: one of {NOISE_MODELS}")
    rng = np.random.default_rng(seed)
    n, n_ch = rec.responses.shape
    act = np.zeros(n, dtype=bool)
    for th in rec.hit_times:
        act |= (rec.t >= th) & (rec.t < th + window)
    rms = np.sqrt(np.mean(rec.responses[act] ** 2, axis=0))
    if model == "proportional":
        noise = rng.normal(size=(n, n_ch)) * (level * rms)[None, :]
    elif model == "floor":
        i0 = [k for k, ch in enumerate(rec.channels) if ch.index == 0]
        ref = rms[i0[0]] if i0 else rms.max()
        noise = rng.normal(size=(n, n_ch)) * level * ref
    else:
        phi = 0.8
        e = lfilter([1.0], [1.0, -phi], rng.normal(size=(n + 200, n_ch)), axis=0)[200:]
        common = lfilter([1.0], [1.0, -phi], rng.normal(size=n + 200))[200:]
        z = (0.8 * e + 0.6 * common[:, None]) / math.sqrt(1.0 / (1.0 - phi * phi))
        noise = z * (level * rms)[None, :]
    fpk = float(np.sqrt(np.mean(rec.force[act] ** 2)))
    force = rec.force + rng.normal(size=n) * level * force_noise * fpk
    return Recording(
        t=rec.t,
        fs=rec.fs,
        force=force,
        responses=rec.responses + noise,
        channels=rec.channels,
        force_spec=_spec("/hammer/force", "force", 0),
    )
