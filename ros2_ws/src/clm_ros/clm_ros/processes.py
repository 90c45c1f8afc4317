"""Starting and stopping ROS node processes on loopback, in a domain of their own.

Used by the demo launcher, the benchmarks and the tests (one allocator of
domain ids for all of them, so concurrent runs on one machine never share a
domain). Standard library only: importable without rclpy.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import random
import signal
import subprocess
import tempfile
import time
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from clm_ros.errors import ClmRosError

#: Domain ids handed out (0 is the default and avoided; Fast DDS allows up to 232).
DOMAIN_IDS = range(100, 232)


def _lock_dir() -> Path:
    path = Path(tempfile.gettempdir()) / "clm_ros_test_domains"
    path.mkdir(exist_ok=True)
    return path


@contextlib.contextmanager
def hold_domain_id(domain_id: int | None = None) -> Iterator[int]:
    """Hold a ROS domain id exclusively among the clm runs of this machine (a file lock) while the context is open.

    Parameters
    ----------
    domain_id : int, optional
        The id to hold; default: any free one of :data:`DOMAIN_IDS`.

    Raises
    ------
    ClmRosError
        ``domain_id`` is held by another process, or every id of :data:`DOMAIN_IDS` is.
    """
    if domain_id is not None:
        fd = _try_lock(domain_id)
        if fd is None:
            raise ClmRosError(f"ROS domain {domain_id} is in use by another clm run on this machine; "
                              "choose another (--domain)")
        try:
            yield domain_id
        finally:
            _unlock(fd)
        return
    ids = list(DOMAIN_IDS)
    start = random.randrange(len(ids))
    for candidate in ids[start:] + ids[:start]:
        fd = _try_lock(candidate)
        if fd is None:
            continue
        try:
            yield candidate
        finally:
            _unlock(fd)
        return
    raise ClmRosError(f"all ROS domain ids {DOMAIN_IDS.start}-{DOMAIN_IDS.stop - 1} are in use")


def _try_lock(domain_id: int) -> int | None:
    fd = os.open(_lock_dir() / f"{domain_id}.lock", os.O_CREAT | os.O_RDWR, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    return fd


def _unlock(fd: int) -> None:
    fcntl.flock(fd, fcntl.LOCK_UN)
    os.close(fd)


def proc_cpu_s(pid: int) -> float | None:
    """CPU time (user + system) of process ``pid`` so far [s]; None where /proc is not readable."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def ros_env(domain_id: int, base: Mapping[str, str] | None = None, pythonpath: Iterable[str] = ()) -> dict[str, str]:
    """Environment of a ROS process isolated on loopback in ``domain_id``.

    Parameters
    ----------
    domain_id : int
        ``ROS_DOMAIN_ID`` of the process.
    base : mapping, optional
        Environment to start from; default ``os.environ``.
    pythonpath : iterable of str
        Directories put in front of ``PYTHONPATH``.
    """
    env = dict(os.environ if base is None else base)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_STATIC_PEERS", None)
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated in Jazzy; warns if set with the above
    env["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    # a synchronous write sends from the publishing thread (no hand-over to a Fast DDS thread per message:
    # about half the publisher's CPU per 1-kHz message, clm_ros.node_main)
    env.setdefault("RMW_FASTRTPS_PUBLICATION_MODE", "SYNCHRONOUS")
    env["PYTHONUNBUFFERED"] = "1"
    paths = [*pythonpath, env.get("PYTHONPATH", "")]
    if any(paths):
        env["PYTHONPATH"] = os.pathsep.join(p for p in paths if p)
    return env


def ros_args(params: Mapping[str, Any]) -> list[str]:
    """``--ros-args -p name:=value ...`` for a parameter mapping (booleans true/false, an empty string ``''``)."""
    out = ["--ros-args"]
    for k, v in params.items():
        text = str(v).lower() if isinstance(v, bool) else "''" if v == "" else str(v)
        out += ["-p", f"{k}:={text}"]
    return out


def stop_processes(procs: Iterable[subprocess.Popen[Any]], timeout: float = 15.0) -> None:
    """SIGINT the processes still running; wait up to ``timeout`` s for all of them together, then SIGTERM what is
    left and wait up to a quarter of ``timeout`` more, then kill what is still left."""
    procs = list(procs)
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for sig, wait in ((signal.SIGTERM, timeout), (signal.SIGKILL, timeout / 4)):
        deadline = time.monotonic() + wait
        for p in procs:
            try:
                p.wait(timeout=max(deadline - time.monotonic(), 0.01))
            except subprocess.TimeoutExpired:
                pass
        left = [p for p in procs if p.poll() is None]
        if not left:
            return
        for p in left:
            p.send_signal(sig)
    for p in procs:
        p.wait()
