"""Real-time scheduling of a node process: every thread under ``SCHED_FIFO`` at one priority, when permitted.

On the 2-core machine the suite is measured on, the vehicle node, the track
node, a recorder and one busy-loop process share two cores at equal priority:
the answer lag's tail is then the scheduler's time slice (p99 6-33 ms with one
busy loop, over the 20-ms target in 4 of 14 demo runs; issue 10). Under
``SCHED_FIFO`` a node's thread that becomes runnable preempts every normal
thread at once, so another process's load no longer delays an answer; the
node's threads block between messages, so they take the CPU only for the work
itself (at 1 kHz 0.3-0.4 ms per message). ros2_control's controller manager
runs its loop the same way.

:func:`apply_fifo` is called by :func:`clm_ros.node_main.run_node` once a
node is built (JIT compilation, factorisation and discovery set-up done at
normal priority) and its executor exists, so it covers the threads of rclpy,
Fast DDS and the node; threads started later inherit the policy from the
thread that starts them. Linux's real-time throttling
(``/proc/sys/kernel/sched_rt_runtime_us``, 0.95 s in every 1 s by default)
keeps a runaway real-time thread from locking a core up.

Permission: root, ``CAP_SYS_NICE``, or an ``RLIMIT_RTPRIO`` (``ulimit -r``,
``rtprio`` in ``/etc/security/limits.conf``) at least the priority asked for.
Refused, the process keeps its normal scheduling and the outcome says why
(the nodes log it once and report it on /diagnostics): a node that cannot have
real-time scheduling still runs.

Linux only (``/proc/self/task`` and ``os.sched_setscheduler``); elsewhere the
outcome says it is not available.
"""

from __future__ import annotations

import errno
import os
from dataclasses import dataclass
from pathlib import Path

from clm_ros.parameters import REALTIME_PRIORITY

__all__ = ["MAX_PRIORITY", "NORMAL_THREADS", "NOT_APPLIED", "Scheduling", "apply_fifo", "release_fifo",
           "thread_scheduling"]

#: Highest priority a node may ask for: the setting's bound (99 is left to the kernel's watchdogs).
MAX_PRIORITY = int(REALTIME_PRIORITY.maximum or 0)

_TASKS = Path("/proc/self/task")


@dataclass(frozen=True)
class Scheduling:
    """What :func:`apply_fifo` did to the process.

    Attributes
    ----------
    requested : int
        The ``SCHED_FIFO`` priority asked for (0: none asked).
    priority : int
        The priority every thread has now (0: normal scheduling).
    threads : int
        Threads whose policy was set.
    reason : str
        Why the process runs at normal priority (``""`` when it got the
        priority, or none was asked).
    """

    requested: int
    priority: int
    threads: int = 0
    reason: str = ""

    @property
    def text(self) -> str:
        """One line for logs and /diagnostics: ``SCHED_FIFO 10 (12 threads)``, ``normal (...)``."""
        if self.priority:
            return f"SCHED_FIFO {self.priority} ({self.threads} threads)"
        if self.requested:
            return f"normal (SCHED_FIFO {self.requested} refused: {self.reason})"
        return f"normal ({self.reason or 'realtime_priority = 0'})"


#: Threads left under normal scheduling by :func:`apply_fifo` (prefixes of ``/proc/<pid>/task/<tid>/comm``): Fast DDS's
#: asynchronous writer thread (``dds.asyn.<participant>.<n>``), which in synchronous publication mode only resends
#: to reliable readers that missed samples, off the answer path. It waits for a writer's mutex in a ``try_lock``
#: loop (rmw_fastrtps#666): under ``SCHED_FIFO`` it never lets the holder run on its core, and two such threads held
#: both cores of the 2-core machine for the 600 s of a fleet's timeout (issue 21: ``clm fleet --trains 3`` 2 of 5
#: quiet runs, each track node's ``dds.asyn.0.0`` at 97 % CPU from 1 s into the train, 340-1540 of 5001 messages).
NORMAL_THREADS: tuple[str, ...] = ("dds.asyn",)

