"""A vehicle that streams its wheel loads to an external track model.

This is the physics of the vehicle simulator node (and the reference for any
external simulator talking to the track node): the multibody vehicle and the
Hertz contact of :mod:`clm_core.vehicle` advance step by step, while the
track is a separate model (the track node) that answers each wheel-load
message with the rail deflection under the wheels, a few messages late.

Co-simulation of a stiff Hertz contact with a delayed partner needs a local
predictor: each wheel runs on a single-DOF equivalent of the track (mass
M_t, stiffness K_t, damping C_t fitted to the model's point dynamic
stiffness, :func:`clm_core.vehicle.impact.equivalent_track`), integrated
with the same Newmark step, so the contact solution stays implicit and
stable. In closed loop the track's reported deflection corrects the
predictor: the latest difference between the track's rail deflection and
the predictor's at the same stamp is added to the predicted deflection,

    w(t) = w_sdof(t) + [w_track(t_k) - w_sdof(t_k)],

so slow differences (static deflection shape, coupling between wheels, a
non-uniform track the vehicle does not know) come from the track model and
only fast dynamics rely on the predictor. In open loop the vehicle runs on
the predictor alone.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from clm_core.arrays import Array
from clm_core.errors import InputError, ParameterError
from clm_core.vehicle._streaming_kernel import OUTSIDE_PROFILE, message_steps, work_size
from clm_core.vehicle.contact import static_compression
from clm_core.vehicle.coupled import CoupledSimulation
from clm_core.vehicle.multibody import VehicleNewmark


class StreamingVehicle:
    """Vehicle + Hertz contact stepped against an external track.

    Parameters
    ----------
    sim : CoupledSimulation
        Describes the run (train, track parameters, speed, dt, irregularity,
        start position, Hertz constants); built e.g. by
        :func:`clm_core.vehicle.run.build_vehicle_run`. Its own track engine
        is not used.
    compiled_irregularity : bool
        Evaluate the rail profile under the wheels in the compiled step
        (default). False: evaluate it with numpy in Python every call (the
        reference path, identical up to the rounding of ``cos`` and
        ``interp``). A run with isolated defects or wheel flats always uses
        the Python evaluation for them.

    Notes
    -----
    One :meth:`advance` is one compiled call (:func:`clm_core.vehicle._streaming_kernel.message_steps`):
    wheel positions, irregularity, and per step the predictor, the vehicle's
    Newmark prediction, the Hertz contact Newton solution and the updates.
    ``benchmarks/vehicle_step.py`` prints its cost per message.
    """

    def __init__(self, sim: CoupledSimulation, compiled_irregularity: bool = True) -> None:
        from clm_core.vehicle.impact import equivalent_track

        self.sim = sim
        tr = sim.train
        self.train = tr
        self.dt = dt = sim.dt
        self.k = 0
        x0 = sim.wheel_positions(np.zeros(1))[0]
        self.x0 = x0
        self.eq = equivalent_track(sim.params)
        Kt, Mt, Ct = self.eq.Kt, self.eq.Mt, self.eq.Ct
        if not (Kt > 0 and Mt >= 0 and Ct >= 0):
            raise ParameterError(f"equivalent track K_t = {Kt:g}, M_t = {Mt:g}, C_t = {Ct:g}: not a valid SDOF track")
        self._S = Kt + 2.0 * Ct / dt + 4.0 * Mt / dt**2
        n = tr.n_wheels
        #: step compliance of the predictor [m/N] (diagonal: wheels >= 2 m apart barely interact)
        self.G = np.eye(n) / self._S
        self.P = tr.static_wheel_loads()
        self.w = self.P / Kt  # predictor state: static deflection, at rest
        self.v = np.zeros(n)
        self.a = np.zeros(n)
        self.offset = np.zeros(n)
        self.delta = np.ascontiguousarray(static_compression(self.P, sim.hertz), dtype=np.float64)
        r0 = sim.irregularity.wheel_irregularity(x0[None, :], x0, tr.wheel_radius)[0]
        self.veh = VehicleNewmark(tr, dt)
        self.veh.set_state(tr.static_state(self.w + r0 + self.delta), None, self.P)
        self._history: dict[int, Array] = {0: self.w.copy()}
        self.contact_lost_steps = 0
        self._last_response_step = 0
        irr = sim.irregularity
        #: irregularity evaluated in Python (numpy) and passed to the compiled step
        self.python_irregularity = not compiled_irregularity or bool(irr.defects) or bool(irr.flats)
        prof = irr.profile
        self._px = np.ascontiguousarray(prof.x if prof is not None else np.zeros(0), dtype=np.float64)
        self._pr = np.ascontiguousarray(prof.r if prof is not None else np.zeros(0), dtype=np.float64)
        self._lead_in = float(irr.lead_in)
        self._x_start = float(sim.x_start)
        self._speed = float(sim.speed)
        self._offsets = np.ascontiguousarray(tr.wheel_offset, dtype=np.float64)
        self._x0 = np.ascontiguousarray(x0, dtype=np.float64)
        #: wheel positions now [m] (those of :meth:`positions`, kept by :meth:`advance`)
        self.x: Array = self._x0.copy()
        self._work: dict[int, tuple[Array, Array]] = {}
        self._kwork = np.empty(work_size(self.veh.u.shape[0], n))
        self.warm_up()

    def warm_up(self) -> None:
        """Compile (or load from the on-disk cache) the stepping kernel on copies of the state: no effect on the run."""
        n = self.train.n_wheels
        self._call(self.veh.u.copy(), self.veh.v.copy(), self.veh.a.copy(), self.delta.copy(), self.P.copy(),
                   self.w.copy(), self.v.copy(), self.a.copy(), np.empty((1, n)), np.zeros((1, n)),
                   self.python_irregularity)

    def _call(self, u: Array, v: Array, a: Array, delta: Array, P: Array, w: Array, vw: Array, aw: Array,
              X: Array, R: Array, given_R: bool) -> tuple[int, int, float, int]:
        tr, veh = self.train, self.veh
        return message_steps(
            veh._Kinv, veh._KinvB, veh.H, tr.M, tr.C, tr.gravity_force, tr.wheel_dof, u, v, a, self.dt,
            self.sim.hertz, delta, P, self.eq.Mt, self.eq.Ct, self._S, self.G, w, vw, aw, self.offset, 1e-14, 50,
            self._kwork, self.k, self._x_start, self._speed, self._offsets, self._px, self._pr, self._lead_in,
            self._x0, X, R, given_R,
        )

    @property
    def t(self) -> float:
        """Current time [s] since the start."""
        return self.k * self.dt

    @property
    def rail(self) -> Array:
        """Predicted rail deflection under the wheels now [m]."""
        return np.asarray(self.w + self.offset)

    def positions(self, t: float | None = None) -> Array:
        """Wheel positions [m] at time ``t`` (default now)."""
        tt = self.t if t is None else t
        return np.asarray(self.sim.wheel_positions(np.array([tt]))[0])

    #: time constant of the low-pass on the track correction [s]: only slow differences
    #: between track and predictor are fed back (a fast, delayed correction through the
    #: stiff Hertz contact would be unstable)
    correction_time_constant: float = 0.02

    def set_track_response(self, step: int, rail_deflection: ArrayLike) -> None:
        """The track's rail deflection under the wheels [m] at step ``step`` (closes the loop).

        The correction w_track - w_predictor is low-pass filtered
        (``correction_time_constant``) before it is applied.
        """
        w = np.asarray(rail_deflection, dtype=float)
        n = self.train.n_wheels
        if w.shape != (n,):
            raise InputError(f"track response: {w.size} deflections; expected {n}")
        if not np.all(np.isfinite(w)):
            raise InputError("track response: non-finite rail deflection")
        ref = self._history.pop(int(step), None)
        if ref is None:
            raise InputError(f"track response for step {step}: no prediction kept for it")
        for old in [k for k in self._history if k < step]:
            del self._history[old]
        gap = max(step - self._last_response_step, 1) * self.dt
        self._last_response_step = step
        alpha = 1.0 - math.exp(-gap / self.correction_time_constant)
        self.offset = np.ascontiguousarray(self.offset + alpha * ((w - ref) - self.offset))

    def advance(self, n_steps: int) -> Array:
        """Advance ``n_steps`` steps of ``dt``; return the contact forces P [N] at the end.

        Raises
        ------
        ParameterError
            ``n_steps`` < 1.
        InputError
            A wheel runs off the sampled rail profile (nothing advanced), or
            the contact Newton iteration did not converge.
        """
        if n_steps < 1:
            raise ParameterError(f"n_steps = {n_steps}: must be >= 1")
        work = self._work.get(n_steps)
        if work is None:
            n = self.train.n_wheels
            work = self._work[n_steps] = (np.empty((n_steps, n)), np.empty((n_steps, n)))
        X, R = work
        if self.python_irregularity:
            t = np.asarray((self.k + 1 + np.arange(n_steps)) * self.dt, dtype=np.float64)
            R[:] = self.sim.irregularity.wheel_irregularity(self.sim.wheel_positions(t), self.x0,
                                                            self.train.wheel_radius)
        veh = self.veh
        P = np.empty(self.train.n_wheels)
        status, _, worst, lost = self._call(veh.u, veh.v, veh.a, self.delta, P, self.w, self.v, self.a, X, R,
                                            self.python_irregularity)
        if status == OUTSIDE_PROFILE:
            # the profile's own message (which positions, which coverage)
            self.sim.irregularity.wheel_irregularity(X, self.x0, self.train.wheel_radius)
            raise InputError(f"wheels at [{X.min():g}, {X.max():g}] m run off the rail profile")
        if not worst <= 1e-14:  # a non-finite force gives an infinite residual
            raise InputError(f"contact Newton iteration did not converge (residual {worst:.3g} m)")
        self.P = P
        self.x = X[-1].copy()
        self.contact_lost_steps += int(lost)
        self.k += n_steps
        self._history[self.k] = self.w.copy()
        if len(self._history) > 100_000:  # no answers coming: keep memory bounded
            self._history.pop(next(iter(self._history)))
        return P
