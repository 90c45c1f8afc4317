"""Warm-up of the study workers: the compiled kernels loaded once per worker process, at connect.

:class:`WarmUp` is a ``distributed`` worker plugin: the scheduler runs its
:meth:`~WarmUp.setup` on every worker connected when the study starts *and*
on every worker that joins later, before any case runs there. The first
worker process of a host compiles the numba kernels and writes them to
numba's on-disk cache; the others of the same host wait on a file lock
(:func:`host_lock`) and then load the cached code instead of compiling it
again concurrently. Imported by :mod:`clm_core.studies.engine` only when an
engine opens (it imports ``distributed``).
"""

from __future__ import annotations

import fcntl
import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

from clm_core.studies.inputs import inputs_root

log = logging.getLogger(__name__)


@contextmanager
def host_lock(name: str = "compile.lock") -> Iterator[None]:
    """An exclusive lock shared by the processes of this host and user (``flock`` on a file in the temp folder)."""
    root = inputs_root()
    root.mkdir(parents=True, exist_ok=True)
    with open(root / name, "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


class WarmUp(WorkerPlugin):
    """Run ``warm`` once in every worker process, at connect, one process of a host at a time.

    Parameters
    ----------
    warm : callable
        Loads the code (:func:`clm_core.studies.runner.warm_up`); importable, so picklable by reference.
    """

    name = "clm-study-warm-up"

    def __init__(self, warm: Callable[[], str]) -> None:
        self.warm = warm

    async def setup(self, worker: Any) -> None:
        """Called by the worker when the plugin is registered or the worker joins. The warm-up runs in a thread,
        so the worker's event loop keeps answering the scheduler (heartbeats) while it compiles or waits for the
        host's lock. Never raises (a broken install then fails each case in its row, with its message)."""
        import asyncio

        worker.clm_warm = await asyncio.get_running_loop().run_in_executor(None, self.run)

    def run(self) -> dict[str, Any]:
        """Warm this process, one process of the host at a time; return what it took (``warm_s``,
        ``lock_wait_s`` [s], ``error``)."""
        t0 = time.perf_counter()
        waited = 0.0
        error = ""
        try:
            with host_lock():
                waited = time.perf_counter() - t0
                self.warm()
        except Exception as exc:  # reported in study.json; the cases report their own failure
            log.warning("clm study warm-up failed: %s: %s", type(exc).__name__, exc)
            error = f"{type(exc).__name__}: {exc}"
        return {"warm_s": time.perf_counter() - t0, "lock_wait_s": waited, "error": error}


def warm_info(dask_worker: Any) -> dict[str, Any]:
    """What :class:`WarmUp` did in this worker (run with ``Client.run``): ``warm_s``, ``lock_wait_s``, ``error``."""
    info = getattr(dask_worker, "clm_warm", None)
    return dict(info) if isinstance(info, dict) else {"warm_s": None, "lock_wait_s": None, "error": "not warmed"}


def task_warm_info() -> dict[str, Any]:
    """:func:`warm_info` of the worker running this task (submit it as a task: it runs after the worker's setup)."""
    from distributed import get_worker

    return warm_info(get_worker())
