"""``clm calibrate``: fit model parameters to a recorded bag (issue 6).

    clm calibrate BAG --method impact|receptance|passby --out DIR
        [--channels MAP.yaml] [--fmin HZ] [--fmax HZ] [--norm NORM]
        [--model clm|lysmer|winkler] [--fit kp,dp,kb,db] [--soil fixed|joint]
        [--params FILE] [... every calibration setting] [--options OPTIONS.yaml] [--no-plots] [--no-progress]
    clm calibrate FOLDER --method ... --out DIR [--scheduler ADDRESS] [--workers N] [--retry-failed]

The calibration options are generated from the calibration settings
(:data:`clm_core.calibration.options.CALIBRATION_SETTINGS`, through
:func:`clm_core.commands._options.add_setting` as every command's settings):
one option per scalar field of
:class:`~clm_core.calibration.options.CalibrationOptions`, checked while
the arguments are parsed. An option given overrides the ``--options`` file;
one not given leaves the file's value (or the default).

Writes params.yaml, soil.yaml / track.yaml, summary.json, report.md and PNG
plots into DIR (:func:`clm_core.outputs.calibration_report.write_outputs`). A
progress bar is shown on a terminal only (:class:`clm_core.progress.Progress`).

Given a folder of bags (bag directories or ``.mcap``/``.db3`` files), every
bag is calibrated the same way on the study engine (a local dask cluster, or
``--scheduler``; :func:`clm_core.studies.calibrate_folder`): each bag's
outputs in ``DIR/bags/<bag>/``, one row per bag in
``DIR/calibrations.parquet`` and ``DIR/calibrations.csv`` (values, 95 %
intervals, misfit, ``status``, ``error``); resumable like ``clm study``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from clm_core.calibration.options import CALIBRATION_SETTINGS, METHODS, CalibrationOptions
from clm_core.commands._common import add_command, check_output, output_dir, quantity
from clm_core.commands._options import add_overwrite, add_setting
from clm_core.commands.study import add_engine_arguments
from clm_core.errors import InputError


def register(sub: Any) -> None:
    """Add the ``calibrate`` sub-command."""
    p = add_command(sub, "calibrate", run)
    p.add_argument("bag", help="rosbag2 bag directory or .mcap file, or a folder of bags (one row per bag, on the "
                   "study engine)")
    p.add_argument("--method", required=True, choices=METHODS, help="test type")
    p.add_argument("--out", required=True, help="output directory")
    for s in CALIBRATION_SETTINGS.values():  # None when not given: the --options file's value, else the default
        add_setting(p, s, default=None)
    p.add_argument("--options", default=None, help="options YAML (all settings, window and sampling sections "
                   "too; see docs/calibration.md); the options given override it")
    p.add_argument("--no-plots", action="store_true", help="do not write PNG plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overwrite(p)
    p.add_argument("--allow-partial", action="store_true",
                   help="fit what is left of a damaged bag (missing or damaged chunks are reported as warnings) "
                   "instead of refusing it")
    g = p.add_argument_group("a folder of bags (dask.distributed, as clm study)")
    add_engine_arguments(g, "bags")


def run(args: argparse.Namespace) -> int:
    """Fit soil/track parameters to a recorded bag (impact, receptance, pass-by).

    Fit model parameters to a rosbag2 bag (mcap or sqlite3): a soil impact test (CLM soil), a hammer test on the
    rail (track parameters) or a pass-by (output error through the time-domain engine). The channel map (topic ->
    place, quantity, unit) is --channels or channels.yaml in the bag directory; format in docs/calibration.md.
    """
    from clm_core.calibration.api import calibrate
    from clm_core.outputs.calibration_report import write_outputs

    if args.options:
        path = Path(args.options)
        if not path.is_file():
            raise InputError(f"--options {args.options!r}: file not found")
        opts = CalibrationOptions.from_yaml(path.read_text())
    else:
        opts = CalibrationOptions()
    given = {k: v for k in CALIBRATION_SETTINGS if (v := getattr(args, k)) is not None}
    opts = CalibrationOptions.from_mapping({**opts.to_dict(), **given})
    from clm_core.progress import Progress
    from clm_core.studies.study import is_bag_folder

    if is_bag_folder(args.bag):
        return _run_folder(args, opts)
    if args.scheduler or args.workers or args.retry_failed:
        raise InputError(f"--scheduler, --workers, --retry-failed: for a folder of bags; {args.bag} is one bag")
    check_output(args.out, args.overwrite)
    with Progress(100, "clm calibrate", unit="%", enabled=False if args.no_progress else None) as bar:
        result = calibrate(args.bag, args.method, opts, progress=bar.fraction,
                           allow_partial=getattr(args, "allow_partial", False))
    with output_dir(args.out, args.overwrite) as out:
        files = write_outputs(result, out, plots=not args.no_plots)
    print(f"calibrate: {args.method} test, {result.model}, band {result.band[0]:g}-{result.band[1]:g} Hz, "
          f"{result.norm} norm, misfit {result.misfit:.3g}, {quantity(result.elapsed_s, 's', 3)}")
    for p in result.parameters:
        flag = "" if p.identifiable else "  (not identifiable)"
        print(f"  {p.name:3s} = {p.value:.5g} {p.unit}   95% [{p.ci_low:.5g}, {p.ci_high:.5g}]{flag}")
    for w in result.warnings:
        print(f"  warning: {w}")
    print(f"  -> {files[0].parent}")
    return 0


def _run_folder(args: argparse.Namespace, opts: CalibrationOptions) -> int:
    """``clm calibrate FOLDER``: every bag on the study engine, one row each."""
    import sys

    from clm_core.commands.study import report
    from clm_core.studies import calibrate_folder

    outcome = calibrate_folder(args.bag, args.method, opts.to_dict(), args.out, scheduler=args.scheduler,
                               workers=args.workers, overwrite=args.overwrite, retry_failed=args.retry_failed,
                               plots=not args.no_plots, allow_partial=args.allow_partial,
                               log=lambda m: print(m, file=sys.stderr))
    report(outcome, f"calibrate {args.bag} ({args.method})", unit="bags")
    return 0
