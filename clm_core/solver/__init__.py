"""Streaming time integration of the track–soil model under moving wheel loads (the solver).

:class:`TrackSimulator` advances the state of a track–soil model
(:func:`clm_core.track.assemble`, paper Sec. 5, Fig. 6) under a set of
wheels, each a vertical force [N] (positive downwards) at a position [m]
along the line. The state persists between calls, so the same object serves
the command line, an offline replay and a ROS node.

Integrator
    Newmark average acceleration (gamma = 1/2, beta = 1/4), the trapezoidal
    rule: unconditionally stable when M, K are positive (semi-)definite and
    the damping matrix C is positive semi-definite, which
    :func:`clm_core.track.check_damping` enforces (Kouroussis et al. 2011,
    Sec. 4.2). It is used in its increment form, with the acceleration
    eliminated through the equilibrium at t_n::

        K_eff du = f_{n+1} + f_n - 2 K u_n + (4/dt) M v_n
        u_{n+1} = u_n + du,     v_{n+1} = (2/dt) du - v_n
        K_eff = K + (2/dt) C + (4/dt^2) M      (symmetric positive definite)

    This is algebraically the same scheme as :class:`clm_core.newmark.NewmarkLinear`
    (which carries the acceleration), needs no acceleration state (massless
    Winkler areas are no special case) and stays consistent when the window
    shifts. A mode of frequency f is integrated at f' = tan(pi f dt)/(pi dt);
    the steady response to a harmonic force of frequency f is the exact
    response of the continuous model at f' (bilinear transform).

Cost per step
    K_eff is factorised once per window configuration (LDL^T in envelope
    storage, no fill outside the band profile); each step is one sparse pass
    for the right-hand side, a forward/back substitution and the update, all
    in one compiled kernel (:mod:`clm_core.solver._kernels`) that runs many steps
    per call. Cost and memory per step are O(n_sleepers) and independent of
    the length of line travelled.

Moving window
    The simulated track is a window of ``n_sleepers`` sleepers (global
    indices ``first .. first + n_sleepers - 1``, sleeper ``g`` at
    ``x = g * spacing``). With ``follow=True`` the window shifts by whole
    bays before the foremost wheel comes closer than ``lead_sleepers`` to its
    front end (or the rearmost closer than ``margin_sleepers`` to its rear
    end): the DOF vector moves by whole bays, the sleepers behind are dropped
    and new ones are added at rest (zero displacement and velocity) ahead.
    Because DOFs are in position order and each bay has the same DOF layout,
    a shift is a copy. The window is assembled with one extra bay on its
    leading side whose DOFs are clamped at zero
    (:func:`clm_core.solver.operators.clamp_ghost_bay`):
    a shift then turns clamped zeros into free DOFs at rest and drops
    elements at the free trailing end, so it can never add energy and the
    scheme stays unconditionally stable through any number of shifts.
    Windows with identical per-sleeper properties (a
    uniform track) share one factorisation; a window over per-sleeper
    overrides gets its own, kept in a small LRU cache keyed by the property
    values in the window. See docs/time-domain.md for the error of the window
    against a long fixed track.

Wheels
    Positions [m] and forces [N] per wheel, arrays of shape (n_w,). A wheel
    between rail nodes loads the element's four DOFs with the Hermite shape
    functions (:meth:`clm_core.track.TrackSystem.point_load`); the same
    weights give the rail deflection and velocity under the wheel (the
    material velocity of the rail at the contact point, without the
    convective term speed x slope). A wheel that is not on the track is given
    position NaN (its force must then be 0 or NaN); the number of wheels may
    change between calls.

Vehicle coupling
    :meth:`TrackSimulator.begin_step` / :meth:`TrackSimulator.finish_step`
    split a step around a contact solution found by the caller;
    :meth:`TrackSimulator.coupled_chunk` / :meth:`TrackSimulator.coupled_commit`
    hand the same steps, for a stretch without window shift, to a compiled
    kernel (:mod:`clm_core.vehicle._coupled_kernel`).

Layout of the package (the simulator is made of collaborator objects it holds):

=====================  =========================================================
module                 contents
=====================  =========================================================
``simulator``          :class:`TrackSimulator` (initialize, step/advance,
                       two-phase and compiled coupled steps, outputs)
``state``              :class:`SimulatorState` (what a refused call restores),
                       :class:`PendingStep`
``window``             :class:`Window` (placement and shift rules),
                       :class:`Placement`
``operators``          :class:`OperatorCache` (assembly and factorisation keyed
                       by the window's per-sleeper values), :class:`Operator`,
                       :class:`DofLayout`
``loads``              :class:`LoadTable`, load sources, Hermite load weights,
                       input checks
``records``            :class:`Snapshot`, :class:`Block`, :class:`FrameResponses`
``coupling``           two-phase and compiled coupled steps (vehicle coupling)
``frames``             the compiled per-frame path (:meth:`TrackSimulator.advance_frames`)
``_kernels``           numba kernels (``cache=True``) and their typed inputs
                       (:class:`~clm_core.solver._kernels.StepArgs`)
``_frame_kernel``      the kernel of the per-frame path and its typed inputs
                       (:class:`~clm_core.solver._frame_kernel.FrameLoads`, ...)
=====================  =========================================================

Per-sleeper overrides are applied in one place, :class:`clm_core.track.SleeperValues`.
"""

from __future__ import annotations

from clm_core.solver._frame_kernel import (
    LIM_FORCE,
    LIM_POSITION,
    LIM_SPAN,
    LIM_SPEED,
    LIM_TENSILE,
    STOP_INVALID,
    STOP_RESPONSE,
    STOP_SHIFT,
    FrameLoads,
    check_frame,
)
from clm_core.solver._kernels import free_response
from clm_core.solver.loads import LoadFunction, Loads, LoadTable
from clm_core.solver.operators import DofLayout, Operator, OperatorCache
from clm_core.solver.records import Block, FrameResponses, FrameRule, SleeperFields, Snapshot
from clm_core.solver.simulator import CHUNK_STEPS, TrackSimulator
from clm_core.solver.state import PendingStep, SimulatorState
from clm_core.solver.window import Orientation, Placement, Window

__all__ = [
    "CHUNK_STEPS",
    "LIM_FORCE",
    "LIM_POSITION",
    "LIM_SPAN",
    "LIM_SPEED",
    "LIM_TENSILE",
    "STOP_INVALID",
    "STOP_RESPONSE",
    "STOP_SHIFT",
    "Block",
    "DofLayout",
    "FrameLoads",
    "FrameResponses",
    "FrameRule",
    "LoadFunction",
    "LoadTable",
    "Loads",
    "Operator",
    "OperatorCache",
    "Orientation",
    "PendingStep",
    "Placement",
    "SimulatorState",
    "SleeperFields",
    "Snapshot",
    "TrackSimulator",
    "Window",
    "check_frame",
    "free_response",
]
