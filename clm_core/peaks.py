"""Which part of a run its reported peaks come from: one rule for every reported peak.

A time-domain run starts from a state that is not the steady moving-load
state (static equilibrium under the initial loads, or rest) and ends with
sleepers the loads have not fully passed. Peaks taken over the whole run
include the start-up transient (the rail deflection under a 30 m/s load is
0.7-2 % above its steady value in the first bays) and miss the last sleepers'
passages. Every reported peak (``clm simulate``, vehicle runs, the demo, and
parametric studies) is therefore taken over :class:`PeakWindow`:

- per-sleeper peaks (soil force, rail deflection above the sleeper): sleepers
  at least ``margin_bays`` bays ahead of the foremost load's start position and
  behind the rearmost load's final position, i.e. passed by every load, away
  from the start and the end;
- per-instant values (wheel load, rail deflection under a wheel): instants
  after the loads have travelled ``margin_bays`` bays from their start
  positions (the foremost load at or beyond the first admitted sleeper).

When nothing qualifies (a run too short or a standing load) the peaks are
taken over everything and the summary says so (``fallback``).
:meth:`PeakWindow.describe` is what ``summary.json`` files carry under
``peak_exclusion``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.checks import finite, integer, positive
from clm_core.errors import InputError, ParameterError

#: Bays excluded at each end of a run (start-up transient, sleepers not fully passed).
MARGIN_BAYS = 5

_TOL = 1e-9  # [m] positions on the bay grid


@dataclass(frozen=True)
class PeakWindow:
    """The part of a run its peaks are taken over (see the module docstring).

    Attributes
    ----------
    spacing : float
        Sleeper spacing d [m].
    front_start : float
        Position of the foremost load at the start [m].
    rear_end : float
        Position of the rearmost load at the end [m].
    margin_bays : int
        Bays excluded at each end.
    """

    spacing: float
    front_start: float
    rear_end: float
    margin_bays: int = MARGIN_BAYS

    def __post_init__(self) -> None:
        """Check and convert the fields.

        Raises
        ------
        ParameterError
            ``spacing`` not finite and > 0, a position that is not a real
            number, or ``margin_bays`` not an integer >= 0.
        """
        object.__setattr__(self, "spacing", positive("spacing", self.spacing, unit="m"))
        for name in ("front_start", "rear_end"):
            value = getattr(self, name)
            try:
                object.__setattr__(self, name, float(value))
            except (TypeError, ValueError):
                raise ParameterError(f"{name} = {value!r}: must be a real number [m]") from None
        object.__setattr__(self, "margin_bays", integer("margin_bays", self.margin_bays, 0))

    @property
    def x_from(self) -> float:
        """First admitted sleeper position [m]: ``margin_bays`` bays ahead of the foremost load's start."""
        return self.front_start + self.margin_bays * self.spacing

    @property
    def x_to(self) -> float:
        """Last admitted sleeper position [m]: ``margin_bays`` bays behind the rearmost load's end."""
        return self.rear_end - self.margin_bays * self.spacing

    def sleepers(self, x: ArrayLike) -> NDArray[np.bool_]:
        """Mask of the admitted sleepers at positions ``x`` [m]."""
        xa = np.asarray(x, dtype=float)
        return np.asarray((xa >= self.x_from - _TOL) & (xa <= self.x_to + _TOL))

    def instants(self, front_position: ArrayLike) -> NDArray[np.bool_]:
        """Mask of the admitted instants, from the foremost load's position at each [m]."""
        f = np.asarray(front_position, dtype=float)
        return np.asarray(np.nan_to_num(f, nan=-np.inf) >= self.x_from - _TOL)

    def describe(self, sleeper_index: ArrayLike | None = None, sleeper_mask: ArrayLike | None = None,
                 instants_from_s: float | None = None, sleepers_fallback: bool = False,
                 instants_fallback: bool = False) -> dict[str, Any]:
        """JSON-ready statement of the exclusion (``summary.json`` ``peak_exclusion``).

        Parameters
        ----------
        sleeper_index, sleeper_mask : arrays, optional
            Global indices of the sleepers with peaks and the admitted ones
            (gives ``first_sleeper``/``last_sleeper``).
        instants_from_s : float, optional
            Time of the first admitted instant [s].
        sleepers_fallback, instants_fallback : bool
            No sleeper (instant) qualified: those peaks are over the whole run.
        """
        out: dict[str, Any] = {
            "rule": (f"per-sleeper peaks over sleepers passed by every load, at least {self.margin_bays} bays "
                     f"from the loads' start and end positions; per-instant peaks (wheel loads, rail deflection "
                     f"under a wheel) after the loads have travelled {self.margin_bays} bays"),
            "why": "the start-up transient from the initial state, and sleepers the loads have not fully passed",
            "margin_bays": self.margin_bays,
            "spacing_m": self.spacing,
            "sleepers_from_x_m": self.x_from,
            "sleepers_to_x_m": self.x_to,
            "first_sleeper": None,
            "last_sleeper": None,
            "instants_from_s": instants_from_s,
            "fallback": sleepers_fallback or instants_fallback,
            "sleepers_fallback": sleepers_fallback,
            "instants_fallback": instants_fallback,
        }
        if sleeper_index is not None and sleeper_mask is not None:
            idx = np.asarray(sleeper_index)[np.asarray(sleeper_mask, dtype=bool)]
            if idx.size:
                out["first_sleeper"], out["last_sleeper"] = int(idx.min()), int(idx.max())
        if sleepers_fallback or instants_fallback:
            which = " and ".join(w for w, f in (("sleeper", sleepers_fallback), ("instant", instants_fallback)) if f)
            out["rule"] += f"; NOT APPLIED: no {which} qualified (run too short or loads standing), whole run"
        return out


