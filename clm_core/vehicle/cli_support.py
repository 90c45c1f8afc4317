"""Command-line support for vehicle runs (``clm simulate --vehicle ...``).

:func:`add_vehicle_arguments` adds the vehicle options to a parser (the
``simulate`` command owns ``--speed``, ``--start``, ``--duration``,
``--dt``, ``--sleepers``, ``--lead``, ``--elements-per-bay``,
``--output-dt``, ``--no-csv`` and ``--out``; they are read here with
defaults when absent). :func:`run_vehicle_simulation` runs the coupled
vehicle–track simulation and writes, into ``out_dir``:

``vehicle_history.npz``
    every array of :class:`clm_core.vehicle.coupled.CoupledResult`
    (``t``, ``wheel_position``, ``wheel_load``, ``static_wheel_load``,
    ``compression``, ``wheel_displacement``, ``rail_deflection``,
    ``irregularity``, ``vehicle_energy``, ``newton_iterations``, ``t_out``,
    ``sleeper_index``, ``sleeper_x``, ``soil_force``,
    ``sleeper_rail_deflection``, ``peak_soil_force``) plus ``meta_json``.
``wheels.csv``
    ``t_s`` then per wheel ``x{i}_m, P{i}_N`` (wheel load = contact force),
    ``delta{i}_m`` (Hertz compression), ``z{i}_m`` (axle), ``w{i}_m`` (rail
    under the wheel), ``r{i}_m`` (irregularity, positive downwards), every
    ``--output-dt``.
``sleepers.csv``
    long format ``t_s, sleeper_index, x_m, soil_force_N, rail_deflection_m``
    for the sleepers in the engine's window at each output instant.
``peaks.csv``
    ``sleeper_index, x_m, peak_soil_force_N`` (every step).
``wheel_loads.png``, ``soil_forces.png``, ``spectra.png``
    plots (matplotlib, Agg).
``summary.json``
    the summary (peak/RMS wheel load, peak sleeper soil force, contact
    losses, real-time factor) and the run settings.

Wheel loads are per wheel on the one simulated rail line: half the axle load.
A vehicle run always starts from static equilibrium (``--initial`` is not
used) and ignores ``--load``, ``--axles`` and ``--loads-file``; its default
duration is 2 s.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from clm_core.errors import InputError, ParameterError
from clm_core.params import ModelParams
from clm_core.vehicle.coupled import CoupledResult, CoupledSimulation
from clm_core.vehicle.irregularity import (
    SPECTRA,
    DippedJoint,
    Irregularity,
    JointStep,
    Profile,
    WheelFlat,
    load_profile_csv,
    local_stiffness_change,
    parse_defect,
    random_profile,
)
from clm_core.vehicle.presets import list_vehicle_presets, load_vehicle

#: Default distance over which the rail profile is ramped in [m].
DEFAULT_LEAD_IN = 5.0


def add_vehicle_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--vehicle``, ``--cars``, ``--train``, ``--irregularity``, ``--seed``,
    ``--wavelength-band``, ``--defect``, ``--lead-in``, ``--hertz``, ``--track-engine``."""
    g = parser.add_argument_group("vehicle (coupled vehicle-track simulation)")
    g.add_argument("--vehicle", default=None, metavar="NAME_OR_FILE",
                   help=f"vehicle preset ({', '.join(list_vehicle_presets())}) or vehicle YAML file; runs the "
                   "multibody vehicle on the track with Hertz contact instead of constant moving loads")
    g.add_argument("--cars", type=int, default=None, metavar="N",
                   help="first N cars of the preset's composition (default 1; thalys: 10 = the whole trainset)")
    g.add_argument("--train", default=None, metavar="NAMES",
                   help="composition by vehicle-type names, comma-separated, front to rear; suffix '+' = "
                   "articulated on the previous car's bogie, '~' = reversed (e.g. power_car,trailer_end,trailer+)")
    g.add_argument("--irregularity", default="none", metavar="SPEC",
                   help=f"rail profile: {', '.join(SPECTRA)}, none, or a CSV file (position m, elevation m, "
                   "elevation positive up) (default none)")
    g.add_argument("--seed", type=int, default=1, help="random seed of the irregularity profile (default 1)")
    g.add_argument("--wavelength-band", default="1,50", metavar="LMIN,LMAX",
                   help="wavelength band of the random profile [m] (default 1,50)")
    g.add_argument("--defect", action="append", default=[], metavar="SPEC",
                   help="isolated defect (repeatable): dipped-joint:x=50,depth=0.002[,half_length=1] | "
                   "dipped-joint:x=50,angle=0.01 | joint-step:x=50,height=0.001 | "
                   "wheel-flat:wheel=0,x=20,length=0.05[,depth=..][,shape=rounded|fresh] | "
                   "stiffness:from=30,to=36,kb=20e6 (per-sleeper override)")
    g.add_argument("--lead-in", type=float, default=DEFAULT_LEAD_IN, metavar="M",
                   help=f"distance over which the rail profile is ramped in [m] (default {DEFAULT_LEAD_IN:g})")
    g.add_argument("--hertz", type=float, default=None, metavar="C_H",
                   help="Hertz constant [N/m^1.5] for every wheel (default: from the wheel radius, UIC60 rail head)")
    g.add_argument("--track-engine", choices=("stream", "fixed"), default="stream",
                   help="track engine: stream = moving window (TrackSimulator), fixed = long fixed reference "
                   "track (validation; slower) (default stream)")


