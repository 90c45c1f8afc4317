"""The state of the streaming simulator: what changes while it runs.

:class:`SimulatorState` is everything a
:class:`~clm_core.solver.TrackSimulator` changes as it steps: the window's
placement and operator, the displacement and velocity vectors, the time, the
current loads and the running peaks. The simulator copies it before each
call and puts the copy back when the call is refused, so a refused call
leaves the state unchanged. :class:`PendingStep` is the first half of a
two-phase step (:meth:`~clm_core.solver.TrackSimulator.begin_step`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clm_core.arrays import Array, IntArray
from clm_core.solver import _kernels as kern
from clm_core.solver.operators import DofLayout, Operator
from clm_core.solver.window import Placement, Window


@dataclass(frozen=True)
class PendingStep:
    """A step begun by :meth:`clm_core.solver.TrackSimulator.begin_step`, waiting for its wheel forces.

    Attributes
    ----------
    positions : (n_w,) array
        Wheel positions at t + dt [m].
    x0 : (n,) array
        Step increment with zero wheel forces at t + dt [m].
    dofs, weights : (4 n_w,) int array, (4 n_w,) array
        Wheel element DOFs and Hermite weights.
    Gc : (n, n_w) array
        K_eff^-1 applied to each wheel's load pattern [m/N].
    Wm : (n_w, n) array
        Interpolation of the rail deflection under each wheel.
    k : int
        Step count when the step was begun (a later step invalidates it).
    """

    positions: Array
    x0: Array
    dofs: IntArray
    weights: Array
    Gc: Array
    Wm: Array
    k: int


@dataclass(frozen=True)
class StepSetup:
    """What does not change while a :class:`~clm_core.solver.TrackSimulator` runs, shared with its collaborators.

    ``layout``: the DOF maps of its windows; ``window``: the window's placement
    and shift rules; ``dt``: the time step [s]; ``z``, ``y``: the (n,) work
    arrays of the compiled steps (``z`` is zero between calls).
    """

    layout: DofLayout
    window: Window
    dt: float
    z: Array
    y: Array


@dataclass
class SimulatorState:
    """Everything that changes while a :class:`~clm_core.solver.TrackSimulator` runs (what a refused call restores).

    Attributes
    ----------
    placement : Placement
        Where the window is.
    op : Operator
        The operator of that placement.
    u, v : (n,) arrays
        Displacement [m] and velocity [m/s] of the window's DOFs.
    t0 : float
        Time of the last :meth:`~clm_core.solver.TrackSimulator.initialize` [s].
    k : int
        Steps since then (time ``t0 + k dt``).
    prev_dofs, prev_vals : int array, array
        The load vector at the current time as (DOF, value [N]) pairs.
    pos, F : (n_w,) arrays
        Wheel positions [m] (NaN: absent) and forces [N] at the current time.
    pk_force, pk_rail : (N,) arrays
        Running maxima of the soil force [N] and rail deflection [m] per sleeper.
    pending : PendingStep or None
        The step begun by :meth:`~clm_core.solver.TrackSimulator.begin_step`.
    """

    placement: Placement
    op: Operator
    u: Array
    v: Array
    t0: float
    k: int
    prev_dofs: IntArray
    prev_vals: Array
    pos: Array
    F: Array
    pk_force: Array
    pk_rail: Array
    pending: PendingStep | None = None

    def copy(self) -> SimulatorState:
        """A copy whose arrays are independent of this state's (the operator and pending step are shared)."""
        return SimulatorState(
            self.placement, self.op, self.u.copy(), self.v.copy(), self.t0, self.k, self.prev_dofs.copy(),
            self.prev_vals.copy(), self.pos.copy(), self.F.copy(), self.pk_force.copy(), self.pk_rail.copy(),
            self.pending,
        )

    def kernel_state(self, z: Array, y: Array) -> kern.StepState:
        """This state as the compiled steps take it, with the work arrays ``z``, ``y`` (n,) (updated in place)."""
        return kern.StepState(self.u, self.v, z, y, self.prev_dofs, self.prev_vals, self.pk_force, self.pk_rail)

    def sleeper_fields(self, lay: DofLayout) -> tuple[Array, Array, Array, Array]:
        """Per sleeper: soil force [N], rail deflection above it, sleeper and contact-area displacement [m].

        The soil force is ``k_b (z_s - x_a) + d_b (v_s - v_a)`` (the spring and
        dashpot under the sleeper); with a rigid soil (no contact-area
        DOF) ``x_a = v_a = 0``.
        """
        u, v = self.u, self.v
        zs, vs = u[lay.s_dof], v[lay.s_dof]
        if lay.a_dof[0] >= 0:
            xa, va = u[lay.a_dof], v[lay.a_dof]
        else:
            xa, va = np.zeros_like(zs), np.zeros_like(vs)
        op = self.op.kernel
        fs = op.kb * (zs - xa) + op.db * (vs - va)
        return fs, u[lay.r_dof].copy(), zs.copy(), xa.copy()

    def update_peaks(self, lay: DofLayout) -> None:
        """Raise the running maxima of soil force [N] and rail deflection [m] to the current fields."""
        fs, rw = self.sleeper_fields(lay)[:2]
        np.maximum(self.pk_force, fs, out=self.pk_force)
        np.maximum(self.pk_rail, rw, out=self.pk_rail)


__all__ = ["PendingStep", "SimulatorState", "StepSetup"]
