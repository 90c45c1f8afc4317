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
window holds. It returns to Python (status in ``out.ctl``) when a frame
breaks one of these (``STOP_INVALID``: nothing of the frame was done), when
the window must move (``STOP_SHIFT``: the wheels' span at the next step
leaves the allowed zone), when a frame's response fails its check
(``STOP_RESPONSE``), or when every frame is done (``DONE``). The caller
(:meth:`clm_core.solver.TrackSimulator.advance_frames`) moves the window and
resumes, or restores the state.

The inputs travel in one typed structure, :class:`FrameArgs`; the operator
and state are the :class:`~clm_core.solver._kernels.StepOperator` and
:class:`~clm_core.solver._kernels.StepState` of :func:`run_steps`. The
kernel takes it as plain tuples (:meth:`FrameArgs.plain`) and rebuilds the
named tuples inside, at no cost: numba types a named tuple argument in Python
at every call (10.3 us for this structure, ``timeit``, this machine), a plain
tuple in C (3.1 us), which matters for a call per frame.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from clm_core.solver._kernels import (
    StepOperator,
    StepState,
    _back_update,
    _rhs_forward,
    _sleeper_step,
    _under_wheel,
    hermite_wheel,
)

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: ``out.ctl[CTL_STATUS]`` values.
DONE, STOP_SHIFT, STOP_RESPONSE, STOP_INVALID = 0, 1, 2, 3
#: Indices of ``out.ctl``: step count (in/out), frame (in: first to run; out: reached), status (out),
#: number of load entries written to ``out.prev_dofs``/``prev_vals`` (out; -1: no step made), backup flag (in),
#: the value rule a frame broke and the wheel that broke it (out, with ``STOP_INVALID``).
CTL_K, CTL_FRAME, CTL_STATUS, CTL_PREV, CTL_BACKUP, CTL_RULE, CTL_WHEEL = 0, 1, 2, 3, 4, 5, 6
#: Value rules of :func:`check_values` (0: none broken).
RULE_NON_FINITE, RULE_TENSILE, RULE_FORCE, RULE_POSITION, RULE_SPEED, RULE_SPAN = 1, 2, 3, 4, 5, 6
#: Indices of ``FrameLoads.limits``.
LIM_POSITION, LIM_FORCE, LIM_TENSILE, LIM_SPEED, LIM_SPAN = 0, 1, 2, 3, 4
#: Indices of ``out.ctl_f``: response bounds (in), span of the wheels at a shift stop (out).
CTF_MAX_FORCE, CTF_MAX_DISP, CTF_FRONT, CTF_REAR = 0, 1, 2, 3


