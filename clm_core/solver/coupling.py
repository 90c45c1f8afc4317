"""Two-phase steps of the streaming simulator: the wheel forces are found by the caller (vehicle coupling).

:class:`TwoPhaseSteps` is the part of :class:`clm_core.solver.TrackSimulator`
that serves the implicit vehicle coupling (:mod:`clm_core.vehicle`):
:meth:`~TwoPhaseSteps.begin_step` / :meth:`~TwoPhaseSteps.finish_step` (one
step, Python) and :meth:`~TwoPhaseSteps.coupled_chunk` /
:meth:`~TwoPhaseSteps.coupled_commit` (many steps handed to the compiled
coupling, :mod:`clm_core.vehicle._coupled_kernel`). The simulator inherits
them; they use its state and collaborators (see :mod:`clm_core.solver.simulator`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.errors import InputError
from clm_core.solver import _kernels as kern
from clm_core.solver.loads import check_values, load_weights, wheel_arrays
from clm_core.solver.state import PendingStep

if TYPE_CHECKING:
    from clm_core.solver.operators import DofLayout
    from clm_core.solver.state import SimulatorState
    from clm_core.solver.window import Window

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class _Chunk:
    """The rows handed out by the last :meth:`TwoPhaseSteps.coupled_chunk`."""

    positions: Array
    ldofs: IntArray
    lw: Array


class TwoPhaseSteps:
    """Two-phase and compiled coupled steps (a mixin of :class:`clm_core.solver.TrackSimulator`)."""

    # provided by TrackSimulator
    _s: SimulatorState
    _layout: DofLayout
    _window: Window
    _a1: float
    _chunk: _Chunk | None
    dt: float

    if TYPE_CHECKING:

        @property
        def t(self) -> float: ...

        def _save(self) -> SimulatorState: ...

        def _restore(self, saved: SimulatorState) -> None: ...

        def _place(self, P: Array, what: str, t: float) -> None: ...

        def _step_state(self) -> kern.StepState: ...

        def _sleeper_fields(self) -> tuple[Array, Array, Array, Array]: ...

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
        P, _ = wheel_arrays(positions_next, None, self.t, "begin_step")
        saved = self._save()
        try:
            self._s.pending = None
            self._place(P, "begin_step", self.t + self.dt)
            s = self._s
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
        s = self._s
        pend = s.pending
        if pend is None or pend.k != s.k:
            raise InputError("finish_step: no pending step (call begin_step first)")
        P = pend.positions
        F = np.array(forces_next, dtype=float, ndmin=1)
        if F.shape != P.shape:
            raise InputError(f"finish_step: forces have shape {F.shape}, begin_step had {P.shape} wheels")
        check_values(P[None, :], F[None, :], np.array([self.t + self.dt]), "finish_step")
        F = np.where(np.isfinite(P), F, 0.0)
        du = pend.x0 + pend.Gc @ F
        s.u += du
        s.v = self._a1 * du - s.v
        s.prev_dofs = pend.dofs.copy()
        s.prev_vals = pend.weights * np.repeat(F, 4)
        s.pos, s.F = P.copy(), F.copy()
        s.k += 1
        s.pending = None
        fs, rw = self._sleeper_fields()[:2]
        np.maximum(s.pk_force, fs, out=s.pk_force)
        np.maximum(s.pk_rail, rw, out=s.pk_rail)

    # ------------------------------------------------------------------ compiled two-phase steps

    def coupled_chunk(self, positions: ArrayLike) -> tuple[int, kern.CoupledTrack]:
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
        track : CoupledTrack
            The kernel's track inputs (:class:`clm_core.solver._kernels.CoupledTrack`):
            the operator, the state (updated in place by the kernel), the
            wheels' element DOFs and Hermite weights (m, 4 n_w) and the
            columns ``cols[slot[d]] = K_eff^-1 e_d`` of every DOF they load.

        Raises
        ------
        InputError
            Non-finite positions, or wheels that the window cannot hold (as
            :meth:`begin_step`).
        """
        P = np.ascontiguousarray(np.array(positions, dtype=float, ndmin=2))
        if P.ndim != 2 or P.shape[0] < 1 or not np.all(np.isfinite(P)):
            raise InputError(f"coupled_chunk: positions of shape {P.shape} must be finite rows (S >= 1, n_wheels)")
        self._s.pending = None
        self._place(P[0], "begin_step", self.t + self.dt)
        s = self._s
        front, rear = P.max(axis=1), P.min(axis=1)
        viol = np.nonzero(self._window.outside(s.placement, front, rear))[0]
        m = P.shape[0] if viol.size == 0 else int(viol[0])
        if m < 1:  # pragma: no cover - _place made row 0 fit
            raise InputError(f"coupled_chunk: cannot place the window for wheels at {rear[0]:g} .. {front[0]:g} m")
        ldofs, lw = load_weights(self._layout, s.placement.first, P[:m])
        cols, slot = s.op.columns(ldofs)
        self._chunk = _Chunk(P[:m], ldofs, lw)
        return m, kern.CoupledTrack(s.op.kernel, self._step_state(), ldofs, lw, cols, slot)

    def coupled_commit(self, steps: int, forces_last: ArrayLike) -> None:
        """Record that a kernel advanced ``steps`` rows of the last :meth:`coupled_chunk`.

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
        s = self._s
        s.k += steps
        s.prev_dofs = c.ldofs[steps - 1].copy()
        s.prev_vals = c.lw[steps - 1] * np.repeat(F, 4)
        s.pos, s.F = c.positions[steps - 1].copy(), F.copy()
        s.pending = None


__all__ = ["TwoPhaseSteps"]
