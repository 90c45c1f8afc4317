"""Run a study, or the calibration of a folder of bags, on the engine; resumable; one table out.

:func:`run_study` (``clm study``) and :func:`calibrate_folder` (``clm
calibrate FOLDER``) share one path (:func:`execute`):

1. the output directory: created, or resumed when it holds a result store
   (``cases/``) of an earlier run, or refused when it holds anything else
   (unless ``overwrite``);
2. the cases already in the store (same key: same settings, file contents,
   parameter values and code revision, :mod:`clm_core.studies.inputs`) are reused, not recomputed; the others run on the
   engine (:class:`clm_core.studies.engine.Engine`), each stored atomically
   the moment it finishes (:class:`clm_core.studies.store.ResultStore`), with
   a progress bar on a terminal;
3. the table, one row per case in case order: ``results.parquet`` and
   ``results.csv``; then the figures and ``study.json``.

A case that fails is a row with ``status = 'error'`` and its ``error``; the
others go on. An interrupted run (Ctrl-C, a killed process) loses only the
cases that were running: the same command again finishes the study.
"""

from __future__ import annotations

import shlex
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from clm_core import __version__
from clm_core.errors import ClmError, InputError
from clm_core.io.files import write_json
from clm_core.studies.engine import Engine, EngineInfo, Task
from clm_core.studies.inputs import Shipped, code_revision, identity_key, ship
from clm_core.studies.runner import OUTPUTS, RUN_COLUMNS, SUMMARY_METRICS, calibrate_bag, run_case, warm_up
from clm_core.studies.spec import StudySpec, column_text, simulate_argv
from clm_core.studies.store import ResultStore, columns_of, write_table


class StudyInterrupted(ClmError):
    """The run was interrupted; the finished cases are stored and the same command resumes."""


@dataclass(frozen=True)
class Item:
    """One row to produce: a task, its place in the table and what the store keeps with it."""

    #: Row number (the case's index).
    index: int
    #: The work; its ``key`` is the store's key.
    task: Task
    #: The row's leading columns: the case's varied parameters, or the bag.
    columns: dict[str, Any]
    #: Extra fields of the stored record: the settings, the command of the same run alone.
    record: dict[str, Any] = field(default_factory=dict)
    #: Folder (relative to the output directory) where the client writes the files the task returns
    #: (:data:`clm_core.studies.runner.OUTPUTS`); None: the task returns none.
    outputs: str | None = None


@dataclass
class Outcome:
    """What a study run did (also written to ``study.json``)."""

    out: Path
    rows: list[dict[str, Any]]
    columns: list[str]
    files: list[Path]
    reused: int
    computed: int
    elapsed_s: float
    engine: EngineInfo
    #: CPU time of the engine phase [s]: ``client`` (this process: the client, and the scheduler of a local
    #: cluster) and ``workers`` (every worker process, all threads); empty when nothing ran.
    cpu_s: dict[str, float] = field(default_factory=dict)

    @property
    def failed(self) -> int:
        """Rows whose status is not ``ok``."""
        return sum(1 for r in self.rows if r.get("status") != "ok")

    @property
    def cases_per_minute(self) -> float | None:
        """Computed cases per minute of wall time (None when nothing ran)."""
        return 60.0 * self.computed / self.elapsed_s if self.computed and self.elapsed_s > 0 else None


def prepare_dir(out: str | Path, overwrite: bool) -> tuple[Path, bool]:
    """The output directory: (path, resumed). Created if missing; an earlier run's store is resumed.

    Raises
    ------
    InputError
        ``out`` is a file, or a non-empty directory without a result store
        (``cases/``) and ``overwrite`` is not given.
    """
    p = Path(out)
    if p.exists() and not p.is_dir():
        raise InputError(f"--out {p}: exists and is not a directory")
    store = ResultStore(p)
    if p.is_dir() and any(p.iterdir()):
        if overwrite:
            store.clear()
            return p, False
        if not store.dir.is_dir():
            raise InputError(f"--out {p}: exists, is not empty and holds no earlier study (no cases/); choose "
                             "another directory or pass --overwrite")
        return p, True
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out {p}: cannot create the directory ({exc.strerror})") from None
    return p, False


