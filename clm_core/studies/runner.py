"""What a worker runs: one study case, or the calibration of one bag, into one row.

Both functions are plain, importable and picklable by reference, so any
``dask.distributed`` worker with clm_core installed runs them; they never
raise for a failure of their case (it goes into the row's ``status`` and
``error``), so one bad case never stops a study.

A case runs :func:`clm_core.vehicle.run.simulate_vehicle`, the very function
``clm simulate --vehicle`` runs, on the model of
:func:`clm_core.params.model_from_settings`, the very rule of ``clm
simulate``: a row holds the numbers of that run's ``summary.json``.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from clm_core import settings

#: Result columns of a study row, from the run's summary (units in the names).
SUMMARY_METRICS: tuple[str, ...] = (
    "peak_sleeper_soil_force_N",
    "max_rail_deflection_m",
    "peak_wheel_load_N",
    "min_wheel_load_N",
    "rms_wheel_load_N",
    "rms_dynamic_wheel_load_N",
    "contact_loss_events",
    "contact_loss_time_s",
)

#: Columns every row ends with: the case's own wall time and CPU time (of the thread that ran it) [s] in its
#: worker, its status and error.
RUN_COLUMNS: tuple[str, ...] = ("wall_time_s", "cpu_time_s", "status", "error")


def simulate_case(case_settings: Mapping[str, Any], progress: bool = False) -> dict[str, Any]:
    """Run one case (checked settings, :func:`clm_core.studies.spec.check_settings`); return its summary.

    The summary is the ``summary.json`` of ``clm simulate --vehicle`` with the
    same settings (:func:`clm_core.studies.spec.simulate_argv`).

    Raises
    ------
    ClmError
        A setting combination the run refuses (window too small, unknown vehicle type, ...).
    """
    from clm_core.params import model_from_settings
    from clm_core.vehicle.run import VehicleRunSpec, simulate_vehicle

    model = {k: case_settings.get(k, settings.setting(k).default) for k in ("track", "soil", "model", "params_file")}
    overrides = {k.split(".", 1)[1]: float(v) for k, v in case_settings.items() if k in settings.MODEL_PARAMETERS}
    params = model_from_settings(model["track"], model["soil"], model["model"], model["params_file"], overrides)
    run_values = {k: v for k, v in case_settings.items() if k not in model and k not in settings.MODEL_PARAMETERS}
    if "train" in run_values:
        run_values["train"] = tuple(s for s in str(run_values["train"]).split(",") if s)
    _, _, summary = simulate_vehicle(VehicleRunSpec.from_mapping(run_values), params, progress=progress)
    return summary


def worker_name() -> str:
    """``host:pid`` of the process running a case."""
    return f"{socket.gethostname()}:{os.getpid()}"


def run_case(case_settings: Mapping[str, Any]) -> dict[str, Any]:
    """One study row: :data:`SUMMARY_METRICS` of :func:`simulate_case`, then :data:`RUN_COLUMNS` and ``worker``.

    Never raises for the case itself: any exception becomes ``status =
    'error'`` and ``error = '<ExceptionType>: <message>'`` with the metrics
    None (the study goes on).
    """
    row: dict[str, Any] = dict.fromkeys(SUMMARY_METRICS)

    def work() -> None:
        summary = simulate_case(case_settings)
        row.update({m: summary[m] for m in SUMMARY_METRICS})

    return _timed(work, row)


def _timed(work: Callable[[], None], row: dict[str, Any]) -> dict[str, Any]:
    """Run ``work`` (which fills ``row``), then add :data:`RUN_COLUMNS` and ``worker``; never raises for it."""
    t0, c0 = time.perf_counter(), time.thread_time()
    try:
        work()
        status, error = "ok", ""
    except Exception as exc:  # a failing case is reported in its row; the study goes on
        status, error = "error", f"{type(exc).__name__}: {exc}"
    row.update(wall_time_s=time.perf_counter() - t0, cpu_time_s=time.thread_time() - c0, status=status,
               error=error, worker=worker_name())
    return row


def warm_up() -> str:
    """Import the run's modules and load its compiled kernels in this worker (a 10-step run); return its name.

    Called once on every worker before the cases, so that no case's wall time
    includes loading the compiled code.
    """
    simulate_case({"duration": 1e-3, "irregularity": "none"})
    return worker_name()


# ----------------------------------------------------------------------------- calibration of a bag


def calibrate_bag(bag: str, method: str, options: Mapping[str, Any], out_dir: str | None, plots: bool = True,
                  allow_partial: bool = False) -> dict[str, Any]:
    """One row of ``clm calibrate FOLDER``: calibrate ``bag`` as ``clm calibrate BAG`` does, write its outputs.

    The outputs (:func:`clm_core.calibration.report.write_outputs`) go into
    ``out_dir`` (replaced whole, written beside it first and renamed, so it
    is never half-written); None: nothing is written.

    Returns
    -------
    dict
        ``bag``, ``method``, ``model``, ``misfit``, ``rms_residual``, per
        fitted parameter ``<name>``, ``<name>_ci95_low``, ``<name>_ci95_high``,
        ``warnings`` (joined with `` | ``), then :data:`RUN_COLUMNS` and
        ``worker``. Never raises for the bag itself (``status = 'error'``).
    """
    import shutil
    import uuid

    from clm_core.calibration.api import calibrate
    from clm_core.calibration.options import CalibrationOptions
    from clm_core.calibration.report import write_outputs

    row: dict[str, Any] = {"bag": Path(bag).name, "method": method, "model": None, "misfit": None,
                           "rms_residual": None}

    def work() -> None:
        result = calibrate(bag, method, CalibrationOptions.from_mapping(options), allow_partial=allow_partial)
        row.update(model=result.model, misfit=result.misfit, rms_residual=result.stats.rms)
        for p in result.parameters:
            row.update({p.name: p.value, f"{p.name}_ci95_low": p.ci_low, f"{p.name}_ci95_high": p.ci_high})
        row["warnings"] = " | ".join(result.warnings)
        if out_dir is not None:
            final = Path(out_dir)
            tmp = final.parent / f".{final.name}.partial-{uuid.uuid4().hex[:8]}"
            write_outputs(result, tmp, plots=plots)
            if final.exists():
                shutil.rmtree(final)
            tmp.rename(final)

    return _timed(work, row)
