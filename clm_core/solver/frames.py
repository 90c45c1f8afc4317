"""The compiled per-frame path of the streaming simulator: many stamped wheel-load frames in one go.

:class:`FrameRunner` is the collaborator of :class:`clm_core.solver.TrackSimulator`
that advances through *frames* (one ``clm_msgs/WheelLoads`` message each:
a stamp, wheel positions and forces) rather than through steps: the online
model (:mod:`clm_core.online`) hands it every waiting frame at once, and one
compiled kernel (:func:`clm_core.solver._frame_kernel.run_frames`) integrates
through them, interpolating the wheels linearly between the frames' stamps,
computing the Hermite load weights and recording each frame's response. It
returns to Python only when the window must move (a shift by whole bays, done
by the simulator through the ``move`` it passes, then it resumes) or when a
frame fails. The runner holds what does not change while the simulator runs
(the DOF layout, the window's rules, the kernel's work arrays and control
registers) and its caches (the window geometry as the kernel takes it, the
restore buffers); the simulator passes its state to every call.

A frame fails when its response is not finite or beyond the given bounds,
or when its wheels cannot be placed in the window part-way through its
interval. The state is then restored to what it was after the frame before
it: from a copy taken at the first kernel call, by running the frames before
the failing one again (the computation is deterministic: the same frames
from the same state give the same bits). The result says which frame failed
and why; the caller refuses it and carries on with the next.

Every frame goes through the same kernel whether it comes alone or with
others, and the kernel's state between two calls (displacements,
velocities, peaks, the load vector of the last step, the previous frame's
wheels) is exactly what it holds inside one call, so the responses do not
depend on how a stream is split into calls.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from clm_core.arrays import IntArray
from clm_core.errors import InputError
from clm_core.solver import _frame_kernel as fk
from clm_core.solver.records import FrameResponses, FrameRule
from clm_core.solver.window import Placement

if TYPE_CHECKING:
    from clm_core.solver.state import SimulatorState, StepSetup



def truncated(loads: fk.FrameLoads, r: int) -> fk.FrameLoads:
    """The first ``r`` frames of ``loads`` (same arrays, previous-frame buffers shared)."""
    return loads._replace(ticks=loads.ticks[: r + 1], k_end=loads.k_end[:r], offsets=loads.offsets[: r + 1])


class FrameRunner:
    """Advance a simulator's state through stamped frames of wheel loads (a collaborator of the simulator).

    Parameters
    ----------
    setup : StepSetup
        The simulator's DOF layout, window rules, time step and work arrays.
    touched : (n_t,) int array
        Global indices of the sleepers with overridden values, sorted
        (:attr:`clm_core.track.SleeperValues.touched`): the kernel moves the
        window itself only where the operator stays the same.
    move : callable
        ``move(p)`` moves the window of the state being advanced to
        placement ``p`` (its state shifted by whole bays, the operator of
        ``p``).
    """

    def __init__(self, setup: StepSetup, touched: IntArray, move: Callable[[Placement], None]) -> None:
        self._layout = setup.layout
        self._window = setup.window
        self._touched = touched
        self._dt = setup.dt
        self._work = (setup.z, setup.y)
        self._move = move
        self._geo: tuple[Placement, tuple[object, ...]] | None = None
        self._backup_bufs: tuple[fk.FrameBackup, tuple[object, ...]] | None = None  # the restore buffers, also plain
        self._ctl = (np.zeros(8, dtype=np.int64), np.zeros(4))  # the kernel's control registers

    def advance(
        self, s: SimulatorState, loads: fk.FrameLoads, max_force: float = math.inf, max_displacement: float = math.inf
    ) -> FrameResponses:
        """Advance ``s`` through R frames of wheel loads; the response at each frame's step.

        Parameters
        ----------
        s : SimulatorState
            The simulator's state, advanced in place.
        loads : FrameLoads
            The frames (:class:`clm_core.solver._frame_kernel.FrameLoads`):
            times in integer ticks with the step a whole number of ticks,
            each frame's response step ``k_end`` (steps since
            :meth:`initialize`, non-decreasing, not before the current step),
            the wheel entries of every frame (slot, position [m], force [N],
            finite) and the previous frame's wheels per slot (``P_prev``,
            ``F_prev``: updated in place to the last frame done).
        max_force : float
            Bound on the magnitude of the soil forces of a response [N].
        max_displacement : float
            Bound on the magnitude of the displacements of a response and of
            the rail deflection under the wheels [m].

        Returns
        -------
        FrameResponses
            One row per frame done; ``done < R`` when a frame failed (its
            response not finite or beyond a bound, or its wheels not fitting in
            the window part-way): the state is then that after the frame
            before it, and the frames after it are not done.

        Raises
        ------
        InputError
            A response step before the current step (time going backwards).
        """
        R, W, M = len(loads.k_end), len(loads.P_prev), len(loads.positions)
        if R and loads.k_end[0] < s.k:
            raise InputError(f"advance_frames: frame 0 ends at step {int(loads.k_end[0])}, before the current step "
                             f"{s.k} (time going backwards)")
        sleepers = np.empty((4, R, self._window.n_sleepers))
        wheels = np.empty((2, M))
        q = max(4 * W, len(s.prev_dofs))
        ctl, ctl_f = self._ctl
        ctl_f[fk.CTF_MAX_FORCE] = max_force
        ctl_f[fk.CTF_MAX_DISP] = max_displacement
        first = np.empty(R, dtype=np.int64)
        out = fk.FrameOutputs(sleepers, first, wheels, np.empty(q, dtype=np.int64), np.empty(q), np.empty((2, W)),
                              ctl, ctl_f)
        saved = (s.placement, s.op, s.k, s.prev_dofs, s.prev_vals, s.pos, s.F)
        done, status, failure = self._frames(s, loads, out)
        if status == fk.STOP_INVALID:  # nothing of the frame was done: the state is that after the one before
            rule, wheel = FrameRule(int(ctl[fk.CTL_RULE])), int(ctl[fk.CTL_WHEEL])
            return FrameResponses(first, sleepers, wheels, done, failure, status, rule, wheel)
        if status != fk.DONE:
            bk = self._backup(s, W)
            s.placement, s.op, s.k, s.prev_dofs, s.prev_vals, s.pos, s.F = saved
            s.u[:] = bk.u
            s.v[:] = bk.v
            s.pk_force[:] = bk.pk_force
            s.pk_rail[:] = bk.pk_rail
            loads.P_prev[:] = bk.P_prev
            loads.F_prev[:] = bk.F_prev
            if done:
                again, st, why = self._frames(s, truncated(loads, done), out)
                if st != fk.DONE or again != done:  # pragma: no cover - the computation is deterministic
                    raise RuntimeError(f"advance_frames: replay of {done} frames gave {again} ({why})")
        return FrameResponses(first, sleepers, wheels, done, failure, status)

    def _frames(self, s: SimulatorState, loads: fk.FrameLoads, out: fk.FrameOutputs) -> tuple[int, int, str]:
        """Run the kernel through ``loads`` from ``s``, moving the window when asked; (frames done, status, failure)."""
        ctl = out.ctl
        ctl[fk.CTL_K] = s.k
        ctl[fk.CTL_FRAME] = 0
        ctl[fk.CTL_BACKUP] = 1
        R = len(loads.k_end)
        self._backup(s, len(loads.P_prev))
        assert self._backup_bufs is not None
        args = (tuple(loads), self._backup_bufs[1], tuple(out))
        z, y = self._work
        while True:
            k_before = s.k
            status = fk.run_frames((s.op.kernel_plain, (s.u, s.v, z, y, s.prev_dofs, s.prev_vals,
                                    s.pk_force, s.pk_rail), self._geometry(s.placement), *args))
            k, j, _, q, _, rule, wheel, first = ctl.tolist()
            ctl[fk.CTL_BACKUP] = 0
            s.k = k
            if first != s.placement.first:  # the kernel moved the window forwards (same operator)
                s.placement = Placement(first, s.placement.orientation)
            if q >= 0:
                s.prev_dofs, s.prev_vals = out.prev_dofs[:q], out.prev_vals[:q]
                if k != k_before:
                    s.pos, s.F = out.last[0], out.last[1]
            if status == fk.DONE:
                return R, status, ""
            if status == fk.STOP_INVALID:
                return j, status, f"frame {j} breaks value rule {rule} (wheel {wheel})"
            if status == fk.STOP_RESPONSE:
                return j, status, (f"the response is not finite or beyond its bounds (soil force "
                                   f"{out.ctl_f[fk.CTF_MAX_FORCE]:g} N, displacement {out.ctl_f[fk.CTF_MAX_DISP]:g} m)")
            front, rear = float(out.ctl_f[fk.CTF_FRONT]), float(out.ctl_f[fk.CTF_REAR])
            t = s.t0 + (s.k + 1) * self._dt
            win = self._window
            try:
                if not win.follow:
                    win.check_inside(s.placement, front, rear, "advance_frames", t)
                p = win.required(s.placement, front, rear, "advance_frames", t)
            except InputError as exc:
                return j, fk.STOP_SHIFT, str(exc)
            self._move(p)

    def _geometry(self, p: Placement) -> tuple[object, ...]:
        """The window at ``p`` as the kernel takes it (:class:`~._frame_kernel.FrameGeometry`, plain; cached)."""
        cached = self._geo
        if cached is not None and cached[0] == p:
            return cached[1]
        lay, win = self._layout, self._window
        lo, hi = win.limits(p.orientation)
        orient = {"forward": fk.ORIENT_FORWARD, "backward": fk.ORIENT_BACKWARD}.get(p.orientation, fk.ORIENT_FREE)
        geo = tuple(fk.FrameGeometry(p.first, orient, float(lay.node_x_rel[0]), float(lay.spacing), float(lay.Le),
                                     int(lay.n_el), lay.rail_w, lay.rail_th, lo, hi, win.n_sleepers,
                                     lay.dofs_per_bay, self._touched))
        self._geo = (p, geo)
        return geo

    def _backup(self, s: SimulatorState, W: int) -> fk.FrameBackup:
        """The restore buffers for a run from ``s`` (state sizes fixed; ``W`` wheel slots)."""
        cached = self._backup_bufs
        if cached is None or cached[0].P_prev.shape[0] != W:
            bk = fk.FrameBackup(np.empty_like(s.u), np.empty_like(s.v), np.empty_like(s.pk_force),
                                np.empty_like(s.pk_rail), np.empty(W), np.empty(W))
            if cached is not None:
                old = cached[0]
                bk = bk._replace(u=old.u, v=old.v, pk_force=old.pk_force, pk_rail=old.pk_rail)
            cached = self._backup_bufs = (bk, tuple(bk))
        return cached[0]


__all__ = ["FrameRunner", "truncated"]
