"""The engine of studies: ``dask.distributed``, on a local cluster or a remote scheduler.

:class:`Engine` opens a client on

- a :class:`distributed.LocalCluster` by default: worker *processes*, one
  per core (or ``workers``), one thread each (the runs hold the GIL in
  compiled loops, so processes, not threads, scale), on the loopback
  interface, without a dashboard;
- an existing scheduler with ``scheduler='tcp://host:port'``: ``dask
  scheduler`` and ``dask worker`` started by the user on any hosts that
  have the same clm_core installed (the files of the cases travel with them,
  :mod:`clm_core.studies.inputs`); a worker connected at the start whose
  code revision differs from the client's is refused before anything runs.

:meth:`Engine.run` submits the tasks, hands each finished one to a callback
as soon as it completes (the caller stores it and moves the progress bar)
and returns when all are done. dask is imported here only, and only when an
engine is opened, so ``clm --help`` stays fast.
"""

from __future__ import annotations

import logging
import os
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

from clm_core import environ
from clm_core.errors import ClmError, InputError

#: Seconds to wait for a remote scheduler's workers.
WORKER_WAIT_S = 60.0

#: How long the local cluster may take to start [s].
START_TIMEOUT_S = 120.0

#: dask settings of the local cluster (scheduler, nannies, workers): the cases are long compute-bound calls, so
#: the servers' sampling of themselves is switched off or slowed down (the statistical profiler alone took ~25 %
#: of a case's wall time; the 20-ms event-loop tick cost an idle worker 18 ms of CPU per second, 4 ms at 200 ms),
#: and glibc keeps its default heap trimming (dask's 64 KiB threshold made every run fault its large arrays in
#: again: 5x the page faults). One BLAS/OpenMP thread per worker, as dask's default. A remote cluster has its
#: own settings (docs/studies.md says how to set the same).
WORKER_CONFIG: dict[str, Any] = {
    "distributed.admin.tick.interval": "200ms",
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.gil.enabled": False,
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.nanny.pre-spawn-environ": {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1,
                                            "NUMBA_NUM_THREADS": 1},
}


def _distributed() -> Any:
    """The ``distributed`` module, imported on first use (a declared dependency; the message says how to add it)."""
    import importlib

    try:
        return importlib.import_module("distributed")
    except ImportError as exc:  # pragma: no cover
        raise InputError(f"studies need dask.distributed ({exc}); pip install 'dask[distributed]'") from None


def _shipped_in(args: Sequence[Any]) -> list[Any]:
    """The :class:`~clm_core.studies.inputs.Shipped` inputs among task arguments (direct, or values of a mapping)."""
    from clm_core.studies.inputs import Shipped

    out = []
    for a in args:
        if isinstance(a, Shipped):
            out.append(a)
        elif isinstance(a, Mapping):
            out += [v for v in a.values() if isinstance(v, Shipped)]
    return out


def _swap_shipped(arg: Any, shared: Mapping[tuple[str, str, str], Any]) -> Any:
    """``arg`` with each shared input replaced by its future (dask hands the task the data itself)."""
    from clm_core.studies.inputs import Shipped

    if isinstance(arg, Shipped):
        return shared.get(_ident(arg), arg)
    if isinstance(arg, Mapping) and any(isinstance(v, Shipped) for v in arg.values()):
        return {k: shared.get(_ident(v), v) if isinstance(v, Shipped) else v for k, v in arg.items()}
    return arg


def _ident(item: Any) -> tuple[str, str, str]:
    """What makes two shipped inputs the same object for a task: content, name and the client's path (the
    outputs name it), not the content alone."""
    return (str(item.sha256), str(item.name), str(item.source))


def _process_cpu() -> float:
    """User + system CPU time of this process [s] (runs on a worker)."""
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


@dataclass(frozen=True)
class Task:
    """One unit of work: ``func(*args)`` returns a row (a dict)."""

    #: Identity of the work (the result store's key).
    key: str
    #: An importable function (pickled by reference, so remote workers need clm_core installed).
    func: Callable[..., dict[str, Any]]
    #: Its arguments (plain data).
    args: tuple[Any, ...] = ()