#: A node's scheduling until :func:`clm_ros.node_main.run_node` has applied its ``realtime_priority``.
NOT_APPLIED = Scheduling(0, 0, reason="not set by run_node")


def _thread_ids() -> list[int]:
    """The ids of this process's threads now."""
    return sorted(int(p.name) for p in _TASKS.iterdir() if p.name.isdigit())


def _stays_normal(tid: int) -> bool:
    """Whether thread ``tid`` is one of :data:`NORMAL_THREADS` (False when it ended meanwhile)."""
    try:
        name = (_TASKS / str(tid) / "comm").read_text().strip()
    except OSError:
        return False
    return name.startswith(NORMAL_THREADS)


def thread_scheduling(pid: int | str = "self") -> dict[int, tuple[int, int]]:
    """Policy and real-time priority of every thread of a process, read from ``/proc``.

    Parameters
    ----------
    pid : int or "self"
        The process.

    Returns
    -------
    dict
        Thread id -> (policy, rt_priority): policy 0 is ``SCHED_OTHER``, 1
        ``SCHED_FIFO``, 2 ``SCHED_RR`` (fields 41 and 40 of
        ``/proc/<pid>/task/<tid>/stat``). A thread that ends while it is read
        is left out.
    """
    out: dict[int, tuple[int, int]] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) ": field 3 onwards
        out[int(task.name)] = (int(fields[41 - 3]), int(fields[40 - 3]))
    return out


def apply_fifo(priority: int) -> Scheduling:
    """Put every thread of this process under ``SCHED_FIFO`` at ``priority``, or leave them all as they are.

    Threads named in :data:`NORMAL_THREADS` keep normal scheduling.

    Parameters
    ----------
    priority : int
        1 to :data:`MAX_PRIORITY`; 0 changes nothing.

    Returns
    -------
    Scheduling
        What was done. When a thread's change is refused (no permission),
        the threads already changed are put back to ``SCHED_OTHER``: the
        process is never left half real-time.

    Raises
    ------
    ValueError
        ``priority`` outside 0 to :data:`MAX_PRIORITY`.
    """
    if not 0 <= priority <= MAX_PRIORITY:
        raise ValueError(f"realtime_priority = {priority}: must be 0 (off) to {MAX_PRIORITY}")
    if priority == 0:
        return Scheduling(0, 0)
    if not (hasattr(os, "sched_setscheduler") and _TASKS.is_dir()):
        return Scheduling(priority, 0, reason="not available on this system (Linux only)")
    done: list[int] = []
    try:
        for tid in _thread_ids():
            if _stays_normal(tid):
                continue
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            except ProcessLookupError:
                continue  # the thread ended meanwhile
            done.append(tid)
    except OSError as exc:
        for tid in done:
            try:
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
            except OSError:
                pass
        why = ("not permitted: needs root, CAP_SYS_NICE or `ulimit -r` >= the priority"
               if exc.errno == errno.EPERM else os.strerror(exc.errno or 0))
        return Scheduling(priority, 0, reason=why)
    return Scheduling(priority, priority, threads=len(done))


def release_fifo() -> int:
    """Put every real-time thread of this process back under ``SCHED_OTHER``; return how many were.

    :func:`clm_ros.node_main.run_node` calls it as soon as a stop is
    requested: the shut-down (the node's drain, the executor, the DDS
    participant and its transports) runs at normal priority. A wait that
    spins there (a yield loop on another thread's progress, a resend to a
    starved peer) is then one normal process among others instead of a
    ``SCHED_FIFO`` one that preempts everything normal, the peer it waits for
    included (issue 21: fleet pairs stuck at ~92 % CPU after SIGINT, load 124,
    until SIGKILL). Threads that end meanwhile are skipped; errors are ignored
    (a process that could raise its priority can lower it).
    """
    if not (hasattr(os, "sched_setscheduler") and _TASKS.is_dir()):
        return 0
    n = 0
    for tid, (policy, _) in thread_scheduling().items():
        if policy in (os.SCHED_FIFO, os.SCHED_RR):
            try:
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                n += 1
            except OSError:
                continue
    return n
