"""Compiled per-frame path: many stamped wheel-load frames in one kernel call.

:func:`run_frames` advances the state of the window through consecutive
*frames* (stamped wheel loads, one ``clm_msgs/WheelLoads`` message each) as
:func:`clm_core.solver._kernels.run_steps` advances it through steps, with
the per-step work of the Python side moved inside:

- frame times are integer *ticks* (nanoseconds for the online model) and the
  step is a whole number of ticks, so step ``K`` is at ``K dt_ticks`` and the
  steps of frame ``j`` are those after the previous frame's last step up to
  ``k_end[j]`` (no rounding of large stamps);
- between two frames each wheel's position and force are interpolated
  linearly in time, ``a = (K dt - t_prev) / (t_j - t_prev)`` from integers,
  ``a = 1`` exactly at the frame's stamp; a wheel present in only the new
  frame carries its new values over the whole interval, one absent from it
  is absent; when that would make the wheels span more than the window holds
  part-way (a wheel entering while another jumps far), the new frame's
  values hold over the whole interval;
- the cubic Hermite weights of every wheel are computed at every step
  (:func:`clm_core.solver._kernels.hermite_wheel`);
- at each frame's end the sleeper fields and the rail deflection and
  velocity under the frame's wheels (at their positions in the frame) are
  recorded and checked: all finite and within the given bounds.

Before a frame is stepped its values are checked (:func:`check_values`, the
value rules of the online input policy): finite positions and forces, no
infinite speed, forces not below ``-tensile``, not above the force bound,
positions and speeds within theirs, and the wheels' span within what the
window holds. A window that follows forwards is moved forwards by whole bays in
the kernel (the rule of :meth:`clm_core.solver.window.Window.required`, the
state shifted as :func:`clm_core.solver.window.shift_bays` and
``shift_entries`` do) as long as the operator stays the same (no overridden
sleeper in the new window). It returns to Python (status in ``out.ctl``)
when a frame breaks a value rule (``STOP_INVALID``: nothing of the frame was
done), when the window must move otherwise (``STOP_SHIFT``: backwards, over
overridden sleepers, a fixed window, or wheels it cannot hold), when a
frame's response fails its check
(``STOP_RESPONSE``), or when every frame is done (``DONE``). The caller
(:meth:`clm_core.solver.TrackSimulator.advance_frames`) moves the window and
resumes, or restores the state.

The inputs travel as one tuple of six plain tuples: the fields of the
operator and state (the :class:`~clm_core.solver._kernels.StepOperator` and
:class:`~clm_core.solver._kernels.StepState` of :func:`run_steps`), of the
:class:`FrameGeometry`, :class:`FrameLoads`, :class:`FrameBackup` and
:class:`FrameOutputs`, in that order (built by
:class:`clm_core.solver.frames.FrameRunner`). The kernel rebuilds the
named tuples inside, at no cost: numba types a named tuple argument in Python
at every call (10.3 us for this structure, ``timeit``, this machine), a plain
tuple in C (3.1 us), which matters for a call per frame.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from clm_core.arrays import Array, IntArray
from clm_core.solver import _kernels as kern
from clm_core.solver._kernels import StepOperator, StepState, hermite_wheel
from clm_core.solver.records import FrameRule

#: ``out.ctl[CTL_STATUS]`` values.
DONE, STOP_SHIFT, STOP_RESPONSE, STOP_INVALID = 0, 1, 2, 3
#: Indices of ``out.ctl``: step count (in/out), frame (in: first to run; out: reached), status (out),
#: number of load entries written to ``out.prev_dofs``/``prev_vals`` (out; -1: no step made), backup flag (in),
#: the value rule a frame broke and the wheel that broke it (out, with ``STOP_INVALID``), the window's first
#: sleeper at the end (out: the kernel may have shifted the window).
CTL_K, CTL_FRAME, CTL_STATUS, CTL_PREV, CTL_BACKUP, CTL_RULE, CTL_WHEEL, CTL_FIRST = 0, 1, 2, 3, 4, 5, 6, 7
#: Value rules of :func:`check_values` (0: none broken): the codes of :class:`clm_core.solver.FrameRule`, as plain
#: ints (compile-time constants of the kernels).
RULE_NON_FINITE, RULE_TENSILE, RULE_FORCE, RULE_POSITION, RULE_SPEED, RULE_SPAN = (
    int(FrameRule.NON_FINITE), int(FrameRule.TENSILE), int(FrameRule.FORCE), int(FrameRule.POSITION),
    int(FrameRule.SPEED), int(FrameRule.SPAN))
#: ``FrameGeometry.orient`` values.
ORIENT_FORWARD, ORIENT_BACKWARD, ORIENT_FREE = 0, 1, 2
#: Relative tolerance of the allowed zone and of the placement rule (as :mod:`clm_core.solver.window`).
TOL = 1e-9
#: Largest |position| [m] the kernel places itself (as :data:`clm_core.solver.window.MAX_POSITION`).
MAX_POSITION = 1e12
#: Indices of ``FrameLoads.limits``.
LIM_POSITION, LIM_FORCE, LIM_TENSILE, LIM_SPEED, LIM_SPAN = 0, 1, 2, 3, 4
#: Indices of ``out.ctl_f``: response bounds (in), span of the wheels at a shift stop (out).
CTF_MAX_FORCE, CTF_MAX_DISP, CTF_FRONT, CTF_REAR = 0, 1, 2, 3


class FrameGeometry(NamedTuple):
    """Where the window is, its rail, and where its wheels may be without a shift.

    Attributes
    ----------
    first : int
        Global index of the window's first sleeper.
    orient : int
        Its ghost bay (``ORIENT_*``): ahead (following forwards; the kernel
        shifts such a window forwards itself when the operator stays the
        same), behind, none (a fixed window).
    x0rel : float
        Position of rail node 0 relative to the first sleeper [m].
    spacing, Le : float
        Sleeper spacing and rail element length [m].
    n_el : int
        Rail elements of the window (``n_el + 1`` nodes).
    rail_w, rail_th : (n_el + 1,) int arrays
        The rail nodes' deflection and rotation DOFs.
    lo_bay, hi_bay : int
        The allowed zone in bays from the first sleeper
        (:meth:`clm_core.solver.window.Window.limits`).
    n_sleepers : int
        Sleepers in the window.
    dofs_per_bay : int
        DOFs per sleeper bay (the stride of a shift).
    touched : (t,) int array
        Overridden sleepers, sorted: a window over one of them has another
        operator (the kernel then stops, ``STOP_SHIFT``).
    """

    first: int
    orient: int
    x0rel: float
    spacing: float
    Le: float
    n_el: int
    rail_w: IntArray
    rail_th: IntArray
    lo_bay: int
    hi_bay: int
    n_sleepers: int
    dofs_per_bay: int
    touched: IntArray


class FrameLoads(NamedTuple):
    """R frames of wheel loads (W wheel slots, M wheel entries in all).

    Attributes
    ----------
    ticks : (R + 1,) int array
        Frame times [ticks]; ``ticks[0]`` is the previous frame (the one the
        state was advanced to), ``ticks[j + 1]`` frame ``j``.
    k_end : (R,) int array
        Step of each frame's response (steps since the state's start; step
        ``K`` is at ``K dt_ticks``), non-decreasing.
    dt_ticks : int
        The time step [ticks].
    offsets : (R + 1,) int array
        Frame ``j``'s wheels are entries ``offsets[j] .. offsets[j + 1] - 1``.
    slots, positions, forces : (M,) int array, (M,) arrays
        Each entry's wheel slot (0 .. W - 1), position [m] and force [N]
        (negative forces down to ``-limits[LIM_TENSILE]`` are taken as 0).
    speeds : (S,) array
        Wheel speeds [m/s] (NaN: unknown), frame ``j``'s at ``soffsets[j] ..
        soffsets[j + 1] - 1`` (none, or one per wheel); checked only.
    soffsets : (R + 1,) int array
        Where each frame's speeds start.
    limits : (5,) array
        The value rules (``LIM_*``): largest ``|position|`` [m], force [N],
        tensile force [N], ``|speed|`` [m/s], span of the wheels [m].
    P_prev, F_prev : (W,) arrays
        Position [m] (NaN: absent) and force [N] of each slot in the previous
        frame; updated in place to the last frame done.
    """

    ticks: IntArray
    k_end: IntArray
    dt_ticks: int
    offsets: IntArray
    slots: IntArray
    positions: Array
    forces: Array
    speeds: Array
    soffsets: IntArray
    limits: Array
    P_prev: Array
    F_prev: Array


class FrameBackup(NamedTuple):
    """Copies of the state taken at the first call of a run (``ctl[CTL_BACKUP]`` set), to restore it.

    The displacements ``u`` [m] and velocities ``v`` [m/s] (n,), the running
    peaks ``pk_force`` [N] and ``pk_rail`` [m] (N,), and the previous frame's
    wheels ``P_prev`` [m] and ``F_prev`` [N] (W,).
    """

    u: Array
    v: Array
    pk_force: Array
    pk_rail: Array
    P_prev: Array
    F_prev: Array


class FrameOutputs(NamedTuple):
    """Outputs of R frames (N sleepers, M wheel entries, W slots) and the kernel's control registers.

    Attributes
    ----------
    sleepers : (4, R, N) array
        Soil force [N], rail deflection above the sleeper, sleeper and
        contact-area displacement [m] at each frame's response step.
    first : (R,) int array
        Global index of the window's first sleeper at each frame's response.
    wheels : (2, M) array
        Rail deflection [m] and velocity [m/s] under each wheel entry.
    prev_dofs, prev_vals : (q,) int array, (q,) array
        The load vector at the last step made, as (DOF, value [N]) pairs
        (``ctl[CTL_PREV]`` of them; q >= 4 W).
    last : (2, W) array
        Wheel positions [m] (NaN: absent) and forces [N] at the last step made.
    ctl : (8,) int array
        Control registers (``CTL_*``).
    ctl_f : (4,) array
        Response bounds in, wheel span out (``CTF_*``).
    """

    sleepers: Array
    first: IntArray
    wheels: Array
    prev_dofs: IntArray
    prev_vals: Array
    last: Array
    ctl: IntArray
    ctl_f: Array


@njit(cache=True, inline="always")
def check_values(pos, force, speed, a, b, sa, sb, lim):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """The first value rule broken by the frame at entries ``a .. b - 1`` (speeds ``sa .. sb - 1``).

    Rules in order (``RULE_*``): a position or force not finite, a speed
    infinite (NaN: unknown); a force below ``-lim[LIM_TENSILE]``; above
    ``lim[LIM_FORCE]``; ``|position|`` above ``lim[LIM_POSITION]``; ``|speed|``
    above ``lim[LIM_SPEED]``; the wheels spanning more than ``lim[LIM_SPAN]``.
    Returns ``(rule, wheel)``: the rule (0: none) and the index in the frame
    of the wheel that breaks it (-1: the frame as a whole).
    """
    for e in range(a, b):
        if not (abs(pos[e]) < np.inf and abs(force[e]) < np.inf):
            return RULE_NON_FINITE, e - a
    for e in range(sa, sb):
        if abs(speed[e]) == np.inf:
            return RULE_NON_FINITE, e - sa
    for e in range(a, b):
        if force[e] < -lim[LIM_TENSILE]:
            return RULE_TENSILE, e - a
    for e in range(a, b):
        if force[e] > lim[LIM_FORCE]:
            return RULE_FORCE, e - a
    for e in range(a, b):
        if abs(pos[e]) > lim[LIM_POSITION]:
            return RULE_POSITION, e - a
    for e in range(sa, sb):
        if abs(speed[e]) > lim[LIM_SPEED]:
            return RULE_SPEED, e - sa
    if b > a:
        lo = pos[a]
        hi = pos[a]
        for e in range(a, b):
            lo = min(lo, pos[e])
            hi = max(hi, pos[e])
        if hi - lo > lim[LIM_SPAN]:
            return RULE_SPAN, -1
    return 0, -1


@njit(cache=True)
def check_frame(pos, force, speed, lim):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """:func:`check_values` of one frame's arrays (positions, forces, speeds, limits): ``(rule, wheel)``."""
    return check_values(pos, force, speed, 0, pos.shape[0], 0, speed.shape[0], lim)


