"""The calibration node's book of calibrations (the queue, the running one, the counts, the request ids) and worker.

:class:`JobBook` holds, under one lock (the executor thread admits and
concludes, the worker thread runs), every calibration the node knows:

- admission (:meth:`JobBook.busy_reason`): one runs, at most ``max_queued``
  wait; a new one when the queue is full is refused with the reason;
- the service's **request ids** (issue 21): a ``clm_msgs/srv/Calibrate``
  request with a non-empty ``request_id`` is registered under it
  (:meth:`JobBook.by_request_id`); a request that comes again with the same
  id (a client that sent again after a lost response) gets the first one's
  job, waits for it if it still runs and is answered with its outcome: never
  a second fit. The last :data:`REQUEST_IDS_KEPT` ids are remembered. A
  refused request (busy, shutting down) is not registered: no fit was done,
  so sending it again later may run it (still at most once);
- the counts and last outcome of ``/diagnostics`` (:meth:`JobBook.values`,
  :func:`status`).

:class:`JobRunner` runs them one at a time in a worker thread, and stops it
all at shutdown. No ROS here but :class:`rclpy.task.Future` (each job's outcome, awaited by its
goal or service call(s)).
"""

from __future__ import annotations

import queue
import threading
import time
from collections import Counter, OrderedDict, deque
from collections.abc import Callable
from typing import Any

from rclpy.task import Future

from clm_ros.calibration_goal import ABORTED, CANCELED, SUCCEEDED, CalibrationOutcome, CalibrationRequest, failed

#: How many service request ids (and their calibrations) are remembered for a repeated request.
REQUEST_IDS_KEPT = 1000


class Job:
    """One calibration in the node: the request, its goal (None for a service call), its state."""

    def __init__(self, request: CalibrationRequest, goal: Any, label: str) -> None:
        self.request = request
        self.goal = goal
        self.label = label
        self.done = Future()  # CalibrationOutcome, set by the worker (or by a shutdown)
        self.state = "queued"  # queued | running | dropped (canceled or aborted before it started)
        self.started = 0.0
        self.stage = "queued"
        self.fraction = 0.0

    def cancel_requested(self) -> bool:
        """True once a cancel of its goal was accepted."""
        return self.goal is not None and bool(self.goal.is_cancel_requested)


class JobBook:
    """The queue, the running calibration, the goals by id, the service's request ids, the counts.

    Every attribute is read and changed with :attr:`lock` held.
    """

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.queue: deque[Job] = deque()
        self.running: Job | None = None
        self.goals: dict[bytes, Job] = {}
        self.counts: Counter[str] = Counter()
        self.last: dict[str, str] = {}
        self.requests: OrderedDict[str, Job] = OrderedDict()
        self.n_requests = 0

    def busy_reason(self, stopping: bool, max_queued: int) -> str:
        """Why a new calibration cannot wait now ('' if it can)."""
        if stopping:
            return "the node is shutting down"
        if self.running is not None and len(self.queue) >= max_queued:
            run = self.running
            return (f"a calibration is running ({run.request.method} of {run.request.bag!r}, {run.stage}) and "
                    f"{len(self.queue)} wait (max_queued = {max_queued})")
        return ""

    def admit(self, job: Job, request_id: str = "") -> None:
        """Queue ``job`` (counted accepted; under ``request_id`` when one is given)."""
        self.counts["accepted"] += 1
        self.queue.append(job)
        if request_id:
            self.requests[request_id] = job
            while len(self.requests) > REQUEST_IDS_KEPT:
                self.requests.popitem(last=False)

    def by_request_id(self, request_id: str) -> Job | None:
        """The calibration of an earlier request with this id (counted as a repeated request), or None."""
        job = self.requests.get(request_id) if request_id else None
        if job is not None:
            self.counts["repeated_requests"] += 1
        return job

    def concluded(self, job: Job, outcome: CalibrationOutcome) -> None:
        """Count a job's outcome and keep it as the last one."""
        key = {SUCCEEDED: "succeeded", CANCELED: "canceled"}.get(outcome.status, "failed")
        self.counts[key] += 1
        if job.goal is not None:
            self.goals.pop(bytes(job.goal.goal_id.uuid), None)
        if self.running is job:
            self.running = None
        self.last["outcome"] = f"{outcome.status}: {outcome.message}"
        self.last["goal"] = job.label
        if outcome.result is not None:
            r = outcome.result
            self.last.update(misfit=f"{r.misfit:.6g}", duration_s=f"{r.elapsed_s:.3f}", method=r.method, bag=r.bag)
        if outcome.push is not None:
            p = outcome.push
            self.last.update(push_target=p.target, push="accepted" if p.accepted else f"failed: {p.reason}")

    def values(self) -> dict[str, str]:
        """The key-value pairs of the node's ``/diagnostics`` status."""
        run, c = self.running, self.counts
        values = {
            "state": "running" if run is not None else "idle",
            "queued": str(len(self.queue)),
            **{f"goals_{k}": str(c[k]) for k in ("accepted", "rejected", "succeeded", "failed", "canceled")},
            "repeated_requests": str(c["repeated_requests"]),
        }
        if run is not None:
            values.update(current_goal=run.label, current_method=run.request.method, current_bag=run.request.bag,
                          current_stage=run.stage, current_fraction=f"{run.fraction:.3f}",
                          current_elapsed_s=f"{time.monotonic() - run.started:.3f}")
        values.update({f"last_{k}": v for k, v in self.last.items()})
        return values


