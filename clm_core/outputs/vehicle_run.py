"""The files of a vehicle run: :func:`run_vehicle` (``clm simulate --vehicle``) runs and writes it.

The computing core is :func:`clm_core.vehicle.run.simulate_vehicle` (also every
case of ``clm study``); this module writes what it returns: the history
(:func:`clm_core.outputs.history.write_coupled_history`), the figures
(:func:`clm_core.outputs.plots.plot_vehicle_run`) and ``summary.json``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from clm_core.io.files import write_json
from clm_core.outputs.history import window_columns, write_coupled_history
from clm_core.params import ModelParams
from clm_core.peaks import sleeper_envelope
from clm_core.progress import Progress
from clm_core.vehicle.coupled import CoupledResult
from clm_core.vehicle.run import VehicleRunSpec, simulate_vehicle

__all__ = ["run_vehicle", "write_vehicle_outputs"]


def run_vehicle(
    spec: VehicleRunSpec, params: ModelParams, out_dir: str | Path, csv_files: bool = True, progress: bool = False
) -> dict[str, Any]:
    """Build and run the coupled simulation of ``spec`` (:func:`simulate_vehicle`); write its outputs into ``out_dir``.

    Parameters
    ----------
    spec : VehicleRunSpec
    params : ModelParams
    out_dir : str or Path
        Output directory (created): ``vehicle_history.npz``, ``peaks.csv``,
        with ``csv_files`` ``wheels.csv`` and ``sleepers.csv`` (layouts in
        :mod:`clm_core.outputs.history`), the figures
        (:data:`clm_core.outputs.plots.VEHICLE_FIGURES`) and ``summary.json``.
    csv_files : bool
        Also write the CSV files.
    progress : bool
        Show progress bars (on a terminal): the stepping, then the writing.

    Returns
    -------
    dict
        The summary written to ``summary.json``: ``peak_wheel_load_N``,
        ``rms_wheel_load_N``, ``rms_dynamic_wheel_load_N``,
        ``peak_sleeper_soil_force_N``, ``max_rail_deflection_m``,
        ``contact_loss_steps``, ``contact_loss_events``, ``real_time_factor``
        (simulated / wall time of the stepping), ``compute_wall_time_s``,
        the wheel-load statistics (:func:`clm_core.peaks.wheel_load_statistics`:
        ``wheel_load_dynamic_std_N``, ``dynamic_factor``, ...), the envelope
        (:meth:`clm_core.peaks.SleeperEnvelope.describe`), ``peak_exclusion``
        (which part of the run the peaks come from) and ``settings``.
    """
    from clm_core.outputs.plots import VEHICLE_FIGURES

    tic, cpu = time.perf_counter(), time.process_time()
    run, res, summary = simulate_vehicle(spec, params, progress=progress)
    summary["compute_wall_time_s"] = time.perf_counter() - tic
    summary["compute_cpu_time_s"] = time.process_time() - cpu
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = run.settings
    with Progress(2 + 2 * csv_files + len(VEHICLE_FIGURES) + 1, "clm simulate: writing", unit="file",
                  enabled=None if progress else False) as bar:
        def wrote(p: Path) -> None:
            bar.stage(p.name)
            bar.update(1)

        summary.update(write_vehicle_outputs(res, out, csv_files, f"{s['vehicle']} x{len(s['cars'])}, "
                                             f"{run.simulation.speed:g} m/s, {s['model']}, irregularity "
                                             f"{s['irregularity']}", wrote))
        write_json(out / "summary.json", summary)
        wrote(out / "summary.json")
    return summary


def write_vehicle_outputs(res: CoupledResult, out: Path, csv_files: bool, title: str,
                          on_file: Any = None) -> dict[str, Any]:
    """The files of a vehicle run (history, CSV on request, figures); return the envelope's summary entries."""
    from clm_core.outputs.plots import plot_vehicle_run

    first, sf = window_columns(res.soil_force)
    write_coupled_history(res, out, csv_files=csv_files, on_file=on_file, window=(first, sf))
    lo = int(res.sleeper_index[0]) if res.sleeper_index.size else 0
    env = sleeper_envelope(first + lo, sf, res.sleeper_index, res.peak_soil_force)
    plot_vehicle_run(res, out, title=title, envelope=env, on_file=on_file)
    window = res.peak_window()
    return env.describe(window.sleepers(env.sleeper_index * window.spacing))