def peak_window(front_start: float, rear_end: float, spacing: float, margin_bays: int = MARGIN_BAYS) -> PeakWindow:
    """The :class:`PeakWindow` of a run whose loads start with the foremost at ``front_start`` [m]
    and end with the rearmost at ``rear_end`` [m] on a track of sleeper spacing ``spacing`` [m]."""
    return PeakWindow(spacing=spacing, front_start=front_start, rear_end=rear_end, margin_bays=margin_bays)


def masked_max(values: ArrayLike, mask: ArrayLike) -> tuple[float, int, bool]:
    """Maximum of ``values`` where ``mask`` (NaN ignored); over every finite value if none is admitted.

    Parameters
    ----------
    values : array_like
        Values, any shape.
    mask : array_like of bool
        Admitted entries (broadcast to the shape of ``values``).

    Returns
    -------
    (value, index, fallback)
        The maximum, its flat index in ``values`` (of one occurrence when it
        occurs more than once) and whether the fallback was used (NaN, -1,
        True when there is no finite value at all).

    Raises
    ------
    InputError
        A ``mask`` that does not broadcast to the shape of ``values``.
    """
    v = np.asarray(values, dtype=float)
    mk = np.asarray(mask, dtype=bool)
    try:
        np.broadcast_shapes(mk.shape, v.shape)
        if np.broadcast_shapes(mk.shape, v.shape) != v.shape:
            raise ValueError
    except ValueError:
        raise InputError(f"mask: shape {mk.shape}: does not broadcast to the values' shape {v.shape}") from None
    if mk.ndim == v.ndim and v.ndim > 1 and mk.size < v.size:
        return _masked_max_reduced(v, mk)
    m = np.broadcast_to(mk, v.shape).ravel()
    v = v.ravel()
    ok = np.isfinite(v)
    sel = ok & m
    fallback = not sel.any()
    if fallback:
        sel = ok
    if not sel.any():
        return float("nan"), -1, True
    i = int(np.argmax(np.where(sel, v, -np.inf)))
    return float(v[i]), i, fallback


def _masked_max_reduced(v: NDArray[np.float64], mk: NDArray[np.bool_]) -> tuple[float, int, bool]:
    """:func:`masked_max` for a mask constant along some axes (size 1 there): reduce those axes first.

    One pass over ``v`` instead of a full-size mask and copies (a vehicle run's (instants, sleepers)
    arrays). The value and fallback are those of the plain path; the index is that of the first
    occurrence of the maximum within the first admitted mask cell holding it."""
    axes = tuple(a for a in range(v.ndim) if mk.shape[a] == 1 and v.shape[a] > 1)
    r = np.fmax.reduce(v, axis=axes, keepdims=True, initial=-np.inf, where=np.isfinite(v))
    r = np.where(np.isneginf(r), np.nan, r)
    value, i_r, fallback = masked_max(r, np.broadcast_to(mk, r.shape))  # r has the mask's shape
    if i_r < 0:
        return value, -1, True
    pos = np.unravel_index(i_r, r.shape)
    sl = tuple(slice(None) if a in axes else slice(int(pos[a]), int(pos[a]) + 1) for a in range(v.ndim))
    sub = v[sl]
    k = np.unravel_index(int(np.argmax(sub == value)), sub.shape)
    full = tuple(int(k[a]) if a in axes else int(pos[a]) for a in range(v.ndim))
    return value, int(np.ravel_multi_index(full, v.shape)), fallback


