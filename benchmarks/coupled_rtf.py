"""Benchmark: real-time factor of the coupled vehicle–track simulation and of the track alone.

One vehicle (the Thalys power car preset, 4 wheels) on the Mevergnies CLM
track, a 61-sleeper window, dt = 1e-4 s, 300 km/h, FRA class 5 profile
(seed 1). In the same run:

- ``coupled``: :class:`clm_core.vehicle.coupled.CoupledSimulation` with
  ``engine='stream'``, the compiled coupled kernel (vehicle Newmark + Hertz
  contact by Newton + the track step, many steps per call between window
  shifts, :mod:`clm_core.vehicle._coupled_kernel`), the stepping loop only;
- ``coupled_per_step``: the same run with ``engine='stream-python'`` (the
  track's ``begin_step`` / ``finish_step`` and the vehicle's compiled
  contact step called from Python at every step), and the largest relative
  difference of the wheel loads between the two paths;
- ``track_advance``: the track alone under the 4 static wheel loads moving
  at the same speed, :meth:`TrackSimulator.advance` (compiled multi-step path);
- ``track_two_phase``: the track alone stepped through ``begin_step`` /
  ``finish_step`` from Python (the calls the per-step coupling makes).

Real-time factor = simulated time / wall-clock time (> 1: faster than real
time). Usage: python benchmarks/coupled_rtf.py [--duration 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from clm_core.params import load_model
from clm_core.solver import TrackSimulator
from clm_core.vehicle.coupled import CoupledSimulation
from clm_core.vehicle.irregularity import Irregularity, random_profile
from clm_core.vehicle.presets import load_vehicle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=2.0, help="simulated time [s] (default 2)")
    ap.add_argument("--speed", type=float, default=83.3, help="speed [m/s] (default 83.3)")
    ap.add_argument("--dt", type=float, default=1e-4)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()

    params = load_model("mevergnies", "mevergnies", "clm")
    train = load_vehicle("thalys").train(1)
    V, dt, T = a.speed, a.dt, a.duration
    x_start = 20.0
    prof = random_profile("fra5", x_start - 20.0, V * T + 25.0, seed=1)
    irr = Irregularity(profile=prof, lead_in=5.0)

    # warm-up (numba compilation or cache load of the contact, coupled and track kernels)
    for engine in ("stream", "stream-python"):
        CoupledSimulation(train, params, V, dt, irr, x_start=x_start, n_sleepers=61, engine=engine).run(0.01)

    sim = CoupledSimulation(train, params, V, dt, irr, x_start=x_start, n_sleepers=61)
    res = sim.run(T)
    coupled = res.real_time_factor
    res_py = CoupledSimulation(train, params, V, dt, irr, x_start=x_start, n_sleepers=61,
                               engine="stream-python").run(T)
    coupled_py = res_py.real_time_factor
    max_rel_diff = float(np.max(np.abs(res.wheel_load - res_py.wheel_load)) / np.max(np.abs(res_py.wheel_load)))

    n = int(round(T / dt))
    x0 = x_start - train.wheel_offset
    P0 = train.static_wheel_loads()
    ts = TrackSimulator(params, dt, 61, start_position=float(x0.mean()))
    ts.initialize(x0, P0)
    tic = time.perf_counter()
    ts.advance(n * dt, (x0 + V * n * dt, P0))
    track_advance = T / (time.perf_counter() - tic)

    ts = TrackSimulator(params, dt, 61, start_position=float(x0.mean()))
    ts.initialize(x0, P0)
    tic = time.perf_counter()
    for k in range(1, n + 1):
        ts.begin_step(x0 + V * k * dt)
        ts.finish_step(P0)
    track_two_phase = T / (time.perf_counter() - tic)

    n_steps = n
    out = {
        "simulated_time_s": T,
        "dt_s": dt,
        "speed_m_per_s": V,
        "window_sleepers": sim.n_sleepers,
        "wheels": train.n_wheels,
        "real_time_factor_coupled": coupled,
        "real_time_factor_coupled_per_step": coupled_py,
        "speed_up_compiled_over_per_step": coupled / coupled_py,
        "real_time_factor_track_advance": track_advance,
        "real_time_factor_track_two_phase": track_two_phase,
        "coupled_cost_over_track_advance": track_advance / coupled,
        "us_per_step_coupled": 1e6 * res.wall_time / n_steps,
        "us_per_step_coupled_per_step": 1e6 * res_py.wall_time / n_steps,
        "us_per_step_track_advance": 1e6 * T / track_advance / n_steps,
        "us_per_step_track_two_phase": 1e6 * T / track_two_phase / n_steps,
        "max_rel_diff_wheel_load_compiled_vs_per_step": max_rel_diff,
        "newton_iterations_mean": float(np.mean(res.newton_iterations[1:])),
    }
    if a.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"coupled vehicle-track, compiled (stream):       real-time factor {coupled:.3f}  "
              f"({out['us_per_step_coupled']:.1f} us/step, {out['newton_iterations_mean']:.2f} Newton iterations/step)")
        print(f"coupled vehicle-track, per step (stream-python): real-time factor {coupled_py:.3f}  "
              f"({out['us_per_step_coupled_per_step']:.1f} us/step)")
        print(f"  compiled / per step: {out['speed_up_compiled_over_per_step']:.1f}x faster; "
              f"max relative difference of the wheel loads {max_rel_diff:.1e}")
        print(f"track alone, advance():                          real-time factor {track_advance:.3f}  "
              f"({out['us_per_step_track_advance']:.1f} us/step; coupled costs "
              f"{out['coupled_cost_over_track_advance']:.2f}x)")
        print(f"track alone, begin/finish_step:                  real-time factor {track_two_phase:.3f}  "
              f"({out['us_per_step_track_two_phase']:.1f} us/step)")
        print(f"({T:g} s simulated, dt = {dt:g} s, {sim.n_sleepers} sleepers, {train.n_wheels} wheels, {V:g} m/s)")

if __name__ == "__main__":
    main()
