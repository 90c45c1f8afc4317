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
from clm_core.studies.inputs import Shipped, check_code, materialise

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


def model_settings(case_settings: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, float]]:
    """The model settings of a case (``track``, ``soil``, ``model``, ``params_file``, defaults filled in) and its
    parameter overrides (``{name: value}`` of the ``<section>.<name>`` settings), as
    :func:`clm_core.params.model_from_settings` takes them."""
    model = {k: case_settings.get(k, settings.setting(k).default) for k in ("track", "soil", "model", "params_file")}
    overrides = {k.split(".", 1)[1]: float(v) for k, v in case_settings.items() if k in settings.MODEL_PARAMETERS}
    return model, overrides


def simulate_case(case_settings: Mapping[str, Any], progress: bool = False) -> dict[str, Any]:
    """Run one case (checked settings, :func:`clm_core.studies.spec.check_settings`); return its summary.

    The summary is the ``summary.json`` of ``clm simulate --vehicle`` with the
    same settings (:func:`clm_core.studies.spec.simulate_argv`). File settings
    are paths of this process (:func:`run_case` puts the shipped files there).

    Raises
    ------
    ClmError
        A setting combination the run refuses (window too small, unknown vehicle type, ...).
    """
    from clm_core.params import model_from_settings
    from clm_core.vehicle.run import VehicleRunSpec, simulate_vehicle

    model, overrides = model_settings(case_settings)
    params = model_from_settings(model["track"], model["soil"], model["model"], model["params_file"], overrides)
    run_values = {k: v for k, v in case_settings.items() if k not in model and k not in settings.MODEL_PARAMETERS}
    if "train" in run_values:
        run_values["train"] = tuple(s for s in str(run_values["train"]).split(",") if s)
    _, _, summary = simulate_vehicle(VehicleRunSpec.from_mapping(run_values), params, progress=progress)
    return summary


def worker_name() -> str:
    """``host:pid`` of the process running a case."""
    return f"{socket.gethostname()}:{os.getpid()}"


def run_case(case_settings: Mapping[str, Any], files: Mapping[str, Shipped] | None = None,
             code: str | None = None) -> dict[str, Any]:
    """One study row: :data:`SUMMARY_METRICS` of :func:`simulate_case`, then :data:`RUN_COLUMNS` and ``worker``.

    Parameters
    ----------
    case_settings : mapping
        The case's checked settings.
    files : mapping, optional
        ``{setting: Shipped}``: the files the case reads, as the client read
        them (:class:`clm_core.studies.inputs.CaseInput`); they are rebuilt in
        this worker's temporary directory and the settings point there (the
        client's paths are never opened). None: the settings' paths are read here.
    code : str, optional
        The client's code revision; a worker running other clm_core code
        refuses the case (``status = 'error'``).

    Never raises for the case itself: any exception becomes ``status =
    'error'`` and ``error = '<ExceptionType>: <message>'`` with the metrics
    None (the study goes on).
    """
    row: dict[str, Any] = dict.fromkeys(SUMMARY_METRICS)

    def work() -> None:
        if code is not None:
            check_code(code)
        local = {**case_settings, **{k: str(materialise(f)) for k, f in (files or {}).items()}}
        summary = simulate_case(local)
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
    from clm_core.studies.inputs import code_revision

    code_revision()  # hashed now, at connect: the code this process imported
    simulate_case({"duration": 1e-3, "irregularity": "none"})
    return worker_name()


# ----------------------------------------------------------------------------- calibration of a bag


#: Key of a row that carries a case's output files back to the client (``{relative path: bytes}``); the client
#: writes them under its own output directory and drops the key (:func:`clm_core.studies.study.execute`).
OUTPUTS = "_outputs"


def calibrate_bag(bag: Shipped, method: str, options: Mapping[str, Any], files: Mapping[str, Shipped] | None = None,
                  plots: bool = True, allow_partial: bool = False, code: str | None = None) -> dict[str, Any]:
    """One row of ``clm calibrate FOLDER``: calibrate ``bag`` as ``clm calibrate BAG`` does; return its outputs.

    Parameters
    ----------
    bag : Shipped
        The bag (directory or file) as the client read it; rebuilt in a
        temporary folder of this worker and removed afterwards.
    method : str
    options : mapping
        :class:`clm_core.calibration.options.CalibrationOptions` as a mapping.
    files : mapping, optional
        ``{option: Shipped}``: the files the options name (channel map,
        parameter file, track or soil file), rebuilt here; the options point there.
    plots : bool
        Include the PNG plots in the outputs.
    allow_partial : bool
        Fit what is left of a damaged bag.
    code : str, optional
        The client's code revision (a worker running other code refuses the bag).

    Returns
    -------
    dict
        ``method``, ``model``, ``misfit``, ``rms_residual``, per fitted
        parameter ``<name>``, ``<name>_ci95_low``, ``<name>_ci95_high``,
        ``warnings`` (joined with `` | ``), then :data:`RUN_COLUMNS` and
        ``worker``; and :data:`OUTPUTS`: the files of
        :func:`clm_core.outputs.calibration_report.write_outputs` (``params.yaml``,
        ``summary.json``, ``report.md``, plots) as ``{relative path: bytes}``,
        written by the client. The outputs name the bag and channel map by
        the client's paths. Never raises for the bag itself (``status = 'error'``).
    """
    import dataclasses
    import shutil
    import tempfile

    from clm_core.calibration.api import calibrate
    from clm_core.calibration.options import CalibrationOptions
    from clm_core.outputs.calibration_report import write_outputs

    row: dict[str, Any] = {"method": method, "model": None, "misfit": None, "rms_residual": None}

    def work() -> None:
        if code is not None:
            check_code(code)
        with tempfile.TemporaryDirectory(prefix="clm-bag-") as tmp:
            local_bag = materialise(bag, Path(tmp) / "in")
            given = dict(files or {})
            local = {k: str(materialise(f, Path(tmp) / "in")) for k, f in given.items()}
            result = calibrate(local_bag, method, CalibrationOptions.from_mapping({**options, **local}),
                               allow_partial=allow_partial)
            # the outputs name the client's files, not this worker's copies
            swap = {str(local_bag): bag.source, **{local[k]: f.source for k, f in given.items()}}
            result = dataclasses.replace(
                result, bag=bag.source, warnings=tuple(_swap(w, swap) for w in result.warnings),
                channel_map=dataclasses.replace(result.channel_map, source=_swap(result.channel_map.source, swap)))
            row.update(model=result.model, misfit=result.misfit, rms_residual=result.stats.rms)
            for p in result.parameters:
                row.update({p.name: p.value, f"{p.name}_ci95_low": p.ci_low, f"{p.name}_ci95_high": p.ci_high})
            row["warnings"] = " | ".join(result.warnings)
            out = Path(tmp) / "out"
            write_outputs(result, out, plots=plots)
            row[OUTPUTS] = {f.relative_to(out).as_posix(): f.read_bytes() for f in sorted(out.rglob("*"))
                            if f.is_file()}
            shutil.rmtree(out, ignore_errors=True)

    return _timed(work, row)


def _swap(text: str, paths: Mapping[str, str]) -> str:
    """``text`` with every worker path of ``paths`` replaced by the client's."""
    for mine, theirs in paths.items():
        text = text.replace(mine, theirs)
    return text