def masked_min(values: ArrayLike, mask: ArrayLike) -> tuple[float, int, bool]:
    """Minimum of ``values`` where ``mask``; see :func:`masked_max`."""
    v, i, fb = masked_max(-np.asarray(values, dtype=float), mask)
    return -v, i, fb


class BlockPeaks:
    """The largest per-instant value of a streaming run (rail deflection under the wheels) after the start margin.

    A streaming run reports, per block of steps, the largest value under each
    wheel over every step of the block, plus the values at the block's output
    instants. A block whose steps all come after the loads travelled
    ``margin_bays`` bays (the foremost load at or past ``x_from`` before the
    block began; loads move forwards) counts with its every-step maximum; the
    block in which the loads cross ``x_from`` counts with its output instants
    past it. The result is the per-instant rule of :class:`PeakWindow`, exact
    when every step is an output instant.

    Parameters
    ----------
    front_start : float
        Position of the foremost load at the start [m].
    spacing : float
        Sleeper spacing [m].
    margin_bays : int
        Bays excluded at the start.
    t_start : float
        Time of the start [s].

    Raises
    ------
    ParameterError
        ``front_start`` or ``t_start`` not finite, or a bad ``spacing`` or
        ``margin_bays`` (:class:`PeakWindow`).
    """

    def __init__(self, front_start: float, spacing: float, margin_bays: int = MARGIN_BAYS,
                 t_start: float = 0.0) -> None:
        self._front = finite("front_start", front_start)
        self._t = finite("t_start", t_start)
        self.x_from = peak_window(self._front, math.inf, spacing, margin_bays).x_from
        self._best = -math.inf
        self._best_all = -math.inf
        self.t_from: float | None = None  # time of the first admitted instant [s]

    def add(self, block_peaks: ArrayLike, front_positions: ArrayLike, times: ArrayLike, values: ArrayLike) -> None:
        """One block: per-wheel every-step maxima (W,); then, at its k output instants, the foremost load's
        positions (k,) [m], the times (k,) [s] and the values under the wheels (k, W).

        Raises
        ------
        InputError
            Positions and times of different counts, or values that are not k x W.
        """
        pk = np.asarray(block_peaks, dtype=float)
        f = np.asarray(front_positions, dtype=float)
        t = np.asarray(times, dtype=float)
        v = np.asarray(values, dtype=float)
        if f.size != t.size or v.size != t.size * pk.size:
            raise InputError(
                f"BlockPeaks.add: {f.size} positions, {t.size} times and {v.size} values for {pk.size} wheels: "
                "need k positions, k times and k x W values"
            )
        v = v.reshape(t.size, -1) if t.size else np.empty((0, pk.size))  # a block without output instants
        if np.isfinite(pk).any():
            self._best_all = max(self._best_all, float(np.nanmax(np.where(np.isfinite(pk), pk, -np.inf))))
        if self._front >= self.x_from - _TOL:
            if np.isfinite(pk).any():
                self._best = max(self._best, float(np.max(pk[np.isfinite(pk)])))
                if self.t_from is None:
                    self._mark(self._t)
        else:
            ok = np.nan_to_num(f, nan=-np.inf) >= self.x_from - _TOL
            rows = v[ok]
            if rows.size and np.isfinite(rows).any():
                self._best = max(self._best, float(np.nanmax(rows)))
                self._mark(float(t[ok][0]))
        if f.size and np.isfinite(f[-1]):
            self._front = float(f[-1])
        if t.size:
            self._t = float(t[-1])

    def _mark(self, t: float) -> None:
        if self.t_from is None:
            self.t_from = t

    def maximum(self) -> tuple[float, float | None, bool]:
        """(largest admitted value, time of the first admitted instant [s], fallback: nothing admitted,
        the value is over the whole run)."""
        if self._best > -math.inf:
            return self._best, self.t_from, False
        return (self._best_all if self._best_all > -math.inf else math.nan), None, True


# ----------------------------------------------------------------------------- report statistics


