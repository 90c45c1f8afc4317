"""The calibration node: fits model parameters to a recorded bag, as an action with progress and cancel.

``clm_calibration_node`` offers, under one name (``/clm_calibration_node/calibrate``
with the default node name):

- the **action** ``clm_msgs/action/Calibrate``: the goal names a bag, a
  method (``impact``, ``receptance``, ``passby``; empty: the
  ``default_method`` parameter) and typed options (band, norm, soil model,
  chain length or automatic, interval method, fitted names, starting values,
  ...; ``options_yaml`` for the rare rest) and optionally a node to push the
  fitted parameters to. Feedback: ``stage``, ``fraction`` (0 to 1, never
  decreasing), ``message``, ``elapsed``, at every stage of
  :func:`clm_core.calibration.calibrate` (impact test: reading bag, records
  checked, transfer functions, CLM fit, comparison fits, done), within a fit
  at most every :data:`FEEDBACK_PERIOD` s as its model evaluations add up,
  and at the push. Result: ``success``, a one-line ``message``, the fitted parameters
  (``names``, ``units``, ``values``, ``std_error``, ``ci95_low``,
  ``ci95_high``, ``identifiable``, ``at_bound``), fit quality (``misfit``,
  ``rms_residual``, ``n_areas``, ``fit_duration``, ``warnings``), the
  parameter file (``parameters_yaml``), the push outcome and ``metrics_json``
  (``summary.json``: first estimate, comparisons, chain trials, residual
  check, record information).
- the **service** ``clm_msgs/srv/Calibrate`` (options as YAML): the same
  queue, the same code path, the same outcome, without feedback or cancel.

Terminal states: SUCCEEDED (fit done and, if asked, pushed), ABORTED (bad
bag, path, method or options, a fit that cannot be done, a refused or failed
push: ``message`` says which; a fit that succeeded before a failed push is
still in the result), CANCELED (cancel accepted; the result says at which
stage).

**One calibration at a time, the others queued.** Goals and service calls
are run in arrival order by one worker thread; a goal waiting its turn stays
ACCEPTED and gets a ``queued`` feedback. At most ``max_queued`` wait: a goal
arriving when the queue is full is rejected (logged, counted in
``/diagnostics``), a service call is answered at once with ``success =
false`` and a message starting with ``busy``. ``max_queued = 0``: no queue,
reject while busy. A burst (goals, cancels, result requests, service calls
sent at once) is taken whole up to :data:`REQUEST_DEPTH` per queue: each one
is answered, or refused and counted (issue 26.1; rclpy's default depth of 10
dropped the rest unanswered).

**What a goal may read.** The bag, ``params_file`` and ``channels`` must lie
under a directory of ``allowed_roots`` and be regular files (a bag directory
holds only regular files and directories): a goal cannot make the node read
any file of the machine, nor block it on a FIFO or a device; a refusal names
the path and the rule, never the file's contents
(:func:`clm_ros.calibration_goal.check_paths`). Every failure of a goal,
invalid or hostile options included (YAML nested too deeply for the parser),
aborts it with its reason.

**Cancel.** A running fit stops at its next progress report, at the latest
after the model evaluation under way (each evaluation of a fit reports; the
longest stretch without a report on the shipped bags is 0.2-0.6 s, between
stages), and the goal ends CANCELED; a queued goal ends CANCELED within 0.05 s. A
cancel arriving during the push does not interrupt it (one atomic request,
bounded by ``push_timeout``): the goal ends with the push's outcome.

**Push.** With ``push_to_node`` the fitted parameters go to a running track
node (``target_node``, e.g. ``/clm_track_node``) as ``<section>.<name>``
DOUBLE parameters (:func:`clm_ros.calibration_push.push_values`) through its
``set_parameters_atomically`` service: the track node validates the whole set
against its own configuration and takes all of it or none. A refusal, a
target that is not running or that stops answering (dies) within
``push_timeout`` is logged, reported in the result and in ``/diagnostics``;
the node keeps serving and the next push reaches a target that has come
back.

**Diagnostics.** ``/diagnostics`` every ``diagnostics_period`` and at every
start and end of a calibration: state (idle, running), queue length, counts
of goals accepted, rejected, succeeded, failed, canceled, the running goal's
stage and fraction, the last fit's outcome, misfit and duration, the last
push's target and outcome. Level WARN when the last calibration or push
failed.

**Threading.** The callbacks (goals, cancels, service calls, timers) run in
a single-threaded executor and never block; the fit and the push run one at
a time in a worker thread, which publishes the feedback and completes the
goal's future.

**Shutdown.** SIGINT or SIGTERM: no new goal is accepted, queued goals are
aborted, a running fit is stopped at its next progress report (given at
most :data:`SHUTDOWN_GRACE` s; the fit runs in a daemon thread, so a stage
that takes longer does not hold the exit), the results go out, and the
process exits with code 0 (within 2 s).

Parameters
----------
default_method : str
    Method used when a goal or request leaves ``method`` empty (default ``impact``).
push_timeout : float
    How long a push waits for the target's parameter service and its answer [s] (default 10).
max_queued : int
    Goals and requests that may wait while one runs (default 4).
allowed_roots : str
    Directories (comma-separated) under which bags, parameter files and
    channel maps may lie (default ``.``, the node's working directory; read-only).
diagnostics_period : float
    Period of ``/diagnostics`` [s] (default 1; read-only), on the steady clock:
    they go on with ``use_sim_time`` and no ``/clock``, and so does the check of
    queued goals for a cancel.

Run: ``python -m clm_ros.calibration_node`` or the console script
``calibration_node`` (``ros2 run clm_ros calibration_node`` in a full ROS
install); ``ros2 action send_goal --feedback /clm_calibration_node/calibrate
clm_msgs/action/Calibrate "{bag_path: bags/calibration/impact_mevergnies,
fmax: 140.0}"``.
"""

