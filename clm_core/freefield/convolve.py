"""Receiver velocities from sleeper soil forces: offline (FFT) and streaming (frame by frame).

Both evaluate the discrete-time model of :mod:`clm_core.freefield.model`
(increments, Butterworth band limit, block-sum decimation, step-response
FIR) on the same numbers: :func:`receiver_velocity` by a zero-padded FFT
convolution of whole records, :class:`ReceiverStream` by a direct sum over a
ring buffer, one model step at a time, as the forces arrive. The two agree
to rounding (tests/freefield/test_stream.py: <= 1e-12 of the peak); the
band-limit filter runs with the same ``sosfilt`` recursion in both, sample
by sample, so the filtered increments are bit-equal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from clm_core.arrays import Array
from clm_core.errors import InputError
from clm_core.freefield.model import FreeFieldModel

__all__ = ["ReceiverStream", "VelocityRecord", "receiver_velocity", "zone_forces"]


@dataclass(frozen=True)
class VelocityRecord:
    """Receiver velocity histories.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Output times t_0 + m Delta [s].
    velocity : ndarray, shape (R, n)
        Vertical surface velocity at each receiver [m/s], positive downwards.
    """

    t: Array
    velocity: Array


def zone_forces(model: FreeFieldModel, first_sleeper: ArrayLike, soil_force: ArrayLike) -> Array:
    """Forces on the zone sleepers, shape (J, n) [N], from window-relative records.

    Parameters
    ----------
    model : FreeFieldModel
    first_sleeper : array_like of int, shape (n,)
        Global index of column 0 of ``soil_force`` at each instant.
    soil_force : array_like, shape (n, N)
        Ballast force on the soil under each window sleeper [N] (the layout of ``history.npz``).
    """
    fs = np.asarray(first_sleeper, dtype=np.int64).reshape(-1)
    F = np.asarray(soil_force, dtype=float)
    if F.ndim != 2 or F.shape[0] != fs.size:
        raise InputError(f"soil_force: need shape (n, N) with n = len(first_sleeper) = {fs.size}, got {F.shape}")
    if not np.all(np.isfinite(F)):
        raise InputError("soil_force: contains non-finite values")
    out = np.zeros((model.n_zone, fs.size))
    cols = fs[:, None] + np.arange(F.shape[1])[None, :] - model.first_sleeper
    ok = (cols >= 0) & (cols < model.n_zone)
    rows = np.broadcast_to(np.arange(fs.size)[:, None], cols.shape)
    out[cols[ok], rows[ok]] = F[ok]
    return out


def receiver_velocity(model: FreeFieldModel, t: ArrayLike, first_sleeper: ArrayLike,
                      soil_force: ArrayLike) -> VelocityRecord:
    """Offline receiver velocities of a whole record (FFT convolution).

    Parameters
    ----------
    model : FreeFieldModel
        Receivers, soil and FIR filters; ``model.dt`` must be the step of ``t``.
    t : array_like, shape (n,)
        Uniform input times [s].
    first_sleeper, soil_force
        As in :func:`zone_forces`.

    Returns
    -------
    VelocityRecord
        At every ``model.decimation``-th input time, from ``t[0]``.
    """
    tt = np.asarray(t, dtype=float).reshape(-1)
    if tt.size < 2:
        raise InputError(f"t: need at least 2 instants, got {tt.size}")
    steps = np.diff(tt)
    if not np.allclose(steps, model.dt, rtol=1e-6, atol=0.0):
        raise InputError(f"t: steps in [{steps.min():g}, {steps.max():g}] s; the model needs uniform "
                         f"dt = {model.dt:g} s")
    M = model.decimation
    n_out = (tt.size - 1) // M + 1
    if n_out - model.delay < 2:
        need = (model.delay + 1) * model.model_dt
        raise InputError(f"t: a record of {tt[-1] - tt[0]:.4g} s gives no receiver velocity: the filters' delay is "
                         f"{model.delay} model steps ({model.delay * model.model_dt:.4g} s); record more than "
                         f"{need:.4g} s")
    F = zone_forces(model, first_sleeper, soil_force)
    e = np.diff(F, axis=1, prepend=F[:, :1])
    c = model.decimation_taps
    nf = int(2 ** math.ceil(math.log2(tt.size + c.size)))
    full = np.fft.irfft(np.fft.rfft(e, n=nf, axis=1) * np.fft.rfft(c, n=nf)[None, :], n=nf, axis=1)
    b = full[:, : (n_out - 1) * M + 1: M]
    L = model.n_fir
    nfft = int(2 ** math.ceil(math.log2(n_out + L)))
    Bf = np.fft.rfft(b, n=nfft, axis=1)
    R = model.receivers.shape[0]
    v = np.zeros((R, n_out))
    for r in range(R):
        Gf = np.fft.rfft(model.step_response[:, r, :], n=nfft, axis=1)
        v[r] = np.fft.irfft(np.sum(Gf * Bf, axis=0), n=nfft)[:n_out]
    D = model.delay
    t_out = tt[0] + np.arange(n_out - D) * model.model_dt
    return VelocityRecord(t=t_out, velocity=np.ascontiguousarray(v[:, D:]))


class ReceiverStream:
    """Streaming receiver velocities: one frame of sleeper forces in, a velocity sample out every M frames.

    Gives the numbers of :func:`receiver_velocity` on the same forces (to
    rounding): the same increments, the same decimation FIR c (band limit and
    block sum) and the same step-response FIR g, both summed directly over
    ring buffers (increments of the last len(c) frames, decimated increments
    of the last L model steps) instead of by FFT. Only the contiguous range
    of zone sleepers whose buffers hold a non-zero value enters the sums
    (the others contribute exact zeros), so the cost follows the sleepers
    near the loads, not the zone.

    Parameters
    ----------
    model : FreeFieldModel
        Receivers, soil and FIR filters; frames must come every ``model.dt``.
    """

    def __init__(self, model: FreeFieldModel) -> None:
        self.model = model
        J, R, L = model.step_response.shape
        self._G = np.ascontiguousarray(model.step_response[:, :, ::-1].transpose(1, 0, 2)).reshape(R, J * L)
        self._c = np.ascontiguousarray(model.decimation_taps[::-1])
        K = self._c.size
        self._E = np.zeros((J, 2 * K))  # increments, per sleeper a doubled time ring
        self._B = np.zeros((J, 2 * L))  # decimated increments
        self._pe = 0
        self._pb = 0
        self._last_e = np.full(J, -(1 << 40), dtype=np.int64)  # frame of the last non-zero increment
        self._last_b = np.full(J, -(1 << 40), dtype=np.int64)  # model step of the last non-zero b
        self._prev = np.zeros(J)
        self._n = -1
        self._t0 = math.nan

    @property
    def frames(self) -> int:
        """Frames consumed."""
        return self._n + 1

    def push(self, t: float, sleeper_index: ArrayLike, soil_force: ArrayLike) -> tuple[float, Array] | None:
        """Consume one frame; return (t_out [s], velocities (R,) [m/s]) when a model step completes, else None.

        ``t_out`` = t - D Delta (the filters' delay, ``model.delay`` model steps).

        Parameters
        ----------
        t : float
            Time of the frame [s]; frames must be consecutive (``model.dt`` apart).
        sleeper_index : array_like of int, shape (N,)
            Global indices of the sleepers in the frame (the simulated window).
        soil_force : array_like, shape (N,)
            Their ballast forces on the soil [N]; sleepers not in the frame have F = 0.

        Raises
        ------
        InputError
            Mismatched arrays, non-finite forces, or a frame not ``dt`` after the previous one.
        """
        m = self.model
        idx = np.asarray(sleeper_index, dtype=np.int64).reshape(-1)
        F = np.asarray(soil_force, dtype=float).reshape(-1)
        if idx.size != F.size:
            raise InputError(f"frame: {idx.size} sleeper indices for {F.size} forces")
        if not np.all(np.isfinite(F)):
            raise InputError("frame: soil_force contains non-finite values")
        if not math.isfinite(t):
            raise InputError(f"frame: t = {t}: must be finite")
        n = self._n + 1
        if n == 0:
            self._t0 = float(t)
        else:
            expected = self._t0 + n * m.dt
            if abs(t - expected) > 1e-6 * m.dt + 1e-9:
                raise InputError(f"frame: t = {t:.9g} s, expected {expected:.9g} s (frames every dt = {m.dt:g} s, "
                                 "no gaps)")
        Fz = np.zeros(m.n_zone)
        pos, cols = m.zone_columns(idx)
        Fz[cols] = F[pos]
        if n == 0:
            self._prev = Fz
        e = Fz - self._prev
        self._prev = Fz
        self._last_e[e != 0.0] = n
        K = self._c.size
        p = self._pe
        self._E[:, p] = e
        self._E[:, p + K] = e
        self._pe = (p + 1) % K
        self._n = n
        if n % m.decimation:
            return None
        mstep = n // m.decimation
        live = np.nonzero(self._last_e > n - K)[0]
        b = np.zeros(m.n_zone)
        if live.size:
            lo, hi = int(live[0]), int(live[-1]) + 1
            b[lo:hi] = self._E[lo:hi, p + 1: p + 1 + K] @ self._c
        L = m.n_fir
        q = self._pb
        self._B[:, q] = b
        self._B[:, q + L] = b
        self._pb = (q + 1) % L
        self._last_b[b != 0.0] = mstep
        live = np.nonzero(self._last_b > mstep - L)[0]
        if live.size:
            lo, hi = int(live[0]), int(live[-1]) + 1
            window = np.ascontiguousarray(self._B[lo:hi, q + 1: q + 1 + L]).reshape(-1)  # oldest .. newest
            v = self._G[:, lo * L: hi * L] @ window
        else:
            v = np.zeros(m.receivers.shape[0])
        if mstep < m.delay:
            return None  # the velocity of an instant before the first frame
        return self._t0 + (mstep - m.delay) * m.model_dt, v