def wheel_load_statistics(
    wheel_load: ArrayLike, static: ArrayLike, admitted: ArrayLike | None = None
) -> dict[str, Any]:
    """Static load, dynamic part and dynamic factor of wheel loads, JSON-ready (``summary.json`` entries).

    The dynamic part of a wheel load is P - P_static; its spread about the
    static load (the root mean square of P - P_static, i.e. the standard
    deviation about the static load, not about the mean) is what a track
    engineer quotes, not the rms of P itself, which is essentially the
    static load. The dynamic factor is the largest P / P_static.

    Parameters
    ----------
    wheel_load : (k, W) array_like
        Wheel loads [N] (NaN: wheel absent at that instant; ignored).
    static : (W,) array_like
        Static wheel loads [N] (> 0).
    admitted : (k,) or (k, W) array_like of bool, optional
        Instants (or entries) the statistics are over (e.g.
        :meth:`PeakWindow.instants`); default every instant. If none is
        admitted, every instant is used and ``wheel_load_statistics_fallback`` is true.

    Returns
    -------
    dict
        ``wheel_load_static_N`` (list, per wheel), ``wheel_load_dynamic_std_N``
        (over every wheel), ``wheel_load_dynamic_std_per_wheel_N`` (list),
        ``wheel_load_rms_including_static_N`` (rms of P, for comparison),
        ``dynamic_factor`` (max P / P_static over the wheels),
        ``dynamic_factor_wheel`` (its wheel), ``unloading_factor``
        (min P / P_static), ``wheel_load_statistics_instants``,
        ``wheel_load_statistics_fallback``.

    Raises
    ------
    InputError
        Shapes that do not match, or a static load that is not finite and > 0.
    """
    P = np.asarray(wheel_load, dtype=float)
    if P.ndim == 1:
        P = P[:, None]
    s = np.asarray(static, dtype=float).reshape(-1)
    if P.ndim != 2 or s.size != P.shape[1]:
        raise InputError(f"wheel_load_statistics: wheel loads of shape {np.shape(wheel_load)} and {s.size} static "
                         "load(s): need (k, W) loads and W static loads")
    if not np.all(np.isfinite(s) & (s > 0)):
        raise InputError(f"wheel_load_statistics: static loads {s.tolist()}: must be finite and > 0 N")
    if admitted is None:
        m = np.ones(P.shape, dtype=bool)
    else:
        try:
            m = np.broadcast_to(np.asarray(admitted, dtype=bool).reshape(
                (-1, 1) if np.ndim(admitted) == 1 else np.shape(admitted)), P.shape)
        except ValueError:
            raise InputError(f"wheel_load_statistics: admitted of shape {np.shape(admitted)} for loads of shape "
                             f"{P.shape}") from None
    ok = np.isfinite(P)
    fallback = not (m & ok).any()
    sel = ok if fallback else (m & ok)
    dP = np.where(sel, P - s[None, :], np.nan)
    ratio = np.where(sel, P / s[None, :], np.nan)
    with np.errstate(invalid="ignore"):
        per_wheel = np.sqrt(np.nanmean(dP**2, axis=0)) if sel.any() else np.full(s.size, np.nan)
    any_sel = bool(sel.any())
    df_wheel = int(np.nanargmax(np.nanmax(np.where(sel, ratio, -np.inf), axis=0))) if any_sel else -1
    return {
        "wheel_load_static_N": [float(v) for v in s],
        "wheel_load_dynamic_std_N": float(np.sqrt(np.nanmean(dP[sel] ** 2))) if any_sel else math.nan,
        "wheel_load_dynamic_std_per_wheel_N": [float(v) for v in per_wheel],
        "wheel_load_rms_including_static_N": float(np.sqrt(np.mean(P[sel] ** 2))) if any_sel else math.nan,
        "dynamic_factor": float(np.max(ratio[sel])) if any_sel else math.nan,
        "dynamic_factor_wheel": df_wheel,
        "unloading_factor": float(np.min(ratio[sel])) if any_sel else math.nan,
        "wheel_load_statistics_instants": int(np.count_nonzero(np.any(sel, axis=1))),
        "wheel_load_statistics_fallback": fallback,
    }