@njit(cache=True, inline="always")
def _wheels_at(P0, F0, P1, F1, num, span, hold, Pc, Fc):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Wheels at the step ``num`` ticks after the previous frame (of ``span``): into ``Pc``, ``Fc``; (front, rear).

    A wheel in both frames is interpolated linearly (``a = num / span``; ``a = 1``
    exactly at the frame, and throughout with ``hold``); one only in the new
    frame (``P1``) carries its values; one absent from it is absent (NaN, 0).
    Without wheels, front is -inf and rear +inf.
    """
    a = num / span if span != 0 else 1.0
    front = -np.inf
    rear = np.inf
    for w in range(P1.shape[0]):
        p1 = P1[w]
        if p1 == p1:
            p0 = P0[w]
            if p0 == p0 and num != span and not hold:
                p = p0 + a * (p1 - p0)
                Fc[w] = F0[w] + a * (F1[w] - F0[w])
            else:
                p = p1
                Fc[w] = F1[w]
            Pc[w] = p
            if p > front:
                front = p
            if p < rear:
                rear = p
        else:
            Pc[w] = np.nan
            Fc[w] = 0.0
    return front, rear


@njit(cache=True, inline="always")
def _shift(a, m):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Move ``a`` by ``m`` entries towards its start (the window moved forwards); entries that enter are 0."""
    n = a.shape[0]
    if m >= n:
        a[:] = 0.0
        return
    for i in range(n - m):
        a[i] = a[i + m]
    for i in range(n - m, n):
        a[i] = 0.0


