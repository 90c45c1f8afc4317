"""Receiver transfer functions and their causal FIR filters (step 2 of the two-step method).

The two-step method (Kouroussis et al. 2011, Sec. 2: the sleeper soil forces
"evaluate the ground vibrations induced on the neighbourhood"): step 1, the
CLM track model gives the ballast force F_j(t) on each sleeper's contact
area (global sleeper index j, centre x_j = j d along the track, y = 0);
step 2, these forces act on the free surface of the soil (uniform pressure
F_j / (2a 2b) over the area, the other areas not interacting: no
soil–structure coupling in step 2) and the vertical surface velocity at a
receiver (x_r, y_r) is

    v_r(t) = sum_j int h_jr(tau) F_j(t - tau) d tau,

h_jr the velocity impulse response of the pair (area j, receiver r).

Transfer functions
------------------
U_jr(w) = (1 / A) int_area u_z(|x - x_r|, w) dA, u_z the point-load surface
Green's function of the layered half-space (:mod:`clm_core.halfspace.green`,
time dependence exp(+i w t), displacement and force positive downwards):
the Boussinesq part c0 / rho is integrated in closed form
(:func:`clm_core.halfspace.bem.rect_inverse_distance`, valid for a receiver
anywhere, on an area included), the smooth remainder g_s by Gauss–Legendre
points (at least 3 per Rayleigh wavelength at the top frequency). The
velocity transfer function is H_jr(w) = i w U_jr(w).

Discrete-time model (causal, exact to rounding in both evaluations)
------------------------------------------------------------------
Forces arrive at the input step dt (the simulator's output interval or the
track node's frame period). With M = max(1, floor(1 / (dt f_model))) the
model step is Delta = M dt (f_s = 1 / Delta, about ``model_rate`` = 250 Hz):

1. increments e_j[n] = F_j[n] - F_j[n-1], with F_j[-1] = F_j[0]: before the
   first input the forces are held at their first value (the simulator
   starts from static equilibrium, whose velocity field is zero), so a run
   does not start with a spurious load step; a sleeper outside the
   simulated window has F = 0 (it enters and leaves with one increment);
2. band limit: a causal digital Butterworth low-pass (order 8, cut-off
   ``band`` = 100 Hz, -0.1 dB at 80 Hz) on e_j at the input rate (this is
   the anti-alias filter of the decimation; it is part of the model and
   delays the response by its group delay, about 8 ms at low frequency);
   its impulse response is cut where it falls below 1e-16 of its peak
   (a FIR of about 300 taps at 1 kHz);
3. decimation by block sums b_j[m] = sum over the M inputs (m-1)M+1 .. mM
   (the increment of the filtered force over one model step); steps 2 and
   3 are one FIR c = (cut Butterworth response) * (M ones) evaluated at
   every M-th input (:func:`decimation_filter`);
4. v_r[m] = sum_j sum_{k=0}^{L-1} g_jr[k] b_j[m-k] with g_jr the step
   response of the velocity FIR: g[k] = sum_{i<=k} h[i], h = irfft of
   H_jr(f_k) T(f_k) on f_k = k f_s / N (N >= 2 L), T a cosine taper from
   ``band`` to 1.25 ``band`` (zero above, so H is never needed beyond the
   Nyquist frequency), delayed by D = ceil(6 f_s / ``band``) model steps
   (the zero-phase taper's precursor, about 6 periods of the band limit,
   then lies at positive lags instead of being cut off) and truncated to
   its first L taps (``memory`` = the longest travel time
   r_max / (0.87 c_s,min) + ``tail``, plus D). The few taps left beyond
   (the remaining precursor, indices >= 3L/2 of the FFT period) are folded
   into the first tap and those beyond the memory into the last one, so
   that g ends at exactly zero (a constant force gives no velocity); the
   largest of them relative to the peak tap is
   :attr:`FreeFieldModel.leakage`.

Outputs: v_r[m] is the velocity at t_0 + (m - D) Delta; the offline record
starts at t_0 (the first D outputs precede the first input and are dropped)
and ends D steps before the last input; the stream returns the velocity of
t - D Delta with the frame of time t (a latency of D Delta, 60 ms at the
default 100 Hz band and 250 Hz model rate). Sleepers farther than
``influence_length`` along the track from a receiver are left out for that
receiver, and those in its last 30 % are faded out by a cosine weight, so
that loads enter and leave the zone gradually (an abrupt edge sends a
spurious Rayleigh pulse to the receiver as the train enters the zone);
docs/freefield.md gives the truncation error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import signal, sparse

from clm_core.arrays import Array, CArray, IntArray
from clm_core.checks import positive
from clm_core.errors import InputError, ParameterError
from clm_core.freefield import cache as fcache
from clm_core.halfspace.bem import rect_inverse_distance
from clm_core.halfspace.green import KernelEngine, lagrange_weights
from clm_core.profile import SoilProfile

__all__ = ["AreaTransfer", "FreeFieldModel", "band_filter", "receivers_from_distances"]

#: Order of the Butterworth band limit (anti-alias filter) on the force increments.
BAND_ORDER = 8
#: Gauss points per Rayleigh wavelength (at the top frequency) over a contact area.
POINTS_PER_WAVELENGTH = 3.0
#: Radial grid points of the Green's function per Rayleigh wavelength at the top frequency (4-point Lagrange
#: interpolation: relative error ~ 1e-3).
DR_PER_WAVELENGTH = 16.0
#: Part of the influence length over which the sources are faded out (cosine) towards its end.
EDGE_FRACTION = 0.3
#: Delay of the FIR filters in periods of the band limit (keeps the band limit's precursor causal). The precursor
#: left out is the error that converges with it: moving-load check at 8 m, 2.26 % (3 periods), 1.70 % (4), 1.93 %
#: (5), 1.66 % (6), 1.69 % (8), 1.58 % (12); docs/validation.md.
PRECURSOR_CYCLES = 6.0


def receivers_from_distances(distances: ArrayLike, x: float = 0.0) -> Array:
    """Receivers (R, 2) at distances ``distances`` [m] from the track axis, all at position ``x`` [m]."""
    y = np.atleast_1d(np.asarray(distances, dtype=float))
    if y.ndim != 1 or y.size == 0 or not np.all(np.isfinite(y)):
        raise InputError(f"receiver distances {distances!r}: need finite numbers [m]")
    return np.column_stack([np.full(y.size, float(x)), y])


def band_filter(band: float, dt: float) -> Array:
    """Second-order sections of the causal Butterworth band limit (order 8, cut-off ``band`` [Hz], step ``dt`` [s])."""
    return np.asarray(signal.butter(BAND_ORDER, band, btype="low", output="sos", fs=1.0 / dt), dtype=np.float64)


def decimation_filter(sos: Array, decimation: int) -> Array:
    """FIR taps c of the band limit followed by the block sum of ``decimation`` inputs: b[m] = sum_i c[i] e[mM - i].

    c = (Butterworth impulse response, cut where its tail is below 1e-16 of its peak) * (M ones).
    """
    n = 256
    while True:
        x = np.zeros(n)
        x[0] = 1.0
        h = signal.sosfilt(sos, x)
        peak = float(np.max(np.abs(h)))
        big = np.nonzero(np.abs(h) > 1e-16 * peak)[0]
        if big[-1] < n - n // 4 or n > 1 << 20:
            break
        n *= 2
    h = h[: big[-1] + 1]
    return np.asarray(np.convolve(h, np.ones(decimation)), dtype=np.float64)


class AreaTransfer:
    """Surface vertical displacement at receivers per unit force spread uniformly over a contact area [m/N].

    U(w) = (1/A) int_area u_z(rho, w) dA for area-receiver pairs: the
    Boussinesq part c0 / rho in closed form (any receiver position, on the
    area included), the smooth remainder by Gauss–Legendre points (at least
    ``POINTS_PER_WAVELENGTH`` per Rayleigh wavelength at ``f_top``) and
    4-point interpolation on the radial grid of :class:`KernelEngine`.

    Parameters
    ----------
    profile : SoilProfile
    dx, y : array_like, shape (P,)
        Area centre minus receiver along the track, and receiver distance
        from the area's centre line (the track axis) [m].
    f_top : float
        Highest frequency [Hz].
    contact_length, contact_width : float
        Area across and along the track [m] (both 0: point loads).
    """

    def __init__(self, profile: SoilProfile, dx: ArrayLike, y: ArrayLike, f_top: float,
                 contact_length: float, contact_width: float) -> None:
        dxa = np.atleast_1d(np.asarray(dx, dtype=float))
        ya = np.atleast_1d(np.asarray(y, dtype=float))
        n_p = dxa.size
        lam = 0.87 * profile.min_cs / f_top
        pts = []
        for size in (contact_width, contact_length):
            n = max(1, int(math.ceil(POINTS_PER_WAVELENGTH * size / lam))) if size > 0 else 1
            x, w = np.polynomial.legendre.leggauss(n)
            pts.append((0.5 * size * x, 0.5 * w if size > 0 else np.ones(1)))
        (gx, wx), (gy, wy) = pts
        gw = np.outer(wx, wy).ravel()  # weights of the mean over the area (sum 1)
        gxx, gyy = np.repeat(gx, gy.size), np.tile(gy, gx.size)
        dist = np.hypot(dxa[:, None] + gxx[None, :], gyy[None, :] - ya[:, None])
        self.r_far = float(np.max(np.hypot(np.abs(dxa) + 0.5 * contact_width, np.abs(ya) + 0.5 * contact_length)))
        dr = min(lam / DR_PER_WAVELENGTH, max(self.r_far, 1.0) / 200.0)
        h1 = profile.first_interface_depth
        if h1 is not None:
            dr = min(dr, h1 / 8.0)
        self.engine = KernelEngine(profile, max(self.r_far, 8.0 * dr), dr, f_top)
        W = lagrange_weights(self.engine.r, dist.ravel())
        rows = np.repeat(np.arange(n_p), gw.size)
        S = sparse.csr_matrix((np.tile(gw, n_p), (rows, np.arange(rows.size))), shape=(n_p, rows.size))
        self._W = (S @ W).tocsr()
        if contact_length > 0 and contact_width > 0:
            self._static = rect_inverse_distance(
                np.zeros(n_p), ya, dxa - 0.5 * contact_width, dxa + 0.5 * contact_width,
                np.full(n_p, -0.5 * contact_length), np.full(n_p, 0.5 * contact_length),
            ) / (contact_length * contact_width)
        elif contact_length == 0 and contact_width == 0:
            r0 = np.hypot(dxa, ya)
            if np.any(r0 <= 0):
                raise InputError("receivers: a receiver coincides with a point load (point loads need r > 0)")
            self._static = 1.0 / r0
        else:
            raise ParameterError(f"contact_length = {contact_length}, contact_width = {contact_width}: give both > 0 "
                                 "(areas) or both 0 (point loads)")

    def __call__(self, omega: float) -> CArray:
        """U at circular frequency ``omega`` [rad/s], shape (P,) [m/N]."""
        ker = self.engine(omega)
        return np.asarray(ker.c0 * self._static + self._W @ ker.gs, dtype=np.complex128)


@dataclass(frozen=True)
class _Geometry:
    j0: int
    n_zone: int
    mask: Array  # (J, R) bool


class FreeFieldModel:
    """Receiver FIR filters of one soil, one track geometry and one set of receivers.

    Parameters
    ----------
    profile : SoilProfile
        Layered (or homogeneous) half-space.
    receivers : array_like, shape (R, 2)
        Receiver positions (x along the track, y from the track axis) [m].
    spacing : float
        Sleeper spacing d [m]; sleeper j is centred at x = j d.
    dt : float
        Input step of the sleeper forces [s].
    contact_length, contact_width : float
        Contact area across (2a) and along (2b) the track [m]; both 0: point loads.
    influence_length : float
        Sleepers within this distance along the track of a receiver act on it [m].
    band : float
        Band limit of the model [Hz] (<= 0.4 x the model rate).
    model_rate : float
        Target model rate [Hz]; the model step is a whole number M of input steps.
    tail : float
        Memory kept after the slowest arrival [s].
    cache : bool
        Read the filters from, and write them to, the on-disk cache
        (:mod:`clm_core.freefield.cache`, keyed by every input above and the
        code revision); False: always build them.

    Attributes
    ----------
    step_response : ndarray, shape (J, R, L)
        g_jr[k] of the module docstring [m/s per N] (zero for pairs beyond the influence length).
    first_sleeper : int
        Global index of zone sleeper 0 (zone sleeper i is global ``first_sleeper + i``).
    decimation : int
        M (input steps per model step).
    leakage : float
        max |h| over the dropped taps / max |h| (non-causal leakage and truncation) [-].
    cached : bool
        The filters were read from the cache (``cache_key`` names the entry).
    """

    def __init__(
        self,
        profile: SoilProfile,
        receivers: ArrayLike,
        spacing: float,
        dt: float,
        *,
        contact_length: float = 2.5,
        contact_width: float = 0.285,
        influence_length: float = 60.0,
        band: float = 100.0,
        model_rate: float = 250.0,
        tail: float = 0.25,
        cache: bool = True,
    ) -> None:
        rec = np.asarray(receivers, dtype=float)
        if rec.ndim != 2 or rec.shape[1] != 2 or rec.shape[0] == 0:
            raise InputError(f"receivers: need an (R, 2) array of (x, y) positions [m], got shape {rec.shape}")
        if not np.all(np.isfinite(rec)):
            raise InputError("receivers: positions must be finite numbers [m]")
        self.profile = profile
        self.receivers = rec
        self.spacing = positive("spacing", spacing, unit="m")
        self.dt = positive("dt", dt, unit="s")
        self.influence_length = positive("influence_length", influence_length, unit="m")
        self.band = positive("band", band, unit="Hz")
        positive("model_rate", model_rate, unit="Hz")
        self.tail = positive("tail", tail, unit="s")
        for name, v in (("contact_length", contact_length), ("contact_width", contact_width)):
            if not (math.isfinite(v) and v >= 0):
                raise ParameterError(f"{name} = {v}: must be >= 0 [m]")
        self.contact_length = float(contact_length)
        self.contact_width = float(contact_width)
        self.model_rate = float(model_rate)
        self.decimation = max(1, int(math.floor(1.0 / (self.dt * model_rate) + 1e-9)))
        self.model_dt = self.decimation * self.dt
        fs = 1.0 / self.model_dt
        if self.band > 0.4 * fs * (1 + 1e-9):
            raise ParameterError(
                f"band = {self.band:g} Hz: must be <= 0.4 x the model rate {fs:g} Hz (input step dt = {self.dt:g} s, "
                f"{self.decimation} per model step); lower the band or give forces at a shorter step"
            )
        self.sos = band_filter(self.band, self.dt)
        self.decimation_taps = decimation_filter(self.sos, self.decimation)
        self._geom = self._zone()
        self.first_sleeper = self._geom.j0
        self.cached = False
        key, text = fcache.model_key(
            self.profile, self.receivers, spacing=self.spacing, dt=self.dt, contact_length=self.contact_length,
            contact_width=self.contact_width, influence_length=self.influence_length, band=self.band,
            model_rate=self.model_rate, tail=self.tail, band_order=BAND_ORDER,
            points_per_wavelength=POINTS_PER_WAVELENGTH, dr_per_wavelength=DR_PER_WAVELENGTH,
            edge_fraction=EDGE_FRACTION, precursor_cycles=PRECURSOR_CYCLES)
        self.cache_key = key
        hit = fcache.load(key, text) if cache else None
        if hit is not None and hit["step_response"].shape[:2] == (self.n_zone, rec.shape[0]):
            self.step_response = np.asarray(hit["step_response"], dtype=np.float64)
            self.leakage, self.n_fir, self.delay = float(hit["leakage"]), int(hit["n_fir"]), int(hit["delay"])
            self.freqs, self.transfer = hit["freqs"], hit["transfer"]
            self.cached = True
        else:
            self.step_response, self.leakage, self.n_fir = self._design()
            if cache:
                fcache.store(key, text, {"step_response": self.step_response, "freqs": self.freqs,
                                         "transfer": self.transfer, "leakage": self.leakage, "n_fir": self.n_fir,
                                         "delay": self.delay})

    # ------------------------------------------------------------------ geometry
    def _zone(self) -> _Geometry:
        d, lc = self.spacing, self.influence_length
        xr = self.receivers[:, 0]
        j0 = int(math.ceil((xr.min() - lc) / d - 1e-9))
        j1 = int(math.floor((xr.max() + lc) / d + 1e-9))
        xj = np.arange(j0, j1 + 1) * d
        mask = np.abs(xj[:, None] - xr[None, :]) <= lc + 1e-9
        return _Geometry(j0=j0, n_zone=j1 - j0 + 1, mask=mask)

    @property
    def n_zone(self) -> int:
        """Number J of sleepers in the zone of influence of any receiver."""
        return self._geom.n_zone

    @property
    def sleeper_positions(self) -> Array:
        """Centres x_j of the zone sleepers [m]."""
        return np.asarray((self.first_sleeper + np.arange(self.n_zone)) * self.spacing, dtype=np.float64)

    # ------------------------------------------------------------------ FIR design
    def _design(self) -> tuple[Array, float, int]:
        g = self._geom
        fs = 1.0 / self.model_dt
        f_top = 1.25 * self.band
        pj, pr = np.nonzero(g.mask)
        dx = self.sleeper_positions[pj] - self.receivers[pr, 0]
        yr = self.receivers[pr, 1]
        kern = AreaTransfer(self.profile, dx, yr, f_top, self.contact_length, self.contact_width)
        memory = kern.r_far / (0.87 * self.profile.min_cs) + self.tail
        self.delay = int(math.ceil(PRECURSOR_CYCLES / self.band * fs))
        L = int(math.ceil(memory * fs)) + 1 + self.delay
        N = 2 * L
        freqs = np.arange(N // 2 + 1) * fs / N
        taper = np.where(
            freqs <= self.band, 1.0,
            np.where(freqs < f_top, 0.5 * (1.0 + np.cos(math.pi * (freqs - self.band) / (f_top - self.band))), 0.0),
        )
        Hv = np.zeros((dx.size, freqs.size), dtype=np.complex128)
        for k, f in enumerate(freqs):
            if taper[k] == 0.0 or f == 0.0:
                continue  # the velocity transfer vanishes at f = 0
            w = 2.0 * math.pi * f
            Hv[:, k] = 1j * w * kern(w) * taper[k] * np.exp(-1j * w * self.delay * self.model_dt)
        # smooth edge of the zone of influence: a load entering it rises over the last EDGE_FRACTION of the
        # influence length instead of appearing at once (a sudden load would send a spurious Rayleigh pulse)
        u = np.clip((np.abs(dx) / self.influence_length - (1.0 - EDGE_FRACTION)) / EDGE_FRACTION, 0.0, 1.0)
        Hv *= (0.5 * (1.0 + np.cos(math.pi * u)))[:, None]
        h = np.fft.irfft(Hv, n=N, axis=1)
        peak = float(np.max(np.abs(h))) or 1.0
        leakage = float(np.max(np.abs(h[:, L:]))) / peak
        # fold the dropped taps: those at negative time (the band limit's precursor, indices >= 3L/2 of the period)
        # into the first tap, those beyond the memory into the last one, so that sum(h[:L]) = H(0) = 0 and the
        # step response g ends at zero: a constant force gives no velocity (else the dropped area leaves a drift)
        h[:, 0] += h[:, (3 * L) // 2:].sum(axis=1)
        h[:, L - 1] += h[:, L: (3 * L) // 2].sum(axis=1)
        gsteps = np.cumsum(h[:, :L], axis=1)
        out = np.zeros((g.n_zone, self.receivers.shape[0], L))
        out[pj, pr, :] = gsteps
        self.freqs = freqs
        self.transfer = np.zeros((g.n_zone, self.receivers.shape[0], freqs.size), dtype=np.complex128)
        self.transfer[pj, pr, :] = Hv
        return out, leakage, L

    # ------------------------------------------------------------------ helpers
    def zone_columns(self, sleeper_index: ArrayLike) -> tuple[IntArray, IntArray]:
        """(positions in the input, zone columns) of the input sleepers that lie in the zone."""
        idx = np.asarray(sleeper_index, dtype=np.int64) - self.first_sleeper
        ok = (idx >= 0) & (idx < self.n_zone)
        return np.nonzero(ok)[0].astype(np.int64), idx[ok]
