"""The moving window of sleepers: where it is placed, and when and how it shifts.

The simulated track is a window of ``n_sleepers`` sleepers, global indices
``first .. first + n_sleepers - 1``, sleeper ``g`` at ``x = g * spacing``
[m]. :class:`Window` holds the rules (sizes, lead and margin, whether it
follows the wheels); a :class:`Placement` is where it is: its first sleeper
and the side of its clamped ghost bay.

Allowed zone
    Wheels are accepted without a shift between ``margin_sleepers`` behind
    the rear end and ``lead_sleepers`` before the front end when the window
    follows forwards (``orientation='forward'``), the mirror image after a
    backward shift (``'backward'``), ``margin_sleepers`` from either end for
    a fixed window (``'free'``).

Shift
    With ``follow=True`` the window moves by whole bays before the foremost
    wheel leaves the allowed zone at the front (to the start closest to the
    current one that restores ``lead_sleepers`` ahead), or the rearmost at
    the rear (mirror image). Because DOFs are in position order and every
    bay has the same DOF layout, a shift of ``s`` bays moves the state
    vectors by ``s`` times the DOFs per bay (:func:`shift_bays`): sleepers
    behind are dropped, new ones are added at rest ahead.

Ghost bay
    A following window is assembled with one extra bay on its leading side
    whose DOFs are clamped at zero (:func:`clm_core.solver.operators.clamp_ghost_bay`):
    a shift then turns clamped zeros into free DOFs at rest and drops elements
    at the free trailing end, so it never adds energy (docs/time-domain.md).
    :meth:`Window.span` gives the sleepers assembled for a placement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array, IntArray
from clm_core.checks import integer
from clm_core.errors import InputError, ParameterError
from clm_core.track import check_size

#: Side of the clamped ghost bay: ahead ('forward'), behind ('backward'), none ('free', a fixed window).
Orientation = Literal["forward", "backward", "free"]

_TOL = 1e-9
#: Largest |position| [m] of a wheel: global sleeper indices stay far inside int64 (1e19 m overflowed them).
MAX_POSITION = 1e12


@dataclass(frozen=True)
class Placement:
    """Where the window is.

    Attributes
    ----------
    first : int
        Global index of the window's first sleeper.
    orientation : {'forward', 'backward', 'free'}
        Side of its clamped ghost bay (see :data:`Orientation`).
    """

    first: int
    orientation: Orientation


@dataclass(frozen=True)
class Window:
    """Placement and shift rules of the moving window (see the module notes).

    Attributes
    ----------
    n_sleepers : int
        Sleepers in the window.
    spacing : float
        Sleeper spacing [m].
    lead_sleepers : int
        Sleepers kept ahead of the foremost wheel when following.
    margin_sleepers : int
        Least number of sleeper bays between any wheel and either end.
    follow : bool
        The window moves with the wheels (else wheels outside the allowed
        zone are refused).
    """

    n_sleepers: int
    spacing: float
    lead_sleepers: int
    margin_sleepers: int
    follow: bool

    @classmethod
    def create(
        cls,
        n_sleepers: int,
        spacing: float,
        lead_sleepers: int | None = None,
        margin_sleepers: int | None = None,
        follow: bool = True,
        elements_per_bay: int = 2,
    ) -> Window:
        """Validated rules with the defaults ``lead = n // 3``, ``margin = max(2, min(10, n // 6))``.

        Raises
        ------
        ParameterError
            A count that is not an integer, ``margin < 1``, ``lead < margin``, ``n_sleepers < lead + margin + 1``
            or ``< 4``, or a following window with ``elements_per_bay < 2``
            (the shift needs rail-only nodes at the window ends).
        """
        counts = {"n_sleepers": n_sleepers, "lead_sleepers": lead_sleepers, "margin_sleepers": margin_sleepers,
                  "elements_per_bay": elements_per_bay}
        for name, value in counts.items():
            if value is not None:
                integer(name, value)
        n = int(n_sleepers)
        check_size(n, int(elements_per_bay))  # before the operator cache keys its n-sleeper values
        margin = max(2, min(10, n // 6)) if margin_sleepers is None else int(margin_sleepers)
        lead = n // 3 if lead_sleepers is None else int(lead_sleepers)
        if margin < 1:
            raise ParameterError(f"margin_sleepers = {margin}: must be >= 1")
        if lead < margin:
            raise ParameterError(f"lead_sleepers = {lead}: must be >= margin_sleepers = {margin}")
        if n - 1 - lead - margin < 0 or n < 4:
            raise ParameterError(
                f"n_sleepers = {n}: too small for lead_sleepers = {lead} and "
                f"margin_sleepers = {margin} (need n_sleepers >= lead + margin + 1 and >= 4)"
            )
        if follow and int(elements_per_bay) < 2:
            raise ParameterError(
                f"elements_per_bay = {int(elements_per_bay)}: a following window needs >= 2 (the window "
                "shifts by whole bays and needs rail-only nodes at its ends)"
            )
        return cls(n_sleepers=n, spacing=float(spacing), lead_sleepers=lead, margin_sleepers=margin,
                   follow=bool(follow))

    # ------------------------------------------------------------------ placement

    def start(self, position: float) -> Placement:
        """The placement centred on ``position`` [m] (forward ghost bay when following)."""
        first = int(round(float(position) / self.spacing)) - (self.n_sleepers - 1) // 2
        return Placement(first, "forward" if self.follow else "free")

    def limits(self, orientation: Orientation) -> tuple[int, int]:
        """Allowed wheel zone in sleeper bays from the window's first sleeper, for an orientation."""
        N, m, ld = self.n_sleepers, self.margin_sleepers, self.lead_sleepers
        if orientation == "forward":
            return m, N - 1 - ld
        if orientation == "backward":
            return ld, N - 1 - m
        return m, N - 1 - m

    def allowed_range(self, p: Placement) -> tuple[float, float]:
        """Positions [m] where wheels are accepted without a shift, for placement ``p``."""
        lo, hi = self.limits(p.orientation)
        return (p.first + lo) * self.spacing, (p.first + hi) * self.spacing

    def span(self, p: Placement) -> tuple[int, int]:
        """Global sleepers (first, count) assembled for ``p``: the window plus its clamped ghost bay."""
        N = self.n_sleepers
        if p.orientation == "forward":
            return p.first, N + 1
        if p.orientation == "backward":
            return p.first - 1, N + 1
        return p.first, N

    def sleeper_index(self, p: Placement) -> IntArray:
        """Global indices (N,) of the window's sleepers."""
        return np.arange(p.first, p.first + self.n_sleepers, dtype=np.int64)

    def outside(self, p: Placement, front: Array, rear: Array) -> NDArray[np.bool_]:
        """Which rows of wheel spans (foremost ``front``, rearmost ``rear`` [m]) leave the allowed zone.

        Rows without wheels have ``front = -inf``, ``rear = +inf`` and never leave it.
        """
        lo, hi = self.allowed_range(p)
        eps = _TOL * self.spacing
        return np.asarray((front > hi + eps) | (rear < lo - eps))

    def required(self, p: Placement, front: float, rear: float, what: str, t: float) -> Placement:
        """The placement closest to ``p`` with the wheels spanning ``rear .. front`` [m] in the allowed zone.

        ``p`` itself when they are inside; wheels beyond the front limit shift
        the window forwards (front bay clamped, ``lead_sleepers`` kept ahead);
        wheels behind the rear limit shift it backwards (mirror image).

        Raises
        ------
        InputError
            The wheels span more bays than the allowed zone holds, or lie
            beyond +-:data:`MAX_POSITION` (``what`` and ``t`` [s] go into the
            message).
        """
        d, N = self.spacing, self.n_sleepers
        if not (abs(front) <= MAX_POSITION and abs(rear) <= MAX_POSITION):
            raise InputError(f"{what}: wheels at t = {t:g} s span {rear:g} .. {front:g} m: beyond the line's range "
                             f"+-{MAX_POSITION:g} m")
        lo, hi = self.allowed_range(p)
        eps = _TOL * d
        orient: Orientation
        if front > hi + eps:
            orient = "forward"
        elif rear < lo - eps:
            orient = "backward"
        else:
            return p
        a, b = self.limits(orient)
        g_lo = math.ceil(front / d - _TOL - b)
        g_hi = math.floor(rear / d + _TOL - a)
        if g_lo > g_hi:
            raise InputError(
                f"{what}: wheels at t = {t:g} s span {rear:g} .. {front:g} m ({(front - rear) / d:.1f} bays); "
                f"the window of {N} sleepers holds at most {b - a} bays between "
                f"lead_sleepers = {self.lead_sleepers} and margin_sleepers = {self.margin_sleepers}"
            )
        return Placement(g_lo if orient == "forward" else g_hi, orient)

    def check_inside(self, p: Placement, front: float, rear: float, what: str, t: float) -> None:
        """Refuse wheels spanning ``rear .. front`` [m] that are not all in the allowed zone of ``p``.

        Raises
        ------
        InputError
            Names the wheel position, the time ``t`` [s] and the allowed zone.
        """
        lo, hi = self.allowed_range(p)
        eps = _TOL * self.spacing
        if rear < lo - eps or front > hi + eps:
            bad = rear if rear < lo - eps else front
            raise InputError(
                f"{what}: wheel at {bad:g} m at t = {t:g} s is outside the allowed part "
                f"{lo:g} .. {hi:g} m of the window (sleepers {p.first} .. "
                f"{p.first + self.n_sleepers - 1}, margin {self.margin_sleepers} bays"
                + (", follow=False)" if not self.follow else ")")
            )

    def place(self, p: Placement, positions: Array, what: str, t: float) -> Placement:
        """The placement for wheels at ``positions`` (n_w,) [m]: shifted when following, else checked.

        Absent wheels (NaN) are ignored; without any wheel, ``p``.

        Raises
        ------
        InputError
            Wheels that the window cannot hold, or (``follow=False``) that
            are outside its allowed zone.
        """
        pres = positions[np.isfinite(positions)]
        if pres.size == 0:
            return p
        front, rear = float(pres.max()), float(pres.min())
        if self.follow:
            p = self.required(p, front, rear, what, t)
        self.check_inside(p, front, rear, what, t)
        return p


def shift_bays(a: Array, s: int, stride: int) -> None:
    """Move ``a`` in place by ``s`` bays of ``stride`` entries: the window moved ``s`` bays forward.

    Entries of bays that leave the window are dropped; bays that enter it
    are zero (at rest). ``s < 0``: the window moved backwards.
    """
    n = a.shape[0]
    m = abs(s) * stride
    if m >= n:
        a[:] = 0.0
    elif s > 0:
        a[: n - m] = a[m:]
        a[n - m :] = 0.0
    elif s < 0:
        a[m:] = a[: n - m].copy()
        a[:m] = 0.0


def shift_entries(dofs: IntArray, vals: Array, s: int, stride: int, n: int) -> tuple[IntArray, Array]:
    """(DOF, value) pairs of a window vector after a shift of ``s`` bays (``stride`` DOFs per bay, ``n`` DOFs).

    DOFs are renumbered; pairs whose DOF left the window are dropped.
    """
    d = dofs - s * stride
    keep = (d >= 0) & (d < n)
    return np.ascontiguousarray(d[keep]), np.ascontiguousarray(vals[keep])


__all__ = ["MAX_POSITION", "Orientation", "Placement", "Window", "shift_bays", "shift_entries"]