from __future__ import annotations

import math
import queue
import sys
import threading
import time
import traceback
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from clm_msgs.action import Calibrate as CalibrateAction
from clm_msgs.srv import Calibrate
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.clock import Clock, ClockType
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future

from clm_core.calibration import BagError, CalibrationError, calibrate
from clm_core.calibration.options import METHODS
from clm_core.errors import ClmError
from clm_core.settings import Setting
from clm_ros.calibration_goal import (
    ABORTED,
    ALLOWED_ROOTS,
    CANCELED,
    SUCCEEDED,
    CalibrationOutcome,
    CalibrationRequest,
    action_result,
    check_paths,
    failed,
    fit_message,
    parse_roots,
    request_from_goal,
    request_from_service,
    service_response,
)
from clm_ros.calibration_push import (
    ParameterPusher,
    PushOutcome,
    one_line,
    parameter_messages,
    push_values,
    target_service,
)
from clm_ros.diagnostics import publish_status
from clm_ros.node_main import StopSignals, run_node
from clm_ros.parameters import declare_settings

__all__ = ["CalibrationNode", "PushOutcome", "main", "parameter_messages", "push_values", "target_service"]

NODE_NAME = "clm_calibration_node"
#: Action and service name, relative to the node (``/clm_calibration_node/calibrate``).
ACTION_NAME = SERVICE_NAME = "~/calibrate"
#: How long a shutdown waits for a running fit to stop at its next progress report [s].
SHUTDOWN_GRACE = 0.5
#: After the last calibration ended, how long a shutdown keeps spinning so its result reaches the client [s].
FLUSH_S = 0.2
#: How often queued goals are checked for a cancel request [s].
QUEUE_POLL_S = 0.05
#: Share of the feedback fraction given to the fit when a push follows.
FIT_SHARE_WITH_PUSH = 0.9
#: Least time between two feedback messages of one stage [s] (a new stage is sent at once; a cancel is checked at
#: every progress report, sent or not).
FEEDBACK_PERIOD = 0.1

DEFAULT_METHOD: Setting[str] = Setting("default_method", str, "impact", "-",
                                       "method used when a goal leaves 'method' empty", choices=METHODS)
MAX_QUEUED: Setting[int] = Setting("max_queued", int, 4, "-", "goals that may wait while one runs (0: reject "
                                   "while busy)", minimum=0, maximum=1000)

#: History depth of the action's services (goal, cancel, result), its feedback and the ``Calibrate`` service, on
#: both sides of each (request and response). rclpy's default is 10: of a burst of goals, cancels, result requests
#: or service calls sent faster than the executor takes them, the middleware kept the last 10 and dropped the rest
#: unanswered (issue 26.1: 10 of 20 and 10 of 50 service calls answered, 12 of 400 cancels). A burst of up to this
#: many is now taken whole and each one answered (or refused, counted); a client that sends bursts needs the same
#: depth on its side (:func:`request_qos`) or its own middleware may drop the answers.
REQUEST_DEPTH = 1000


