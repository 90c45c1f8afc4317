"""A real ``dask scheduler`` and ``dask worker`` started as processes for the study tests.

:func:`dask_processes` starts them in a folder of the test's choosing (the
worker's working directory differs from the client's), optionally behind a
command prefix (``ip netns exec NS``: in another network namespace), and
stops them at the end.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from distributed import Client

ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False"}
DASK = str(Path(sys.executable).with_name("dask"))


def _stop(procs: Sequence[subprocess.Popen[bytes]]) -> None:
    for p in reversed(procs):
        if p.poll() is None:
            p.terminate()
    for p in reversed(procs):
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@contextmanager
def dask_processes(folder: Path, host: str = "127.0.0.1", workers: int = 1, prefix: Sequence[str] = (),
                   worker_cwd: Path | None = None, log: Path | None = None) -> Iterator[str]:
    """``dask scheduler`` and ``dask worker --nworkers N --nthreads 1`` on ``host``; yields the scheduler address
    once the N workers are connected (a loaded machine can take a minute to start them).

    Both run in ``worker_cwd`` (default ``folder``) behind ``prefix``; their
    logs go to ``log`` (default ``folder/dask.log``).
    """
    folder.mkdir(parents=True, exist_ok=True)
    sched_file = folder / "scheduler.json"
    cwd = worker_cwd or folder
    out = open(log or folder / "dask.log", "ab")  # closed below
    procs: list[subprocess.Popen[bytes]] = []
    try:
        procs.append(subprocess.Popen([*prefix, DASK, "scheduler", "--host", host, "--port", "0", "--no-dashboard",
                                       "--scheduler-file", str(sched_file)], env=ENV, cwd=cwd, stdout=out,
                                      stderr=subprocess.STDOUT))
        deadline = time.monotonic() + 120
        while not sched_file.is_file() or not sched_file.read_text().strip():
            assert procs[0].poll() is None, f"dask scheduler exited: {(log or folder / 'dask.log').read_text()}"
            assert time.monotonic() < deadline, "dask scheduler did not start in 120 s"
            time.sleep(0.1)
        address = str(json.loads(sched_file.read_text())["address"])
        procs.append(subprocess.Popen([*prefix, DASK, "worker", address, "--nworkers", str(workers), "--nthreads", "1",
                                       "--host", host, "--no-dashboard"], env=ENV, cwd=cwd, stdout=out,
                                      stderr=subprocess.STDOUT))
        with Client(address, timeout="120s") as client:  # connected before the test's own client waits (60 s)
            client.wait_for_workers(workers, timeout=600)
        yield address
    finally:
        _stop(procs)
        out.close()