@dataclass
class EngineInfo:
    """What ran the tasks (for ``study.json``)."""

    kind: str = "local"
    address: str = ""
    workers: int = 0
    threads_per_worker: int = 1
    worker_names: list[str] = field(default_factory=list)
    #: Per worker connected at the start: what its warm-up took (``warm_s``, ``lock_wait_s`` [s], ``error``).
    warm: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"kind": self.kind, "scheduler": self.address, "workers": self.workers,
                "threads_per_worker": self.threads_per_worker, "worker_processes": list(self.worker_names),
                "warm_up": list(self.warm)}


class Engine:
    """A ``dask.distributed`` client for the duration of a ``with`` block.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:port``); None: a local cluster.
    workers : int, optional
        Local: worker processes (default: one per core). Remote: wait until
        this many workers are connected (default: at least one).
    warm : callable, optional
        Run once in every worker process before its first task, on the
        workers connected now and on those that join later
        (:class:`clm_core.studies.warm.WarmUp`, a worker plugin; one process
        of a host at a time, so the others load the compiled code its first
        process wrote to numba's cache).
    """

    def __init__(self, scheduler: str | None = None, workers: int | None = None,
                 warm: Callable[[], str] | None = None) -> None:
        if workers is not None and workers < 1:
            raise InputError(f"--workers {workers}: must be >= 1")
        self.scheduler = scheduler
        self.workers = workers
        self.warm = warm
        self.info = EngineInfo()
        self._cluster: Any = None
        self._client: Any = None
        self._environ: environ.Saved = {}

    def __enter__(self) -> Engine:
        dist = _distributed()
        try:
            if self.scheduler:
                self._open_remote(dist.Client)
            else:
                import dask

                n = self.workers or os.cpu_count() or 1
                # a nanny writes its pre-spawn environment into *this* process's os.environ before it spawns
                # a worker (distributed/nanny.py); numba then refuses to compile with NUMBA_NUM_THREADS changed
                # under its running thread pool: the caller's environment is put back after every spawn
                self._environ = environ.save(WORKER_CONFIG["distributed.nanny.pre-spawn-environ"])
                with dask.config.set(WORKER_CONFIG):
                    self._cluster = dist.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                                      host="127.0.0.1", dashboard_address=None,
                                                      silence_logs=logging.ERROR)
                self._restore_environ()
                self._client = dist.Client(self._cluster, timeout=f"{START_TIMEOUT_S}s")
                self._client.wait_for_workers(n, timeout=START_TIMEOUT_S)
                self.info = EngineInfo("local", str(self._cluster.scheduler_address), n)
            self._check_code()
            if self.warm is not None:
                from clm_core.studies.runner import worker_name
                from clm_core.studies.warm import WarmUp, warm_info

                # on every worker now and on every worker that joins later, before its first case
                self._client.register_plugin(WarmUp(self.warm), name=WarmUp.name)
                warm = self._client.run(warm_info)
                self.info.warm = [warm[a] for a in sorted(warm)]
                names = self._client.run(worker_name)
                self.info.worker_names = sorted(str(v) for v in names.values())
        except BaseException:
            self.close()
            raise
        return self

    def _open_remote(self, client_cls: Any) -> None:
        addr = str(self.scheduler)
        try:
            self._client = client_cls(addr, timeout="15s")
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler {addr}: cannot connect ({type(exc).__name__}: {exc}); start one with "
                             "`dask scheduler` and workers with `dask worker ADDRESS`") from None
        want = self.workers or 1
        try:
            self._client.wait_for_workers(want, timeout=WORKER_WAIT_S)
        except TimeoutError:
            have = len(self._client.scheduler_info().get("workers", {}))
            raise InputError(f"--scheduler {addr}: {have} worker(s) connected, {want} needed, after "
                             f"{WORKER_WAIT_S:g} s; start workers with `dask worker {addr}`") from None
        workers = self._client.scheduler_info().get("workers", {})
        threads = max((int(w.get("nthreads", 1)) for w in workers.values()), default=1)
        self.info = EngineInfo("remote", addr, len(workers), threads)

    def _check_code(self) -> None:
        """Refuse workers that run other clm_core code than this process (their cases would not be ours)."""
        from clm_core.studies.inputs import code_revision

        mine = code_revision()
        theirs = self._client.run(code_revision)
        other = sorted(f"{addr} (revision {rev[:12]})" for addr, rev in theirs.items() if rev != mine)
        if other:
            from clm_core import __version__

            raise InputError(f"{len(other)} worker(s) run other clm_core code than this client (revision "
                             f"{mine[:12]}, version {__version__}): {', '.join(other)}; install the same clm_core on "
                             "every worker")

    @property
    def client(self) -> Any:
        """The ``distributed.Client`` (inside the with-block)."""
        if self._client is None:
            raise ClmError("Engine.client outside its with-block")
        return self._client

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Close the client and the local cluster (a remote scheduler and its workers stay up)."""
        logging.getLogger("distributed").setLevel(logging.CRITICAL)  # no shutdown chatter
        if self._client is not None:
            try:
                self._client.close()
            finally:
                self._client = None
        if self._cluster is not None:
            try:
                self._cluster.close()
            finally:
                self._cluster = None
                self._restore_environ()

    def _restore_environ(self) -> None:
        """Put back the variables a nanny's pre-spawn environment overwrote in this process."""
        environ.restore(self._environ)

    def worker_cpu(self) -> float:
        """CPU time used so far by the worker processes, all threads, summed [s] (``getrusage``)."""
        if self._client is None:
            return 0.0
        return float(sum(self._client.run(_process_cpu).values()))

    def _share_inputs(self, tasks: Sequence[Task]) -> dict[tuple[str, str, str], Any]:
        """Shipped files that more than one task reads, sent to the workers once (``scatter``, to every worker,
        so one lost worker loses no input): ``{(sha256, name, source): future}``. The others travel inside
        their one task."""
        from clm_core.studies.inputs import Shipped

        count: dict[tuple[str, str, str], int] = {}
        first: dict[tuple[str, str, str], Shipped] = {}
        for t in tasks:
            for item in _shipped_in(t.args):
                count[_ident(item)] = count.get(_ident(item), 0) + 1
                first.setdefault(_ident(item), item)
        return {k: self._client.scatter(first[k], broadcast=True, hash=False) for k, n in count.items() if n > 1}

    def run(self, tasks: Sequence[Task], done: Callable[[Task, Mapping[str, Any] | None, str], None]) -> None:
        """Run every task; call ``done(task, row, '')`` as each finishes, in completion order.

        A task that could not return a row (its worker died repeatedly, the
        scheduler lost it) calls ``done(task, None, reason)`` instead. The
        tasks' own failures are inside their rows (they never raise).
        """
        as_completed = _distributed().as_completed
        if self._client is None:
            raise ClmError("Engine.run outside its with-block")
        nonce = uuid.uuid4().hex[:8]
        shared = self._share_inputs(tasks)
        futures = {}
        for t in tasks:
            args = tuple(_swap_shipped(a, shared) for a in t.args)
            fut = self._client.submit(t.func, *args, key=f"clm-{t.key}-{nonce}", pure=False)
            futures[fut.key] = (fut, t)
        for fut in as_completed([f for f, _ in futures.values()]):
            task = futures[fut.key][1]
            if fut.status == "finished":
                done(task, fut.result(), "")
            else:
                try:
                    err = fut.exception()
                    reason = f"{type(err).__name__}: {err}"
                except Exception as exc:  # cancelled: no exception to fetch
                    reason = f"{type(exc).__name__}: {exc}"
                done(task, None, reason)
            fut.release()
        self._restore_environ()  # a worker respawned during the run wrote its pre-spawn environment again