def request_qos() -> QoSProfile:
    """QoS of the action's and the service's requests and answers: reliable, keep last :data:`REQUEST_DEPTH`."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=REQUEST_DEPTH, reliability=ReliabilityPolicy.RELIABLE)


class CalibrationStopped(BaseException):
    """Raised inside a running fit (from its progress callback) on cancel or shutdown.

    A ``BaseException`` so that no ``except Exception`` on the way swallows it.
    """


class _Job:
    """One calibration in the node: the request, its goal (None for a service call), its state."""

    def __init__(self, request: CalibrationRequest, goal: ServerGoalHandle | None, label: str) -> None:
        self.request = request
        self.goal = goal
        self.label = label
        self.done = Future()  # CalibrationOutcome, set by the worker (or by a shutdown)
        self.state = "queued"  # queued | running | dropped (canceled or aborted before it started)
        self.started = 0.0
        self.stage = "queued"
        self.fraction = 0.0

    def cancel_requested(self) -> bool:
        return self.goal is not None and self.goal.is_cancel_requested


class CalibrationNode(Node):
    """Node offering the ``~/calibrate`` action and service; see the module docstring.

    Parameters
    ----------
    signals : StopSignals, optional
        The process's SIGINT/SIGTERM (:func:`clm_ros.node_main.run_node`), named in the shutdown's log.
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ...).

    Raises
    ------
    ValueError
        ``default_method`` is not a method.
    """

    def __init__(self, signals: StopSignals | None = None, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._signals = signals  # the process's SIGINT/SIGTERM (clm_ros.node_main), for the shutdown's log
        declare_settings(self, (DEFAULT_METHOD, MAX_QUEUED, ALLOWED_ROOTS, "push_timeout", "diagnostics_period"))
        method = str(self.get_parameter("default_method").value)
        DEFAULT_METHOD.check(method)  # the values at start (later changes are checked by declare_settings)
        self._roots = parse_roots(str(self.get_parameter("allowed_roots").value))  # read-only: fixed at start

        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._queue: deque[_Job] = deque()
        self._running: _Job | None = None
        self._goals: dict[bytes, _Job] = {}
        self._counts: Counter[str] = Counter()
        self._last: dict[str, str] = {}
        self._n_requests = 0
        self._pusher = ParameterPusher(self, self._stop)
        self._inbox: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()

        # callbacks run in a single-threaded executor and never block: the fit and the push run in
        # self._worker; a goal or call awaits its job's future, which the worker completes and wakes
        self._wake = self.create_guard_condition(lambda: None)
        self.action_server = ActionServer(
            self, CalibrateAction, ACTION_NAME, self._execute_goal,
            goal_callback=self._on_goal, handle_accepted_callback=self._on_accepted,
            cancel_callback=self._on_cancel, goal_service_qos_profile=request_qos(),
            result_service_qos_profile=request_qos(), cancel_service_qos_profile=request_qos(),
            feedback_pub_qos_profile=request_qos(),
        )
        self.service = self.create_service(Calibrate, SERVICE_NAME, self._serve, qos_profile=request_qos())
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # both timers on the steady clock: with use_sim_time and no /clock, ROS time stands still and timers of
        # the node's default clock would never fire (no diagnostics, a queued goal's cancel never seen)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._diag_timer = self.create_timer(float(self.get_parameter("diagnostics_period").value),
                                             self.publish_diagnostics, clock=steady)
        self._queue_timer = self.create_timer(QUEUE_POLL_S, self._pump, clock=steady)
        self._worker = threading.Thread(target=self._work, name="calibration", daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"ready: action and service {self.service.service_name} (methods {', '.join(METHODS)}, "
            f"up to {self._max_queued()} queued; files read under {', '.join(map(str, self._roots))})"
        )

    # ------------------------------------------------------------------ admission and queue

    def _max_queued(self) -> int:
        return int(self.get_parameter("max_queued").value)

    def _default_method(self) -> str:
        return str(self.get_parameter("default_method").value)

    def _busy_reason(self) -> str:
        """Why a new calibration cannot wait now ('' if it can); call with the lock held."""
        if self._stop.is_set():
            return "the node is shutting down"
        if self._running is not None and len(self._queue) >= self._max_queued():
            run = self._running
            return (f"a calibration is running ({run.request.method} of {run.request.bag!r}, {run.stage}) and "
                    f"{len(self._queue)} wait (max_queued = {self._max_queued()})")
        return ""

    def _on_goal(self, goal: CalibrateAction.Goal) -> GoalResponse:
        with self._lock:
            reason = self._busy_reason()
            if reason:
                self._counts["rejected"] += 1
        if reason:
            self.get_logger().warning(f"goal rejected ({goal.method or self._default_method()} of "
                                      f"{goal.bag_path!r}): {reason}")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_accepted(self, goal: ServerGoalHandle) -> None:
        label = bytes(goal.goal_id.uuid).hex()[:8]
        try:
            request = request_from_goal(goal.request, self._default_method())
        except BaseException as exc:  # an accepted goal is always registered, so that it is always answered
            request = CalibrationRequest(bag=str(goal.request.bag_path), method=str(goal.request.method),
                                         error=f"invalid goal: {type(exc).__name__}: {exc}")
        job = _Job(request, goal, label)
        with self._lock:
            self._goals[bytes(goal.goal_id.uuid)] = job
            self._counts["accepted"] += 1
            self._queue.append(job)
            ahead = len(self._queue) - 1 + (self._running is not None)
        if ahead:
            self._feedback(job, "queued", 0.0, f"queued: {ahead} calibration(s) ahead")
        self._pump()

    def _on_cancel(self, goal: ServerGoalHandle) -> CancelResponse:
        job = self._goals.get(bytes(goal.goal_id.uuid))
        if job is None or job.done.done():
            return CancelResponse.REJECT
        self.get_logger().info(f"goal {job.label}: cancel requested ({job.stage})")
        return CancelResponse.ACCEPT

    def _pump(self) -> None:
        """Start the next calibration if none runs; drop queued goals whose cancel was accepted."""
        start: list[_Job] = []
        with self._lock:
            for job in [j for j in self._queue if j.cancel_requested()]:
                self._queue.remove(job)
                job.state = "dropped"
                self._complete(job, failed(CANCELED, "canceled while queued (never started)", job.request))
                start.append(job)
            if self._running is None and self._queue and not self._stop.is_set():
                job = self._queue.popleft()
                job.state = "running"
                job.started = time.monotonic()
                self._running = job
                start.append(job)
        for job in start:
            if job.goal is not None:
                job.goal.execute()  # -> EXECUTING (or stays CANCELING); the action server calls _execute_goal
            if job.state == "running":
                self._inbox.put(job)

    def _complete(self, job: _Job, outcome: CalibrationOutcome) -> None:
        """Give a job its outcome (once) and wake the executor so the waiting goal or call concludes."""
        if not job.done.done():
            job.done.set_result(outcome)
        self._wake.trigger()

    # ------------------------------------------------------------------ action and service

    async def _execute_goal(self, goal: ServerGoalHandle) -> CalibrateAction.Result:
        job = self._goals.get(bytes(goal.goal_id.uuid))
        if job is None:  # not expected: every accepted goal is registered first
            goal.abort()
            return CalibrateAction.Result(success=False, message="internal error: unknown goal")
        outcome: CalibrationOutcome = await job.done
        try:
            result = action_result(outcome, CalibrateAction.Result)
        except Exception as exc:  # the goal must end with a result that says what happened
            self.get_logger().error(traceback.format_exc())
            outcome = failed(ABORTED, f"internal error of the calibration node: {type(exc).__name__}: {exc}",
                             job.request)
            result = action_result(outcome, CalibrateAction.Result)
        self._conclude(job, outcome)
        return result

    async def _serve(self, request: Calibrate.Request, response: Calibrate.Response) -> Calibrate.Response:
        """The ``Calibrate`` service: the same queue and code path as a goal, answered when done."""
        with self._lock:
            self._n_requests += 1
            label = f"request-{self._n_requests}"
            reason = self._busy_reason()
            if reason:
                self._counts["rejected"] += 1
            else:
                job = _Job(request_from_service(request, self._default_method()), None, label)  # never raises
                self._counts["accepted"] += 1
                self._queue.append(job)
        if reason:
            self.get_logger().warning(f"{label} refused: busy: {reason}")
            return service_response(failed(ABORTED, f"busy: {reason}; try again later"), response)
        self._pump()
        outcome: CalibrationOutcome = await job.done
        self._conclude(job, outcome)
        return service_response(outcome, response)

    def _conclude(self, job: _Job, outcome: CalibrationOutcome) -> None:
        """End a job (executor thread): the goal's terminal state, counters, the next job, diagnostics."""
        goal = job.goal
        if goal is not None:
            try:
                if outcome.status == SUCCEEDED:
                    goal.succeed()
                elif outcome.status == CANCELED and goal.is_cancel_requested:
                    goal.canceled()
                else:
                    goal.abort()
            except Exception as exc:  # an invalid transition must not take the node down
                self.get_logger().error(f"goal {job.label}: cannot set its final state: {exc}")
        key = {SUCCEEDED: "succeeded", CANCELED: "canceled"}.get(outcome.status, "failed")
        with self._lock:
            self._counts[key] += 1
            if goal is not None:
                self._goals.pop(bytes(goal.goal_id.uuid), None)
            if self._running is job:
                self._running = None
            self._last["outcome"] = f"{outcome.status}: {outcome.message}"
            self._last["goal"] = job.label
            if outcome.result is not None:
                r = outcome.result
                self._last.update(misfit=f"{r.misfit:.6g}", duration_s=f"{r.elapsed_s:.3f}", method=r.method,
                                  bag=r.bag)
            if outcome.push is not None:
                p = outcome.push
                self._last.update(push_target=p.target, push="accepted" if p.accepted else f"failed: {p.reason}")
        # (one call site per severity: rclpy refuses a severity change at the same call site)
        if outcome.status == ABORTED:
            self.get_logger().warning(f"{job.label} {outcome.status}: {outcome.message}")
        else:
            self.get_logger().info(f"{job.label} {outcome.status}: {outcome.message}")
        self._pump()
        self.publish_diagnostics()

    # ------------------------------------------------------------------ the worker

    def _feedback(self, job: _Job, stage: str, fraction: float, message: str = "") -> None:
        fraction = min(1.0, max(job.fraction, fraction))
        changed = stage != job.stage
        job.stage, job.fraction = stage, fraction
        if changed and job.state == "running":
            self.get_logger().info(f"{job.label}: {stage} ({100 * fraction:.0f} %)")
        if job.goal is not None:
            elapsed = time.monotonic() - job.started if job.started else 0.0
            job.goal.publish_feedback(CalibrateAction.Feedback(
                stage=stage, fraction=fraction, message=message or f"{stage} ({100 * fraction:.0f} %)",
                elapsed=elapsed))

    def _work(self) -> None:
        """Worker thread: run the jobs handed over by :meth:`_pump`, one at a time."""
        while True:
            job = self._inbox.get()
            if job is None:
                return
            try:
                outcome = self._run(job)
            except BaseException as exc:  # the worker must survive anything and answer
                self.get_logger().error(traceback.format_exc())
                outcome = failed(ABORTED, f"internal error of the calibration node: {type(exc).__name__}: {exc}",
                                 job.request)
            self._complete(job, outcome)

    def _check_stop(self, job: _Job) -> None:
        if self._stop.is_set():
            raise CalibrationStopped("node shutting down")
        if job.cancel_requested():
            raise CalibrationStopped("canceled")

    def _run(self, job: _Job) -> CalibrationOutcome:
        """One calibration (worker thread): checks, the fit with feedback, the push. Never raises."""
        req = job.request
        if req.error:
            return failed(ABORTED, req.error, req)
        if not req.bag:
            return failed(ABORTED, "bag_path is empty: give the bag directory or .mcap/.db3 file", req)
        if req.method not in METHODS:
            return failed(ABORTED, f"method = {req.method!r}: must be one of {', '.join(METHODS)}", req)
        refused = check_paths(req, self._roots)  # under allowed_roots, exists, regular files only (no FIFO)
        if refused:
            return failed(ABORTED, refused, req)
        path = Path(req.bag).expanduser()
        share = FIT_SHARE_WITH_PUSH if req.push else 1.0
        self.get_logger().info(f"{job.label}: calibrating: {req.method} on {req.bag!r}")
        self.publish_diagnostics()

        sent = -math.inf

        def progress(stage: str, frac: float) -> None:
            nonlocal sent
            self._check_stop(job)
            now = time.monotonic()
            if stage != job.stage or frac >= 1.0 or now - sent >= FEEDBACK_PERIOD:
                sent = now
                self._feedback(job, stage, share * frac)

        try:
            result = calibrate(path, req.method, req.options, progress=progress, allow_partial=req.allow_partial)
        except CalibrationStopped as why:
            if str(why) == "canceled":
                return failed(CANCELED, f"canceled during '{job.stage}' ({100 * job.fraction:.0f} %)", req)
            return failed(ABORTED, f"node shutting down: stopped during '{job.stage}'", req)
        except BagError as exc:
            return failed(ABORTED, f"bag refused: {exc}", req)
        except ClmError as exc:  # CalibrationError (options, channel map, band), ParameterError
            return failed(ABORTED, f"calibration failed: {exc}", req)
        except RecursionError:
            return failed(ABORTED, "calibration failed: the options are nested too deeply (Python's recursion "
                          f"limit, {sys.getrecursionlimit()}, reached while reading them)", req)
        except Exception as exc:  # the node must survive anything a bag can trigger
            self.get_logger().error(traceback.format_exc())
            return failed(ABORTED, f"calibration failed with an unexpected {type(exc).__name__}: {exc} "
                          "(traceback in the node's log)", req)
        fit_text = fit_message(result)
        if not req.push:
            return CalibrationOutcome(SUCCEEDED, one_line(fit_text), result, None, req.context())
        if job.cancel_requested() or self._stop.is_set():
            canceled = job.cancel_requested()
            reason = "canceled" if canceled else "node shutting down"
            return CalibrationOutcome(CANCELED if canceled else ABORTED,
                                      one_line(f"{reason} after the fit, before the push: nothing pushed ({fit_text})"),
                                      result, None, req.context())
        self._feedback(job, "pushing", share, f"pushing the fitted parameters to {req.target}")
        push = self._push(result, req.target)
        if push.accepted:
            self._feedback(job, "done", 1.0, f"pushed {len(push.values)} parameter(s) to {push.target}")
            msg = f"{fit_text}; pushed {len(push.values)} parameter(s) to {push.target}"
            return CalibrationOutcome(SUCCEEDED, one_line(msg), result, push, req.context())
        msg = (f"fit succeeded but the push to {push.target or repr(req.target)} failed: {push.reason} "
               f"({fit_text}; fitted parameters in the result)")
        return CalibrationOutcome(ABORTED, one_line(msg), result, push, req.context())

    def _push(self, result: Any, target: str) -> PushOutcome:
        try:
            values = push_values(result)
        except CalibrationError as exc:
            return PushOutcome(target=target, service="", accepted=False, reason=str(exc))
        return self._pusher.push(values, target, float(self.get_parameter("push_timeout").value))

    def push_parameters(self, values: dict[str, float], target_node: str, timeout: float | None = None) -> PushOutcome:
        """Set DOUBLE parameters on a running node, all or none (:meth:`ParameterPusher.push`).

        Parameters
        ----------
        values : mapping
            ``{'soil.kf': 7.2e7, ...}`` [SI].
        target_node : str
            Target node name.
        timeout : float, optional
            Default the ``push_timeout`` parameter [s].
        """
        budget = float(self.get_parameter("push_timeout").value) if timeout is None else float(timeout)
        return self._pusher.push(values, target_node, budget)

    # ------------------------------------------------------------------ diagnostics

    def diagnostics_values(self) -> dict[str, str]:
        """The key-value pairs of the node's ``/diagnostics`` status."""
        with self._lock:
            run = self._running
            c = self._counts
            values = {
                "state": "running" if run is not None else "idle",
                "queued": str(len(self._queue)),
                **{f"goals_{k}": str(c[k]) for k in ("accepted", "rejected", "succeeded", "failed", "canceled")},
            }
            if run is not None:
                values.update(current_goal=run.label, current_method=run.request.method,
                              current_bag=run.request.bag, current_stage=run.stage,
                              current_fraction=f"{run.fraction:.3f}",
                              current_elapsed_s=f"{time.monotonic() - run.started:.3f}")
            values.update({f"last_{k}": v for k, v in self._last.items()})
        return values

    def publish_diagnostics(self) -> None:
        """Publish the node's status on ``/diagnostics`` (timer, and at every start and end of a calibration)."""
        values = self.diagnostics_values()
        level, message = DiagnosticStatus.OK, values["state"]
        if values["state"] == "running":
            message = (f"running {values['current_method']} on {values['current_bag']!r}: "
                       f"{values['current_stage']} ({100 * float(values['current_fraction']):.0f} %)")
        last = values.get("last_outcome", "")
        if last.startswith(("aborted", "failed")) or values.get("last_push", "").startswith("failed"):
            level = DiagnosticStatus.WARN
            if values["state"] == "idle":
                message = f"idle; last calibration {last[:200]}"
        publish_status(self, self._pub_diag, f"{self.get_fully_qualified_name()}: calibration", level, message,
                       values)

    # ------------------------------------------------------------------ shutdown

    def begin_shutdown(self) -> None:
        """Accept nothing more, abort what waits, ask the running fit to stop at its next progress report."""
        self._stop.set()
        with self._lock:
            waiting = list(self._queue)
            self._queue.clear()
        for job in waiting:
            job.state = "dropped"
            self._complete(job, failed(ABORTED, "node shutting down before the calibration started", job.request))
            if job.goal is not None:
                job.goal.execute()

    def idle(self) -> bool:
        """True when no calibration runs or waits."""
        with self._lock:
            return self._running is None and not self._queue

    def abandon(self) -> None:
        """Answer a fit that did not stop in time (its daemon thread is left to the process exit); stop the worker."""
        with self._lock:
            run = self._running
        if run is not None:
            self._complete(run, failed(ABORTED, f"node shutting down: the fit did not stop within "
                                       f"{SHUTDOWN_GRACE:g} s ('{run.stage}')", run.request))
        self._inbox.put(None)

    def abandoned(self) -> bool:
        """True if a fit was abandoned at shutdown and its thread still runs (the fit's thread cannot be
        interrupted and would slow the interpreter's teardown down, holding the GIL for much of its work: the
        process ends at once, :func:`clm_ros.node_main.run_node`)."""
        return self._worker.is_alive() and self._stop.is_set()

    def drain(self, spin_until: Callable[[Callable[[], bool], float], None]) -> None:
        """After SIGINT/SIGTERM (:func:`clm_ros.node_main.run_node`): abort what waits, give the running fit
        :data:`SHUTDOWN_GRACE` s to stop, then :data:`FLUSH_S` s for the results to reach the clients
        (``spin_until`` returns early at a second signal)."""
        t_signal = time.monotonic()
        name = self._signals.name if self._signals is not None else "signal"
        self.get_logger().info(f"{name}: shutting down")
        self.begin_shutdown()
        busy = not self.idle()
        spin_until(self.idle, SHUTDOWN_GRACE)
        self.abandon()
        if busy:  # let the results of what was running or waiting reach the clients
            spin_until(lambda: False, FLUSH_S)
        self.get_logger().info(f"{name}: node stopped {time.monotonic() - t_signal:.3f} s after the signal")

    def destroy_node(self) -> None:
        """Stop the worker, then destroy the node."""
        self._stop.set()
        self._inbox.put(None)
        self.action_server.destroy()
        super().destroy_node()  # type: ignore[no-untyped-call]  # rclpy leaves Node.destroy_node unannotated


def main(args: list[str] | None = None) -> int:
    """Console entry point ``calibration_node``: init, spin until SIGINT/SIGTERM, shut down cleanly.

    Parameters
    ----------
    args : list of str, optional
        Command line (``--ros-args`` ...); default ``sys.argv``.

    Returns
    -------
    int
        0 (also after SIGINT or SIGTERM, within 2 s even mid-fit), or 2 for
        an invalid parameter at start (e.g. ``default_method``). After a
        signal that found a fit in a stage longer than
        :data:`SHUTDOWN_GRACE`, the process ends with ``os._exit(0)`` once
        ROS is shut down (the fit's thread cannot be interrupted; see
        :meth:`CalibrationNode.abandoned`).
    """
    # SingleThreadedExecutor: the action server's goal handles are served from its spin_once
    return run_node(CalibrationNode, args, NODE_NAME, executor_type=SingleThreadedExecutor)


if __name__ == "__main__":
    sys.exit(main())
