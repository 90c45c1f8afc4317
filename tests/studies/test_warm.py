"""The compile-cache warm-up of the study workers (:class:`clm_core.studies.warm.WarmUp`, a worker plugin): every
worker process is warmed once, at connect, before its first case, including a worker that joins a running study;
one process of a host at a time (a file lock). Real processes: ``dask scheduler`` and ``dask worker``."""

from __future__ import annotations

import subprocess
import threading
import time
from pathlib import Path

from clm_core.studies.engine import Engine
from clm_core.studies.runner import warm_up
from clm_core.studies.warm import host_lock, task_warm_info, warm_info
from tests.studies.cluster import DASK, ENV, dask_processes


def test_a_worker_that_joins_later_is_warmed_before_its_first_task(tmp_path: Path) -> None:
    with dask_processes(tmp_path / "dask", workers=1) as address, \
            Engine(address, workers=1, warm=warm_up) as engine:
        first = engine.info.warm
        assert len(first) == 1 and first[0]["error"] == "" and first[0]["warm_s"] > 0
        before = set(engine.client.scheduler_info()["workers"])
        late = subprocess.Popen([DASK, "worker", address, "--nthreads", "1", "--host", "127.0.0.1",
                                 "--no-dashboard"], env=ENV, cwd=tmp_path, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        try:
            engine.client.wait_for_workers(2, timeout=300)
            new = sorted(set(engine.client.scheduler_info()["workers"]) - before)
            assert len(new) == 1
            # the new worker's first task already finds the warm-up done (the setup runs before it takes tasks)
            info = engine.client.submit(task_warm_info, workers=new, pure=False).result(timeout=300)
            assert info["error"] == "" and info["warm_s"] > 0, info
            # and it was warmed once: the first worker's record is the one of the start, unchanged
            again = engine.client.run(warm_info)
            assert len(again) == 2 and all(v["error"] == "" for v in again.values())
            assert [v for k, v in again.items() if k not in new] == first
        finally:
            late.terminate()
            late.wait(timeout=60)


def test_the_host_lock_lets_one_process_at_a_time() -> None:
    inside: list[int] = []
    most = [0]

    def hold() -> None:
        with host_lock("test.lock"):
            inside.append(1)
            most[0] = max(most[0], len(inside))
            time.sleep(0.05)
            inside.pop()

    # flock is per open file description: threads that each open the file exclude one another as processes do
    threads = [threading.Thread(target=hold) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert most[0] == 1