def status(values: dict[str, str]) -> tuple[Any, str, dict[str, str]]:
    """(level, message, values) of the node's ``/diagnostics`` status from :meth:`JobBook.values`: WARN when the last
    calibration or push failed, OK otherwise (``diagnostic_msgs/DiagnosticStatus`` levels, one byte); the message
    says what runs, or the last failure when idle."""
    level, message = b"\x00", values["state"]
    if values["state"] == "running":
        message = (f"running {values['current_method']} on {values['current_bag']!r}: "
                   f"{values['current_stage']} ({100 * float(values['current_fraction']):.0f} %)")
    last = values.get("last_outcome", "")
    if last.startswith(("aborted", "failed")) or values.get("last_push", "").startswith("failed"):
        level = b"\x01"
        if values["state"] == "idle":
            message = f"idle; last calibration {last[:200]}"
    return level, message, values


class JobRunner:
    """The worker thread that runs the book's calibrations one at a time, and the stop of it all.

    Parameters
    ----------
    book : JobBook
    run : callable
        ``run(job) -> CalibrationOutcome``, called in the worker thread (never raises:
        :func:`clm_ros.calibration_work.run_job`).
    wake : callable
        Wakes the executor (a guard condition's ``trigger``): a job's outcome is there.
    log : NodeLog
        The node's log (:class:`clm_ros.node_log.NodeLog`).
    """

    def __init__(self, book: JobBook, run: Callable[[Job], CalibrationOutcome], wake: Callable[[], None],
                 log: Any) -> None:
        self.book, self._run, self._wake, self._log = book, run, wake, log
        #: set at shutdown: nothing new starts, a running fit stops at its next progress report
        self.stop = threading.Event()
        self._inbox: queue.SimpleQueue[Job | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._work, name="calibration", daemon=True)
        self._thread.start()

    def complete(self, job: Job, outcome: CalibrationOutcome) -> None:
        """Give a job its outcome (once) and wake the executor so the waiting goal or call concludes."""
        if not job.done.done():
            job.done.set_result(outcome)
        self._wake()

    def pump(self) -> None:
        """Start the next calibration if none runs; drop queued goals whose cancel was accepted (executor thread)."""
        start: list[Job] = []
        book = self.book
        with book.lock:
            for job in [j for j in book.queue if j.cancel_requested()]:
                book.queue.remove(job)
                job.state = "dropped"
                self.complete(job, failed(CANCELED, "canceled while queued (never started)", job.request))
                start.append(job)
            if book.running is None and book.queue and not self.stop.is_set():
                job = book.queue.popleft()
                job.state, job.started, book.running = "running", time.monotonic(), job
                start.append(job)
        for job in start:
            if job.goal is not None:
                job.goal.execute()  # -> EXECUTING (or stays CANCELING); the action server runs the goal
            if job.state == "running":
                self._inbox.put(job)

    def _work(self) -> None:
        """Worker thread: run the jobs handed over by :meth:`pump`, one at a time."""
        while True:
            job = self._inbox.get()
            if job is None:
                return
            try:
                outcome = self._run(job)
            except BaseException as exc:  # the worker must survive anything and answer
                self._log.exception(f"{job.label}: internal error of the calibration node")
                outcome = failed(ABORTED, f"internal error of the calibration node: {type(exc).__name__}: {exc}",
                                 job.request)
            self.complete(job, outcome)

    def begin_shutdown(self) -> None:
        """Accept nothing more, abort what waits, ask the running fit to stop at its next progress report."""
        self.stop.set()
        with self.book.lock:
            waiting = list(self.book.queue)
            self.book.queue.clear()
        for job in waiting:
            job.state = "dropped"
            self.complete(job, failed(ABORTED, "node shutting down before the calibration started", job.request))
            if job.goal is not None:
                job.goal.execute()

    def idle(self) -> bool:
        """True when no calibration runs or waits."""
        with self.book.lock:
            return self.book.running is None and not self.book.queue

    def abandon(self, grace: float) -> None:
        """Answer a fit that did not stop within ``grace`` s (its daemon thread is left to the process exit); stop
        the worker."""
        with self.book.lock:
            run = self.book.running
        if run is not None:
            self.complete(run, failed(ABORTED, f"node shutting down: the fit did not stop within {grace:g} s "
                                      f"('{run.stage}')", run.request))
        self.close()

    def abandoned(self) -> bool:
        """True if a fit was abandoned at shutdown and its thread still runs."""
        return self._thread.is_alive() and self.stop.is_set()

    def close(self) -> None:
        """Stop the worker (after the job under way)."""
        self.stop.set()
        self._inbox.put(None)
