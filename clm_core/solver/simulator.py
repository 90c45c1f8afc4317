"""Streaming time integration of the track–soil model under moving wheel loads.

:class:`TrackSimulator` advances the state of a track–soil model
(:func:`clm_core.track.assemble`, paper Sec. 5, Fig. 6) under a set of
wheels, each a vertical force [N] (positive downwards) at a position [m]
along the line. The state persists between calls, so the same object serves
the command line, an offline replay and a ROS node.

Integrator
    Newmark average acceleration (gamma = 1/2, beta = 1/4), the trapezoidal
    rule: unconditionally stable when M, K are positive (semi-)definite and
    the damping matrix C is positive semi-definite, which
    :func:`clm_core.track.check_damping` enforces (Kouroussis et al. 2011,
    Sec. 4.2). It is used in its increment form, with the acceleration
    eliminated through the equilibrium at t_n::

        K_eff du = f_{n+1} + f_n - 2 K u_n + (4/dt) M v_n
        u_{n+1} = u_n + du,     v_{n+1} = (2/dt) du - v_n
        K_eff = K + (2/dt) C + (4/dt^2) M      (symmetric positive definite)

    This is algebraically the same scheme as :class:`clm_core.newmark.NewmarkLinear`
    (which carries the acceleration), needs no acceleration state (massless
    Winkler areas are no special case) and stays consistent when the window
    shifts. A mode of frequency f is integrated at f' = tan(pi f dt)/(pi dt);
    the steady response to a harmonic force of frequency f is the exact
    response of the continuous model at f' (bilinear transform).

Cost per step
    K_eff is factorised once per window configuration (LDL^T in envelope
    storage, no fill outside the band profile); each step is one sparse pass
    for the right-hand side, a forward/back substitution and the update, all
    in one compiled kernel (:mod:`clm_core._kernels`) that runs many steps
    per call. Cost and memory per step are O(n_sleepers) and independent of
    the length of line travelled.

Moving window
    The simulated track is a window of ``n_sleepers`` sleepers (global
    indices ``first .. first + n_sleepers - 1``, sleeper ``g`` at
    ``x = g * spacing``). With ``follow=True`` the window shifts by whole
    bays before the foremost wheel comes closer than ``lead_sleepers`` to its
    front end (or the rearmost closer than ``margin_sleepers`` to its rear
    end): the DOF vector moves by whole bays, the sleepers behind are dropped
    and new ones are added at rest (zero displacement and velocity) ahead.
    Because DOFs are in position order and each bay has the same DOF layout,
    a shift is a copy. The window is assembled with one extra bay on its
    leading side whose DOFs are clamped at zero (:func:`_clamp_ghost_bay`):
    a shift then turns clamped zeros into free DOFs at rest and drops
    elements at the free trailing end, so it can never add energy and the
    scheme stays unconditionally stable through any number of shifts.
    Windows with identical per-sleeper properties (a
    uniform track) share one factorisation; a window over per-sleeper
    overrides gets its own, kept in a small LRU cache keyed by the property
    values in the window. See docs/time-domain.md for the error of the window
    against a long fixed track.

Wheels
    Positions [m] and forces [N] per wheel, arrays of shape (n_w,). A wheel
    between rail nodes loads the element's four DOFs with the Hermite shape
    functions (:meth:`clm_core.track.TrackSystem.point_load`); the same
    weights give the rail deflection and velocity under the wheel (the
    material velocity of the rail at the contact point, without the
    convective term speed x slope). A wheel that is not on the track is given
    position NaN (its force must then be 0 or NaN); the number of wheels may
    change between calls.

Vehicle coupling
    :meth:`TrackSimulator.begin_step` / :meth:`TrackSimulator.finish_step`
    split a step around a contact solution found by the caller;
    :meth:`TrackSimulator.coupled_chunk` / :meth:`TrackSimulator.coupled_commit`
    hand the same steps, for a stretch without window shift, to a compiled
    kernel (:mod:`clm_core.vehicle._coupled_kernel`).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal, Union

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from clm_core import _kernels as kern
from clm_core.errors import InputError, ParameterError, StabilityError
from clm_core.params import PER_SLEEPER_NAMES, ModelParams, SleeperOverride
from clm_core.track import TrackSystem, assemble

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]
LoadFunction = Callable[[float], tuple[ArrayLike, ArrayLike]]
Orientation = Literal["forward", "backward", "free"]
Loads = Union[tuple[ArrayLike, ArrayLike], LoadFunction, "LoadTable"]

#: Steps per kernel call at most (bounds the per-call work arrays: flat memory).
CHUNK_STEPS = 2048
_TOL = 1e-9


# ----------------------------------------------------------------------------- results


@dataclass(frozen=True)
class Snapshot:
    """State of the simulated track at one instant (copies; positive downwards).

    Attributes
    ----------
    t : float
        Time [s].
    sleeper_index : (N,) int64 array
        Global sleeper indices of the window.
    sleeper_x : (N,) array
        Sleeper positions along the line [m].
    soil_force : (N,) array
        Soil reaction force under every sleeper [N]: the ballast force on the
        contact area, k_b (z_s - x_f) + d_b (v_s - v_f), compression positive.
    rail_deflection : (N,) array
        Rail deflection above every sleeper [m].
    sleeper_displacement : (N,) array
        Sleeper displacement [m].
    area_displacement : (N,) array
        Soil contact-area displacement [m] (zeros for a rigid soil).
    wheel_positions : (n_w,) array
        Wheel positions [m] (NaN: wheel not on the track).
    wheel_forces : (n_w,) array
        Wheel forces [N] applied at ``t``.
    wheel_deflection : (n_w,) array
        Rail deflection under each wheel [m] (NaN for an absent wheel).
    wheel_velocity : (n_w,) array
        Rail velocity under each wheel [m/s] (material velocity).
    """

    t: float
    sleeper_index: IntArray
    sleeper_x: Array
    soil_force: Array
    rail_deflection: Array
    sleeper_displacement: Array
    area_displacement: Array
    wheel_positions: Array
    wheel_forces: Array
    wheel_deflection: Array
    wheel_velocity: Array


@dataclass(frozen=True)
class Block:
    """Outputs of consecutive steps with the window in one position.

    Emitted by :meth:`TrackSimulator.advance` to its ``callback``; the arrays
    are fresh (the callback may keep them). ``k`` output instants, ``N``
    sleepers, ``W`` wheels.

    Attributes
    ----------
    first_sleeper : int
        Global index of column 0 of the sleeper arrays.
    sleeper_x : (N,) array
        Sleeper positions [m].
    t : (k,) array
        Output times [s].
    soil_force, rail_deflection, sleeper_displacement, area_displacement : (k, N) arrays
        As in :class:`Snapshot` [N], [m].
    wheel_positions, wheel_forces, wheel_deflection, wheel_velocity : (k, W) arrays
        As in :class:`Snapshot` [m], [N], [m], [m/s].
    peak_soil_force, peak_rail_deflection : (N,) arrays
        Running maxima over every step (not only output steps) since the
        sleeper entered the window or since :meth:`TrackSimulator.reset_peaks`,
        up to the end of the block [N], [m]. The block emitted just before a
        window shift holds the final values of the sleepers being dropped.
    peak_wheel_deflection : (W,) array
        Largest rail deflection under each wheel over every step of the block
        [m] (-inf for a wheel absent throughout).
    """

    first_sleeper: int
    sleeper_x: Array
    t: Array
    soil_force: Array
    rail_deflection: Array
    sleeper_displacement: Array
    area_displacement: Array
    wheel_positions: Array
    wheel_forces: Array
    wheel_deflection: Array
    wheel_velocity: Array
    peak_soil_force: Array
    peak_rail_deflection: Array
    peak_wheel_deflection: Array

    @property
    def sleeper_index(self) -> IntArray:
        """Global sleeper indices of the columns."""
        return np.arange(self.first_sleeper, self.first_sleeper + len(self.sleeper_x), dtype=np.int64)


# ----------------------------------------------------------------------------- loads


class LoadTable:
    """Wheel loads tabulated in time, linearly interpolated (vectorised).

    Parameters
    ----------
    t : (n_t,) array
        Strictly increasing times [s].
    positions : (n_t, n_w) array
        Wheel positions [m]; NaN where a wheel is not on the track.
    forces : (n_t, n_w) array
        Wheel forces [N]; ignored (may be NaN) where the position is NaN.

    Notes
    -----
    Between two rows a wheel is present only if it is present in both; its
    position and force are interpolated linearly.
    """

    def __init__(self, t: ArrayLike, positions: ArrayLike, forces: ArrayLike) -> None:
        tt = np.asarray(t, dtype=float)
        P = np.asarray(positions, dtype=float)
        F = np.asarray(forces, dtype=float)
        if P.ndim == 1:
            P = P[:, None]
        if F.ndim == 1:
            F = F[:, None]
        if tt.ndim != 1 or tt.size < 2:
            raise InputError(f"load table: time column has shape {tt.shape}; need at least 2 rows")
        if P.shape != (tt.size, P.shape[1]) or F.shape != P.shape:
            raise InputError(
                f"load table: positions {P.shape} and forces {F.shape} must both be "
                f"(n_times={tt.size}, n_wheels)"
            )
        if not np.all(np.isfinite(tt)):
            raise InputError("load table: time column has NaN or infinite values")
        bad = np.nonzero(np.diff(tt) <= 0)[0]
        if bad.size:
            i = int(bad[0]) + 1
            raise InputError(
                f"load table: time must increase strictly; row {i} has t = {tt[i]:g} s after {tt[i - 1]:g} s"
            )
        present = np.isfinite(P)
        badf = present & ~np.isfinite(F)
        if badf.any():
            r, c = np.argwhere(badf)[0]
            raise InputError(
                f"load table: wheel {c + 1} at t = {tt[r]:g} s has position {P[r, c]:g} m but force {F[r, c]}"
            )
        self.t, self.positions, self.forces = tt, P, np.where(present, F, 0.0)
        self.n_wheels = P.shape[1]

    def __call__(self, t: ArrayLike) -> tuple[Array, Array]:
        """Positions [m] and forces [N] at times ``t``: arrays (n_t, n_w) (or (n_w,) for a scalar)."""
        tq = np.asarray(t, dtype=float)
        scalar = tq.ndim == 0
        tq = np.atleast_1d(tq)
        lo, hi = self.t[0], self.t[-1]
        eps = _TOL * max(1.0, abs(hi))
        if np.any(tq < lo - eps) or np.any(tq > hi + eps):
            raise InputError(f"load table covers t = {lo:g} .. {hi:g} s; asked for t = {tq.min():g} .. {tq.max():g} s")
        tq = np.clip(tq, lo, hi)
        j = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, self.t.size - 2)
        a = ((tq - self.t[j]) / (self.t[j + 1] - self.t[j]))[:, None]
        P0, P1 = self.positions[j], self.positions[j + 1]
        P = P0 + a * (P1 - P0)
        F = self.forces[j] + a * (self.forces[j + 1] - self.forces[j])
        # exactly on a row: take that row (a wheel present there is present)
        at1 = a[:, 0] >= 1.0
        P[at1], F[at1] = P1[at1], self.forces[j + 1][at1]
        at0 = a[:, 0] <= 0.0
        P[at0], F[at0] = P0[at0], self.forces[j][at0]
        F = np.where(np.isfinite(P), F, 0.0)
        if scalar:
            return P[0], F[0]
        return P, F

    @classmethod
    def read_csv(cls, path: str) -> LoadTable:
        """Read a wheel-load time history (CSV).

        Format: one header line, then one row per time; the columns are the
        time [s], then for each wheel its position [m] along the line and its
        vertical force [N] (positive downwards)::

            t,x1,F1,x2,F2
            0.0,10.0,100e3,7.5,100e3
            0.1,13.0,102e3,10.5,98e3

        An empty or ``nan`` position marks a wheel that is not on the track
        at that time. Lines starting with ``#`` are comments.
        """
        try:
            with open(path, encoding="utf-8") as fh:
                lines = [ln.strip() for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
        except OSError as exc:
            raise InputError(f"load file {path!r}: cannot read ({exc.strerror})") from None
        if len(lines) < 3:
            raise InputError(f"load file {path!r}: need a header and at least 2 rows, found {len(lines)} lines")
        header = [h.strip() for h in lines[0].split(",")]
        ncol = len(header)
        if ncol < 3 or ncol % 2 == 0:
            raise InputError(
                f"load file {path!r}: header has {ncol} columns; expected time then (position, force) per wheel"
            )
        rows = []
        for k, ln in enumerate(lines[1:], start=2):
            cells = [c.strip() for c in ln.split(",")]
            if len(cells) != ncol:
                raise InputError(f"load file {path!r}: data line {k} has {len(cells)} columns, header has {ncol}")
            try:
                rows.append([float(c) if c else math.nan for c in cells])
            except ValueError:
                raise InputError(f"load file {path!r}: data line {k}: not a number in {ln!r}") from None
        data = np.array(rows)
        return cls(data[:, 0], data[:, 1::2], data[:, 2::2])


# ----------------------------------------------------------------------------- operator


@dataclass
class _Operator:
    """Matrices and factorisation of one window configuration (position independent)."""

    system: TrackSystem
    indptr: IntArray
    indices: IntArray
    Ka: Array  # -2 K on the union pattern
    Mb: Array  # (4/dt) M on the union pattern
    env: tuple[IntArray, IntArray, Array, Array]  # first, ptr, L, D of K_eff
    kb: Array
    db: Array
    Dinv: Array
    orientation: str = "free"
    static_env: tuple[IntArray, IntArray, Array, Array] | None = None
    # columns K_eff^-1 e_d of rail DOFs d that wheels have loaded (compiled coupling), filled on demand
    cols: Array | None = None  # (capacity, n); row col_slot[d] is the column of DOF d
    col_slot: IntArray | None = None  # (n,) row of each DOF's column, -1: not computed
    n_cols: int = 0


def _envelope(A: sp.spmatrix) -> tuple[IntArray, IntArray, Array, Array]:
    """Envelope storage of the lower triangle of a symmetric matrix."""
    A = sp.csr_matrix(A)
    A.eliminate_zeros()
    coo = sp.tril(A, k=-1).tocoo()
    n = A.shape[0]
    first = np.arange(n, dtype=np.int64)
    np.minimum.at(first, coo.row, coo.col.astype(np.int64))
    lengths = np.arange(n) - first
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(lengths, out=ptr[1:])
    L = np.zeros(int(ptr[-1]))
    L[ptr[coo.row] + coo.col - first[coo.row]] = coo.data
    D = np.ascontiguousarray(A.diagonal(), dtype=float)
    return first, ptr, L, D


def _factorise(A: sp.spmatrix, what: str) -> tuple[IntArray, IntArray, Array, Array]:
    first, ptr, L, D = _envelope(A)
    bad = int(kern.ldlt_envelope(first, ptr, L, D))
    if bad >= 0:
        raise StabilityError(
            f"{what} is not positive definite (pivot <= 0 at DOF {bad}); the time integration "
            "would not be stable for this parameter set"
        )
    return first, ptr, L, D


def _member(gidx: IntArray, sorted_unique: IntArray) -> NDArray[np.bool_]:
    """Which of ``gidx`` are in the sorted unique array (O(len(gidx) log m))."""
    if sorted_unique.size == 0:
        return np.zeros(gidx.shape, dtype=bool)
    i = np.clip(np.searchsorted(sorted_unique, gidx), 0, sorted_unique.size - 1)
    return np.asarray(sorted_unique[i] == gidx)


def _clamp_ghost_bay(full: TrackSystem, orient: Orientation) -> TrackSystem:
    """The window inside an assembly with one extra (ghost) bay, whose DOFs are clamped at zero.

    ``forward``: the ghost bay is the last one (ahead of the window), so the
    window's front is connected to fixed zero DOFs and its rear end is free;
    ``backward``: the mirror image; ``free``: returned as is (both ends free).
    A window shift towards the clamped end turns the clamped DOFs (zero) into
    free ones with their true value (zero) and drops elements at the free
    end: the discrete energy 1/2 v^T M v + 1/2 u^T K u cannot grow across a
    shift, so the Newmark scheme stays unconditionally stable through any
    number of shifts. (With a free front end, the elements added ahead of it
    inject energy at every shift; repeated shifts then amplify the weakly
    damped high-frequency rail modes, see docs/time-domain.md.)
    """
    if orient == "free":
        return full
    ne = full.elements_per_bay
    dpb = int(full.sleeper_dof[1] - full.sleeper_dof[0])
    n = full.n_dof - dpb
    nn = len(full.node_x) - ne
    N = full.n_sleepers - 1
    if orient == "forward":
        keep, nodes, sl, off, noff = slice(0, n), slice(0, nn), slice(0, N), 0, 0
    else:
        keep, nodes, sl, off, noff = slice(dpb, dpb + n), slice(ne, ne + nn), slice(1, N + 1), dpb, ne
    props = full.props
    new_props = type(props)(**{
        k: (getattr(props, k)[sl.start: sl.start + N - 1] if k in ("kc", "dc") else getattr(props, k)[sl]).copy()
        for k in ("kp", "dp", "ms", "kb", "db", "mf", "kf", "df", "kc", "dc")
    })
    M, C, K = (sp.csr_matrix(A)[keep][:, keep].tocsr() for A in (full.M, full.C, full.K))
    area = full.area_dof[sl]
    return replace(
        full, M=M, C=C, K=K, node_x=full.node_x[nodes].copy(),
        rail_w=full.rail_w[nodes] - off, rail_th=full.rail_th[nodes] - off,
        sleeper_index=full.sleeper_index[sl].copy(), sleeper_x=full.sleeper_x[sl].copy(),
        sleeper_node=full.sleeper_node[sl] - noff, sleeper_dof=full.sleeper_dof[sl] - off,
        area_dof=np.where(area >= 0, area - off, -1), props=new_props,
    )


# ----------------------------------------------------------------------------- simulator


class TrackSimulator:
    """Streaming simulator of the track–soil model under moving wheel loads.

    Parameters
    ----------
    params : ModelParams
        Rail, track and soil parameters with per-sleeper overrides (global
        sleeper indices). Refused with :class:`~clm_core.errors.StabilityError`
        if the damping matrix of the window or of any overridden stretch of
        line is not positive semi-definite (Sec. 4.2).
    dt : float
        Time step [s].
    n_sleepers : int
        Sleepers in the simulated window (>= lead_sleepers + margin_sleepers + 1).
    elements_per_bay : int
        Rail beam elements per sleeper bay (2 is the paper's choice).
    start_position : float
        Position of the window centre at start [m].
    lead_sleepers : int, optional
        Sleepers kept ahead of the foremost wheel when following (default
        ``n_sleepers // 3``).
    follow : bool
        Move the window with the wheels. When False, wheels closer than
        ``margin_sleepers`` to an end of the window are refused.
    margin_sleepers : int, optional
        Least number of sleeper bays between any wheel and either end of the
        window (default ``max(2, min(10, n_sleepers // 6))``).
    cache_size : int
        Window factorisations kept (LRU) for non-uniform tracks.

    Raises
    ------
    ParameterError
        Bad sizes, time step or per-sleeper values.
    StabilityError
        Damping matrix not positive semi-definite somewhere on the line.
    """

    def __init__(
        self,
        params: ModelParams,
        dt: float,
        n_sleepers: int = 61,
        elements_per_bay: int = 2,
        start_position: float = 0.0,
        lead_sleepers: int | None = None,
        follow: bool = True,
        *,
        margin_sleepers: int | None = None,
        cache_size: int = 64,
    ) -> None:
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ParameterError(f"dt = {dt}: time step must be finite and > 0 s")
        n_sleepers = int(n_sleepers)
        margin = max(2, min(10, n_sleepers // 6)) if margin_sleepers is None else int(margin_sleepers)
        lead = n_sleepers // 3 if lead_sleepers is None else int(lead_sleepers)
        if margin < 1:
            raise ParameterError(f"margin_sleepers = {margin}: must be >= 1")
        if lead < margin:
            raise ParameterError(f"lead_sleepers = {lead}: must be >= margin_sleepers = {margin}")
        if n_sleepers - 1 - lead - margin < 0 or n_sleepers < 4:
            raise ParameterError(
                f"n_sleepers = {n_sleepers}: too small for lead_sleepers = {lead} and "
                f"margin_sleepers = {margin} (need n_sleepers >= lead + margin + 1 and >= 4)"
            )
        if not math.isfinite(float(start_position)):
            raise ParameterError(f"start_position = {start_position}: must be finite")
        if cache_size < 1:
            raise ParameterError(f"cache_size = {cache_size}: must be >= 1")
        self.params = params
        self.dt = dt
        self.n_sleepers = n_sleepers
        self.elements_per_bay = int(elements_per_bay)
        self.lead_sleepers = lead
        self.margin_sleepers = margin
        self.follow = bool(follow)
        self.spacing = float(params.track.spacing)
        self._a1 = 2.0 / dt
        self._cache: OrderedDict[tuple[str, bytes], _Operator] = OrderedDict()
        self._cache_size = int(cache_size)
        self.n_factorisations = 0

        kern.warm_up()
        # per-sleeper override bookkeeping (global indices touched by any override)
        self._ov = [(np.unique(np.asarray(o.sleepers, dtype=np.int64)), dict(o.values)) for o in params.overrides]
        touched = [s for s, _ in self._ov]
        self._touched = np.unique(np.concatenate(touched)) if touched else np.zeros(0, dtype=np.int64)
        t, s = params.track, params.soil
        self._base = {"kp": t.kp, "dp": t.dp, "ms": t.ms, "kb": t.kb, "db": t.db,
                      "mf": s.mf, "kf": s.kf, "df": s.df, "kc": s.kc, "dc": s.dc}
        self._uniform_keys = {m: self._raw_key(None, m) for m in (n_sleepers, n_sleepers + 1)}
        if self.follow and self.elements_per_bay < 2:
            raise ParameterError(
                f"elements_per_bay = {self.elements_per_bay}: a following window needs >= 2 (the window "
                "shifts by whole bays and needs rail-only nodes at its ends)"
            )

        first = int(round(float(start_position) / self.spacing)) - (n_sleepers - 1) // 2
        op = self._operator(first, "forward" if self.follow else "free")
        sysm = op.system
        self._layout(sysm, first)
        self._first = first
        self._op = op
        self._check_overrides()

        n = sysm.n_dof
        self._u = np.zeros(n)
        self._v = np.zeros(n)
        self._z = np.zeros(n)  # kernel work arrays (z stays zero between calls)
        self._y = np.zeros(n)
        self._prev_dofs = np.zeros(0, dtype=np.int64)
        self._prev_vals = np.zeros(0)
        self._pos = np.zeros(0)
        self._F = np.zeros(0)
        self._pk_force = np.zeros(n_sleepers)
        self._pk_rail = np.zeros(n_sleepers)
        self._t0 = 0.0
        self._k = 0
        self._pending: tuple[Array, Array, IntArray, Array, Array, Array, int] | None = None
        self._chunk: tuple[Array, IntArray, Array] = (np.zeros((0, 0)), np.zeros((0, 0), dtype=np.int64),
                                                      np.zeros((0, 0)))

    # ------------------------------------------------------------------ properties

    @property
    def t(self) -> float:
        """Current simulation time [s]."""
        return self._t0 + self._k * self.dt

    @property
    def window(self) -> tuple[int, int]:
        """(global index of the first sleeper of the window, number of sleepers)."""
        return self._first, self.n_sleepers

    @property
    def n_dof(self) -> int:
        """Degrees of freedom of the window."""
        return int(self._u.size)

    @property
    def system(self) -> TrackSystem:
        """Assembled model of the current window (matrices; positions of the window it was built for)."""
        return self._op.system

    def allowed_range(self) -> tuple[float, float]:
        """Positions [m] where wheels are accepted without shifting the window.

        Following forwards: from ``margin_sleepers`` behind the window's rear
        end to ``lead_sleepers`` before its front end; following backwards
        (after the last shift was backwards): the mirror image; not following:
        ``margin_sleepers`` from either end.
        """
        d = self.spacing
        lo, hi = self._limits(self._op.orientation)
        return (self._first + lo) * d, (self._first + hi) * d

    def _limits(self, orient: str) -> tuple[int, int]:
        """Allowed wheel zone in sleeper bays from the window start, for an orientation."""
        N, m, ld = self.n_sleepers, self.margin_sleepers, self.lead_sleepers
        if orient == "forward":
            return m, N - 1 - ld
        if orient == "backward":
            return ld, N - 1 - m
        return m, N - 1 - m

    # ------------------------------------------------------------------ set-up

    def _raw_key(self, gidx: IntArray | None, n: int | None = None) -> bytes:
        """Per-sleeper raw parameter values of sleepers ``gidx`` (None: ``n`` uniform ones), as a cache key."""
        m = len(gidx) if gidx is not None else int(n if n is not None else self.n_sleepers)
        vals = {k: np.full(m, float(v)) for k, v in self._base.items()}
        if gidx is not None:
            for s, values in self._ov:
                mask = _member(gidx, s)
                if mask.any():
                    for name, v in values.items():
                        vals[name][mask] = v
        return np.concatenate([vals[k] for k in PER_SLEEPER_NAMES]).tobytes() + m.to_bytes(8, "little")

    def _span(self, first: int, orient: Orientation) -> tuple[int, int]:
        """Global sleepers (first, count) assembled for a window: the window plus its clamped ghost bay."""
        N = self.n_sleepers
        if orient == "forward":
            return first, N + 1
        if orient == "backward":
            return first - 1, N + 1
        return first, N

    def _key(self, first: int, orient: Orientation) -> tuple[str, bytes]:
        a, m = self._span(first, orient)
        if self._touched.size:
            i = np.searchsorted(self._touched, a)
            if i < self._touched.size and self._touched[i] < a + m:
                return orient, self._raw_key(np.arange(a, a + m, dtype=np.int64))
        return orient, self._uniform_keys[m]

    def _build(self, first: int, orient: Orientation) -> _Operator:
        a, m = self._span(first, orient)
        full = assemble(self._restricted(a, a + m), m, elements_per_bay=self.elements_per_bay,
                        first_sleeper=a, check_stability=True)
        sysm = _clamp_ghost_bay(full, orient)
        if hasattr(self, "_kind") and not (
            np.array_equal(sysm.rail_w, self._rail_w) and np.array_equal(sysm.sleeper_dof, self._s_dof)
            and np.array_equal(sysm.area_dof, self._a_dof)
        ):  # pragma: no cover - a layout bug, not a user error
            raise RuntimeError(f"window DOF layout of the {orient} operator differs from the first window's")
        dt = self.dt
        K, C, M = sysm.K, sysm.C, sysm.M
        Keff = (K + (2.0 / dt) * C + (4.0 / dt**2) * M).tocsr()
        env = _factorise(Keff, "the Newmark effective matrix K + 2/dt C + 4/dt^2 M")
        pat = (abs(K) + abs(M)).tocsr()
        pat.eliminate_zeros()
        pat.sort_indices()
        r = np.repeat(np.arange(pat.shape[0]), np.diff(pat.indptr))
        c = pat.indices
        Kv = np.asarray(sp.csr_matrix(K)[r, c]).ravel()
        Mv = np.asarray(sp.csr_matrix(M)[r, c]).ravel()
        self.n_factorisations += 1
        return _Operator(
            system=sysm,
            indptr=pat.indptr.astype(np.int64), indices=c.astype(np.int64),
            Ka=np.ascontiguousarray(-2.0 * Kv), Mb=np.ascontiguousarray((4.0 / dt) * Mv),
            env=env, Dinv=1.0 / env[3], kb=np.ascontiguousarray(sysm.props.kb, dtype=float),
            db=np.ascontiguousarray(sysm.props.db, dtype=float), orientation=orient,
        )

    def _operator(self, first: int, orient: Orientation) -> _Operator:
        key = self._key(first, orient)
        op = self._cache.get(key)
        if op is None:
            op = self._build(first, orient)
            self._cache[key] = op
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(key)
        return op

    def _layout(self, sysm: TrackSystem, first: int) -> None:
        """DOF maps shared by every window (same layout per bay)."""
        d = self.spacing
        self._rail_w = sysm.rail_w.astype(np.int64)
        self._rail_th = sysm.rail_th.astype(np.int64)
        self._s_dof = sysm.sleeper_dof.astype(np.int64)
        self._a_dof = sysm.area_dof.astype(np.int64)
        self._r_dof = sysm.rail_w[sysm.sleeper_node].astype(np.int64)
        self._node_x_rel = sysm.node_x - first * d
        self._Le = d / self.elements_per_bay
        self._n_el = len(sysm.node_x) - 1
        self._dpb = int(self._s_dof[1] - self._s_dof[0])
        if np.any(self._rail_w < 0) or np.any(self._rail_th < 0):
            raise ParameterError("track window: constrained rail DOFs are not supported (free rail ends)")
        kind = np.zeros(sysm.n_dof, dtype=np.int64)
        kind[self._rail_th] = 1
        kind[self._s_dof] = 2
        kind[self._a_dof[self._a_dof >= 0]] = 3
        self._kind = kind
        if self.follow and not np.array_equal(kind[self._dpb:], kind[: -self._dpb]):
            raise ParameterError(  # pragma: no cover - guarded by elements_per_bay >= 2
                "track window: the DOF layout is not periodic per bay; cannot shift the window by copying"
            )

    def _check_overrides(self) -> None:
        """Refuse a line whose overridden stretches are unstable, before any stepping."""
        if not self._touched.size:
            return
        # clusters of touched sleepers, each checked with two neighbours on either side,
        # in pieces of at most 400 sleepers overlapping by 20; identical pieces checked once
        g = self._touched
        breaks = np.nonzero(np.diff(g) > 4)[0]
        starts = np.concatenate([[g[0]], g[breaks + 1]])
        ends = np.concatenate([g[breaks], [g[-1]]])
        seen: set[bytes] = set()
        piece, overlap = 400, 20
        for a, b in zip(starts, ends):
            lo, hi = int(a) - 2, int(b) + 3
            s = lo
            while True:
                e = min(hi, s + piece)
                n = max(e - s, 2)
                gidx = np.arange(s, s + n, dtype=np.int64)
                key = self._raw_key(gidx)
                if key not in seen:
                    seen.add(key)
                    assemble(self._restricted(s, s + n), n,
                             elements_per_bay=self.elements_per_bay, first_sleeper=s, check_stability=True)
                if e >= hi:
                    break
                s = e - overlap

    def _restricted(self, lo: int, hi: int) -> ModelParams:
        """The parameters with overrides cut to sleepers lo..hi-1 (keeps assembly O(window))."""
        out = []
        for s, values in self._ov:
            part = s[np.searchsorted(s, lo) : np.searchsorted(s, hi)]
            if part.size:
                out.append(SleeperOverride(sleepers=tuple(int(g) for g in part), values=dict(values)))
        return replace(self.params, overrides=tuple(out))

    # ------------------------------------------------------------------ state save / restore

    def _save(self) -> tuple[object, ...]:
        return (self._u.copy(), self._v.copy(), self._first, self._op, self._k, self._t0,
                self._prev_dofs.copy(), self._prev_vals.copy(), self._pos.copy(), self._F.copy(),
                self._pk_force.copy(), self._pk_rail.copy(), self._pending)

    def _restore(self, s: tuple[object, ...]) -> None:
        (self._u, self._v, self._first, self._op, self._k, self._t0, self._prev_dofs,
         self._prev_vals, self._pos, self._F, self._pk_force, self._pk_rail, self._pending) = s  # type: ignore[assignment]

    # ------------------------------------------------------------------ input checks

    def _wheels(self, positions: ArrayLike, forces: ArrayLike | None, what: str) -> tuple[Array, Array]:
        P = np.array(positions, dtype=float, ndmin=1)
        if P.ndim != 1:
            raise InputError(f"{what}: positions must be a 1-D array (n_wheels,), got shape {P.shape}")
        if forces is None:
            F = np.zeros_like(P)
        else:
            F = np.array(forces, dtype=float, ndmin=1)
            if F.shape != P.shape:
                raise InputError(f"{what}: forces have shape {F.shape}, positions {P.shape}; one force per wheel")
        _check_values(P[None, :], F[None, :], np.array([self.t]), what)
        return P, np.where(np.isfinite(P), F, 0.0)

    def _required_first(self, front: float, rear: float, what: str, t: float) -> tuple[int, Orientation]:
        """Window start (and orientation) closest to the current one with the wheels in the allowed zone.

        Wheels beyond the front limit shift the window forwards (front bay
        clamped, ``lead_sleepers`` kept ahead); wheels behind the rear limit
        shift it backwards (mirror image).
        """
        d, N = self.spacing, self.n_sleepers
        lo, hi = self.allowed_range()
        eps = _TOL * d
        orient: Orientation
        if front > hi + eps:
            orient = "forward"
        elif rear < lo - eps:
            orient = "backward"
        else:
            return self._first, self._op.orientation  # type: ignore[return-value]
        a, b = self._limits(orient)
        g_lo = math.ceil(front / d - _TOL - b)
        g_hi = math.floor(rear / d + _TOL - a)
        if g_lo > g_hi:
            raise InputError(
                f"{what}: wheels at t = {t:g} s span {rear:g} .. {front:g} m ({(front - rear) / d:.1f} bays); "
                f"the window of {N} sleepers holds at most {b - a} bays between "
                f"lead_sleepers = {self.lead_sleepers} and margin_sleepers = {self.margin_sleepers}"
            )
        return (g_lo if orient == "forward" else g_hi), orient

    def _check_inside(self, front: float, rear: float, what: str, t: float) -> None:
        lo, hi = self.allowed_range()
        eps = _TOL * self.spacing
        if rear < lo - eps or front > hi + eps:
            bad = rear if rear < lo - eps else front
            raise InputError(
                f"{what}: wheel at {bad:g} m at t = {t:g} s is outside the allowed part "
                f"{lo:g} .. {hi:g} m of the window (sleepers {self._first} .. "
                f"{self._first + self.n_sleepers - 1}, margin {self.margin_sleepers} bays"
                + (", follow=False)" if not self.follow else ")")
            )

    # ------------------------------------------------------------------ window motion

    def _shift_to(self, first: int, orient: Orientation) -> None:
        """Move the window so that it starts at global sleeper ``first`` (clamped bay on the ``orient`` side)."""
        s = first - self._first
        if s == 0 and orient == self._op.orientation:
            return
        op = self._operator(first, orient)
        n = self._u.size
        m = abs(s) * self._dpb
        N = self.n_sleepers
        for a in (self._u, self._v):
            if m >= n:
                a[:] = 0.0
            elif s > 0:
                a[: n - m] = a[m:]
                a[n - m :] = 0.0
            else:
                a[m:] = a[: n - m].copy()
                a[:m] = 0.0
        for pk in (self._pk_force, self._pk_rail):
            if abs(s) >= N:
                pk[:] = 0.0
            elif s > 0:
                pk[: N - s] = pk[s:]
                pk[N - s :] = 0.0
            else:
                pk[-s:] = pk[: N + s].copy()
                pk[:-s] = 0.0
        dofs = self._prev_dofs - s * self._dpb
        keep = (dofs >= 0) & (dofs < n)
        self._prev_dofs = np.ascontiguousarray(dofs[keep])
        self._prev_vals = np.ascontiguousarray(self._prev_vals[keep])
        self._first = first
        self._op = op

    def _place(self, P: Array, what: str, t: float) -> None:
        """Shift the window (follow=True) or check the wheels (follow=False) for positions P."""
        pres = P[np.isfinite(P)]
        if pres.size == 0:
            return
        front, rear = float(pres.max()), float(pres.min())
        if self.follow:
            self._shift_to(*self._required_first(front, rear, what, t))
        self._check_inside(front, rear, what, t)

    # ------------------------------------------------------------------ loads on the window

    def _weights(self, P: Array) -> tuple[IntArray, Array]:
        """DOFs and Hermite weights (S, 4 W) for wheel positions P (S, W) in the current window."""
        x0 = float(self._node_x_rel[0] + self._first * self.spacing)
        P = np.ascontiguousarray(P, dtype=np.float64)
        return kern.hermite_weights(P, x0, float(self._Le), int(self._n_el), self._rail_w, self._rail_th)

    def _load_entries(self, P: Array, F: Array) -> tuple[IntArray, Array]:
        d, w = self._weights(P[None, :])
        return d[0].copy(), (w[0] * np.repeat(F, 4)).copy()

    # ------------------------------------------------------------------ public API

    def initialize(
        self,
        positions: ArrayLike,
        forces: ArrayLike,
        t0: float = 0.0,
        state: Literal["static", "rest"] = "static",
    ) -> None:
        """Reset the state at time ``t0`` under the given wheel loads.

        Parameters
        ----------
        positions : (n_w,) array_like
            Wheel positions [m] (NaN: not on the track).
        forces : (n_w,) array_like
            Wheel forces [N], positive downwards.
        t0 : float
            Start time [s].
        state : {'static', 'rest'}
            ``static``: static equilibrium K u = F under these loads, zero
            velocity (no start transient for constant loads). ``rest``: zero
            displacement and velocity, the loads apply suddenly at ``t0``.

        Raises
        ------
        InputError
            NaN forces, mismatched sizes, wheels that do not fit in the
            window; the state is then unchanged.
        """
        if state not in ("static", "rest"):
            raise InputError(f"initialize: state = {state!r}: must be 'static' or 'rest'")
        t0 = float(t0)
        if not math.isfinite(t0):
            raise InputError(f"initialize: t0 = {t0}: must be finite")
        saved = self._save()
        try:
            P, F = self._wheels(positions, forces, "initialize")
            self._place(P, "initialize", t0)
            n = self._u.size
            dofs, vals = self._load_entries(P, F)
            u = np.zeros(n)
            if state == "static" and np.any(vals != 0.0):
                np.add.at(u, dofs, vals)
                first, ptr, L, D = self._static_factor()
                kern.solve_envelope(first, ptr, L, D, u)
            self._u = u
            self._v = np.zeros(n)
            self._prev_dofs, self._prev_vals = dofs, vals
            self._pos, self._F = P, F
            self._t0, self._k = t0, 0
            self._pending = None
            self.reset_peaks()
        except BaseException:
            self._restore(saved)
            raise

    def _static_factor(self) -> tuple[IntArray, IntArray, Array, Array]:
        op = self._op
        if op.static_env is None:
            op.static_env = _factorise(op.system.K, "the stiffness matrix K")
        return op.static_env

    def reset_peaks(self) -> None:
        """Restart the running maxima of soil force and rail deflection from the current state."""
        fs, rw = self._sleeper_fields()[:2]
        self._pk_force = fs.copy()
        self._pk_rail = rw.copy()

    def peaks(self) -> tuple[IntArray, Array, Array]:
        """Running maxima in the window: (global sleeper index, soil force [N], rail deflection [m])."""
        idx = np.arange(self._first, self._first + self.n_sleepers, dtype=np.int64)
        return idx, self._pk_force.copy(), self._pk_rail.copy()

    def step(self, positions: ArrayLike, forces: ArrayLike) -> None:
        """Advance one time step to t + dt.

        Parameters
        ----------
        positions : (n_w,) array_like
            Wheel positions [m] at t + dt.
        forces : (n_w,) array_like
            Wheel forces [N] at t + dt.

        Raises
        ------
        InputError
            NaN forces, mismatched sizes, wheels outside the allowed part of
            the window (follow=False) or not fitting in it; the state is
            then unchanged.
        """
        P, F = self._wheels(positions, forces, "step")
        saved = self._save()
        try:
            self._pending = None
            self._run(P[None, :], F[None, :], None, 0, "step")
        except BaseException:
            self._restore(saved)
            raise

    def advance(
        self,
        t_end: float,
        loads: Loads,
        *,
        callback: Callable[[Block], None] | None = None,
        output_every: int = 1,
    ) -> None:
        """Advance by whole steps of ``dt`` to the last step time <= ``t_end``.

        Parameters
        ----------
        t_end : float
            End time [s]; must not lie before the current time.
        loads : tuple (positions_end, forces_end), callable or LoadTable
            ``(positions_end, forces_end)``: wheel positions [m] and forces [N]
            at ``t_end``, linearly interpolated from the current ones (same
            number of wheels; a wheel absent now, NaN, appears at ``t_end``). A callable ``t -> (positions, forces)`` is
            evaluated at every step time. A :class:`LoadTable` is evaluated
            vectorised.
        callback : callable, optional
            Receives a :class:`Block` of outputs for each stretch of steps with
            the window in one position (at least one per call and one before
            every window shift). Without it nothing is recorded.
        output_every : int
            Record sleeper and wheel outputs every this many steps (global
            step count since :meth:`initialize`; peaks use every step).

        Raises
        ------
        InputError
            ``t_end`` before the current time, NaN forces, mismatched sizes,
            wheels outside the allowed part of the window. The state is then
            unchanged (also when the bad value comes from a callable
            mid-interval).
        """
        t_end = float(t_end)
        if not math.isfinite(t_end):
            raise InputError(f"advance: t_end = {t_end}: must be finite")
        if t_end < self.t - _TOL * self.dt:
            raise InputError(
                f"advance: t_end = {t_end:g} s is before the current time t = {self.t:g} s (time going backwards)"
            )
        if output_every < 1:
            raise InputError(f"advance: output_every = {output_every}: must be >= 1")
        n_total = int(math.floor((t_end - self.t) / self.dt + 1e-6))
        if n_total <= 0:
            return
        t_start, k_start = self.t, self._k
        source: Callable[[Array], tuple[Array, Array]]
        if isinstance(loads, tuple):
            if len(loads) != 2:
                raise InputError(f"advance: loads tuple has {len(loads)} items; expected (positions_end, forces_end)")
            P1, F1 = self._wheels(loads[0], loads[1], "advance")
            if P1.shape != self._pos.shape:
                raise InputError(
                    f"advance: {P1.size} wheels at t_end but {self._pos.size} now; linear interpolation needs "
                    "the same wheels (use step() or a callable when wheels enter or leave)"
                )
            P0, F0 = self._pos.copy(), self._F.copy()
            span = t_end - t_start

            def source(tq: Array) -> tuple[Array, Array]:
                a = ((tq - t_start) / span)[:, None]
                P = P0 + a * (P1 - P0)
                F = F0 + a * (F1 - F0)
                last = a[:, 0] >= 1.0 - 1e-12
                P[last], F[last] = P1, F1
                return P, np.where(np.isfinite(P), F, 0.0)
        elif isinstance(loads, LoadTable):
            source = loads
        elif callable(loads):
            fn = loads

            def source(tq: Array) -> tuple[Array, Array]:
                rows = []
                for ti in tq:
                    res = fn(float(ti))
                    if not (isinstance(res, tuple) and len(res) == 2):
                        raise InputError(
                            f"advance: load function returned {type(res).__name__} at t = {ti:g} s; "
                            "expected (positions, forces)"
                        )
                    p = np.array(res[0], dtype=float, ndmin=1)
                    f = np.array(res[1], dtype=float, ndmin=1)
                    if p.ndim != 1 or f.shape != p.shape:
                        raise InputError(
                            f"advance: load function at t = {ti:g} s: positions {p.shape} and forces {f.shape} "
                            "must be equal 1-D shapes"
                        )
                    rows.append((p, f))
                W = max(p.size for p, _ in rows)
                P = np.full((len(rows), W), np.nan)
                F = np.zeros((len(rows), W))
                for i, (p, f) in enumerate(rows):
                    P[i, : p.size], F[i, : f.size] = p, f
                return P, F
        else:
            raise InputError(
                f"advance: loads of type {type(loads).__name__}: expected (positions, forces), "
                "a callable or a LoadTable"
            )

        saved = self._save()
        try:
            self._pending = None
            done = 0
            while done < n_total:
                n = min(CHUNK_STEPS, n_total - done)
                tq: Array = self._t0 + (k_start + done + 1 + np.arange(n, dtype=np.float64)) * self.dt
                P, F = source(tq)
                P = np.asarray(P, dtype=float)
                F = np.asarray(F, dtype=float)
                if P.ndim != 2 or P.shape[0] != n or F.shape != P.shape:
                    raise InputError(
                        f"advance: loads gave positions {P.shape} and forces {F.shape}; expected ({n}, n_wheels) each"
                    )
                _check_values(P, F, tq, "advance")
                self._run(np.ascontiguousarray(P), np.ascontiguousarray(np.where(np.isfinite(P), F, 0.0)),
                          callback, output_every, "advance")
                done += n
        except BaseException:
            self._restore(saved)
            raise

    def _run(self, P: Array, F: Array, callback: Callable[[Block], None] | None, every: int, what: str) -> None:
        """Step through rows of P, F (S, W), shifting the window between stretches."""
        S, W = P.shape
        pres = np.isfinite(P)
        any_p = pres.any(axis=1)
        front = np.where(any_p, np.max(np.where(pres, P, -np.inf), axis=1), -np.inf)
        rear = np.where(any_p, np.min(np.where(pres, P, np.inf), axis=1), np.inf)
        d = self.spacing
        s = 0
        while s < S:
            lo, hi = self.allowed_range()
            eps = _TOL * d
            viol = np.nonzero((front[s:] > hi + eps) | (rear[s:] < lo - eps))[0]
            e = S if viol.size == 0 else s + int(viol[0])
            if e == s:
                t = self._t0 + (self._k + 1) * self.dt
                if not self.follow:
                    self._check_inside(float(front[s]), float(rear[s]), what, t)
                first, orient = self._required_first(float(front[s]), float(rear[s]), what, t)
                if first == self._first and orient == self._op.orientation:  # pragma: no cover - safety
                    raise InputError(f"{what}: cannot place the window for wheels at {rear[s]:g} .. {front[s]:g} m")
                self._shift_to(first, orient)
                continue
            self._kernel(P[s:e], F[s:e], callback, every)
            s = e

    def _kernel(self, P: Array, F: Array, callback: Callable[[Block], None] | None, every: int) -> None:
        S, W = P.shape
        op = self._op
        N = self.n_sleepers
        ldofs, lw = self._weights(P)
        wdefl = np.empty((S, W))
        wvel = np.empty((S, W))
        if callback is not None:
            phase = (self._k + 1) % every
            n_out = len(range((every - phase) % every, S, every))
            outs = [np.empty((n_out, N)) for _ in range(4)]
            out_every = every
        else:
            phase, n_out, out_every = 0, 0, 0
            outs = [np.empty((0, N)) for _ in range(4)]
        first, ptr, L, _ = op.env
        kout = kern.run_steps(
            op.indptr, op.indices, op.Ka, op.Mb, first, ptr, L, op.Dinv, self._a1,
            self._u, self._v, self._z, self._y, self._prev_dofs, self._prev_vals,
            ldofs, lw, F,
            self._s_dof, self._a_dof, self._r_dof, op.kb, op.db,
            wdefl, wvel, out_every, phase, outs[0], outs[1], outs[2], outs[3],
            self._pk_force, self._pk_rail,
        )
        assert kout == n_out
        k0 = self._k
        self._k += S
        self._prev_dofs = ldofs[-1].copy()
        self._prev_vals = lw[-1] * np.repeat(F[-1], 4)
        self._pos, self._F = P[-1].copy(), F[-1].copy()
        if callback is not None:
            sel = np.arange((every - phase) % every, S, every)
            absent = ~np.isfinite(P[sel])
            callback(Block(
                first_sleeper=self._first,
                sleeper_x=np.arange(self._first, self._first + N, dtype=np.float64) * self.spacing,
                t=self._t0 + (k0 + 1 + sel.astype(np.float64)) * self.dt,
                soil_force=outs[0], rail_deflection=outs[1],
                sleeper_displacement=outs[2], area_displacement=outs[3],
                wheel_positions=P[sel].copy(), wheel_forces=F[sel].copy(),
                wheel_deflection=np.where(absent, np.nan, wdefl[sel]),
                wheel_velocity=np.where(absent, np.nan, wvel[sel]),
                peak_soil_force=self._pk_force.copy(), peak_rail_deflection=self._pk_rail.copy(),
                peak_wheel_deflection=np.max(np.where(np.isfinite(P), wdefl, -np.inf), axis=0),
            ))

    # ------------------------------------------------------------------ two-phase step

    def begin_step(self, positions_next: ArrayLike) -> tuple[Array, Array, Array]:
        """First half of a step whose wheel forces are found by the caller (vehicle coupling).

        Parameters
        ----------
        positions_next : (n_w,) array_like
            Wheel positions [m] at t + dt. The window may shift here.

        Returns
        -------
        w_free : (n_w,) array
            Rail deflection under each wheel at t + dt if the wheel forces at
            t + dt were zero [m].
        v_free : (n_w,) array
            Rail velocity under each wheel at t + dt, same assumption [m/s].
        G : (n_w, n_w) array
            Compliance [m/N]: for forces P at t + dt, w = w_free + G @ P and
            v = v_free + (2/dt) G @ P. Symmetric positive definite.

        Notes
        -----
        Complete the step with :meth:`finish_step`; calling ``begin_step``
        again discards the pending step. Absent wheels (NaN) give NaN rows.
        """
        P, _ = self._wheels(positions_next, None, "begin_step")
        saved = self._save()
        try:
            self._pending = None
            self._place(P, "begin_step", self.t + self.dt)
            op = self._op
            dofs, wts = self._weights(P[None, :])
            dofs, wts = dofs[0], wts[0]
            first, ptr, L, D = op.env
            x0 = np.empty_like(self._u)
            kern.free_rhs(op.indptr, op.indices, op.Ka, op.Mb, self._u, self._v,
                          self._prev_dofs, self._prev_vals, x0)
            kern.solve_envelope(first, ptr, L, D, x0)
            W = P.size
            Gc = np.zeros((self._u.size, W))
            for j in range(W):
                if np.isfinite(P[j]):
                    b = np.zeros(self._u.size)
                    np.add.at(b, dofs[4 * j : 4 * j + 4], wts[4 * j : 4 * j + 4])
                    kern.solve_envelope(first, ptr, L, D, b)
                    Gc[:, j] = b
            Wm = np.zeros((W, self._u.size))
            for j in range(W):
                np.add.at(Wm[j], dofs[4 * j : 4 * j + 4], wts[4 * j : 4 * j + 4])
            w_free = Wm @ (self._u + x0)
            v_free = Wm @ (self._a1 * x0 - self._v)
            G = Wm @ Gc
            absent = ~np.isfinite(P)
            w_free[absent] = np.nan
            v_free[absent] = np.nan
            G[absent, :] = np.nan
            G[:, absent] = np.nan
            self._pending = (P, x0, dofs, wts, Gc, Wm, self._k)
        except BaseException:
            self._restore(saved)
            raise
        return w_free, v_free, G

    def finish_step(self, forces_next: ArrayLike) -> None:
        """Complete the step begun with :meth:`begin_step` with the wheel forces [N] at t + dt.

        Raises
        ------
        InputError
            No pending step, NaN forces or a size different from the
            positions given to ``begin_step``; the state is then unchanged.
        """
        if self._pending is None or self._pending[6] != self._k:
            raise InputError("finish_step: no pending step (call begin_step first)")
        P, x0, dofs, wts, Gc, Wm, _ = self._pending
        F = np.array(forces_next, dtype=float, ndmin=1)
        if F.shape != P.shape:
            raise InputError(f"finish_step: forces have shape {F.shape}, begin_step had {P.shape} wheels")
        _check_values(P[None, :], F[None, :], np.array([self.t + self.dt]), "finish_step")
        F = np.where(np.isfinite(P), F, 0.0)
        du = x0 + Gc @ F
        self._u += du
        self._v = self._a1 * du - self._v
        self._prev_dofs = dofs.copy()
        self._prev_vals = wts * np.repeat(F, 4)
        self._pos, self._F = P.copy(), F.copy()
        self._k += 1
        self._pending = None
        fs, rw = self._sleeper_fields()[:2]
        np.maximum(self._pk_force, fs, out=self._pk_force)
        np.maximum(self._pk_rail, rw, out=self._pk_rail)

    # ------------------------------------------------------------------ compiled two-phase steps

    def coupled_chunk(self, positions: ArrayLike) -> tuple[int, tuple[object, ...]]:
        """Prepare consecutive two-phase steps for a compiled coupling kernel (vehicle coupling).

        The compiled equivalent of calling :meth:`begin_step` and
        :meth:`finish_step` for each row of ``positions``
        (:mod:`clm_core.vehicle._coupled_kernel`): the window is placed for
        row 0 as :meth:`begin_step` would place it, then the rows it holds
        without another shift are handed to the kernel, which advances the
        state in place. Complete with :meth:`coupled_commit`.

        Parameters
        ----------
        positions : (S, n_w) array_like
            Wheel positions [m] at the next S step times t + dt, t + 2 dt, ...
            (all finite).

        Returns
        -------
        m : int
            Leading rows (1 <= m <= S) the window holds without a shift.
        args : tuple
            Kernel inputs: ``(indptr, indices, Ka, Mb, first, ptr, L, Dinv,
            a1, u, v, z, x, prev_dofs, prev_vals, ldofs, lw, cols, slot,
            s_dof, a_dof, r_dof, kb, db, pk_force, pk_rail)``: the operator
            (see :func:`clm_core._kernels.run_steps`), the state and work
            arrays (updated in place; z is zero), the element DOFs and
            Hermite weights (m, 4 n_w) of the wheels, the columns
            ``cols[slot[d]] = K_eff^-1 e_d`` of every DOF in ``ldofs`` and the
            sleeper maps and running peaks.

        Raises
        ------
        InputError
            Non-finite positions, or wheels that the window cannot hold (as
            :meth:`begin_step`).
        """
        P = np.ascontiguousarray(np.array(positions, dtype=float, ndmin=2))
        if P.ndim != 2 or P.shape[0] < 1 or not np.all(np.isfinite(P)):
            raise InputError(f"coupled_chunk: positions of shape {P.shape} must be finite rows (S >= 1, n_wheels)")
        self._pending = None
        t1 = self.t + self.dt
        self._place(P[0], "begin_step", t1)
        lo, hi = self.allowed_range()
        eps = _TOL * self.spacing
        front, rear = P.max(axis=1), P.min(axis=1)
        viol = np.nonzero((front > hi + eps) | (rear < lo - eps))[0]
        m = P.shape[0] if viol.size == 0 else int(viol[0])
        if m < 1:  # pragma: no cover - _place made row 0 fit
            raise InputError(f"coupled_chunk: cannot place the window for wheels at {rear[0]:g} .. {front[0]:g} m")
        ldofs, lw = self._weights(P[:m])
        cols, slot = self._columns(ldofs)
        op = self._op
        first, ptr, L, _ = op.env
        self._chunk = (P[:m], ldofs, lw)
        return m, (
            op.indptr, op.indices, op.Ka, op.Mb, first, ptr, L, op.Dinv, self._a1,
            self._u, self._v, self._z, self._y, self._prev_dofs, self._prev_vals,
            ldofs, lw, cols, slot, self._s_dof, self._a_dof, self._r_dof, op.kb, op.db,
            self._pk_force, self._pk_rail,
        )

    def coupled_commit(self, steps: int, forces_last: ArrayLike) -> None:
        """Record that a kernel advanced ``steps`` rows of the last :meth:`coupled_chunk`.

        ``forces_last``: the wheel forces [N] of the last step made (the
        loads f_n of the next step).
        """
        P, ldofs, lw = self._chunk
        steps = int(steps)
        if not 0 <= steps <= P.shape[0]:
            raise InputError(f"coupled_commit: {steps} steps, the chunk has {P.shape[0]}")
        if steps == 0:
            return
        F = np.array(forces_last, dtype=float, ndmin=1)
        self._k += steps
        self._prev_dofs = ldofs[steps - 1].copy()
        self._prev_vals = lw[steps - 1] * np.repeat(F, 4)
        self._pos, self._F = P[steps - 1].copy(), F.copy()
        self._pending = None

    def _columns(self, dofs: IntArray) -> tuple[Array, IntArray]:
        """Columns K_eff^-1 e_d of the current operator for the DOFs ``dofs`` (computed once per operator)."""
        op = self._op
        n = self._u.size
        if op.cols is None or op.col_slot is None:
            op.cols = np.empty((min(n, 32), n))
            op.col_slot = np.full(n, -1, dtype=np.int64)
            op.n_cols = 0
        need = np.unique(dofs)
        need = np.ascontiguousarray(need[op.col_slot[need] < 0])
        if need.size:
            k = op.n_cols + need.size
            if k > op.cols.shape[0]:
                grown = np.empty((min(n, max(k, 2 * op.cols.shape[0])), n))
                grown[: op.n_cols] = op.cols[: op.n_cols]
                op.cols = grown
            rows = np.arange(op.n_cols, k, dtype=np.int64)
            first, ptr, L, D = op.env
            kern.unit_columns(first, ptr, L, D, need, op.cols, rows)
            op.col_slot[need] = rows
            op.n_cols = k
        return op.cols, op.col_slot

    # ------------------------------------------------------------------ outputs

    def _sleeper_fields(self) -> tuple[Array, Array, Array, Array]:
        u, v = self._u, self._v
        op = self._op
        zs, vs = u[self._s_dof], v[self._s_dof]
        if self._a_dof[0] >= 0:
            xa, va = u[self._a_dof], v[self._a_dof]
        else:
            xa, va = np.zeros_like(zs), np.zeros_like(vs)
        fs = op.kb * (zs - xa) + op.db * (vs - va)
        return fs, u[self._r_dof].copy(), zs.copy(), xa.copy()

    def snapshot(self) -> Snapshot:
        """The current state (copies), see :class:`Snapshot`."""
        fs, rw, zs, xa = self._sleeper_fields()
        P = self._pos.copy()
        if P.size:
            dofs, wts = self._weights(P[None, :])
            W = P.size
            wd = (wts[0] * self._u[dofs[0]]).reshape(W, 4).sum(axis=1)
            wv = (wts[0] * self._v[dofs[0]]).reshape(W, 4).sum(axis=1)
            absent = ~np.isfinite(P)
            wd[absent] = np.nan
            wv[absent] = np.nan
        else:
            wd = np.zeros(0)
            wv = np.zeros(0)
        idx = np.arange(self._first, self._first + self.n_sleepers, dtype=np.int64)
        return Snapshot(
            t=self.t, sleeper_index=idx, sleeper_x=idx.astype(np.float64) * self.spacing, soil_force=fs,
            rail_deflection=rw, sleeper_displacement=zs, area_displacement=xa,
            wheel_positions=P, wheel_forces=self._F.copy(), wheel_deflection=wd, wheel_velocity=wv,
        )

    def block(self) -> Block:
        """The current state as a one-row :class:`Block` (e.g. the initial row of a recorded history)."""
        snap = self.snapshot()
        W = snap.wheel_positions.size
        return Block(
            first_sleeper=self._first, sleeper_x=snap.sleeper_x, t=np.array([snap.t]),
            soil_force=snap.soil_force[None, :], rail_deflection=snap.rail_deflection[None, :],
            sleeper_displacement=snap.sleeper_displacement[None, :],
            area_displacement=snap.area_displacement[None, :],
            wheel_positions=snap.wheel_positions.reshape(1, W), wheel_forces=snap.wheel_forces.reshape(1, W),
            wheel_deflection=snap.wheel_deflection.reshape(1, W), wheel_velocity=snap.wheel_velocity.reshape(1, W),
            peak_soil_force=self._pk_force.copy(), peak_rail_deflection=self._pk_rail.copy(),
            peak_wheel_deflection=np.where(np.isfinite(snap.wheel_deflection), snap.wheel_deflection, -np.inf),
        )

    def state_vectors(self) -> tuple[Array, Array]:
        """Copies of the window's displacement [m] and velocity [m/s] vectors (DOF order of :attr:`system`)."""
        return self._u.copy(), self._v.copy()


def _check_values(P: Array, F: Array, t: Array, what: str) -> None:
    """Refuse NaN/inf forces on present wheels, infinite positions, forces on absent wheels."""
    if np.any(np.isinf(P)):
        r, c = np.argwhere(np.isinf(P))[0]
        raise InputError(
            f"{what}: wheel {c} position {P[r, c]} m at t = {t[r]:g} s: must be finite (NaN = not on the track)"
        )
    present = np.isfinite(P)
    bad = present & ~np.isfinite(F)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(f"{what}: wheel {c} force {F[r, c]} N at t = {t[r]:g} s: must be finite")
    bad = ~present & np.isfinite(F) & (F != 0.0)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(
            f"{what}: wheel {c} has force {F[r, c]:g} N at t = {t[r]:g} s but position NaN "
            "(a wheel not on the track carries no force)"
        )


__all__: Sequence[str] = ["Block", "LoadTable", "Snapshot", "TrackSimulator"]