def execute(items: Sequence[Item], out: Path, *, scheduler: str | None = None, workers: int | None = None,
            retry_failed: bool = False, desc: str = "clm study", warm: Callable[[], str] | None = None,
            lead: Sequence[str] = (), table: str = "results", log: Callable[[str], None] | None = None) -> Outcome:
    """Run the items not in the store of ``out``, store each as it finishes, write the table.

    Parameters
    ----------
    items : sequence of Item
    out : Path
        The output directory (:func:`prepare_dir`).
    scheduler, workers
        The engine (:class:`Engine`).
    retry_failed : bool
        Run again the stored cases whose status is ``error``.
    desc : str
        Label of the progress bar.
    warm : callable, optional
        Run on every worker first (:func:`clm_core.studies.runner.warm_up`).
    lead : sequence of str
        Columns that come first in the table (after ``case``).
    table : str
        Name of the table files, ``out/<table>.parquet`` and ``.csv``.
    log : callable, optional
        Receives one-line messages (resumption, interruption).

    Returns
    -------
    Outcome

    Raises
    ------
    StudyInterrupted
        On KeyboardInterrupt, after writing the table of what is finished.
    """
    from clm_core.progress import Progress

    store = ResultStore(out)
    stored = store.load()
    records: dict[str, Mapping[str, Any]] = {}
    for it in items:
        rec = stored.get(it.task.key)
        if rec is not None and not (retry_failed and rec["row"].get("status") != "ok"):
            records[it.task.key] = rec
    reused = len(records)
    todo = [it for it in items if it.task.key not in records]
    lost: dict[str, str] = {}
    if reused and log is not None:
        log(f"{desc}: resuming: {reused} of {len(items)} cases already done in {store.dir}, {len(todo)} to run")
    by_key = {it.task.key: it for it in todo}
    failed = [0]

    def done(bar: Progress, task: Task, row: Mapping[str, Any] | None, reason: str) -> None:
        it = by_key[task.key]
        if row is None:
            lost[task.key] = reason
            if "KilledWorker" not in reason:  # the scheduler lost it: run again on resumption
                bar.update(1)
                return
            row = {"status": "error", "error": f"the case killed its worker process ({reason})"}
        row = dict(row)
        shipped = row.pop(OUTPUTS, None)
        if it.outputs is not None and shipped is not None:
            row["outputs"] = write_outputs(out, it.outputs, shipped)
        rec = {"key": task.key, "index": it.index, "columns": it.columns, **it.record, "row": row,
               "finished_at": datetime.now(timezone.utc).isoformat(timespec="seconds"), "clm_core": __version__}
        store.put(rec)
        records[task.key] = rec
        bar.update(1)
        if row.get("status") != "ok":
            failed[0] += 1
            bar.stage(f"{failed[0]} failed")

    info = EngineInfo(kind="none")
    t0 = t1 = time.perf_counter()
    cpu: dict[str, float] = {}
    try:
        if todo:
            with Progress(len(todo), desc, unit="case") as bar:
                bar.stage("starting the engine")
                with Engine(scheduler, workers, warm) as engine:
                    info = engine.info
                    bar.stage(f"{info.workers} worker{'s' if info.workers != 1 else ''}")
                    w0, d0, t0 = engine.worker_cpu(), time.process_time(), time.perf_counter()
                    engine.run([it.task for it in todo], lambda t, r, why: done(bar, t, r, why))
                    t1 = time.perf_counter()
                    cpu.update(client=time.process_time() - d0, workers=engine.worker_cpu() - w0)

    except KeyboardInterrupt:
        outcome = _finish(items, records, lost, out, lead, table, reused, time.perf_counter() - t0, info, cpu)
        raise StudyInterrupted(
            f"interrupted: {len(records)} of {len(items)} cases done and stored in {store.dir}; run the same command "
            f"again to finish the study (partial table in {outcome.files[1]})"
        ) from None
    return _finish(items, records, lost, out, lead, table, reused, t1 - t0, info, cpu)


def write_outputs(out: Path, folder: str, files: Mapping[str, bytes]) -> list[str]:
    """Write a task's returned files into ``out/folder`` (replaced whole: written beside it, then renamed).

    Written by the client, so the outputs of every case are on the client's
    disk whatever worker ran it. Returns the relative paths written.

    Raises
    ------
    ClmError
        A returned path that would leave ``out/folder`` (absolute, or with ``..``).
    """
    import shutil
    import uuid

    final = out / folder
    tmp = final.parent / f".{final.name}.partial-{uuid.uuid4().hex[:8]}"
    for rel in files:
        parts = Path(rel).parts
        if Path(rel).is_absolute() or ".." in parts or not parts:
            raise ClmError(f"a worker returned the output path {rel!r}: must be relative, inside the case's folder")
    for rel, data in files.items():
        dest = tmp / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_bytes(data)
    tmp.mkdir(parents=True, exist_ok=True)
    if final.exists():
        shutil.rmtree(final)
    tmp.rename(final)
    return sorted(files)