@njit(cache=True, inline="always")
def _zone(first, geo):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """(x0, lo, hi) of the window whose first sleeper is ``first``: rail node 0 and the allowed zone with tolerance."""
    d = geo.spacing
    eps = TOL * d
    return geo.x0rel + first * d, (first + geo.lo_bay) * d - eps, (first + geo.hi_bay) * d + eps


@njit(cache=True, inline="always")
def _forward_first(first, front, rear, geo):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """The first sleeper of the window moved forwards for wheels at ``rear .. front`` [m], or -1 for Python to do it.

    The rule of :meth:`clm_core.solver.window.Window.required` for a forward
    window that stays forward; -1 when the wheels are too far apart or too
    far out, or when the new window (with its ghost bay) holds an overridden
    sleeper (another operator).
    """
    if not (abs(front) <= MAX_POSITION and abs(rear) <= MAX_POSITION):
        return -1
    d = geo.spacing
    g_lo = int(math.ceil(front / d - TOL - geo.hi_bay))
    g_hi = int(math.floor(rear / d + TOL - geo.lo_bay))
    if g_lo > g_hi or g_lo <= first:
        return -1
    t = geo.touched
    if t.shape[0]:
        i = np.searchsorted(t, g_lo)
        if i < t.shape[0] and t[i] < g_lo + geo.n_sleepers + 1:
            return -1
    return g_lo