def _band(text: str) -> tuple[float, float]:
    try:
        parts = [float(s) for s in str(text).split(",")]
    except ValueError:
        raise ParameterError(f"--wavelength-band {text!r}: expected LMIN,LMAX in m") from None
    if len(parts) != 2:
        raise ParameterError(f"--wavelength-band {text!r}: expected two values LMIN,LMAX in m")
    return parts[0], parts[1]


def _get(args: argparse.Namespace, name: str, default: Any) -> Any:
    v = getattr(args, name, None)
    return default if v is None else v


def build_run(
    args: argparse.Namespace, params: ModelParams
) -> tuple[CoupledSimulation, float, dict[str, Any]]:
    """Build the coupled simulation the arguments describe; returns (simulation, duration, settings)."""
    if not getattr(args, "vehicle", None):
        raise InputError("--vehicle: a vehicle preset or file is needed for a vehicle run")
    vf = load_vehicle(args.vehicle)
    if getattr(args, "train", None):
        if getattr(args, "cars", None) is not None:
            raise ParameterError("--train and --cars: give one of them")
        cars = vf.compose([s for s in str(args.train).split(",") if s.strip()])
    else:
        cars = vf.cars(_get(args, "cars", 1))
    from clm_core.vehicle.multibody import build_train

    train = build_train(cars)

    speed = float(_get(args, "speed", 30.0))
    duration = float(_get(args, "duration", 2.0))
    dt = float(_get(args, "dt", 1e-4))
    x_start = float(_get(args, "start", 0.0))
    for name, v in (("--speed", speed), ("--duration", duration), ("--dt", dt), ("--start", x_start)):
        if not math.isfinite(v):
            raise ParameterError(f"{name} {v}: must be finite")
    if speed < 0:
        raise ParameterError(f"--speed {speed}: must be >= 0 m/s (the train runs towards +x)")

    # defects and track changes
    rail_defects: list[DippedJoint | JointStep] = []
    flats: list[WheelFlat] = []
    for spec in _get(args, "defect", []):
        d = parse_defect(spec)
        if isinstance(d, dict):
            vals = {k: v for k, v in d.items() if k not in ("from", "to")}
            params = local_stiffness_change(params, d["from"], d["to"], values=vals)
        elif isinstance(d, WheelFlat):
            if d.wheel >= train.n_wheels:
                raise ParameterError(f"--defect {spec!r}: wheel {d.wheel}; the train has {train.n_wheels} wheels")
            flats.append(d)
        else:
            rail_defects.append(d)

    # rail profile over the whole path of the wheels
    x_lo = x_start - float(train.wheel_offset[-1]) - 1.0
    x_hi = x_start + speed * duration + 1.0
    spec = str(_get(args, "irregularity", "none")).strip()
    profile: Profile | None
    if spec.lower() == "none":
        profile = None
    elif spec.lower() in SPECTRA:
        profile = random_profile(spec.lower(), x_lo, x_hi - x_lo, seed=int(_get(args, "seed", 1)),
                                 band=_band(_get(args, "wavelength_band", "1,50")))
    else:
        p = Path(spec)
        if not p.exists() and p.suffix.lower() != ".csv":
            raise ParameterError(
                f"--irregularity {spec!r}: not a spectrum ({', '.join(SPECTRA)}), 'none', or an existing CSV file"
            )
        profile = load_profile_csv(p)
    irr = Irregularity(profile=profile, defects=tuple(rail_defects), flats=tuple(flats),
                       lead_in=float(_get(args, "lead_in", DEFAULT_LEAD_IN)) if profile is not None else 0.0)

    every = max(1, int(round(float(_get(args, "output_dt", 5e-4)) / dt)))
    sim = CoupledSimulation(
        train, params, speed, dt, irregularity=irr, x_start=x_start,
        engine=_get(args, "track_engine", "stream"), n_sleepers=getattr(args, "sleepers", None),
        elements_per_bay=int(_get(args, "elements_per_bay", 2)), lead_sleepers=getattr(args, "lead", None),
        hertz=getattr(args, "hertz", None), snapshot_every=every, duration_hint=duration,
    )
    settings: dict[str, Any] = {
        "vehicle": str(args.vehicle),
        "cars": [c.vehicle.name + ("~" if c.reversed else "") + ("+" if c.shares_front_bogie else "") for c in cars],
        "n_wheels": train.n_wheels,
        "wheel_offsets_m": train.wheel_offset.tolist(),
        "static_wheel_loads_N": train.static_wheel_loads().tolist(),
        "weight_per_rail_N": train.weight_per_rail,
        "note": "one rail line: wheel loads are per wheel, half the axle load",
        "speed_m_per_s": speed,
        "duration_s": duration,
        "dt_s": dt,
        "start_m": x_start,
        "irregularity": spec,
        "irregularity_rms_m": profile.rms() if profile is not None else 0.0,
        "seed": int(_get(args, "seed", 1)) if spec.lower() in SPECTRA else None,
        "wavelength_band_m": list(_band(_get(args, "wavelength_band", "1,50"))) if spec.lower() in SPECTRA else None,
        "lead_in_m": irr.lead_in,
        "defects": list(_get(args, "defect", [])),
        "hertz_constant_N_per_m1.5": sim.hertz.tolist(),
        "track_engine": sim.engine,
        "window_sleepers": sim.n_sleepers,
        "elements_per_bay": sim.elements_per_bay,
        "model": params.name or "parameter file",
        "soil_model": params.soil.model,
        "n_overrides": len(params.overrides),
    }
    return sim, duration, settings


