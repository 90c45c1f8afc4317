"""``clm simulate``: moving wheel loads on the track–soil model in the time domain.

Moving constant loads (``--load``, ``--speed``, ``--axles``) or a wheel-load
time history (``--loads-file``, CSV, format in
:meth:`clm_core.stepper.LoadTable.read_csv`) drive the streaming simulator
(:class:`clm_core.stepper.TrackSimulator`, a window of sleepers that follows
the wheels). Writes to ``--out``: ``history.npz``, ``sleepers.csv``,
``wheels.csv``, ``peaks.csv`` (layout in :mod:`clm_core.results`),
``simulate.png`` and ``summary.json``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any

import numpy as np
from tqdm import tqdm

from clm_core.commands._common import add_model_arguments, model_from_args, out_dir, write_json
from clm_core.errors import InputError, ParameterError
from clm_core.results import HistoryWriter, plot_run
from clm_core.stepper import LoadTable, TrackSimulator

#: Sleeper bays kept between the summary's sleepers and the loads at the start and end of the run.
PASSED_MARGIN_BAYS = 5


def register(sub: Any) -> None:
    """Add the ``simulate`` sub-command."""
    p = sub.add_parser(
        "simulate", help="moving wheel loads in the time domain (streaming, moving window)",
        description="Time-domain response of the track-soil model to moving wheel loads: sleeper soil "
        "forces, rail, sleeper and soil deflections, on a simulated window of sleepers that follows the "
        "wheels (Newmark average acceleration).",
    )
    add_model_arguments(p, sleepers_default=61)
    for a in p._actions:  # window size: automatic unless given
        if a.dest == "sleepers":
            a.default = None
            a.help = ("sleepers in the simulated window (default: 61, or more when the axles need it: "
                      "the wheels stay lead sleepers from its front and 10 from its rear)")
    p.add_argument("--load", default="100e3",
                   help="wheel load(s) [N], positive downwards: one value for every axle or one per axle, "
                   "comma-separated (default 100e3)")
    p.add_argument("--speed", type=float, default=30.0, help="speed [m/s] (default 30)")
    p.add_argument("--axles", default="0",
                   help="axle offsets [m] behind the first axle, comma-separated (default 0: one load)")
    p.add_argument("--start", type=float, default=0.0, help="position of the first axle at the start [m] (default 0)")
    p.add_argument("--loads-file", default=None,
                   help="wheel-load time history (CSV: t_s, then x_m, F_N per wheel; empty = wheel not on the "
                   "track); replaces --load/--speed/--axles/--start")
    p.add_argument("--duration", type=float, default=None,
                   help="simulated time [s] (default 1.0, or the span of --loads-file)")
    p.add_argument("--dt", type=float, default=1e-4, help="time step [s] (default 1e-4)")
    p.add_argument("--lead", type=int, default=None,
                   help="sleepers kept ahead of the first axle (default: a third of the window)")
    p.add_argument("--initial", choices=("static", "rest"), default="static",
                   help="initial state: static equilibrium under the initial loads, or at rest (default static)")
    p.add_argument("--output-dt", type=float, default=5e-4,
                   help="interval of the written time histories [s], rounded to whole steps (default 5e-4; "
                   "peaks use every step)")
    p.add_argument("--no-csv", action="store_true", help="write the NPZ only (no sleepers.csv / wheels.csv)")
    p.add_argument("--bag", choices=("mcap", "sqlite3"), default=None,
                   help="also write the time histories as a rosbag2 bag DIR/bag (clm_msgs; needs the ROS layer)")
    p.add_argument("--out", required=True, help="output directory")
    from clm_core.vehicle.cli_support import add_vehicle_arguments

    add_vehicle_arguments(p)
    p.set_defaults(func=run)


def _floats(text: str, what: str) -> np.ndarray:
    try:
        vals = np.array([float(s) for s in str(text).split(",") if s.strip()])
    except ValueError:
        raise InputError(f"{what} {text!r}: expected comma-separated numbers") from None
    if vals.size == 0 or not np.all(np.isfinite(vals)):
        raise InputError(f"{what} {text!r}: expected finite numbers")
    return vals


def _window_size(span_bays: float, lead: int | None) -> int:
    """Smallest window >= 61 holding a wheel set spanning ``span_bays`` with the default lead and margin."""
    n = 61
    while True:
        ld = n // 3 if lead is None else lead
        margin = max(2, min(10, n // 6))
        if n - 1 - ld - margin >= span_bays + 1:  # + 1: wheels anywhere within a bay
            return n
        n += 2


def run(args: argparse.Namespace) -> int:
    """Run the simulation and write the outputs; return 0."""
    t_setup = time.perf_counter()
    params = model_from_args(args)
    if args.vehicle:
        return _run_vehicle(args, params)
    d = params.track.spacing
    dt = float(args.dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ParameterError(f"--dt {args.dt}: must be > 0 s")

    table: LoadTable | None = None
    if args.loads_file:
        table = LoadTable.read_csv(args.loads_file)
        t0 = float(table.t[0])
        duration = float(args.duration) if args.duration is not None else float(table.t[-1] - t0)
        P0, F0 = table(t0)
        span = np.nanmax(table.positions, axis=1) - np.nanmin(table.positions, axis=1)
        span_bays = float(np.nanmax(span)) / d if np.isfinite(span).any() else 0.0
        speed = float("nan")
    else:
        offsets = _floats(args.axles, "--axles")
        loads = _floats(args.load, "--load")
        if loads.size == 1:
            loads = np.full(offsets.size, loads[0])
        if loads.size != offsets.size:
            raise InputError(
                f"--load has {loads.size} values for {offsets.size} axles (--axles {args.axles}); "
                "give one or one per axle"
            )
        speed = float(args.speed)
        if not math.isfinite(speed):
            raise InputError(f"--speed {args.speed}: must be finite")
        duration = 1.0 if args.duration is None else float(args.duration)
        t0 = 0.0
        P0 = float(args.start) - offsets
        F0 = loads
        span_bays = float(offsets.max() - offsets.min()) / d
    if not (math.isfinite(duration) and duration > 0):
        raise InputError(f"--duration {duration}: must be > 0 s")

    n_sleepers = args.sleepers if args.sleepers is not None else _window_size(span_bays, args.lead)
    lead = n_sleepers // 3 if args.lead is None else int(args.lead)
    front0 = float(np.nanmax(P0)) if np.isfinite(P0).any() else float(args.start)
    centre = front0 - ((n_sleepers - 1) / 2 - lead) * d
    sim = TrackSimulator(params, dt, n_sleepers, args.elements_per_bay, start_position=centre, lead_sleepers=lead)
    sim.initialize(P0, F0, t0=t0, state=args.initial)
    initial_max_force = float(sim.snapshot().soil_force.max())

    n_steps = int(math.floor(duration / dt + 1e-6))
    every = max(1, int(round(args.output_dt / dt)))
    W = int(np.size(P0))
    d_out = out_dir(args.out)
    writer = HistoryWriter(d_out, n_steps // every + 2, n_sleepers, W, d, dt, csv=not args.no_csv)
    writer(sim.block())
    setup_time = time.perf_counter() - t_setup

    out_wall = [0.0]

    def record(block: Any) -> None:
        tic = time.perf_counter()
        writer(block)
        out_wall[0] += time.perf_counter() - tic

    seg_steps = max(500, n_steps // 100)
    bar = tqdm(total=n_steps, unit="step", disable=not sys.stderr.isatty(), desc="clm simulate", leave=False)
    wall = 0.0
    done = 0
    try:
        while done < n_steps:
            k = min(seg_steps, n_steps - done)
            t_end = t0 + (done + k) * dt
            if table is not None:
                loads_arg: Any = table
            else:
                loads_arg = (P0 + speed * (t_end - t0), F0)
            tic = time.perf_counter()
            sim.advance(t_end, loads_arg, callback=record, output_every=every)
            wall += time.perf_counter() - tic
            done += k
            bar.update(k)
    finally:
        bar.close()
    sim_time = n_steps * dt
    digest = writer.close({"t0": t0})
    if args.bag:
        _write_bag(d_out, args.bag)

    # summary: peaks over sleepers the loads have fully passed, away from the start
    idx = digest.peak_sleeper_index
    x = idx * d
    P_fin = np.asarray(sim.snapshot().wheel_positions)
    rear_end = float(np.nanmin(P_fin)) if np.isfinite(P_fin).any() else -np.inf
    m = PASSED_MARGIN_BAYS * d
    passed = (x >= front0 + m - 1e-9) & (x <= rear_end - m + 1e-9)
    if passed.any():
        basis = (f"sleepers {int(idx[passed][0])}..{int(idx[passed][-1])}: passed by every load, "
                 f"at least {PASSED_MARGIN_BAYS} bays from the loads' start and end positions")
        sel = passed
    else:
        basis = "every sleeper the window held (the loads did not fully pass any sleeper: run too short)"
        sel = np.ones_like(passed)
    peak_force = float(np.max(digest.peak_soil_force[sel]))
    max_defl = float(max(digest.max_wheel_deflection, np.max(digest.peak_rail_deflection)))
    g_peak = int(idx[sel][np.argmax(digest.peak_soil_force[sel])])
    plot_idx = idx[sel]
    picks = sorted({int(plot_idx[int(round(q * (plot_idx.size - 1)))]) for q in (0.0, 0.33, 0.67, 1.0)})
    plot_run(d_out / "history.npz", digest, picks, d_out / "simulate.png",
             title=f"{params.name or 'parameter file'}: "
             + (f"{W} load(s), {speed:g} m/s" if table is None else f"loads from {args.loads_file}"))
    summary: dict[str, Any] = {
        "peak_sleeper_soil_force_N": peak_force,
        "peak_sleeper_index": g_peak,
        "peak_basis": basis,
        "max_rail_deflection_m": max_defl,
        "max_rail_deflection_under_wheel_m": float(digest.max_wheel_deflection),
        "initial_max_sleeper_soil_force_N": initial_max_force,
        "initial_state": args.initial,
        "real_time_factor": sim_time / (wall - out_wall[0]) if wall > out_wall[0] else None,
        "real_time_factor_with_recording": sim_time / wall if wall > 0 else None,
        "stepping_wall_time_s": wall - out_wall[0],
        "recording_wall_time_s": out_wall[0],
        "setup_time_s": setup_time,
        "simulated_time_s": sim_time,
        "steps": n_steps,
        "dt_s": dt,
        "speed_m_per_s": speed if table is None else None,
        "wheel_loads_N": [float(f) for f in np.atleast_1d(F0)],
        "wheel_start_positions_m": [float(p) for p in np.atleast_1d(P0)],
        "window_sleepers": n_sleepers,
        "lead_sleepers": sim.lead_sleepers,
        "margin_sleepers": sim.margin_sleepers,
        "elements_per_bay": args.elements_per_bay,
        "n_dof_window": sim.n_dof,
        "factorisations": sim.n_factorisations,
        "final_window_first_sleeper": sim.window[0],
        "output_interval_s": every * dt,
        "output_rows": digest.n_rows,
        "model": params.name or "parameter file",
        "soil_model": params.soil.model,
        "n_overrides": len(params.overrides),
    }
    write_json(d_out / "summary.json", summary)
    print(f"peak sleeper soil force {peak_force / 1e3:.2f} kN (sleeper {g_peak}), "
          f"max rail deflection {max_defl * 1e3:.3f} mm, real-time factor {summary['real_time_factor']:.2f} "
          f"-> {d_out}")
    return 0


def _run_vehicle(args: argparse.Namespace, params: Any) -> int:
    """``--vehicle``: the coupled vehicle-track simulation (clm_core.vehicle)."""
    from clm_core.vehicle.cli_support import run_vehicle_simulation

    if args.duration is None:
        args.duration = 2.0
    if args.loads_file:
        raise InputError("--vehicle and --loads-file: give one of them (the vehicle computes its own wheel loads)")
    summary = run_vehicle_simulation(args, params, out_dir(args.out))
    keys = ("peak_wheel_load_N", "rms_wheel_load_N", "peak_sleeper_soil_force_N", "contact_losses", "real_time_factor")
    print("simulate --vehicle: " + ", ".join(f"{k} = {summary[k]}" for k in keys if k in summary) + f" -> {args.out}")
    return 0


def _write_bag(d_out: Any, storage: str) -> None:
    """DIR/bag from DIR/history.npz (clm_ros.history_bag; rosbags only, no middleware)."""
    try:
        from clm_ros.history_bag import write_history_bag
    except ImportError as exc:
        raise InputError(f"--bag needs the ROS layer (clm_ros, clm_msgs): {exc}; run scripts/bootstrap.sh") from None
    from clm_core.results import load_history

    write_history_bag(load_history(d_out / "history.npz"), d_out / "bag", storage)