@njit(cache=True)
def run_frames(a):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Advance through frames ``ctl[CTL_FRAME]`` .. R - 1 in place; return the status (also in ``ctl``).

    Parameters
    ----------
    a : tuple
        The fields of the operator, state (updated in place), geometry,
        frames, backup and outputs as plain tuples (module notes: what it
        takes, when it stops).
    """
    op = StepOperator(*a[0])
    st = StepState(*a[1])
    geo = FrameGeometry(*a[2])
    ld = FrameLoads(*a[3])
    bk = FrameBackup(*a[4])
    out = FrameOutputs(*a[5])
    u, v, z, y = st.u, st.v, st.z, st.y
    n = u.shape[0]
    ctl, ctf = out.ctl, out.ctl_f
    P_prev, F_prev = ld.P_prev, ld.F_prev
    W = P_prev.shape[0]
    R = ld.k_end.shape[0]
    dt = ld.dt_ticks
    if ctl[CTL_BACKUP] != 0:
        bk.u[:] = u
        bk.v[:] = v
        bk.pk_force[:] = st.pk_force
        bk.pk_rail[:] = st.pk_rail
        bk.P_prev[:] = P_prev
        bk.F_prev[:] = F_prev
    max_force = ctf[CTF_MAX_FORCE]
    max_disp = ctf[CTF_MAX_DISP]
    force, rail, sleeper, area = out.sleepers[0], out.sleepers[1], out.sleepers[2], out.sleepers[3]
    first = geo.first
    x0, lo, hi = _zone(first, geo)
    P1 = np.empty(W)
    F1 = np.empty(W)
    Pc = np.empty(W)
    Fc = np.empty(W)
    pP = np.full(W, np.nan)
    pF = np.zeros(W)
    wd = np.zeros(4, dtype=np.int64)
    ww = np.zeros(4)
    # the load vector f_n of the last step as (DOF, value) entries in wheel order: the state's at the start
    cap = max(4 * W, st.prev_dofs.shape[0])
    pe_d = np.empty(cap, dtype=np.int64)
    pe_v = np.empty(cap)
    pe_n = st.prev_dofs.shape[0]
    for i in range(pe_n):
        pe_d[i] = st.prev_dofs[i]
        pe_v[i] = st.prev_vals[i]
    k = ctl[CTL_K]
    stepped = False
    moved = False
    status = DONE
    j = ctl[CTL_FRAME]
    while j < R:
        rule, wheel = check_values(ld.positions, ld.forces, ld.speeds, ld.offsets[j], ld.offsets[j + 1],
                                   ld.soffsets[j], ld.soffsets[j + 1], ld.limits)
        if rule != 0:
            ctl[CTL_RULE] = rule
            ctl[CTL_WHEEL] = wheel
            status = STOP_INVALID
            break
        # the frame's values per slot (absent: NaN)
        for w in range(W):
            P1[w] = np.nan
            F1[w] = 0.0
        for e in range(ld.offsets[j], ld.offsets[j + 1]):
            sl = ld.slots[e]
            P1[sl] = ld.positions[e]
            f = ld.forces[e]
            F1[sl] = f if f > 0.0 else 0.0
        t0 = ld.ticks[j]
        span = ld.ticks[j + 1] - t0
        # wheels entering while others move far could span more than the window holds part-way: then the
        # frame's values hold over its interval (decided on the frame's own steps: the same when resumed)
        hold = False
        for w in range(W):
            if (P1[w] == P1[w]) != (P_prev[w] == P_prev[w]):
                for kk in range(t0 // dt, ld.k_end[j]):
                    front, rear = _wheels_at(P_prev, F_prev, P1, F1, (kk + 1) * dt - t0, span, False, Pc, Fc)
                    if front - rear > ld.limits[LIM_SPAN]:
                        hold = True
                        break
                break
        while k < ld.k_end[j]:
            front, rear = _wheels_at(P_prev, F_prev, P1, F1, (k + 1) * dt - t0, span, hold, Pc, Fc)
            if front > hi or rear < lo:
                g = _forward_first(first, front, rear, geo) if geo.orient == ORIENT_FORWARD and rear >= lo else -1
                if g < 0:
                    ctf[CTF_FRONT] = front
                    ctf[CTF_REAR] = rear
                    status = STOP_SHIFT
                    break
                # the window moves forwards by whole bays, the operator stays: the state moves with it
                m = (g - first) * geo.dofs_per_bay
                _shift(u, m)
                _shift(v, m)
                _shift(st.pk_force, g - first)
                _shift(st.pk_rail, g - first)
                q = 0
                for i in range(pe_n):
                    dof = pe_d[i] - m
                    if 0 <= dof < n:
                        pe_d[q] = dof
                        pe_v[q] = pe_v[i]
                        q += 1
                pe_n = q
                first = g
                x0, lo, hi = _zone(first, geo)
                moved = True
            # loads f_n + f_{n+1} scattered into z (zero on entry); absent wheels add nothing
            for i in range(pe_n):
                z[pe_d[i]] += pe_v[i]
            pe_n = 0
            for w in range(W):
                pP[w] = Pc[w]
                pF[w] = Fc[w]
                if Pc[w] == Pc[w]:
                    hermite_wheel(Pc[w], x0, geo.Le, geo.n_el, geo.rail_w, geo.rail_th, pe_d, pe_v, pe_n)
                    fw = Fc[w]
                    for c in range(pe_n, pe_n + 4):
                        pe_v[c] *= fw
                        z[pe_d[c]] += pe_v[c]
                    pe_n += 4
            kern._rhs_forward(op, u, v, z, y)
            kern._back_update(op, u, v, z, y)
            kern._sleeper_step(op, u, v, st.pk_force, st.pk_rail, force, rail, sleeper, area, -1)
            stepped = True
            k += 1
        if status != DONE:
            break
        # the response at the frame's last step: sleeper fields, and under its wheels at their positions
        ok = True
        out.first[j] = first
        kern._sleeper_step(op, u, v, st.pk_force, st.pk_rail, force, rail, sleeper, area, j)
        for i in range(force.shape[1]):
            if not (abs(force[j, i]) <= max_force and abs(rail[j, i]) <= max_disp
                    and abs(sleeper[j, i]) <= max_disp and abs(area[j, i]) <= max_disp):
                ok = False
        for e in range(ld.offsets[j], ld.offsets[j + 1]):
            hermite_wheel(ld.positions[e], x0, geo.Le, geo.n_el, geo.rail_w, geo.rail_th, wd, ww, 0)
            d, vel = kern._under_wheel(wd, ww, 0, u, v)
            out.wheels[0, e] = d
            out.wheels[1, e] = vel
            if not (abs(d) <= max_disp and abs(vel) < np.inf):
                ok = False
        if not ok:
            status = STOP_RESPONSE
            break
        for w in range(W):
            P_prev[w] = P1[w]
            F_prev[w] = F1[w]
        j += 1
    # write back: the step count, the window, and the wheels and load vector of the last step made
    ctl[CTL_K] = k
    ctl[CTL_FRAME] = j
    ctl[CTL_STATUS] = status
    ctl[CTL_FIRST] = first
    if stepped or moved:
        for i in range(pe_n):
            out.prev_dofs[i] = pe_d[i]
            out.prev_vals[i] = pe_v[i]
        ctl[CTL_PREV] = pe_n
        if stepped:
            for w in range(W):
                out.last[0, w] = pP[w]
                out.last[1, w] = pF[w]
    else:
        ctl[CTL_PREV] = -1
    return status