def _finish(items: Sequence[Item], records: Mapping[str, Mapping[str, Any]], lost: Mapping[str, str], out: Path,
            lead: Sequence[str], table: str, reused: int, elapsed: float, info: EngineInfo,
            cpu: dict[str, float]) -> Outcome:
    rows: list[dict[str, Any]] = []
    for it in items:
        rec = records.get(it.task.key)
        if rec is not None:
            body = dict(rec["row"])
        elif it.task.key in lost:
            body = {"status": "error", "error": f"not finished: {lost[it.task.key]} (run again to retry)"}
        else:
            body = {"status": "pending", "error": "not run yet (interrupted)"}
        body.pop("worker", None)
        body.pop("outputs", None)
        rows.append({"case": it.index, **it.columns, **body, "case_key": it.task.key})
    columns = columns_of(rows, ["case", *lead], [*RUN_COLUMNS, "case_key"])
    files = write_table(rows, columns, out, table)
    return Outcome(out, rows, columns, files, reused, len(records) - reused, elapsed, info, cpu)


# ----------------------------------------------------------------------------- clm study


def study_items(spec: StudySpec) -> list[Item]:
    """The items of a study: one per case, :func:`run_case` on its settings."""
    items = []
    for c in spec.cases():
        argv = simulate_argv(c.settings)
        items.append(Item(
            c.index, Task(c.key, run_case, (c.settings, c.files, c.code)),
            {k: column_text(v) for k, v in c.values.items()},
            {"settings": c.settings, "command": "clm " + shlex.join(argv) + " --out OUT"},
        ))
    return items


def run_study(spec: StudySpec, out: str | Path, *, scheduler: str | None = None, workers: int | None = None,
              overwrite: bool = False, retry_failed: bool = False, figures: bool = True, source_text: str = "",
              log: Callable[[str], None] | None = None) -> Outcome:
    """Run a study (``clm study``): the table ``results.parquet``/``.csv``, the figures, ``study.json``.

    Parameters
    ----------
    spec : StudySpec
        From :func:`clm_core.studies.spec.load_study`.
    out : path
        Output directory; an earlier run's directory is resumed.
    scheduler, workers
        The engine: a local cluster of ``workers`` processes (default one per
        core), or the scheduler at ``scheduler``.
    overwrite : bool
        Discard an earlier run's results (or write into a non-empty directory).
    retry_failed : bool
        Run again the stored cases that failed.
    figures : bool
        Write the figures (:func:`clm_core.outputs.plots.plot_study`).
    source_text : str
        The study file's text, kept as ``out/study.yaml``.
    log : callable, optional
        One-line messages.

    Returns
    -------
    Outcome
    """
    items = study_items(spec)
    d, _ = prepare_dir(out, overwrite)
    if source_text:
        (d / "study.yaml").write_text(source_text)
    outcome = execute(items, d, scheduler=scheduler, workers=workers, retry_failed=retry_failed,
                      desc=f"clm study {spec.name}", warm=warm_up, lead=spec.varied, log=log)
    if figures:
        from clm_core.outputs.plots import plot_study

        outcome.files += plot_study(outcome.rows, spec.varied, d, title=spec.name, fixed=spec.fixed)
    write_json(d / "study.json", {
        "name": spec.name, "description": spec.description, "source": spec.source, "kind": "vehicle",
        "fixed_settings": spec.fixed, "varied": spec.varied, "cases": len(items),
        "metrics": list(SUMMARY_METRICS), **_summary(outcome),
    })
    return outcome


def _summary(o: Outcome) -> dict[str, Any]:
    return {
        "ok": len(o.rows) - o.failed, "failed": o.failed, "reused": o.reused, "computed": o.computed,
        "elapsed_s": o.elapsed_s, "cases_per_minute": o.cases_per_minute, "engine_cpu_s": o.cpu_s,
        "engine": o.engine.as_dict(),
        "files": [f.name for f in o.files], "clm_core": __version__,
        "peak_exclusion": "peaks exclude the start-up transient and the sleepers not fully passed, as clm simulate "
                          "(clm_core.peaks; the rule is in each run's summary.json: clm simulate with the case's "
                          "command in cases/<case_key>.json)",
    }


# ----------------------------------------------------------------------------- clm calibrate FOLDER


