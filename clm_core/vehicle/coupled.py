"""Monolithic vehicle–track simulation with nonlinear Hertzian contact.

One time step (t -> t + dt) couples three implicit pieces:

1. the vehicle, average-acceleration Newmark (:class:`VehicleNewmark`):
   wheel displacements z = z_free - H P, affine in the contact forces P;
2. the track, the streaming engine's two-phase step
   (:meth:`clm_core.solver.TrackSimulator.begin_step`): rail deflection
   under the wheels w = w_free + G P, also average-acceleration Newmark;
3. Hertz's law at each wheel, P = C_H max(delta, 0)^1.5 with
   delta = z - w - r(x), solved for the n_w forces by Newton's method
   (:func:`clm_core.vehicle.contact.solve_contact`).

Then both subsystems are advanced with the converged forces
(:meth:`VehicleNewmark.commit`, ``TrackSimulator.finish_step``). The stiff
contact spring (linearised stiffness ~2e9 N/m against a wheel mass of
1000 kg: ~230 Hz with the rail mass, several kHz on its own) is inside the
implicit solution, so it does not limit the time step the way it would an
explicit scheme or a staggered (force-lagged) coupling; dt is chosen for the
frequencies one wants to resolve (1e-4 s: up to ~1 kHz with < 3 % period
error, see :mod:`clm_core.newmark`).

With ``engine='stream'`` the steps run in a compiled kernel
(:mod:`clm_core.vehicle._coupled_kernel`), many per call between window
shifts, with the track's wheel compliance G from cached columns of the
window's K_eff^-1 instead of n_w solves per step; ``engine='stream-python'``
makes the same steps one by one through the calls above (the same results to
rounding; a reference, and the path of any other engine).

Positions: the first wheel is at ``x_start`` at t = 0 and the train runs
towards +x at constant speed; wheel i is at x_start + V t - offset_i.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.errors import InputError, ParameterError
from clm_core.params import ModelParams
from clm_core.peaks import MARGIN_BAYS, PeakWindow, masked_max, masked_min, peak_window
from clm_core.vehicle.contact import hertz_constant, static_compression
from clm_core.vehicle.irregularity import Irregularity
from clm_core.vehicle.multibody import Train, VehicleNewmark

Engine = Literal["stream", "stream-python", "fixed"]


class TrackEngine(Protocol):
    """What the coupled simulation needs from a track engine (TrackSimulator's API)."""

    @property
    def t(self) -> float: ...

    @property
    def dt(self) -> float: ...

    def initialize(self, positions: Any, forces: Any, t0: float = 0.0, state: Any = "static") -> None: ...

    def begin_step(self, positions_next: Any) -> tuple[Array, Array, Array]: ...

    def finish_step(self, forces_next: Any) -> None: ...

    def snapshot(self) -> Any: ...

    def peaks(self) -> tuple[Any, Any, Any]: ...


@dataclass(frozen=True)
class CoupledResult:
    """Time histories of a coupled run (plain immutable data).

    Attributes
    ----------
    t : (n_t,) array
        Times [s] (t[0] = 0, the static start).
    wheel_position : (n_t, n_w) array
        Wheel positions along the track [m].
    wheel_load : (n_t, n_w) array
        Contact force of each wheel on the rail [N] (the wheel load, per wheel
        = half an axle load; positive downwards on the rail).
    static_wheel_load : (n_w,) array
        Static wheel loads [N].
    compression : (n_t, n_w) array
        Hertz compression delta [m] (negative: contact lost).
    wheel_displacement : (n_t, n_w) array
        Axle-centre displacement [m].
    rail_deflection : (n_t, n_w) array
        Rail deflection under each wheel [m].
    irregularity : (n_t, n_w) array
        r under each wheel [m] (positive downwards).
    vehicle_energy : (n_t,) array
        Vehicle vibration energy about its static state [J].
    t_out : (n_o,) array
        Times of the track snapshots [s].
    sleeper_index : (n_s,) int array
        Global sleeper indices covered by the snapshots.
    sleeper_x : (n_s,) array
        Their positions [m].
    soil_force : (n_o, n_s) array
        Ballast force on the soil under each sleeper [N] (NaN when the sleeper
        is outside the engine's window at that time).
    sleeper_rail_deflection : (n_o, n_s) array
        Rail deflection above each sleeper [m] (NaN outside the window).
    newton_iterations : (n_t,) int array
        Newton iterations per step.
    wall_time : float
        Wall-clock time of the time stepping [s].
    peak_soil_force : (n_s,) array
        Largest soil force of each sleeper of ``sleeper_index`` over every
        step while the engine's window held it [N] (NaN: never held).
    meta : dict
        Run settings (speed, dt, engine, Hertz constants, ...).
    """

    t: Array
    wheel_position: Array
    wheel_load: Array
    static_wheel_load: Array
    compression: Array
    wheel_displacement: Array
    rail_deflection: Array
    irregularity: Array
    vehicle_energy: Array
    t_out: Array
    sleeper_index: NDArray[np.int64]
    sleeper_x: Array
    soil_force: Array
    sleeper_rail_deflection: Array
    newton_iterations: NDArray[np.int64]
    wall_time: float
    peak_soil_force: Array = field(default_factory=lambda: np.zeros(0))
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def simulated_time(self) -> float:
        """Simulated duration [s]."""
        return float(self.t[-1] - self.t[0])

    @property
    def real_time_factor(self) -> float:
        """Simulated time over wall-clock time (> 1: faster than real time)."""
        return self.simulated_time / self.wall_time if self.wall_time > 0 else math.inf

    def contact_losses(self, t_from: float = 0.0) -> tuple[int, int]:
        """(steps with a wheel out of contact, loss events) summed over the wheels, for t >= t_from."""
        sel = self.t >= t_from
        off = self.wheel_load[sel] <= 0.0
        events = int(np.sum(off[1:] & ~off[:-1])) + int(np.sum(off[0]))
        return int(off.sum()), events

    def peak_window(self, margin_bays: int = MARGIN_BAYS) -> PeakWindow:
        """The part of the run the reported peaks come from (:mod:`clm_core.peaks`)."""
        d = float(self.sleeper_x[1] - self.sleeper_x[0]) if self.sleeper_x.size > 1 else 1.0
        return peak_window(float(self.wheel_position[0].max()), float(self.wheel_position[-1].min()), d, margin_bays)

    def peak_soil_force_passed(self, margin_bays: int = MARGIN_BAYS) -> tuple[float, str, int]:
        """Peak soil force [N] over the sleepers every wheel has passed, away from the start and end.

        Sleepers at least ``margin_bays`` bays ahead of the first wheel's
        start position and behind the last wheel's final position (the rule of
        :mod:`clm_core.peaks`, as in ``clm simulate``); all sleepers if none
        qualifies. Returns (peak, description of the basis, global index of the sleeper).
        """
        window = self.peak_window(margin_bays)
        passed = window.sleepers(self.sleeper_x)
        value, i, fallback = masked_max(self.peak_soil_force, passed)
        if i < 0:
            return float("nan"), "no soil force recorded", -1
        if fallback:
            basis = "every sleeper the window held (no sleeper fully passed: run too short)"
        else:
            sel = passed & np.isfinite(self.peak_soil_force)
            basis = (f"sleepers {int(self.sleeper_index[sel][0])}..{int(self.sleeper_index[sel][-1])}: passed by "
                     f"every wheel, at least {margin_bays} bays from the wheels' start and end positions")
        return value, basis, int(self.sleeper_index[i])

    def summary(self, t_from: float | None = None) -> dict[str, Any]:
        """Peak and RMS wheel load, peak soil force, contact losses, real-time factor.

        Contact losses: ``contact_loss_steps`` (wheel-steps with P = 0, summed
        over the wheels; depends on dt), ``contact_loss_time_s`` (the same in
        wheel-seconds) and ``contact_loss_events`` (contact-to-flight
        transitions).

        Statistics are over t >= ``t_from`` [s] (default: ``meta['stats_from']``,
        which skips the start transient). RMS wheel load is the RMS of the
        dynamic part P - P_static over all wheels; ``rms_wheel_load`` is the RMS
        of P itself.
        """
        tf = float(self.meta.get("stats_from", 0.0) if t_from is None else t_from)
        sel = self.t >= tf
        P = self.wheel_load[sel]
        dP = P - self.static_wheel_load[None, :]
        steps, events = self.contact_losses(tf)
        peak_soil, basis, g_peak = self.peak_soil_force_passed()
        # peaks of the wheel loads: after the statistics start and after the loads travelled the margin
        window = self.peak_window()
        admitted = sel & window.instants(self.wheel_position.max(axis=1))
        rows = np.repeat(admitted[:, None], self.wheel_load.shape[1], axis=1)
        p_max, _, fb_max = masked_max(self.wheel_load, rows)
        p_min, _, _ = masked_min(self.wheel_load, rows)
        passed = window.sleepers(self.sleeper_x) & np.isfinite(self.peak_soil_force)
        # rail deflection: under the wheels at the admitted instants, above the passed sleepers (as clm simulate)
        w_wheel, _, fb_wheel = masked_max(self.rail_deflection, rows)
        w_sleeper, _, fb_sleeper = masked_max(self.sleeper_rail_deflection, passed[None, :])
        exclusion = window.describe(self.sleeper_index, passed,
                                    instants_from_s=float(self.t[admitted][0]) if admitted.any() else None,
                                    sleepers_fallback=not passed.any() or fb_sleeper,
                                    instants_fallback=fb_max or fb_wheel)
        exclusion["applies_to"] = ["peak_wheel_load_N", "min_wheel_load_N", "peak_sleeper_soil_force_N",
                                   "peak_sleeper_index", "max_rail_deflection_m", "max_rail_deflection_under_wheel_m",
                                   "max_rail_deflection_above_sleeper_m"]
        exclusion["statistics_from_s"] = tf
        exclusion["whole_run"] = {"peak_wheel_load_N": float(self.wheel_load.max()),
                                  "min_wheel_load_N": float(self.wheel_load.min()),
                                  "peak_sleeper_soil_force_N": float(np.nanmax(self.peak_soil_force))
                                  if np.isfinite(self.peak_soil_force).any() else None,
                                  "max_rail_deflection_m": float(np.nanmax([np.nanmax(self.rail_deflection),
                                                                            _nanmax(self.sleeper_rail_deflection)]))}
        return {
            "peak_wheel_load_N": p_max,
            "min_wheel_load_N": p_min,
            "rms_wheel_load_N": float(np.sqrt(np.mean(P**2))),
            "rms_dynamic_wheel_load_N": float(np.sqrt(np.mean(dP**2))),
            "static_wheel_load_N": [float(v) for v in self.static_wheel_load],
            "peak_sleeper_soil_force_N": peak_soil,
            "peak_sleeper_index": g_peak,
            "peak_basis": basis,
            "max_rail_deflection_m": float(np.nanmax([w_wheel, w_sleeper])),
            "max_rail_deflection_under_wheel_m": w_wheel,
            "max_rail_deflection_above_sleeper_m": w_sleeper,
            "peak_exclusion": exclusion,
            "contact_loss_steps": steps,
            "contact_loss_events": events,
            "contact_loss_time_s": steps * float(self.meta.get("dt", 0.0)),
            "real_time_factor": self.real_time_factor,
            "wall_time_s": self.wall_time,
            "simulated_time_s": self.simulated_time,
            "stats_from_s": tf,
            "newton_iterations_max": int(self.newton_iterations.max()),
            "newton_iterations_mean": float(self.newton_iterations[1:].mean()),
        }


def _nanmax(a: Array) -> float:
    """Largest finite value of ``a`` (NaN if none)."""
    return float(np.nanmax(a)) if np.isfinite(a).any() else math.nan


def window_size(span_bays: float, lead: int | None = None) -> int:
    """Smallest window (>= 61 sleepers) of the streaming engine that holds wheels spanning ``span_bays`` bays.

    The engine keeps ``lead`` sleepers (default a third of the window) ahead
    of the first wheel and max(2, min(10, n // 6)) behind the last one, and
    places the window on whole sleepers: the zone between them must hold the
    span plus one bay (wheels anywhere within a bay), else a train whose span
    is within a bay of the zone is refused at some alignments (the 10-car
    Thalys, 325.1 bays, in 505 sleepers: 326).
    """
    n = 61
    while True:
        ld = n // 3 if lead is None else lead
        if n - 1 - ld - max(2, min(10, n // 6)) >= span_bays + 1:
            return n
        n += 2


class CoupledSimulation:
    """Vehicle–track coupled time integration (monolithic per step, Newton on the contact forces).

    Parameters
    ----------
    train : Train
        Half train on the rail (:func:`clm_core.vehicle.multibody.build_train`).
    params : ModelParams
        Track and soil.
    speed : float
        Constant train speed V [m/s] (>= 0; 0 is a vehicle at rest).
    dt : float
        Time step [s].
    irregularity : Irregularity, optional
        Rail profile, isolated defects and wheel flats (default: smooth).
    x_start : float
        Position of the first wheel at t = 0 [m].
    engine : {'stream', 'stream-python', 'fixed'}
        ``'stream'``: :class:`clm_core.solver.TrackSimulator`, the moving
        window (production), stepped by the compiled coupled kernel
        (:mod:`clm_core.vehicle._coupled_kernel`, many steps per call between
        window shifts). ``'stream-python'``: the same engine and scheme
        stepped per step from Python through ``begin_step`` / ``finish_step``
        (the generic path of any engine; same results to rounding, ~10x
        slower; kept as the reference of the compiled path).
        ``'fixed'``: :class:`FixedTrack`, a long fixed track (reference, for
        validation).
    n_sleepers : int, optional
        Window size of the streaming engine; default the smallest >= 61 that
        holds the wheelbase with ``lead_sleepers`` ahead and the engine's
        margin (10 sleepers) behind (:func:`window_size`).
    lead_sleepers : int, optional
        Sleepers kept ahead of the first wheel (engine default: a third of the window).
    elements_per_bay : int
        Rail elements per sleeper bay.
    hertz : float or None
        Hertz constant C_H [N/m^1.5] for all wheels; default from the vehicle
        data, else :func:`hertz_constant` of the wheel radius on a UIC60 head.
    snapshot_every : int, optional
        Track snapshots (soil forces, rail above sleepers) every this many
        steps; default ~ every 0.5 ms.
    duration_hint : float, optional
        Planned duration [s]; sizes the fixed engine's track.
    track_factory : callable, optional
        ``factory(params, dt, positions0, n_sleepers, elements_per_bay) -> engine``
        to use another engine with the same API.
    """

    def __init__(
        self,
        train: Train,
        params: ModelParams,
        speed: float,
        dt: float = 1.0e-4,
        irregularity: Irregularity | None = None,
        x_start: float = 0.0,
        engine: Engine = "stream",
        n_sleepers: int | None = None,
        elements_per_bay: int = 2,
        lead_sleepers: int | None = None,
        hertz: float | None = None,
        snapshot_every: int | None = None,
        duration_hint: float = 2.0,
        track_factory: Callable[..., TrackEngine] | None = None,
    ) -> None:
        if not (math.isfinite(speed) and speed >= 0):
            raise ParameterError(f"speed = {speed} m/s: must be a finite value >= 0")
        if not (math.isfinite(dt) and 0 < dt <= 1e-2):
            raise ParameterError(f"dt = {dt} s: must be finite, > 0 and <= 0.01 s")
        if not math.isfinite(x_start):
            raise ParameterError(f"x_start = {x_start}: must be finite")
        if engine not in ("stream", "stream-python", "fixed"):
            raise ParameterError(f"engine = {engine!r}: one of 'stream', 'stream-python', 'fixed'")
        self.train = train
        self.params = params
        self.speed = float(speed)
        self.dt = float(dt)
        self.irregularity = irregularity or Irregularity()
        self.x_start = float(x_start)
        self.engine = engine
        self.elements_per_bay = int(elements_per_bay)
        self.lead_sleepers = None if lead_sleepers is None else int(lead_sleepers)
        span = train.wheelbase / params.track.spacing
        self.n_sleepers = window_size(span, self.lead_sleepers) if n_sleepers is None else int(n_sleepers)
        ld = self.n_sleepers // 3 if self.lead_sleepers is None else self.lead_sleepers
        margin = max(2, min(10, self.n_sleepers // 6))
        if self.n_sleepers - 1 - ld - margin < span + 1:
            raise ParameterError(
                f"n_sleepers = {self.n_sleepers}: the window must hold the wheelbase ({train.wheelbase:g} m = "
                f"{span:.1f} bays) plus lead_sleepers = {ld} ahead and {margin} behind: use at least "
                f"{window_size(span, self.lead_sleepers)}"
            )
        if hertz is not None:
            ch = np.full(train.n_wheels, float(hertz))
        else:
            ch = np.array([
                train.hertz_constant[i] if np.isfinite(train.hertz_constant[i])
                else hertz_constant(float(train.wheel_radius[i]))
                for i in range(train.n_wheels)
            ])
        if not np.all(np.isfinite(ch) & (ch > 0)):
            raise ParameterError(f"hertz = {hertz}: Hertz constants must be finite and > 0 N/m^1.5")
        self.hertz = ch
        self.snapshot_every = (
            max(1, int(round(5e-4 / self.dt))) if snapshot_every is None else max(1, int(snapshot_every))
        )
        self.duration_hint = float(duration_hint)
        self._factory = track_factory

    # ---------------------------------------------------------------- set-up
    def wheel_positions(self, t: Array) -> Array:
        """Wheel positions [m] at times t (n_t,) -> (n_t, n_w)."""
        return self.x_start + self.speed * np.asarray(t, dtype=float)[:, None] - self.train.wheel_offset[None, :]

    def _make_track(self, x0: Array, duration: float) -> TrackEngine:
        if self._factory is not None:
            return self._factory(self.params, self.dt, x0, self.n_sleepers, self.elements_per_bay)
        if self.engine == "fixed":
            from clm_core.vehicle.reference_track import FixedTrack

            return FixedTrack(
                self.params, self.dt, float(x0.min()), float(x0.max() + self.speed * duration),
                self.elements_per_bay,
            )
        try:
            from clm_core.solver import TrackSimulator
        except ImportError as exc:  # pragma: no cover - depends on the tree
            raise InputError(
                "engine = 'stream' needs clm_core.solver.TrackSimulator, which is not available "
                f"({exc}); use engine = 'fixed'"
            ) from None
        return TrackSimulator(
            self.params, self.dt, n_sleepers=self.n_sleepers, elements_per_bay=self.elements_per_bay,
            start_position=float(0.5 * (x0.min() + x0.max())), lead_sleepers=self.lead_sleepers, follow=True,
        )

    # ---------------------------------------------------------------- run
    def run(self, duration: float, progress: bool = False) -> CoupledResult:
        """Integrate from the static state for ``duration`` seconds.

        Parameters
        ----------
        duration : float
            Simulated time [s] (> 0).
        progress : bool
            Show a progress bar (:class:`clm_core.progress.Progress`: on a terminal only).

        Returns
        -------
        CoupledResult
        """
        if not (math.isfinite(duration) and duration > 0):
            raise ParameterError(f"duration = {duration} s: must be a finite value > 0")
        n_steps = int(round(duration / self.dt))
        if n_steps < 1:
            raise ParameterError(f"duration = {duration} s is shorter than one step dt = {self.dt} s")
        tr = self.train
        nw = tr.n_wheels
        t = np.asarray(np.arange(n_steps + 1) * self.dt, dtype=float)
        X = self.wheel_positions(t)
        R = self.irregularity.wheel_irregularity(X, X[0], tr.wheel_radius)

        track = self._make_track(X[0], duration)
        P0 = tr.static_wheel_loads()
        track.initialize(X[0], P0, t0=0.0, state="static")
        snap = track.snapshot()
        w0 = np.asarray(snap.wheel_deflection, dtype=float)
        delta0 = static_compression(P0, self.hertz)
        u0 = tr.static_state(w0 + R[0] + delta0)
        veh = VehicleNewmark(tr, self.dt)
        veh.set_state(u0, None, P0)
        wd = tr.wheel_dof

        load = np.empty((n_steps + 1, nw))
        comp = np.empty((n_steps + 1, nw))
        zw = np.empty((n_steps + 1, nw))
        wr = np.empty((n_steps + 1, nw))
        energy = np.empty(n_steps + 1)
        iters = np.zeros(n_steps + 1, dtype=np.int64)
        load[0], comp[0], zw[0], wr[0] = P0, delta0, u0[wd], w0
        energy[0] = 0.0
        snaps: list[tuple[float, NDArray[np.int64], Array, Array, Array]] = []
        snaps.append(self._take(snap))
        peaks: dict[int, float] = {}
        self._merge_peaks(track, peaks)
        M, K = tr.M, tr.K

        delta = delta0.copy()
        bar = None
        if progress:
            from clm_core.progress import Progress

            bar = Progress(n_steps, "clm simulate --vehicle", unit="step")
        compiled = self.engine == "stream" and self._factory is None
        t_wall = time.perf_counter()
        if compiled:
            self._run_compiled(track, veh, u0, X, R, delta, load, comp, zw, wr, energy, iters, snaps, peaks, bar)
        else:
            for n in range(1, n_steps + 1):
                w_free, _v_free, G = track.begin_step(X[n])
                delta, P, it = veh.step_with_contact(w_free, G, R[n], self.hertz, delta)
                track.finish_step(P)
                load[n], comp[n], iters[n] = P, delta, it
                zw[n] = veh.u[wd]
                wr[n] = w_free + G @ P
                du = veh.u - u0
                energy[n] = 0.5 * (veh.v @ M @ veh.v + du @ K @ du)
                if n % self.snapshot_every == 0:
                    snaps.append(self._take(track.snapshot()))
                    self._merge_peaks(track, peaks)
                if bar is not None and n % 200 == 0:
                    bar.update(200)
        wall = time.perf_counter() - t_wall
        if bar is not None:
            bar.close()
        if not np.all(np.isfinite(load)):
            raise InputError("coupled run produced non-finite wheel loads; reduce dt or check the parameters")

        self._merge_peaks(track, peaks)
        t_out, sidx, sx, sf, srd = self._assemble_snapshots(snaps, peaks)
        pk = np.array([peaks.get(int(g), np.nan) for g in sidx])
        stats_from = self._stats_from(duration)
        meta: dict[str, Any] = {
            "speed": self.speed, "dt": self.dt, "duration": duration, "engine": self.engine,
            "n_sleepers": self.n_sleepers, "elements_per_bay": self.elements_per_bay,
            "hertz_constant": self.hertz.tolist(), "x_start": self.x_start,
            "wheel_offset": tr.wheel_offset.tolist(), "lead_in": self.irregularity.lead_in,
            "stats_from": stats_from, "snapshot_every": self.snapshot_every,
            "weight_per_rail": tr.weight_per_rail, "model": self.params.name,
        }
        return CoupledResult(
            t=t, wheel_position=X, wheel_load=load, static_wheel_load=P0, compression=comp,
            wheel_displacement=zw, rail_deflection=wr, irregularity=R, vehicle_energy=energy,
            t_out=t_out, sleeper_index=sidx, sleeper_x=sx, soil_force=sf, sleeper_rail_deflection=srd,
            newton_iterations=iters, wall_time=wall, peak_soil_force=pk, meta=meta,
        )

    def _run_compiled(
        self, track: Any, veh: VehicleNewmark, u0: Array, X: Array, R: Array, delta: Array,
        load: Array, comp: Array, zw: Array, wr: Array, energy: Array, iters: NDArray[np.int64],
        snaps: list[tuple[float, NDArray[np.int64], Array, Array, Array]], peaks: dict[int, float], bar: Any,
    ) -> None:
        """Steps 1 .. n_steps with the compiled coupled kernel, one call per stretch between window shifts.

        The same scheme, window shifts, outputs and peak bookkeeping as the
        per-step loop of :meth:`run` (``engine='stream-python'``): snapshots
        every ``snapshot_every`` steps and the soil-force peaks merged at
        snapshot steps.
        """
        from clm_core.solver import CHUNK_STEPS
        from clm_core.vehicle import _coupled_kernel

        coupled_steps: Callable[..., tuple[int, int, int, float]] = _coupled_kernel.coupled_steps

        tr = self.train
        n_steps = X.shape[0] - 1
        dt = self.dt
        every = self.snapshot_every
        tol, maxit = 1e-14, 50
        f64 = np.float64
        veh_args = (
            veh._Kinv, veh._KinvB, veh.H, np.ascontiguousarray(tr.M, dtype=f64),
            np.ascontiguousarray(tr.C, dtype=f64), np.ascontiguousarray(tr.K, dtype=f64),
            np.ascontiguousarray(tr.gravity_force, dtype=f64), np.ascontiguousarray(tr.wheel_dof, dtype=np.int64),
            veh.u, veh.v, veh.a, np.ascontiguousarray(u0, dtype=f64), dt,
        )
        X = np.ascontiguousarray(X, dtype=f64)
        R = np.ascontiguousarray(R, dtype=f64)
        ch = np.ascontiguousarray(self.hertz, dtype=f64)
        N = int(track.n_sleepers)
        cap = CHUNK_STEPS // every + 2
        step_buf = np.empty(cap, dtype=np.int64)
        pk_buf = np.empty(N)
        n = 1
        look = 64  # rows offered per call: about twice the last stretch between shifts (the search is O(rows))
        while n <= n_steps:
            m, targs = track.coupled_chunk(X[n : min(n_steps + 1, n + look)])
            look = min(CHUNK_STEPS, 2 * m + 16)
            sf_buf = np.empty((cap, N))
            sr_buf = np.empty((cap, N))
            e = n + m
            done, ns, status, rn = coupled_steps(
                *targs, *veh_args, R[n:e], ch, delta, tol, maxit,
                load[n:e], comp[n:e], zw[n:e], wr[n:e], energy[n:e], iters[n:e],
                n, every, sf_buf, sr_buf, step_buf, pk_buf,
            )
            if done:
                track.coupled_commit(done, load[n + done - 1])
            if ns:
                first = int(track.window[0])
                idx = np.arange(first, first + N, dtype=np.int64)
                x = idx.astype(np.float64) * track.spacing
                for k in range(ns):
                    snaps.append((float(track.time_of_step(int(step_buf[k]))), idx, x, sf_buf[k], sr_buf[k]))
                for g, f in zip(idx.tolist(), pk_buf.tolist()):
                    if f > peaks.get(g, -math.inf):
                        peaks[g] = f
            if bar is not None:
                bar.update(done)
            if status:
                raise InputError(
                    f"contact Newton iteration did not converge in {maxit} iterations (residual {rn:.3g} m); "
                    "check the inputs for NaN or an excessive time step"
                )
            n += done

    def _stats_from(self, duration: float) -> float:
        """Start of the statistics window: after the lead-in, at least 0.05 s, at most a quarter of the run."""
        lead = self.irregularity.lead_in / self.speed if self.speed > 0 else 0.0
        return float(min(0.25 * duration, max(0.05, lead)))

    @staticmethod
    def _merge_peaks(track: Any, peaks: dict[int, float]) -> None:
        idx, pf, _ = track.peaks()
        for g, f in zip(np.asarray(idx).tolist(), np.asarray(pf).tolist()):
            if f > peaks.get(g, -math.inf):
                peaks[g] = f

    @staticmethod
    def _take(s: Any) -> tuple[float, NDArray[np.int64], Array, Array, Array]:
        return (
            float(s.t), np.asarray(s.sleeper_index, dtype=np.int64).copy(), np.asarray(s.sleeper_x, dtype=float).copy(),
            np.asarray(s.soil_force, dtype=float).copy(), np.asarray(s.rail_deflection, dtype=float).copy(),
        )

    def _assemble_snapshots(
        self, snaps: list[tuple[float, NDArray[np.int64], Array, Array, Array]], peaks: dict[int, float]
    ) -> tuple[Array, NDArray[np.int64], Array, Array, Array]:
        lo = min(min(int(s[1].min()) for s in snaps), min(peaks))
        hi = max(max(int(s[1].max()) for s in snaps), max(peaks))
        sidx = np.arange(lo, hi + 1, dtype=np.int64)
        sx = np.asarray(sidx * self.params.track.spacing, dtype=float)
        sf = np.full((len(snaps), sidx.size), np.nan)
        rd = np.full((len(snaps), sidx.size), np.nan)
        for k, (_, idx, _x, f, r) in enumerate(snaps):
            sf[k, idx - lo] = f
            rd[k, idx - lo] = r
        t_out = np.array([s[0] for s in snaps], dtype=float)
        return t_out, sidx, sx, sf, rd


def simulate(
    train: Train,
    params: ModelParams,
    speed: float,
    duration: float,
    dt: float = 1.0e-4,
    irregularity: Irregularity | None = None,
    **kwargs: Any,
) -> CoupledResult:
    """Convenience wrapper: build a :class:`CoupledSimulation` and run it."""
    return CoupledSimulation(train, params, speed, dt, irregularity, duration_hint=duration, **kwargs).run(duration)