class FrameGeometry(NamedTuple):
    """Where the rail of the window is, and where its wheels may be without a shift.

    Attributes
    ----------
    x0 : float
        Position of rail node 0 [m].
    Le : float
        Rail element length [m].
    n_el : int
        Rail elements.
    rail_w, rail_th : (n_el + 1,) int arrays
        Deflection and rotation DOF of each rail node.
    lo, hi : float
        The allowed zone [m] widened by its tolerance: a step whose rearmost
        wheel is below ``lo`` or foremost above ``hi`` stops the kernel.
    """

    x0: float
    Le: float
    n_el: int
    rail_w: IntArray
    rail_th: IntArray
    lo: float
    hi: float


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

    Attributes
    ----------
    u, v : (n,) arrays
        Displacement [m] and velocity [m/s].
    pk_force, pk_rail : (N,) arrays
        Running peaks [N], [m].
    P_prev, F_prev : (W,) arrays
        The previous frame's wheels [m], [N].
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
    force, rail, sleeper, area : (R, N) arrays
        Soil force [N], rail deflection above the sleeper, sleeper and
        contact-area displacement [m] at each frame's response step.
    wdefl, wvel : (M,) arrays
        Rail deflection [m] and velocity [m/s] under each wheel entry.
    prev_dofs, prev_vals : (4 W,) int array, (4 W,) array
        The load vector at the last step made, as (DOF, value [N]) pairs
        (``ctl[CTL_PREV]`` of them).
    pos, F : (W,) arrays
        Wheel positions [m] (NaN: absent) and forces [N] at the last step made.
    ctl : (7,) int array
        Control registers (``CTL_*``).
    ctl_f : (4,) array
        Response bounds in, wheel span out (``CTF_*``).
    """

    force: Array
    rail: Array
    sleeper: Array
    area: Array
    wdefl: Array
    wvel: Array
    prev_dofs: IntArray
    prev_vals: Array
    pos: Array
    F: Array
    ctl: IntArray
    ctl_f: Array


class FrameArgs(NamedTuple):
    """Everything :func:`run_frames` reads and writes, in one typed structure."""

    op: StepOperator
    state: StepState
    geo: FrameGeometry
    loads: FrameLoads
    backup: FrameBackup
    out: FrameOutputs

    def plain(self) -> tuple[tuple[object, ...], ...]:
        """The structure as plain tuples, the argument of :func:`run_frames` (cheap to type at a call)."""
        return tuple(tuple(x) for x in self)


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


@njit(cache=True)
def run_frames(a):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Advance through frames ``ctl[CTL_FRAME]`` .. R - 1 in place; return the status (also in ``ctl``).

    Parameters
    ----------
    a : tuple
        :meth:`FrameArgs.plain`: operator, state (updated in place),
        geometry, frames, backup and outputs (see the module notes for when
        it stops).
    """
    op = StepOperator(*a[0])
    st = StepState(*a[1])
    geo = FrameGeometry(*a[2])
    ld = FrameLoads(*a[3])
    bk = FrameBackup(*a[4])
    out = FrameOutputs(*a[5])
    u, v, z, y = st.u, st.v, st.z, st.y
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
    P1 = np.empty(W)
    F1 = np.empty(W)
    Pc = np.empty(W)
    Fc = np.empty(W)
    pdofs = np.zeros(4 * W, dtype=np.int64)
    pwts = np.zeros(4 * W)
    pP = np.full(W, np.nan)
    pF = np.zeros(W)
    ppres = np.zeros(W, dtype=np.bool_)
    wd = np.zeros(4, dtype=np.int64)
    ww = np.zeros(4)
    k = ctl[CTL_K]
    stepped = False
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
            if front > geo.hi or rear < geo.lo:
                ctf[CTF_FRONT] = front
                ctf[CTF_REAR] = rear
                status = STOP_SHIFT
                break
            # loads f_n + f_{n+1} scattered into z (zero on entry); absent wheels add nothing
            if stepped:
                for w in range(W):
                    if ppres[w]:
                        fw = pF[w]
                        for c in range(4 * w, 4 * w + 4):
                            z[pdofs[c]] += pwts[c] * fw
            else:
                for q in range(st.prev_dofs.shape[0]):
                    z[st.prev_dofs[q]] += st.prev_vals[q]
            for w in range(W):
                pP[w] = Pc[w]
                pF[w] = Fc[w]
                ppres[w] = Pc[w] == Pc[w]
                if ppres[w]:
                    hermite_wheel(Pc[w], geo.x0, geo.Le, geo.n_el, geo.rail_w, geo.rail_th, pdofs, pwts, 4 * w)
                    fw = Fc[w]
                    for c in range(4 * w, 4 * w + 4):
                        z[pdofs[c]] += pwts[c] * fw
            _rhs_forward(op, u, v, z, y)
            _back_update(op, u, v, z, y)
            _sleeper_step(op, u, v, st.pk_force, st.pk_rail, out.force, out.rail, out.sleeper, out.area, -1)
            stepped = True
            k += 1
        if status != DONE:
            break
        # the response at the frame's last step: sleeper fields, and under its wheels at their positions
        ok = True
        _sleeper_step(op, u, v, st.pk_force, st.pk_rail, out.force, out.rail, out.sleeper, out.area, j)
        for i in range(out.force.shape[1]):
            if not (abs(out.force[j, i]) <= max_force and abs(out.rail[j, i]) <= max_disp
                    and abs(out.sleeper[j, i]) <= max_disp and abs(out.area[j, i]) <= max_disp):
                ok = False
        for e in range(ld.offsets[j], ld.offsets[j + 1]):
            hermite_wheel(ld.positions[e], geo.x0, geo.Le, geo.n_el, geo.rail_w, geo.rail_th, wd, ww, 0)
            d, vel = _under_wheel(wd, ww, 0, u, v)
            out.wdefl[e] = d
            out.wvel[e] = vel
            if not (abs(d) <= max_disp and abs(vel) < np.inf):
                ok = False
        if not ok:
            status = STOP_RESPONSE
            break
        for w in range(W):
            P_prev[w] = P1[w]
            F_prev[w] = F1[w]
        j += 1
    # write back: the step count, and the wheels and load vector of the last step made
    ctl[CTL_K] = k
    ctl[CTL_FRAME] = j
    ctl[CTL_STATUS] = status
    if stepped:
        q = 0
        for w in range(W):
            out.pos[w] = pP[w]
            out.F[w] = pF[w]
            if ppres[w]:
                fw = pF[w]
                for c in range(4 * w, 4 * w + 4):
                    out.prev_dofs[q] = pdofs[c]
                    out.prev_vals[q] = pwts[c] * fw
                    q += 1
        ctl[CTL_PREV] = q
    else:
        ctl[CTL_PREV] = -1
    return status
