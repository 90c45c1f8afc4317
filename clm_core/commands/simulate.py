"""``clm simulate``: moving wheel loads on the track–soil model in the time domain.

Moving constant loads (``--load``, ``--speed``, ``--axles``), a wheel-load
time history (``--loads-file``, CSV, format in
:meth:`clm_core.solver.LoadTable.read_csv`) or a multibody vehicle
(``--vehicle``, :mod:`clm_core.vehicle.run`) drive the streaming simulator
(:class:`clm_core.solver.TrackSimulator`, a window of sleepers that follows
the wheels). Writes to ``--out``: ``history.npz``, ``peaks.csv``, with
``--csv`` also ``sleepers.csv`` and ``wheels.csv`` (layouts in
:mod:`clm_core.outputs.history`), ``simulate.png``, the report figures
(:data:`clm_core.outputs.plots.RUN_FIGURES`), ``summary.json`` and
``index.html`` (:mod:`clm_core.outputs.report_index`). The writing phase shows
a progress bar on a terminal; the printed real-time factors are named: the
computation's (simulated time / stepping wall time) and the command's
(simulated time / wall time of the whole command, writing included). Every option and its default comes from
the run-settings schema (:mod:`clm_core.settings`); the reported peaks exclude
the start-up transient and the sleepers not fully passed
(:mod:`clm_core.peaks`, stated in ``summary.json`` under ``peak_exclusion``).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

from clm_core.commands._common import (
    add_command,
    add_model_arguments,
    add_window_arguments,
    model_from_args,
    output_dir,
    quantity,
)
from clm_core.commands._options import add_overwrite, add_setting
from clm_core.errors import InputError
from clm_core.settings import DURATION

#: Sleeper bays kept between the summary's sleepers and the loads at the start and end of the run
#: (:data:`clm_core.peaks.MARGIN_BAYS`).
PASSED_MARGIN_BAYS = 5


def register(sub: Any) -> None:
    """Add the ``simulate`` sub-command."""
    p = add_command(sub, "simulate", run)
    add_model_arguments(p)
    add_window_arguments(p, automatic_sleepers="(automatic: 61, or more when the axles need it: the wheels stay "
                         "lead sleepers from its front and 10 from its rear)")
    add_setting(p, "lead_sleepers")
    add_setting(p, "load")
    add_setting(p, "speed")
    add_setting(p, "axles")
    add_setting(p, "start")
    add_setting(p, "loads_file")
    add_setting(p, "duration", default=None, note="(with --loads-file: the span of the file)")
    add_setting(p, "dt")
    add_setting(p, "initial_state", note="(moving loads; a vehicle run starts from static equilibrium)")
    add_setting(p, "output_dt")
    p.add_argument("--csv", action="store_true",
                   help="also write the time histories as CSV (sleepers.csv, wheels.csv; about 10x the size and "
                   "writing time of the NPZ, which holds the same numbers)")
    p.add_argument("--no-csv", action="store_true", help="no CSV files (the default; kept for scripts)")
    p.add_argument("--bag", action="store_true",
                   help="also write the time histories as a rosbag2 bag DIR/bag in --storage (clm_msgs; needs "
                   "the ROS layer)")
    add_setting(p, "storage")
    p.add_argument("--out", required=True, help="output directory")
    add_overwrite(p)
    g = p.add_argument_group("vehicle (coupled vehicle-track simulation)")
    add_setting(g, "vehicle", default=None, optional_value=True,
                note="(give --vehicle alone for the default; without --vehicle: constant moving loads)")
    add_setting(g, "cars", default=None, note="(or --train)")
    add_setting(g, "train")
    add_setting(g, "irregularity")
    add_setting(g, "seed")
    add_setting(g, "wavelength_band")
    g.add_argument("--defect", action="append", default=[], metavar="SPEC",
                   help="isolated defect (repeatable): dipped-joint:x=50,depth=0.002[,half_length=1] | "
                   "dipped-joint:x=50,angle=0.01 | joint-step:x=50,height=0.001 | "
                   "wheel-flat:wheel=0,x=20,length=0.05[,depth=..][,shape=rounded|fresh] | "
                   "stiffness:from=30,to=36,kb=20e6 (per-sleeper override)")
    add_setting(g, "lead_in")
    add_setting(g, "hertz")
    add_setting(g, "track_engine")
    r = p.add_argument_group("free-field receivers (two-step method, clm_core.freefield)")
    for name in ("receivers", "receivers_file", "receiver_x", "receiver_soil", "receiver_influence"):
        add_setting(r, name)


def _floats(text: str, what: str) -> Any:
    import numpy as np

    try:
        vals = np.array([float(s) for s in str(text).split(",") if s.strip()])
    except ValueError:
        raise InputError(f"{what} {text!r}: expected comma-separated numbers") from None
    if vals.size == 0 or not np.all(np.isfinite(vals)):
        raise InputError(f"{what} {text!r}: expected finite numbers")
    return vals


def run(args: argparse.Namespace) -> int:
    """Moving wheel loads in the time domain (streaming, moving window).

    Time-domain response of the track-soil model to moving wheel loads: sleeper soil forces, rail, sleeper and soil
    deflections, on a simulated window of sleepers that follows the wheels (Newmark average acceleration). Constant
    moving loads by default, a wheel-load time history with --loads-file, or a multibody vehicle with --vehicle.
    """
    t_setup = time.perf_counter()
    if args.vehicle and args.loads_file:
        raise InputError("--vehicle and --loads-file: give one of them (the vehicle computes its own wheel loads)")
    if args.train and args.cars is not None:
        raise InputError("--train and --cars: give one of them")
    with output_dir(args.out, args.overwrite) as d_out:
        params = model_from_args(args)
        if args.vehicle:
            code = _run_vehicle(args, params, d_out, t_setup)
        else:
            code = _run_loads(args, params, d_out, t_setup)
        from clm_core.outputs.receivers import receivers_for_run

        receivers_for_run(args, params, d_out)
        return code


def _run_loads(args: argparse.Namespace, params: Any, d_out: Path, t_setup: float) -> int:
    import numpy as np

    from clm_core.outputs.history import HistoryWriter
    from clm_core.outputs.plots import RUN_FIGURES
    from clm_core.peaks import BlockPeaks
    from clm_core.progress import Progress
    from clm_core.solver import LoadTable, TrackSimulator

    d = params.track.spacing
    dt = float(args.dt)
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
        duration = float(args.duration) if args.duration is not None else DURATION.to_ros()
        t0 = 0.0
        P0 = float(args.start) - offsets
        F0 = loads
        span_bays = float(offsets.max() - offsets.min()) / d
    if not (math.isfinite(duration) and duration > 0):
        raise InputError(f"--duration {duration}: must be > 0 s")

    from clm_core.vehicle.coupled import window_size

    n_sleepers = args.n_sleepers if args.n_sleepers is not None else window_size(span_bays, args.lead_sleepers)
    lead = n_sleepers // 3 if args.lead_sleepers is None else int(args.lead_sleepers)
    front0 = float(np.nanmax(P0)) if np.isfinite(P0).any() else float(args.start)
    centre = front0 - ((n_sleepers - 1) / 2 - lead) * d
    sim = TrackSimulator(params, dt, n_sleepers, args.elements_per_bay, start_position=centre, lead_sleepers=lead)
    sim.initialize(P0, F0, t0=t0, state=args.initial_state)
    initial_max_force = float(sim.snapshot().soil_force.max())

    n_steps = int(math.floor(duration / dt + 1e-6))
    every = max(1, int(round(args.output_dt / dt)))
    W = int(np.size(P0))
    writer = HistoryWriter(d_out, n_steps // every + 2, n_sleepers, W, d, dt, csv=bool(args.csv))
    wheel_peaks = BlockPeaks(front0, d, PASSED_MARGIN_BAYS, t0)
    first = sim.block()
    writer(first)
    wheel_peaks.add(first.peak_wheel_deflection, _front(first), first.t, first.wheel_deflection)
    setup_time = time.perf_counter() - t_setup

    out_wall = [0.0]

    def record(block: Any) -> None:
        tic = time.perf_counter()
        writer(block)
        wheel_peaks.add(block.peak_wheel_deflection, _front(block), block.t, block.wheel_deflection)
        out_wall[0] += time.perf_counter() - tic

    seg_steps = max(500, n_steps // 100)
    wall = 0.0
    done = 0
    with Progress(n_steps, "clm simulate", unit="step") as bar:
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
    sim_time = n_steps * dt
    t_write = time.perf_counter()
    n_files = 2 + bool(args.csv) + bool(args.bag) + 1 + len(RUN_FIGURES) + 2  # history, peaks; summary, index
    with Progress(n_files, "clm simulate: writing", unit="file") as wbar:
        def wrote(p: Path) -> None:
            wbar.stage(p.name)
            wbar.update(1)

        digest = writer.close({"t0": t0}, on_file=wrote)
        if args.bag:
            _write_bag(d_out, args.storage)
            wrote(d_out / "bag")
        summary = _loads_summary(args, params, d_out, sim, digest, wheel_peaks, table, (P0, F0, front0), speed,
                                 wrote)
        summary.update({
            "initial_max_sleeper_soil_force_N": initial_max_force,
            "real_time_factor": sim_time / (wall - out_wall[0]) if wall > out_wall[0] else None,
            "real_time_factor_with_recording": sim_time / wall if wall > 0 else None,
            "stepping_wall_time_s": wall - out_wall[0],
            "recording_wall_time_s": out_wall[0],
            "setup_time_s": setup_time,
            "simulated_time_s": sim_time,
            "steps": n_steps,
            "dt_s": dt,
            "output_interval_s": every * dt,
        })
        _finish(d_out, summary, t_setup, t_write, wrote)
    rtf = summary["real_time_factor"]
    print(f"simulate: peak sleeper soil force {quantity(summary['peak_sleeper_soil_force_N'], 'N')} (sleeper "
          f"{summary['peak_sleeper_index']}), max rail deflection {quantity(summary['max_rail_deflection_m'], 'm')}; "
          f"{_rtf_text(rtf, summary)} -> {d_out}")
    return 0


def _rtf_text(compute: float | None, summary: dict[str, Any]) -> str:
    """The two real-time factors, named."""
    return (f"compute real-time factor {quantity(compute, '', 3)} (simulated / stepping wall time), command "
            f"real-time factor {quantity(summary['real_time_factor_command'], '', 3)} (simulated / wall time of "
            f"clm simulate, writing included)")


def _finish(d_out: Path, summary: dict[str, Any], t_start: float, t_write: float | None, wrote: Any) -> None:
    """Command timing into the summary; ``summary.json`` and ``index.html`` (the report of the folder)."""
    from clm_core.io.files import write_json
    from clm_core.outputs.report_index import write_index

    now = time.perf_counter()
    if t_write is not None:
        summary["writing_wall_time_s"] = now - t_write
    summary["command_wall_time_s"] = now - t_start
    summary["command_cpu_time_s"] = time.process_time()  # of the process, Python start-up and imports included
    sim = summary.get("simulated_time_s")
    summary["real_time_factor_command"] = sim / (now - t_start) if sim and now > t_start else None
    summary["real_time_factor_note"] = ("real_time_factor: simulated time / wall time of the time stepping; "
                                        "real_time_factor_command: simulated time / wall time of the command from "
                                        "its start (after the Python start-up) to summary.json, writing included")
    write_json(d_out / "summary.json", summary)
    wrote(d_out / "summary.json")
    wrote(write_index(d_out, title=f"clm simulate: {d_out.name}"))


def _loads_summary(args: argparse.Namespace, params: Any, d_out: Path, sim: Any, digest: Any, wheel_peaks: Any,
                   table: Any, start: tuple[Any, Any, float], speed: float, wrote: Any) -> dict[str, Any]:
    """Peaks (clm_core.peaks), figures and the summary of a moving-load run."""
    import numpy as np

    from clm_core.outputs.plots import plot_run, plot_run_report
    from clm_core.peaks import masked_max, peak_window

    d = params.track.spacing
    P0, F0, front0 = start
    W = int(np.size(P0))

    # peaks over the sleepers the loads have fully passed and the instants after the start-up (clm_core.peaks)
    idx = digest.peak_sleeper_index
    P_fin = np.asarray(sim.snapshot().wheel_positions)
    rear_end = float(np.nanmin(P_fin)) if np.isfinite(P_fin).any() else -np.inf
    window = peak_window(front0, rear_end, d, PASSED_MARGIN_BAYS)
    passed = window.sleepers(idx * d)
    peak_force, i_force, fb_force = masked_max(digest.peak_soil_force, passed)
    peak_rail, _, fb_rail = masked_max(digest.peak_rail_deflection, passed)
    wheel_max, t_from, fb_wheel = wheel_peaks.maximum()
    max_defl = float(np.nanmax([peak_rail, wheel_max]))
    g_peak = int(idx[i_force])
    if fb_force:
        basis = "every sleeper the window held (the loads did not fully pass any sleeper: run too short)"
    else:
        basis = (f"sleepers {int(idx[passed].min())}..{int(idx[passed].max())}: passed by every load, "
                 f"at least {PASSED_MARGIN_BAYS} bays from the loads' start and end positions")
    plot_idx = idx[passed] if passed.any() else idx
    picks = sorted({int(plot_idx[int(round(q * (plot_idx.size - 1)))]) for q in (0.0, 0.33, 0.67, 1.0)})
    title = f"{params.name or 'parameter file'}: " + (f"{W} load(s), {speed:g} m/s" if table is None
                                                       else f"loads from {args.loads_file}")
    plot_run(d_out / "history.npz", digest, picks, d_out / "simulate.png", title=title)
    wrote(d_out / "simulate.png")
    _, env = plot_run_report(d_out / "history.npz", d_out, title, (window.x_from, window.x_to), on_file=wrote)
    exclusion = window.describe(idx, passed, instants_from_s=t_from, sleepers_fallback=fb_force or fb_rail,
                                instants_fallback=fb_wheel)
    exclusion["applies_to"] = ["peak_sleeper_soil_force_N", "peak_sleeper_index", "max_rail_deflection_m",
                               "max_rail_deflection_under_wheel_m", "max_rail_deflection_above_sleeper_m"]
    exclusion["whole_run"] = {
        "peak_sleeper_soil_force_N": float(np.nanmax(digest.peak_soil_force)),
        "max_rail_deflection_m": float(max(digest.max_wheel_deflection, np.nanmax(digest.peak_rail_deflection))),
        "max_rail_deflection_under_wheel_m": float(digest.max_wheel_deflection),
    }
    summary: dict[str, Any] = {
        "peak_sleeper_soil_force_N": peak_force,
        "peak_sleeper_index": g_peak,
        "peak_basis": basis,
        "max_rail_deflection_m": max_defl,
        "max_rail_deflection_under_wheel_m": wheel_max,
        "max_rail_deflection_above_sleeper_m": peak_rail,
        "peak_exclusion": exclusion,
        **env.describe(window.sleepers(env.sleeper_index * d)),
        "initial_state": args.initial_state,
        "speed_m_per_s": speed if table is None else None,
        "wheel_loads_N": [float(f) for f in np.atleast_1d(F0)],
        "wheel_start_positions_m": [float(p) for p in np.atleast_1d(P0)],
        "window_sleepers": sim.n_sleepers,
        "lead_sleepers": sim.lead_sleepers,
        "margin_sleepers": sim.margin_sleepers,
        "elements_per_bay": args.elements_per_bay,
        "n_dof_window": sim.n_dof,
        "factorisations": sim.n_factorisations,
        "final_window_first_sleeper": sim.window[0],
        "output_rows": digest.n_rows,
        "model": params.name or "parameter file",
        "soil_model": params.soil.model,
        "n_overrides": len(params.overrides),
    }
    return summary


def _run_vehicle(args: argparse.Namespace, params: Any, d_out: Path, t_start: float) -> int:
    """``--vehicle``: the coupled vehicle-track simulation (clm_core.vehicle.run)."""
    from clm_core.outputs.vehicle_run import run_vehicle
    from clm_core.progress import terminal
    from clm_core.vehicle.run import VehicleRunSpec

    spec = VehicleRunSpec.from_mapping({
        "vehicle": args.vehicle, "cars": args.cars, "train": tuple(s for s in (args.train or "").split(",") if s),
        "speed": args.speed, "duration": args.duration, "dt": args.dt, "start": args.start,
        "irregularity": args.irregularity, "seed": args.seed, "wavelength_band": args.wavelength_band,
        "defects": tuple(args.defect), "lead_in": args.lead_in, "hertz": args.hertz,
        "track_engine": args.track_engine, "n_sleepers": args.n_sleepers,
        "elements_per_bay": args.elements_per_bay, "lead_sleepers": args.lead_sleepers, "output_dt": args.output_dt,
    })
    s = run_vehicle(spec, params, d_out, csv_files=bool(args.csv), progress=terminal())
    _finish(d_out, s, t_start, None, lambda _p: None)
    print(f"simulate --vehicle: peak wheel load {quantity(s['peak_wheel_load_N'], 'N')} (dynamic factor "
          f"{s['dynamic_factor']:.3f} of the static {quantity(max(s['wheel_load_static_N']), 'N')}), dynamic part "
          f"of the wheel load {quantity(s['wheel_load_dynamic_std_N'], 'N')} (std about the static load), peak "
          f"sleeper soil force {quantity(s['peak_sleeper_soil_force_N'], 'N')} (sleeper {s['peak_sleeper_index']}), "
          f"contact losses {s['contact_loss_events']}; {_rtf_text(s['real_time_factor'], s)} -> {d_out}")
    return 0


def _front(block: Any) -> Any:
    """Position of the foremost wheel at each output instant of a block [m] (NaN: no wheel on the track)."""
    import numpy as np

    P = np.asarray(block.wheel_positions, dtype=float)
    if P.size == 0:
        return np.full(P.shape[0], np.nan)
    return np.max(np.where(np.isfinite(P), P, -np.inf), axis=1)


def _write_bag(d_out: Path, storage: str) -> None:
    """DIR/bag from DIR/history.npz (clm_core.outputs.history_bag.write_history_bag; rosbags only, no middleware)."""
    from clm_core.outputs.history import load_history
    from clm_core.outputs.history_bag import write_history_bag

    bag = d_out / "bag"
    if bag.exists():  # --overwrite (output_dir refused it otherwise)
        from clm_core.commands._common import remove_bag

        remove_bag(bag, "--out")
    write_history_bag(load_history(d_out / "history.npz"), bag, storage)
