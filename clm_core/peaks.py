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
        The maximum, its flat index in ``values`` and whether the fallback was
        used (NaN, -1, True when there is no finite value at all).

    Raises
    ------
    InputError
        A ``mask`` that does not broadcast to the shape of ``values``.
    """
    v = np.asarray(values, dtype=float)
    mk = np.asarray(mask, dtype=bool)
    try:
        m = np.broadcast_to(mk, v.shape).ravel()
    except ValueError:
        raise InputError(f"mask: shape {mk.shape}: does not broadcast to the values' shape {v.shape}") from None
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
