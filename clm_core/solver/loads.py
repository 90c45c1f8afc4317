"""Wheel loads: tabulated histories, input checks and the Hermite weights on the rail.

Wheels are arrays of shape (n_w,): positions [m] along the line and vertical
forces [N], positive downwards. A wheel that is not on the track has position
NaN (its force must then be 0 or NaN). A wheel between rail nodes loads its
element's four DOFs with the cubic Hermite shape functions
(:meth:`clm_core.track.TrackSystem.point_load`); the same weights give the
rail deflection and velocity under the wheel.

- :class:`LoadTable`: a history tabulated in time, linearly interpolated;
- :func:`load_source`: what :meth:`clm_core.solver.TrackSimulator.advance`
  accepts (end values, a callable or a table) as one vectorised function of
  the step times;
- :func:`load_weights`, :func:`load_entries`: DOFs and weights of wheels in a
  window (compiled, :func:`clm_core.solver._kernels.hermite_weights`);
- :func:`wheel_arrays`, :func:`check_values`: the input rules (refusals are
  :class:`~clm_core.errors.InputError` naming the call, wheel and time).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Union

import numpy as np
from numpy.typing import ArrayLike

from clm_core.arrays import Array, IntArray
from clm_core.errors import InputError
from clm_core.solver import _kernels as kern
from clm_core.solver.operators import DofLayout

#: A load function: time [s] -> (positions [m], forces [N]) of the wheels, arrays (n_w,).
LoadFunction = Callable[[float], tuple[ArrayLike, ArrayLike]]
#: A vectorised load source: step times (S,) [s] -> (positions, forces), arrays (S, n_w).
LoadSource = Callable[[Array], tuple[Array, Array]]
#: What :meth:`clm_core.solver.TrackSimulator.advance` accepts as loads.
Loads = Union[tuple[ArrayLike, ArrayLike], LoadFunction, "LoadTable"]

_TOL = 1e-9


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
        bad_force = first_unfinite_force(P, F)
        if bad_force is not None:
            r, c = bad_force
            raise InputError(
                f"load table: wheel {c + 1} at t = {tt[r]:g} s has position {P[r, c]:g} m but force {F[r, c]}"
            )
        self.t, self.positions, self.forces = tt, P, np.where(np.isfinite(P), F, 0.0)
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


def wheel_arrays(positions: ArrayLike, forces: ArrayLike | None, t: float, what: str) -> tuple[Array, Array]:
    """Positions [m] and forces [N] of one instant as checked (n_w,) arrays (absent wheels: force 0).

    ``forces=None``: zero forces (positions only). ``t`` [s] and ``what``
    (the calling method) go into the error messages.

    Raises
    ------
    InputError
        Not real numbers, not 1-D, sizes differ, or a value rule of :func:`check_values`.
    """
    try:
        P = np.array(positions, dtype=float, ndmin=1)
        F = np.zeros_like(P) if forces is None else np.array(forces, dtype=float, ndmin=1)
    except (TypeError, ValueError):
        raise InputError(f"{what}: positions and forces must be real numbers [m], [N]") from None
    if P.ndim != 1:
        raise InputError(f"{what}: positions must be a 1-D array (n_wheels,), got shape {P.shape}")
    if F.shape != P.shape:
        raise InputError(f"{what}: forces have shape {F.shape}, positions {P.shape}; one force per wheel")
    check_values(P[None, :], F[None, :], np.array([t]), what)
    return P, np.where(np.isfinite(P), F, 0.0)


def load_source(loads: Loads, t_start: float, t_end: float, P0: Array, F0: Array) -> LoadSource:
    """The loads of :meth:`clm_core.solver.TrackSimulator.advance` as a vectorised function of time.

    Parameters
    ----------
    loads : tuple (positions_end, forces_end), callable or LoadTable
        End values at ``t_end`` (linear interpolation from ``P0``, ``F0`` at
        ``t_start``; same wheels, a wheel absent at ``t_start`` appears at
        ``t_end``), a function ``t -> (positions, forces)`` evaluated at
        every step time, or a :class:`LoadTable`.
    t_start, t_end : float
        Interval [s] (``t_end > t_start`` for end values).
    P0, F0 : (n_w,) arrays
        Wheel positions [m] and forces [N] at ``t_start``.

    Returns
    -------
    callable
        Step times (S,) -> (positions, forces), arrays (S, n_w); a callable
        may return a different number of wheels at different times (padded
        with absent wheels).

    Raises
    ------
    InputError
        Bad end values (checked here) or a bad type; a callable's bad
        return value is refused when the source is evaluated.
    """
    if isinstance(loads, tuple):
        if len(loads) != 2:
            raise InputError(f"advance: loads tuple has {len(loads)} items; expected (positions_end, forces_end)")
        P1, F1 = wheel_arrays(loads[0], loads[1], t_start, "advance")
        if P1.shape != P0.shape:
            raise InputError(
                f"advance: {P1.size} wheels at t_end but {P0.size} now; linear interpolation needs "
                "the same wheels (use step() or a callable when wheels enter or leave)"
            )
        P0, F0 = P0.copy(), F0.copy()
        span = t_end - t_start

        def interpolate(tq: Array) -> tuple[Array, Array]:
            a = ((tq - t_start) / span)[:, None]
            P = P0 + a * (P1 - P0)
            F = F0 + a * (F1 - F0)
            last = a[:, 0] >= 1.0 - 1e-12
            P[last], F[last] = P1, F1
            return P, np.where(np.isfinite(P), F, 0.0)

        return interpolate
    if isinstance(loads, LoadTable):
        return loads
    if callable(loads):
        return _sampled(loads)
    raise InputError(
        f"advance: loads of type {type(loads).__name__}: expected (positions, forces), a callable or a LoadTable"
    )


def _sampled(fn: LoadFunction) -> LoadSource:
    """A load function evaluated at every step time, padded to the largest number of wheels."""

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

    return source


def load_weights(layout: DofLayout, first: int, P: Array) -> tuple[IntArray, Array]:
    """DOFs and Hermite weights (S, 4 W) of wheels at positions ``P`` (S, W) [m].

    ``layout`` is the window's DOF layout and ``first`` the global index of
    its first sleeper; an absent wheel (NaN) gets weight 0 on DOF 0.
    """
    x0 = float(layout.node_x_rel[0] + first * layout.spacing)
    P = np.ascontiguousarray(P, dtype=np.float64)
    dofs, w = kern.hermite_weights(P, x0, float(layout.Le), int(layout.n_el), layout.rail_w, layout.rail_th)
    return dofs, w


def load_entries(layout: DofLayout, first: int, P: Array, F: Array) -> tuple[IntArray, Array]:
    """The load vector of wheels at ``P`` (n_w,) [m] with forces ``F`` (n_w,) [N], as (DOF, value [N]) pairs."""
    d, w = load_weights(layout, first, P[None, :])
    return d[0].copy(), (w[0] * np.repeat(F, 4)).copy()


def first_unfinite_force(P: Array, F: Array) -> tuple[int, int] | None:
    """The first (row, wheel) where a wheel on the track has a NaN or infinite force, or None.

    ``P``, ``F``: (S, W) wheel positions [m] (NaN: not on the track) and
    forces [N]; rows are scanned in order, wheels within a row.
    """
    bad = np.isfinite(P) & ~np.isfinite(F)
    if not bad.any():
        return None
    r, c = np.argwhere(bad)[0]
    return int(r), int(c)


def check_values(P: Array, F: Array, t: Array, what: str) -> None:
    """Refuse NaN/inf forces on present wheels, infinite positions, forces on absent wheels.

    ``P``, ``F``: (S, W) positions [m] and forces [N] at the times ``t`` (S,)
    [s]; ``what`` names the calling method in the message.

    Raises
    ------
    InputError
        Names the wheel, the time and the rule.
    """
    if math.isfinite(float(P.sum()) + float(F.sum())):
        return  # every value finite (a NaN or inf would make the sum non-finite): nothing to refuse
    if np.any(np.isinf(P)):
        r, c = np.argwhere(np.isinf(P))[0]
        raise InputError(
            f"{what}: wheel {c} position {P[r, c]} m at t = {t[r]:g} s: must be finite (NaN = not on the track)"
        )
    bad_force = first_unfinite_force(P, F)
    if bad_force is not None:
        r, c = bad_force
        raise InputError(f"{what}: wheel {c} force {F[r, c]} N at t = {t[r]:g} s: must be finite")
    bad = ~np.isfinite(P) & np.isfinite(F) & (F != 0.0)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(
            f"{what}: wheel {c} has force {F[r, c]:g} N at t = {t[r]:g} s but position NaN "
            "(a wheel not on the track carries no force)"
        )


__all__ = [
    "LoadFunction", "LoadSource", "LoadTable", "Loads", "check_values", "load_entries", "load_source",
    "load_weights", "wheel_arrays",
]
