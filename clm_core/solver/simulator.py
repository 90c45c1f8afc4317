"""The streaming simulator: state, stepping and outputs, built from its collaborators.

:class:`TrackSimulator` advances the state of the track–soil model under
moving wheel loads (integrator, window and cost in :mod:`clm_core.solver`).
It holds, and delegates to:

- a :class:`~clm_core.solver.window.Window` (placement and shift rules) and
  the current :class:`~clm_core.solver.window.Placement`;
- an :class:`~clm_core.solver.operators.OperatorCache` (assembly and
  factorisation of each window configuration, keyed by its per-sleeper
  values) and the window's :class:`~clm_core.solver.operators.DofLayout`;
- the per-sleeper values of the line (:class:`clm_core.track.SleeperValues`,
  the one place where overrides are applied);
- its :class:`~clm_core.solver.state.SimulatorState`: everything that
  changes while it runs, copied before each call and restored when the call
  is refused;
- a :class:`~clm_core.solver.coupling.TwoPhaseCoupling` (the two-phase and
  compiled coupled steps of the vehicle coupling) and a
  :class:`~clm_core.solver.frames.FrameRunner` (the compiled per-frame path of
  the online model), to which it passes its state at every call.

The compiled steps (:func:`clm_core.solver._kernels.run_steps`) get the
operator, the state, the loads and the output buffers in one typed
structure (:class:`clm_core.solver._kernels.StepArgs`); the results are
:class:`~clm_core.solver.records.Snapshot` and
:class:`~clm_core.solver.records.Block` records.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import ArrayLike

from clm_core.arrays import Array, IntArray
from clm_core.checks import finite, positive
from clm_core.errors import InputError
from clm_core.params import ModelParams
from clm_core.solver import _kernels as kern
from clm_core.solver.coupling import TwoPhaseCoupling
from clm_core.solver.frames import FrameRunner
from clm_core.solver.loads import Loads, check_values, load_entries, load_source, load_weights, wheel_arrays
from clm_core.solver.operators import Operator, OperatorCache
from clm_core.solver.records import Block, Snapshot
from clm_core.solver.state import SimulatorState, StepSetup
from clm_core.solver.window import Placement, Window, shift_bays, shift_entries
from clm_core.track import SleeperValues, TrackSystem, check_overridden_stretches

if TYPE_CHECKING:
    from clm_core.solver._frame_kernel import FrameLoads
    from clm_core.solver.records import FrameResponses


#: Steps per kernel call at most (bounds the per-call work arrays: flat memory).
CHUNK_STEPS = 2048
_TOL = 1e-9


class TrackSimulator:
    """Streaming simulator of the track–soil model under moving wheel loads.

    Parameters
    ----------
    params : ModelParams
        Rail, track and soil parameters with per-sleeper overrides (global
        sleeper indices). Refused with :class:`~clm_core.errors.StabilityError`
        if the damping matrix of the window or of any overridden stretch of
        line is not positive semi-definite (Sec. 4.2).
    dt : float
        Time step [s].
    n_sleepers : int
        Sleepers in the simulated window (>= lead_sleepers + margin_sleepers + 1).
    elements_per_bay : int
        Rail beam elements per sleeper bay (2 is the paper's choice).
    start_position : float
        Position of the window centre at start [m].
    lead_sleepers : int, optional
        Sleepers kept ahead of the foremost wheel when following (default
        ``n_sleepers // 3``).
    follow : bool
        Move the window with the wheels. When False, wheels closer than
        ``margin_sleepers`` to an end of the window are refused.
    margin_sleepers : int, optional
        Least number of sleeper bays between any wheel and either end of the
        window (default ``max(2, min(10, n_sleepers // 6))``).
    cache_size : int
        Window factorisations kept (LRU) for non-uniform tracks.

    Raises
    ------
    ParameterError
        Bad sizes, time step or per-sleeper values.
    StabilityError
        Damping matrix not positive semi-definite somewhere on the line.

    Examples
    --------
    One 100 kN wheel from static equilibrium at x = 0, then 50 ms at 80 m/s
    (the window follows it):

    >>> from clm_core.params import load_model
    >>> from clm_core.solver import TrackSimulator
    >>> sim = TrackSimulator(load_model("mevergnies", "mevergnies", "clm"), dt=1e-4, n_sleepers=31)
    >>> sim.initialize([0.0], [100e3])
    >>> print(f"{sim.snapshot().wheel_deflection[0] * 1e3:.3f} mm")  # static rail deflection, positive down
    1.336 mm
    >>> sim.advance(0.05, ([4.0], [100e3]))  # positions and forces at t_end, interpolated in between
    >>> sim.steps, round(sim.t, 9), sim.window
    (500, 0.05, (-13, 31))
    >>> cp = sim.checkpoint()
    >>> sim.advance(0.06, ([4.8], [100e3]))
    >>> sim.rollback(cp)  # back to t = 0.05 s exactly
    >>> sim.steps
    500
    """

    def __init__(
        self,
        params: ModelParams,
        dt: float,
        n_sleepers: int = 61,
        elements_per_bay: int = 2,
        start_position: float = 0.0,
        lead_sleepers: int | None = None,
        follow: bool = True,
        *,
        margin_sleepers: int | None = None,
        cache_size: int = 64,
    ) -> None:
        dt = positive("dt", dt, unit="s")
        window = Window.create(n_sleepers, params.track.spacing, lead_sleepers, margin_sleepers, follow,
                               elements_per_bay)
        start_position = finite("start_position", start_position)
        self.params = params
        self.dt = dt
        self.elements_per_bay = int(elements_per_bay)
        self.spacing = float(params.track.spacing)
        self._window = window
        self._a1 = 2.0 / dt
        values = SleeperValues(params)
        self._ops = OperatorCache(params, dt, window, self.elements_per_bay, values, cache_size)

        kern.warm_up()
        placement = window.start(float(start_position))
        op = self._ops.get(placement)
        self._layout = self._ops.layout
        check_overridden_stretches(params, self.elements_per_bay, values)

        n, N = self._layout.n_dof, window.n_sleepers
        self._z = np.zeros(n)  # kernel work arrays (z stays zero between calls)
        self._y = np.zeros(n)
        self._s = SimulatorState(
            placement=placement, op=op, u=np.zeros(n), v=np.zeros(n), t0=0.0, k=0,
            prev_dofs=np.zeros(0, dtype=np.int64), prev_vals=np.zeros(0), pos=np.zeros(0), F=np.zeros(0),
            pk_force=np.zeros(N), pk_rail=np.zeros(N),
        )
        setup = StepSetup(self._layout, window, dt, self._z, self._y)
        self._coupling = TwoPhaseCoupling(setup)
        self._frames = FrameRunner(setup, values.touched, self._move)
        self._no_output = (np.zeros(0, dtype=np.int64), np.empty((0, N)))  # output buffers without a callback

    # ------------------------------------------------------------------ properties

    @property
    def n_sleepers(self) -> int:
        """Sleepers in the window."""
        return self._window.n_sleepers

    @property
    def lead_sleepers(self) -> int:
        """Sleepers kept ahead of the foremost wheel when following."""
        return self._window.lead_sleepers

    @property
    def margin_sleepers(self) -> int:
        """Least number of sleeper bays between any wheel and either end of the window."""
        return self._window.margin_sleepers

    @property
    def follow(self) -> bool:
        """Whether the window moves with the wheels."""
        return self._window.follow

    @property
    def t(self) -> float:
        """Current simulation time [s]."""
        return self._s.t0 + self._s.k * self.dt

    @property
    def steps(self) -> int:
        """Steps integrated since the last :meth:`initialize` (the current time is ``t0 + steps * dt``)."""
        return self._s.k

    def time_of_step(self, n: int) -> float:
        """Time [s] of step ``n``, counted from the last :meth:`initialize`."""
        return self._s.t0 + n * self.dt

    @property
    def window(self) -> tuple[int, int]:
        """(global index of the first sleeper of the window, number of sleepers)."""
        return self._s.placement.first, self.n_sleepers

    @property
    def placement(self) -> Placement:
        """Where the window is (first sleeper and side of its clamped ghost bay)."""
        return self._s.placement

    @property
    def n_dof(self) -> int:
        """Degrees of freedom of the window."""
        return int(self._s.u.size)

    @property
    def system(self) -> TrackSystem:
        """Assembled model of the current window (matrices; positions of the window it was built for)."""
        return self._s.op.system

    @property
    def operator(self) -> Operator:
        """Operator (matrices, factorisation) of the current window."""
        return self._s.op

    @property
    def n_factorisations(self) -> int:
        """Window operators assembled and factorised so far."""
        return self._ops.n_factorisations

    def allowed_range(self) -> tuple[float, float]:
        """Positions [m] where wheels are accepted without shifting the window.

        Following forwards: from ``margin_sleepers`` behind the window's rear
        end to ``lead_sleepers`` before its front end; following backwards
        (after the last shift was backwards): the mirror image; not following:
        ``margin_sleepers`` from either end.
        """
        return self._window.allowed_range(self._s.placement)

    # ------------------------------------------------------------------ state

    def checkpoint(self) -> SimulatorState:
        """A copy of everything that changes while the simulator runs, to go back to with :meth:`rollback`.

        The state of a caller that must undo work (the online model refusing a
        frame after it was stepped); the window's operators are not copied
        (they are shared, keyed by placement).
        """
        return self._s.copy()

    def rollback(self, checkpoint: SimulatorState) -> None:
        """Put back the state of :meth:`checkpoint` (the checkpoint stays valid for another rollback)."""
        if not isinstance(checkpoint, SimulatorState):
            raise TypeError(f"rollback: a checkpoint of this simulator expected, got {type(checkpoint).__name__}")
        self._s = checkpoint.copy()

    def _save(self) -> SimulatorState:
        return self._s.copy()

    def _restore(self, saved: SimulatorState) -> None:
        self._s = saved

    def _move(self, p: Placement) -> None:
        """Move the window to placement ``p`` (state shifted by whole bays, new bays at rest)."""
        s = self._s
        if p == s.placement:
            return
        op = self._ops.get(p)
        b = p.first - s.placement.first
        dpb = self._layout.dofs_per_bay
        shift_bays(s.u, b, dpb)
        shift_bays(s.v, b, dpb)
        shift_bays(s.pk_force, b, 1)
        shift_bays(s.pk_rail, b, 1)
        s.prev_dofs, s.prev_vals = shift_entries(s.prev_dofs, s.prev_vals, b, dpb, s.u.size)
        s.placement = p
        s.op = op

    def _place(self, P: Array, what: str, t: float) -> None:
        """Shift the window (follow=True) or check the wheels (follow=False) for positions P (n_w,)."""
        self._move(self._window.place(self._s.placement, P, what, t))

    def _step_state(self) -> kern.StepState:
        """The state as the compiled steps take it (arrays shared, updated in place by the kernel)."""
        return self._s.kernel_state(self._z, self._y)

    # ------------------------------------------------------------------ public API

    def initialize(
        self,
        positions: ArrayLike,
        forces: ArrayLike,
        t0: float = 0.0,
        state: Literal["static", "rest"] = "static",
        centre: float | None = None,
    ) -> None:
        """Reset the state at time ``t0`` under the given wheel loads.

        Parameters
        ----------
        positions : (n_w,) array_like
            Wheel positions [m] (NaN: not on the track).
        forces : (n_w,) array_like
            Wheel forces [N], positive downwards.
        t0 : float
            Start time [s].
        state : {'static', 'rest'}
            ``static``: static equilibrium K u = F under these loads, zero
            velocity (no start transient for constant loads). ``rest``: zero
            displacement and velocity, the loads apply suddenly at ``t0``.
        centre : float, optional
            First place the window centred on this position [m], as a new
            simulator with ``start_position=centre`` would be (default: the
            window moves from where it is only as far as the wheels need).

        Raises
        ------
        InputError
            NaN forces, mismatched sizes, wheels that do not fit in the
            window, a non-finite ``centre``; the state is then unchanged.
        """
        if state not in ("static", "rest"):
            raise InputError(f"initialize: state = {state!r}: must be 'static' or 'rest'")
        t0 = float(t0)
        if not math.isfinite(t0):
            raise InputError(f"initialize: t0 = {t0}: must be finite")
        saved = self._save()
        try:
            P, F = wheel_arrays(positions, forces, self.t, "initialize")
            if centre is not None:
                if not math.isfinite(centre):
                    raise InputError(f"initialize: centre = {centre}: must be finite")
                p = self._window.start(float(centre))
                self._s.placement, self._s.op = p, self._ops.get(p)
            self._place(P, "initialize", t0)
            s = self._s
            n = s.u.size
            dofs, vals = load_entries(self._layout, s.placement.first, P, F)
            u = np.zeros(n)
            if state == "static" and np.any(vals != 0.0):
                np.add.at(u, dofs, vals)
                kern.solve_envelope(*s.op.static_factor(), u)
            s.u, s.v = u, np.zeros(n)
            s.prev_dofs, s.prev_vals = dofs, vals
            s.pos, s.F = P, F
            s.t0, s.k = t0, 0
            s.pending = None
            self.reset_peaks()
        except BaseException:
            self._restore(saved)
            raise

    def reset_peaks(self) -> None:
        """Restart the running maxima of soil force and rail deflection from the current state."""
        fs, rw = self._sleeper_fields()[:2]
        self._s.pk_force = fs.copy()
        self._s.pk_rail = rw.copy()

    def peaks(self) -> tuple[IntArray, Array, Array]:
        """Running maxima in the window: (global sleeper index, soil force [N], rail deflection [m])."""
        s = self._s
        return self._window.sleeper_index(s.placement), s.pk_force.copy(), s.pk_rail.copy()

    def step(self, positions: ArrayLike, forces: ArrayLike) -> None:
        """Advance one time step to t + dt.

        Parameters
        ----------
        positions : (n_w,) array_like
            Wheel positions [m] at t + dt.
        forces : (n_w,) array_like
            Wheel forces [N] at t + dt.

        Raises
        ------
        InputError
            NaN forces, mismatched sizes, wheels outside the allowed part of
            the window (follow=False) or not fitting in it; the state is
            then unchanged.
        """
        P, F = wheel_arrays(positions, forces, self.t, "step")
        saved = self._save()
        try:
            self._s.pending = None
            self._run(P[None, :], F[None, :], None, 0, "step")
        except BaseException:
            self._restore(saved)
            raise

    def advance(
        self,
        t_end: float,
        loads: Loads,
        *,
        callback: Callable[[Block], None] | None = None,
        output_every: int = 1,
    ) -> None:
        """Advance by whole steps of ``dt`` to the last step time <= ``t_end``.

        Parameters
        ----------
        t_end : float
            End time [s]; must not lie before the current time.
        loads : tuple (positions_end, forces_end), callable or LoadTable
            ``(positions_end, forces_end)``: wheel positions [m] and forces [N]
            at ``t_end``, linearly interpolated from the current ones (same
            number of wheels; a wheel absent now, NaN, appears at ``t_end``).
            A callable ``t -> (positions, forces)`` is evaluated at every step
            time. A :class:`~clm_core.solver.loads.LoadTable` is evaluated
            vectorised (see :func:`~clm_core.solver.loads.load_source`).
        callback : callable, optional
            Receives a :class:`Block` of outputs for each stretch of steps with
            the window in one position (at least one per call and one before
            every window shift). Without it nothing is recorded.
        output_every : int
            Record sleeper and wheel outputs every this many steps (global
            step count since :meth:`initialize`; peaks use every step).

        Raises
        ------
        InputError
            ``t_end`` before the current time, NaN forces, mismatched sizes,
            wheels outside the allowed part of the window. The state is then
            unchanged (also when the bad value comes from a callable
            mid-interval).
        """
        t_end = float(t_end)
        if not math.isfinite(t_end):
            raise InputError(f"advance: t_end = {t_end}: must be finite")
        if t_end < self.t - _TOL * self.dt:
            raise InputError(
                f"advance: t_end = {t_end:g} s is before the current time t = {self.t:g} s (time going backwards)"
            )
        if output_every < 1:
            raise InputError(f"advance: output_every = {output_every}: must be >= 1")
        n_total = int(math.floor((t_end - self.t) / self.dt + 1e-6))
        if n_total <= 0:
            return
        t_start, k_start = self.t, self._s.k
        source = load_source(loads, t_start, t_end, self._s.pos, self._s.F)

        saved = self._save()
        try:
            self._s.pending = None
            done = 0
            while done < n_total:
                n = min(CHUNK_STEPS, n_total - done)
                tq: Array = self._s.t0 + (k_start + done + 1 + np.arange(n, dtype=np.float64)) * self.dt
                P, F = source(tq)
                P = np.asarray(P, dtype=float)
                F = np.asarray(F, dtype=float)
                if P.ndim != 2 or P.shape[0] != n or F.shape != P.shape:
                    raise InputError(
                        f"advance: loads gave positions {P.shape} and forces {F.shape}; expected ({n}, n_wheels) each"
                    )
                check_values(P, F, tq, "advance")
                self._run(np.ascontiguousarray(P), np.ascontiguousarray(np.where(np.isfinite(P), F, 0.0)),
                          callback, output_every, "advance")
                done += n
        except BaseException:
            self._restore(saved)
            raise

    def _run(self, P: Array, F: Array, callback: Callable[[Block], None] | None, every: int, what: str) -> None:
        """Step through rows of P, F (S, W), shifting the window between stretches."""
        S = P.shape[0]
        pres = np.isfinite(P)
        any_p = pres.any(axis=1)
        front = np.where(any_p, np.max(np.where(pres, P, -np.inf), axis=1, initial=-np.inf), -np.inf)
        rear = np.where(any_p, np.min(np.where(pres, P, np.inf), axis=1, initial=np.inf), np.inf)
        win = self._window
        s = 0
        while s < S:
            p = self._s.placement
            viol = np.nonzero(win.outside(p, front[s:], rear[s:]))[0]
            e = S if viol.size == 0 else s + int(viol[0])
            if e == s:
                t = self.time_of_step(self._s.k + 1)
                if not win.follow:
                    win.check_inside(p, float(front[s]), float(rear[s]), what, t)
                q = win.required(p, float(front[s]), float(rear[s]), what, t)
                if q == p:  # pragma: no cover - safety
                    raise InputError(f"{what}: cannot place the window for wheels at {rear[s]:g} .. {front[s]:g} m")
                self._move(q)
                continue
            self._steps(P[s:e], F[s:e], callback, every)
            s = e

    def _steps(self, P: Array, F: Array, callback: Callable[[Block], None] | None, every: int) -> None:
        """The compiled steps for rows of P, F (S, W) with the window in one position."""
        S, W = P.shape
        st = self._s
        N = self.n_sleepers
        first = st.placement.first
        ldofs, lw = load_weights(self._layout, first, P)
        if callback is not None:
            phase = (st.k + 1) % every
            sel = np.arange((every - phase) % every, S, every, dtype=np.int64)
            out = kern.StepOutputs(np.empty((S, W)), np.empty((S, W)), sel, np.empty((sel.size, N)),
                                   np.empty((sel.size, N)), np.empty((sel.size, N)), np.empty((sel.size, N)))
        else:
            sel, none = self._no_output  # nothing recorded: the kernel writes no sleeper rows
            out = kern.StepOutputs(np.empty((S, W)), np.empty((S, W)), sel, none, none, none, none)
        kout = kern.run_steps(kern.StepArgs(st.op.kernel, self._step_state(), kern.StepLoads(ldofs, lw, F), out))
        assert kout == sel.size
        k0 = st.k
        st.k += S
        st.prev_dofs = ldofs[-1].copy()
        st.prev_vals = lw[-1] * np.repeat(F[-1], 4)
        st.pos, st.F = P[-1].copy(), F[-1].copy()
        if callback is not None:
            absent = ~np.isfinite(P[sel])
            callback(Block(
                first_sleeper=first,
                sleeper_x=np.arange(first, first + N, dtype=np.float64) * self.spacing,
                t=st.t0 + (k0 + 1 + sel.astype(np.float64)) * self.dt,
                soil_force=out.force, rail_deflection=out.rail,
                sleeper_displacement=out.sleeper, area_displacement=out.area,
                wheel_positions=P[sel].copy(), wheel_forces=F[sel].copy(),
                wheel_deflection=np.where(absent, np.nan, out.wdefl[sel]),
                wheel_velocity=np.where(absent, np.nan, out.wvel[sel]),
                peak_soil_force=st.pk_force.copy(), peak_rail_deflection=st.pk_rail.copy(),
                peak_wheel_deflection=np.max(np.where(np.isfinite(P), out.wdefl, -np.inf), axis=0),
            ))

    # ------------------------------------------------------------------ two-phase steps (vehicle coupling)

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
            return self._coupling.begin(self._s, P)
        except BaseException:
            self._restore(saved)
            raise

    def finish_step(self, forces_next: ArrayLike) -> None:
        """Complete the step begun with :meth:`begin_step` with the wheel forces [N] at t + dt.

        Raises
        ------
        InputError
            No pending step, NaN forces or a size different from the
            positions given to ``begin_step``; the state is then unchanged.
        """
        self._coupling.finish(self._s, forces_next, self.t + self.dt)

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
        return self._coupling.chunk(self._s, P)

    def coupled_commit(self, steps: int, forces_last: ArrayLike) -> None:
        """Record that a kernel advanced ``steps`` rows of the last :meth:`coupled_chunk`.

        ``forces_last``: the wheel forces [N] of the last step made (the
        loads f_n of the next step).
        """
        self._coupling.commit(self._s, steps, forces_last)

    # ------------------------------------------------------------------ stamped frames (online model)

    def advance_frames(
        self, loads: FrameLoads, max_force: float = math.inf, max_displacement: float = math.inf
    ) -> FrameResponses:
        """Advance through R frames of wheel loads; the response at each frame's step.

        See :meth:`clm_core.solver.frames.FrameRunner.advance` (``loads``: a
        :class:`clm_core.solver._frame_kernel.FrameLoads`, response steps
        counted since :meth:`initialize`; ``max_force`` [N] and
        ``max_displacement`` [m] bound a response). When a frame fails the
        state is that after the frame before it.

        Raises
        ------
        InputError
            A response step before the current step (time going backwards).
        """
        return self._frames.advance(self._s, loads, max_force, max_displacement)

    # ------------------------------------------------------------------ outputs

    def _sleeper_fields(self) -> tuple[Array, Array, Array, Array]:
        """Soil force [N], rail deflection above, sleeper and contact-area displacement [m] per sleeper."""
        return self._s.sleeper_fields(self._layout)

    def snapshot(self) -> Snapshot:
        """The current state (copies), see :class:`Snapshot`."""
        fs, rw, zs, xa = self._sleeper_fields()
        s = self._s
        P = s.pos.copy()
        if P.size:
            dofs, wts = load_weights(self._layout, s.placement.first, P[None, :])
            W = P.size
            wd = (wts[0] * s.u[dofs[0]]).reshape(W, 4).sum(axis=1)
            wv = (wts[0] * s.v[dofs[0]]).reshape(W, 4).sum(axis=1)
            absent = ~np.isfinite(P)
            wd[absent] = np.nan
            wv[absent] = np.nan
        else:
            wd = np.zeros(0)
            wv = np.zeros(0)
        idx = self._window.sleeper_index(s.placement)
        return Snapshot(
            t=self.t, sleeper_index=idx, sleeper_x=idx.astype(np.float64) * self.spacing, soil_force=fs,
            rail_deflection=rw, sleeper_displacement=zs, area_displacement=xa,
            wheel_positions=P, wheel_forces=s.F.copy(), wheel_deflection=wd, wheel_velocity=wv,
        )

    def block(self) -> Block:
        """The current state as a one-row :class:`Block` (e.g. the initial row of a recorded history)."""
        s = self._s
        return Block.of_snapshot(self.snapshot(), s.placement.first, s.pk_force, s.pk_rail)

    def state_vectors(self) -> tuple[Array, Array]:
        """Copies of the window's displacement [m] and velocity [m/s] vectors (DOF order of :attr:`system`)."""
        return self._s.u.copy(), self._s.v.copy()


__all__ = ["CHUNK_STEPS", "TrackSimulator"]