def find_bags(folder: str | Path) -> list[Path]:
    """The bags directly inside ``folder``: bag directories and ``.mcap``/``.db3`` files, sorted by name.

    Raises
    ------
    InputError
        ``folder`` is not a directory, or holds no bag.
    """
    from clm_core.io.bags import is_bag

    p = Path(folder)
    if not p.is_dir():
        raise InputError(f"bag folder {str(p)!r}: not a directory")
    bags = sorted(c for c in p.iterdir() if not c.name.startswith(".") and is_bag(c))
    if not bags:
        raise InputError(f"bag folder {str(p)!r}: no rosbag2 bag in it (directories with metadata.yaml, or .mcap/.db3 "
                         "files)")
    return bags


def is_bag_folder(path: str | Path) -> bool:
    """True if ``path`` is a directory of bags rather than one bag."""
    from clm_core.io.bags import is_bag

    p = Path(path)
    return p.is_dir() and not is_bag(p) and any(is_bag(c) for c in p.iterdir() if not c.name.startswith("."))


#: Calibration options that may name a file: always (``channels``, ``params``) or by the preset loader's rule.
CALIBRATION_FILE_OPTIONS: tuple[str, ...] = ("channels", "params", "track", "base_soil")


def calibration_files(options: Mapping[str, Any]) -> dict[str, Shipped]:
    """The files the calibration options name, read here (relative paths from the working directory).

    Raises
    ------
    ParameterError
        A named file that does not exist or cannot be read.
    """
    out = {}
    for k in CALIBRATION_FILE_OPTIONS:
        v = options.get(k)
        if v is None or str(v).strip() == "":
            continue
        if k in ("channels", "params") or Path(str(v)).suffix in (".yaml", ".yml") or Path(str(v)).exists():
            out[k] = ship(str(v), k)
    return out


def calibrate_folder(folder: str | Path, method: str, options: Mapping[str, Any], out: str | Path, *,
                     scheduler: str | None = None, workers: int | None = None, overwrite: bool = False,
                     retry_failed: bool = False, plots: bool = True, allow_partial: bool = False,
                     log: Callable[[str], None] | None = None) -> Outcome:
    """Calibrate every bag of ``folder`` on the engine (``clm calibrate FOLDER``): one row per bag.

    Each bag is read here (relative paths from the working directory) and
    shipped to a worker with the files its options name; the worker returns
    the bag's outputs (those of ``clm calibrate BAG``) and this process
    writes them to ``out/bags/<bag>/``, then the table to
    ``out/calibrations.parquet`` and ``.csv``. Resumable like a study: the
    store key is a hash of the bag's content, the method, the options (the
    content of the files they name), ``plots``, ``allow_partial`` and the
    code revision.
    """
    bags = find_bags(folder)
    d, _ = prepare_dir(out, overwrite)
    (d / "bags").mkdir(exist_ok=True)
    code = code_revision()
    files = calibration_files(options)
    items = []
    names: dict[str, int] = {}
    for i, bag in enumerate(bags):
        stem = bag.stem if bag.is_file() else bag.name
        names[stem] = names.get(stem, 0) + 1
        name = stem if names[stem] == 1 else f"{stem}-{names[stem]}"
        shipped = ship(bag, "bag")
        mine = dict(files)
        if "channels" not in mine and bag.is_file():  # a bag file's channel map sits beside it (a directory's: inside)
            from clm_core.calibration.channels import find_channel_map

            cmap = find_channel_map(bag)
            if cmap is not None:
                mine["channels"] = ship(cmap, "channel map")
        ident = {"bag": {"name": name, **shipped.identity()}, "method": method, "allow_partial": allow_partial,
                 "plots": plots, "code": code,
                 "options": {**dict(options), **{k: f.identity() for k, f in mine.items()}}}
        argv = ["calibrate", str(bag), "--method", method, "--out", str(d / "bags" / name)]
        items.append(Item(i, Task(identity_key(ident), calibrate_bag, (shipped, method, dict(options), mine, plots,
                                                                      allow_partial, code)),
                          {"bag": name}, {"bag_path": shipped.source, "bag_sha256": shipped.sha256,
                                          "command": "clm " + shlex.join(argv)}, outputs=f"bags/{name}"))
    outcome = execute(items, d, scheduler=scheduler, workers=workers, retry_failed=retry_failed,
                      desc="clm calibrate", lead=["bag", "method", "model", "misfit", "rms_residual"],
                      table="calibrations", log=log)
    write_json(d / "calibrations.json", {"folder": str(folder), "method": method, "options": dict(options),
                                         "bags": len(items), **_summary(outcome)})
    return outcome
