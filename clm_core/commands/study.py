"""``clm study``: a parametric study of coupled vehicle–track runs on dask.distributed.

    clm study STUDY.yaml --out DIR [--scheduler tcp://HOST:PORT] [--workers N]
        [--overwrite] [--retry-failed] [--no-figures] [--dry-run]

The study file declares a grid or a seeded random sample over the run
settings (speed, soil and track presets or parameters, vehicle, irregularity
seed, ...) and the fixed settings (format: ``docs/studies.md``; examples:
``examples/studies/``). Each case is the run of ``clm simulate --vehicle``
with its settings; a row holds that run's peaks (start-up excluded, as
``clm simulate``), wheel-load statistics, contact losses, its wall time,
``status`` and ``error``. Writes ``DIR/results.parquet``, ``DIR/results.csv``,
the figures, ``DIR/study.json`` and the per-case store ``DIR/cases/``: running
the same command again after an interruption only runs the missing cases.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from clm_core.commands._common import add_command, quantity
from clm_core.commands._options import add_overwrite
from clm_core.errors import InputError


def add_engine_arguments(p: Any, what: str = "cases") -> None:
    """--scheduler, --workers, --retry-failed (the study engine; shared with ``clm calibrate FOLDER``)."""
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help=f"run the {what} on a running dask.distributed scheduler (tcp://host:port; start it with "
                   "`dask scheduler` and workers with `dask worker ADDRESS`); default: a local cluster")
    p.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                   help="local cluster: worker processes (default one per core, one thread each); with --scheduler: "
                   "wait until N workers are connected")
    p.add_argument("--retry-failed", action="store_true",
                   help=f"when resuming, run again the stored {what} that failed (finished ones are never rerun)")


def _positive_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--workers {text!r}: must be an integer >= 1") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"--workers {n}: must be an integer >= 1")
    return n


def register(sub: Any) -> None:
    """Add the ``study`` sub-command."""
    p = add_command(sub, "study", run)
    p.add_argument("study", metavar="STUDY.yaml", help="study file (docs/studies.md; examples/studies/)")
    p.add_argument("--out", default=None, help="output directory (an earlier run's directory is resumed); required "
                   "unless --dry-run")
    add_engine_arguments(p)
    p.add_argument("--no-figures", action="store_true", help="do not write critical_speed.png / exceedance.png")
    p.add_argument("--dry-run", action="store_true", help="check the study file and list its cases; run nothing")
    add_overwrite(p, "the output directory (an earlier run's results are discarded)")


def run(args: argparse.Namespace) -> int:
    """Parametric study (grid or random sample of vehicle runs) on dask.distributed.

    Run a parametric study: a grid or a seeded random sample over speeds, soils, track and soil parameters,
    vehicles and irregularity seeds, each case a coupled vehicle-track run (clm simulate --vehicle). Local dask
    cluster by default (one worker process per core), or a remote dask.distributed scheduler. Resumable: the same
    command after an interruption runs only the missing cases. Format of STUDY.yaml: docs/studies.md.
    """
    from pathlib import Path

    from clm_core.studies import load_study, run_study

    spec = load_study(args.study)
    if args.dry_run:
        cases = spec.cases()
        print(f"study {spec.name}: {len(cases)} cases; varied: {', '.join(spec.varied) or 'nothing'}")
        for c in cases[:10]:
            print(f"  case {c.index}: " + ", ".join(f"{k} = {v!r}" for k, v in c.values.items()))
        if len(cases) > 10:
            print(f"  ... {len(cases) - 10} more")
        return 0
    if not args.out:
        raise InputError("--out: an output directory is required (unless --dry-run)")
    outcome = run_study(spec, args.out, scheduler=args.scheduler, workers=args.workers, overwrite=args.overwrite,
                        retry_failed=args.retry_failed, figures=not args.no_figures,
                        source_text=Path(args.study).read_text(), log=lambda m: print(m, file=sys.stderr))
    report(outcome, f"study {spec.name}")
    return 0


def report(outcome: Any, what: str, unit: str = "cases") -> None:
    """The closing lines of ``clm study`` and ``clm calibrate FOLDER``."""
    e = outcome.engine
    where = ("nothing to run" if e.kind == "none" else
             f"on {'a local cluster' if e.kind == 'local' else 'the scheduler ' + e.address} of {e.workers} "
             f"worker{'s' if e.workers != 1 else ''}")
    rate = outcome.cases_per_minute
    rate_text = f", {rate:.3g} {unit}/min" if rate else ""
    n = len(outcome.rows)
    print(f"{what}: {n} {unit} ({outcome.computed} run, {outcome.reused} reused) {where} in "
          f"{quantity(outcome.elapsed_s, 's', 3)}{rate_text}; {n - outcome.failed} ok, {outcome.failed} failed")
    for r in [r for r in outcome.rows if r.get("status") != "ok"][:5]:
        print(f"  {r.get('bag') or 'case ' + str(r['case'])}: {r.get('status')}: {r.get('error')}")
    print("  -> " + ", ".join(str(f) for f in outcome.files))