@dataclass(frozen=True)
class SleeperEnvelope:
    """Largest and smallest soil force of each sleeper over a run (the envelope along the track).

    Attributes
    ----------
    sleeper_index : (m,) int array
        Global sleeper indices, ascending (every sleeper with a value).
    maximum, minimum : (m,) arrays
        Largest and smallest soil force of each [N] (compression positive;
        a negative minimum is a tensile ballast force).
    """

    sleeper_index: NDArray[np.int64]
    maximum: NDArray[np.float64]
    minimum: NDArray[np.float64]

    @property
    def tensile(self) -> NDArray[np.bool_]:
        """Sleepers whose soil force went negative (the ballast pulled on the soil)."""
        return np.asarray(self.minimum < 0.0)

    def describe(self, mask: ArrayLike | None = None) -> dict[str, Any]:
        """JSON-ready: the peak sleeper and the tensile sleepers (over ``mask`` of the sleepers, default all)."""
        m = np.ones(self.sleeper_index.size, bool) if mask is None else np.asarray(mask, dtype=bool)
        if not m.any():
            m = np.ones(self.sleeper_index.size, bool)
        i = int(np.flatnonzero(m)[np.argmax(self.maximum[m])])
        j = int(np.flatnonzero(m)[np.argmin(self.minimum[m])])
        ten = self.tensile & m
        return {
            "envelope_peak_sleeper_index": int(self.sleeper_index[i]),
            "envelope_peak_soil_force_N": float(self.maximum[i]),
            "envelope_min_soil_force_N": float(self.minimum[j]),
            "envelope_min_sleeper_index": int(self.sleeper_index[j]),
            "tensile_sleepers": int(np.count_nonzero(ten)),
            "tensile_note": ("negative soil force: the ballast spring of the model pulls on the soil (it carries "
                             "tension; a real ballast bed may lift off instead) at "
                             f"{int(np.count_nonzero(ten))} sleeper(s), down to {float(self.minimum[j]) / 1e3:.2f} kN"
                             if ten.any() else "no tensile (negative) soil force"),
        }


def sleeper_envelope(first_sleeper: ArrayLike, soil_force: ArrayLike,
                     peak_index: ArrayLike | None = None, peak_force: ArrayLike | None = None) -> SleeperEnvelope:
    """The envelope of window-relative sleeper forces (the ``history.npz`` layout).

    Parameters
    ----------
    first_sleeper : (k,) int array_like
        Global index of column 0 at each instant.
    soil_force : (k, N) array_like
        Soil force of the window's sleepers [N] (NaN: not held).
    peak_index, peak_force : (m,) array_like, optional
        Running maxima over every step (``peak_sleeper_index``,
        ``peak_soil_force``): they raise the maxima (the recorded instants
        may miss the step of a peak).

    Returns
    -------
    SleeperEnvelope

    Raises
    ------
    InputError
        Shapes that do not match, or no finite force.
    """
    F = np.asarray(soil_force, dtype=float)
    g0 = np.asarray(first_sleeper).astype(np.int64).reshape(-1)
    if F.ndim != 2 or g0.size != F.shape[0]:
        raise InputError(f"sleeper_envelope: {g0.size} first-sleeper values for forces of shape {F.shape}")
    g = (g0[:, None] + np.arange(F.shape[1])[None, :]).ravel()
    v = F.ravel()
    ok = np.isfinite(v)
    extra_i = np.zeros(0, np.int64) if peak_index is None else np.asarray(peak_index).astype(np.int64).reshape(-1)
    extra_f = np.zeros(0) if peak_force is None else np.asarray(peak_force, dtype=float).reshape(-1)
    if extra_i.size != extra_f.size:
        raise InputError(f"sleeper_envelope: {extra_i.size} peak indices for {extra_f.size} peak forces")
    if not ok.any() and not np.isfinite(extra_f).any():
        raise InputError("sleeper_envelope: no finite soil force")
    g, v = g[ok], v[ok]
    lo = int(min(g.min() if g.size else extra_i.min(), extra_i.min() if extra_i.size else g.min()))
    hi = int(max(g.max() if g.size else extra_i.max(), extra_i.max() if extra_i.size else g.max()))
    mx = np.full(hi - lo + 1, -np.inf)
    mn = np.full(hi - lo + 1, np.inf)
    np.maximum.at(mx, g - lo, v)
    np.minimum.at(mn, g - lo, v)
    fe = np.isfinite(extra_f)
    np.maximum.at(mx, extra_i[fe] - lo, extra_f[fe])
    np.minimum.at(mn, extra_i[fe] - lo, extra_f[fe])
    have = np.isfinite(mx)
    idx = np.arange(lo, hi + 1, dtype=np.int64)[have]
    return SleeperEnvelope(sleeper_index=idx, maximum=mx[have], minimum=mn[have])
