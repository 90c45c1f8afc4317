"""Two-phase steps of the streaming simulator: the wheel forces are found by the caller (vehicle coupling).

:class:`TwoPhaseCoupling` is the collaborator of
:class:`clm_core.solver.TrackSimulator` that serves the implicit vehicle
coupling (:mod:`clm_core.vehicle`): :meth:`~TwoPhaseCoupling.begin` /
:meth:`~TwoPhaseCoupling.finish` (one step, Python) and
:meth:`~TwoPhaseCoupling.chunk` / :meth:`~TwoPhaseCoupling.commit` (many
steps handed to the compiled coupling, :mod:`clm_core.vehicle._coupled_kernel`).
It holds what does not change while the simulator runs (the DOF layout, the
window's rules, the time step, the kernel's work arrays) and the rows of the
last chunk; the simulator passes its :class:`~clm_core.solver.state.SimulatorState`
to every call, with the window already placed for the step's wheels, and
keeps the public methods (:meth:`~clm_core.solver.TrackSimulator.begin_step`,
...), the checks of their arguments and the restore of a refused call.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from clm_core.arrays import Array, IntArray
from clm_core.errors import InputError
from clm_core.solver import _kernels as kern
from clm_core.solver.loads import check_values, load_weights
from clm_core.solver.state import PendingStep

if TYPE_CHECKING:
    from clm_core.solver.state import SimulatorState, StepSetup



@dataclass(frozen=True)
class _Chunk:
    """The rows handed out by the last :meth:`TwoPhaseCoupling.chunk`."""

    positions: Array
    ldofs: IntArray
    lw: Array


class TwoPhaseCoupling:
    """Two-phase and compiled coupled steps of a :class:`clm_core.solver.TrackSimulator` (a collaborator it holds).

    Parameters
    ----------
    setup : StepSetup
        The simulator's DOF layout, window rules, time step and work arrays.
    """

    def __init__(self, setup: StepSetup) -> None:
        self._layout = setup.layout
        self._window = setup.window
        self._a1 = 2.0 / setup.dt
        self._work = (setup.z, setup.y)
        self._chunk: _Chunk | None = None

    def begin(self, s: SimulatorState, P: Array) -> tuple[Array, Array, Array]:
        """First half of a step whose wheel forces are found by the caller.

        Parameters
        ----------
        s : SimulatorState
            The state at time t, its window placed for ``P``; its pending step
            is set here.
        P : (n_w,) array
            Wheel positions [m] at t + dt (NaN: absent).

        Returns
        -------
        w_free, v_free, G : (n_w,), (n_w,), (n_w, n_w) arrays
            As :meth:`clm_core.solver.TrackSimulator.begin_step`: rail
            deflection [m] and velocity [m/s] under each wheel with zero wheel
            forces at t + dt, and the compliance [m/N].
        """
        op = s.op.kernel
        dofs, wts = load_weights(self._layout, s.placement.first, P[None, :])
        dofs, wts = dofs[0], wts[0]
        env = s.op.env
        n = s.u.size
        x0 = np.empty_like(s.u)
        kern.free_rhs(op.indptr, op.indices, op.Ka, op.Mb, s.u, s.v, s.prev_dofs, s.prev_vals, x0)
        kern.solve_envelope(*env, x0)
        W = P.size
        Gc = np.zeros((n, W))
        for j in range(W):
            if np.isfinite(P[j]):
                b = np.zeros(n)
                np.add.at(b, dofs[4 * j : 4 * j + 4], wts[4 * j : 4 * j + 4])
                kern.solve_envelope(*env, b)
                Gc[:, j] = b
        Wm = np.zeros((W, n))
        for j in range(W):
            np.add.at(Wm[j], dofs[4 * j : 4 * j + 4], wts[4 * j : 4 * j + 4])
        w_free = Wm @ (s.u + x0)
        v_free = Wm @ (self._a1 * x0 - s.v)
        G = Wm @ Gc
        absent = ~np.isfinite(P)
        w_free[absent] = np.nan
        v_free[absent] = np.nan
        G[absent, :] = np.nan
        G[:, absent] = np.nan
        s.pending = PendingStep(P, x0, dofs, wts, Gc, Wm, s.k)
        return w_free, v_free, G

    def finish(self, s: SimulatorState, forces_next: ArrayLike, t_next: float) -> None:
        """Complete the pending step of ``s`` with the wheel forces [N] at ``t_next`` = t + dt [s].

        Raises
        ------
        InputError
            No pending step, NaN forces or a size different from the
            positions given to :meth:`begin`; ``s`` is then unchanged.
        """
        pend = s.pending
        if pend is None or pend.k != s.k:
            raise InputError("finish_step: no pending step (call begin_step first)")
        P = pend.positions
        F = np.array(forces_next, dtype=float, ndmin=1)
        if F.shape != P.shape:
            raise InputError(f"finish_step: forces have shape {F.shape}, begin_step had {P.shape} wheels")
        check_values(P[None, :], F[None, :], np.array([t_next]), "finish_step")
        F = np.where(np.isfinite(P), F, 0.0)
        du = pend.x0 + pend.Gc @ F
        s.u += du
        s.v = self._a1 * du - s.v
        s.prev_dofs = pend.dofs.copy()
        s.prev_vals = pend.weights * np.repeat(F, 4)
        s.pos, s.F = P.copy(), F.copy()
        s.k += 1
        s.pending = None
        s.update_peaks(self._layout)

    # ------------------------------------------------------------------ compiled two-phase steps

    def chunk(self, s: SimulatorState, P: Array) -> tuple[int, kern.CoupledTrack]:
        """The rows of ``P`` (S, n_w) the window of ``s`` holds, for a compiled coupling kernel.

        ``s`` has its window placed for row 0. Returns the number ``m`` of
        leading rows it holds without a shift and the kernel's track inputs,
        as :meth:`clm_core.solver.TrackSimulator.coupled_chunk`; the rows are
        kept for :meth:`commit`.
        """
        front, rear = P.max(axis=1), P.min(axis=1)
        viol = np.nonzero(self._window.outside(s.placement, front, rear))[0]
        m = P.shape[0] if viol.size == 0 else int(viol[0])
        if m < 1:  # pragma: no cover - the simulator placed the window for row 0
            raise InputError(f"coupled_chunk: cannot place the window for wheels at {rear[0]:g} .. {front[0]:g} m")
        ldofs, lw = load_weights(self._layout, s.placement.first, P[:m])
        cols, slot = s.op.columns(ldofs)
        self._chunk = _Chunk(P[:m], ldofs, lw)
        return m, kern.CoupledTrack(s.op.kernel, s.kernel_state(*self._work), ldofs, lw, cols, slot)

    def commit(self, s: SimulatorState, steps: int, forces_last: ArrayLike) -> None:
        """Record in ``s`` that a kernel advanced ``steps`` rows of the last :meth:`chunk`.

        ``forces_last``: the wheel forces [N] of the last step made (the
        loads f_n of the next step).
        """
        c = self._chunk
        rows = 0 if c is None else c.positions.shape[0]
        steps = int(steps)
        if not 0 <= steps <= rows:
            raise InputError(f"coupled_commit: {steps} steps, the chunk has {rows}")
        if steps == 0 or c is None:
            return
        F = np.array(forces_last, dtype=float, ndmin=1)
        s.k += steps
        s.prev_dofs = c.ldofs[steps - 1].copy()
        s.prev_vals = c.lw[steps - 1] * np.repeat(F, 4)
        s.pos, s.F = c.positions[steps - 1].copy(), F.copy()
        s.pending = None


__all__ = ["TwoPhaseCoupling"]