def run_vehicle_simulation(args: argparse.Namespace, params: ModelParams, out_dir: str | Path) -> dict[str, Any]:
    """Run the coupled vehicle–track simulation of ``args`` and write its outputs.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (vehicle options of :func:`add_vehicle_arguments` and
        the ``simulate`` options ``speed``, ``start``, ``duration`` (default 2 s),
        ``dt`` (1e-4 s), ``sleepers``, ``lead``, ``elements_per_bay``,
        ``output_dt`` (5e-4 s), ``no_csv``).
    params : ModelParams
        Track and soil (per-sleeper ``stiffness`` defects are added to it).
    out_dir : str or Path
        Output directory (created).

    Returns
    -------
    dict
        The summary also written to ``summary.json``: ``peak_wheel_load_N``,
        ``rms_wheel_load_N``, ``rms_dynamic_wheel_load_N``,
        ``peak_sleeper_soil_force_N``, ``contact_loss_steps``,
        ``contact_loss_events``, ``real_time_factor`` (simulated / wall time of
        the stepping), and the run settings.
    """
    sim, duration, settings = build_run(args, params)
    res = sim.run(duration)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = res.summary()
    summary.update({"settings": settings})
    summary["sleeper_passing_frequency_Hz"] = sim.speed / params.track.spacing if sim.speed > 0 else None
    write_outputs(res, out, csv_files=not bool(getattr(args, "no_csv", False)),
                  title=f"{settings['vehicle']} x{len(settings['cars'])}, {sim.speed:g} m/s, {settings['model']}, "
                        f"irregularity {settings['irregularity']}")
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=_jsonable) + "\n")
    return summary


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_outputs(res: CoupledResult, out: Path, csv_files: bool = True, title: str = "") -> None:
    """Write NPZ, CSV and PNG files of a coupled run into ``out`` (layout in the module docstring)."""
    np.savez_compressed(
        out / "vehicle_history.npz",
        t=res.t, wheel_position=res.wheel_position, wheel_load=res.wheel_load,
        static_wheel_load=res.static_wheel_load, compression=res.compression,
        wheel_displacement=res.wheel_displacement, rail_deflection=res.rail_deflection,
        irregularity=res.irregularity, vehicle_energy=res.vehicle_energy,
        newton_iterations=res.newton_iterations, t_out=res.t_out, sleeper_index=res.sleeper_index,
        sleeper_x=res.sleeper_x, soil_force=res.soil_force, sleeper_rail_deflection=res.sleeper_rail_deflection,
        peak_soil_force=res.peak_soil_force, meta_json=np.array(json.dumps(res.meta, default=_jsonable)),
    )
    every = int(res.meta.get("snapshot_every", 1))
    rows = np.arange(0, res.t.size, every)
    if csv_files:
        nw = res.wheel_load.shape[1]
        with (out / "wheels.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            head = ["t_s"]
            for i in range(nw):
                head += [f"x{i}_m", f"P{i}_N", f"delta{i}_m", f"z{i}_m", f"w{i}_m", f"r{i}_m"]
            w.writerow(head)
            for k in rows.tolist():
                row: list[str] = [f"{res.t[k]:.6g}"]
                for i in range(nw):
                    row += [f"{res.wheel_position[k, i]:.6f}", f"{res.wheel_load[k, i]:.6g}",
                            f"{res.compression[k, i]:.6g}", f"{res.wheel_displacement[k, i]:.6g}",
                            f"{res.rail_deflection[k, i]:.6g}", f"{res.irregularity[k, i]:.6g}"]
                w.writerow(row)
        with (out / "sleepers.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["t_s", "sleeper_index", "x_m", "soil_force_N", "rail_deflection_m"])
            for k in range(res.t_out.size):
                ok = np.isfinite(res.soil_force[k])
                for j in np.nonzero(ok)[0]:
                    w.writerow([f"{res.t_out[k]:.6g}", int(res.sleeper_index[j]), f"{res.sleeper_x[j]:.4f}",
                                f"{res.soil_force[k, j]:.6g}", f"{res.sleeper_rail_deflection[k, j]:.6g}"])
        with (out / "peaks.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["sleeper_index", "x_m", "peak_soil_force_N"])
            for j in np.nonzero(np.isfinite(res.peak_soil_force))[0]:
                w.writerow([int(res.sleeper_index[j]), f"{res.sleeper_x[j]:.4f}", f"{res.peak_soil_force[j]:.6g}"])
    plot_outputs(res, out, title)


def plot_outputs(res: CoupledResult, out: Path, title: str = "") -> None:
    """``wheel_loads.png``, ``soil_forces.png``, ``spectra.png`` (Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.signal import welch

    nw = res.wheel_load.shape[1]
    show = list(range(min(nw, 4)))
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i in show:
        ax[0].plot(res.t, res.wheel_load[:, i] / 1e3, lw=0.7, label=f"wheel {i}")
    ax[0].axhline(0, color="k", lw=0.5)
    ax[0].set_ylabel("wheel load [kN]")
    ax[0].legend(fontsize=7, ncol=4)
    ax[0].set_title(title, fontsize=9)
    ax[1].plot(res.t, res.irregularity[:, 0] * 1e3, lw=0.7, label="irregularity r, wheel 0 (down +)")
    ax[1].plot(res.t, (res.rail_deflection[:, 0]) * 1e3, lw=0.7, label="rail deflection, wheel 0")
    ax[1].set_ylabel("[mm]")
    ax[1].set_xlabel("t [s]")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "wheel_loads.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(2, 1, figsize=(9, 6))
    counts = np.isfinite(res.soil_force).sum(axis=0)
    finite_cols = np.nonzero(counts > 0)[0]
    if finite_cols.size:
        pkv = np.where(np.isfinite(res.peak_soil_force), res.peak_soil_force, -np.inf)
        good = np.nonzero((counts >= 0.5 * counts.max()) & (pkv >= 0.5 * pkv.max()))[0]
        good = good if good.size else finite_cols
        picks = good[np.linspace(0, good.size - 1, 4).round().astype(int)]
        for j in np.unique(picks):
            ax[0].plot(res.t_out, res.soil_force[:, j] / 1e3, lw=0.8, label=f"sleeper {int(res.sleeper_index[j])}")
        ax[0].legend(fontsize=7)
    ax[0].set_xlabel("t [s]")
    ax[0].set_ylabel("soil force [kN]")
    ax[0].set_title("sleeper soil forces (ballast force on the soil, compression +)", fontsize=9)
    ok = np.isfinite(res.peak_soil_force)
    ax[1].plot(res.sleeper_x[ok], res.peak_soil_force[ok] / 1e3, ".-", ms=3, lw=0.6)
    ax[1].set_xlabel("x [m]")
    ax[1].set_ylabel("peak soil force [kN]")
    fig.tight_layout()
    fig.savefig(out / "soil_forces.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(2, 1, figsize=(9, 6))
    dt = float(res.t[1] - res.t[0]) if res.t.size > 1 else 1.0
    sel = res.t >= float(res.meta.get("stats_from", 0.0))
    V = float(res.meta.get("speed", 0.0))
    spacing = float(res.sleeper_x[1] - res.sleeper_x[0]) if res.sleeper_x.size > 1 else 0.6
    if sel.sum() > 16:
        for i in show:
            x = res.wheel_load[sel, i] - res.wheel_load[sel, i].mean()
            f, S = welch(x, fs=1 / dt, nperseg=min(x.size, 4096))
            ax[0].semilogy(f, np.maximum(S, 1e-30), lw=0.7, label=f"wheel {i}")
        if V > 0:
            ax[0].axvline(V / spacing, color="k", ls="--", lw=0.7, label=f"V/d = {V / spacing:.1f} Hz")
        ax[0].set_xlim(0, min(0.5 / dt, 500.0))
        ax[0].legend(fontsize=7)
    ax[0].set_xlabel("f [Hz]")
    ax[0].set_ylabel("PSD wheel load [N^2/Hz]")
    if finite_cols.size:
        j = int(np.argmax(np.where(ok, res.peak_soil_force, -np.inf)))
        y = res.soil_force[:, j]
        fin = np.isfinite(y)
        if fin.sum() > 16 and res.t_out.size > 1:
            dto = float(res.t_out[1] - res.t_out[0])
            yy = y[fin] - np.mean(y[fin])
            f, S = welch(yy, fs=1 / dto, nperseg=min(yy.size, 1024))
            ax[1].semilogy(f, np.maximum(S, 1e-30), lw=0.8, label=f"sleeper {int(res.sleeper_index[j])}")
            ax[1].set_xlim(0, min(0.5 / dto, 250.0))
            ax[1].legend(fontsize=7)
    ax[1].set_xlabel("f [Hz]")
    ax[1].set_ylabel("PSD soil force [N^2/Hz]")
    fig.tight_layout()
    fig.savefig(out / "spectra.png", dpi=110)
    plt.close(fig)
