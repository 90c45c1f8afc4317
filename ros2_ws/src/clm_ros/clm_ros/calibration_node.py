"""The calibration node: fits model parameters to a recorded bag, as an action with progress and cancel.

``clm_calibration_node`` offers, under one name (``/clm_calibration_node/calibrate`` with the default node name),
the **action** ``clm_msgs/action/Calibrate`` (a bag, a method, typed options, optionally a node to push the fitted
parameters to; feedback ``stage``, ``fraction``, ``message``, ``elapsed``; a result with the fitted parameters, the
fit quality, ``parameters_yaml``, the push outcome and ``metrics_json``) and the **service**
``clm_msgs/srv/Calibrate`` (options as YAML): the same queue, the same code path, the same outcome, without feedback
or cancel. docs/ros-nodes.md, "Calibration node", lists every field, stage and state.

- **One calibration at a time, the others queued** (:class:`clm_ros.calibration_jobs.JobBook`): goals and service
  calls run in arrival order in one worker thread (:func:`clm_ros.calibration_work.run_job`); at most
  ``max_queued`` wait, a goal beyond is rejected and a call answered ``busy: ...`` (both counted). A burst is taken
  whole up to :data:`REQUEST_DEPTH` per queue (issue 26.1).
- **A repeated service request** (issue 21): a request with a ``request_id`` already seen (a client that sent again
  after a lost response) is answered with the first one's outcome, waiting for it if it still runs: never a second
  fit (docs/ros-nodes.md, "Service and action races").
- **What a goal may read**: files under ``allowed_roots`` only, regular files only; a refusal never echoes a file
  (:func:`clm_ros.calibration_goal.check_paths`). Every failure of a goal aborts it with its reason.
- **Cancel**: a running fit stops at its next progress report; a queued goal ends CANCELED within
  :data:`QUEUE_POLL_S`; a push under way is not interrupted (one atomic request, bounded by ``push_timeout``).
- **Push** (:class:`clm_ros.calibration_push.ParameterPusher`): the fitted ``<section>.<name>`` parameters through
  the target's ``set_parameters_atomically``: all or none; a refusal or a dead target is reported, the node serves on.
- **Diagnostics** every ``diagnostics_period`` (steady clock: also with ``use_sim_time`` and no ``/clock``) and at
  every start and end of a calibration; WARN when the last calibration or push failed.
- **Threading**: the callbacks run in a single-threaded executor and never block; the worker thread runs the fit and
  the push and completes the job's future.
- **Shutdown**: SIGINT or SIGTERM: nothing new accepted, queued goals aborted, the running fit stopped at its next
  progress report (at most :data:`SHUTDOWN_GRACE` s), the results go out, exit code 0 (within 2 s).

Parameters (node settings, :data:`clm_ros.parameters.NODE_SETTINGS`): ``default_method`` (impact),
``push_timeout`` [s] (10), ``max_queued`` (4), ``allowed_roots`` (``.``, read-only), ``diagnostics_period`` [s]
(1, read-only).

Run: ``python -m clm_ros.calibration_node`` (``ros2 run clm_ros calibration_node``); ``ros2 action send_goal
--feedback /clm_calibration_node/calibrate clm_msgs/action/Calibrate "{bag_path: bags/calibration/impact_mevergnies,
fmax: 140.0}"``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any

from clm_msgs.action import Calibrate as CalibrateAction
from clm_msgs.srv import Calibrate
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from clm_core.calibration.options import METHODS
from clm_ros.calibration_goal import (
    ABORTED,
    CANCELED,
    SUCCEEDED,
    CalibrationOutcome,
    CalibrationRequest,
    action_result,
    failed,
    parse_roots,
    request_from_goal,
    request_from_service,
    service_response,
)
from clm_ros.calibration_jobs import Job, JobBook, JobRunner, status
from clm_ros.calibration_push import ParameterPusher, PushOutcome, parameter_messages, push_values, target_service
from clm_ros.calibration_work import FEEDBACK_PERIOD, FIT_SHARE_WITH_PUSH, CalibrationStopped, run_job
from clm_ros.diagnostics import publish_status
from clm_ros.node_log import NodeLog
from clm_ros.node_main import StopSignals, run_node
from clm_ros.parameters import declare_settings, lookup

__all__ = ["FEEDBACK_PERIOD", "FIT_SHARE_WITH_PUSH", "CalibrationNode", "CalibrationStopped", "PushOutcome", "main",
           "parameter_messages", "push_values", "target_service"]

NODE_NAME = "clm_calibration_node"
#: Action and service name, relative to the node (``/clm_calibration_node/calibrate``).
ACTION_NAME = SERVICE_NAME = "~/calibrate"
#: How long a shutdown waits for a running fit to stop at its next progress report [s].
SHUTDOWN_GRACE = 0.5
#: After the last calibration ended, how long a shutdown keeps spinning so its result reaches the client [s].
FLUSH_S = 0.2
#: How often queued goals are checked for a cancel request [s].
QUEUE_POLL_S = 0.05

#: History depth of the action's services (goal, cancel, result), its feedback and the ``Calibrate`` service, on
#: both sides of each (request and response). rclpy's default is 10: of a burst sent faster than the executor takes
#: it, the middleware kept the last 10 and dropped the rest unanswered (issue 26.1). A burst of up to this many is
#: taken whole; a client that sends bursts needs the same depth on its side (:func:`request_qos`).
REQUEST_DEPTH = 1000


def request_qos() -> QoSProfile:
    """QoS of the action's and the service's requests and answers: reliable, keep last :data:`REQUEST_DEPTH`."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=REQUEST_DEPTH, reliability=ReliabilityPolicy.RELIABLE)


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
        declare_settings(self, ("default_method", "max_queued", "allowed_roots", "push_timeout", "diagnostics_period"))
        lookup("default_method").check(self._default_method())  # the value at start (changes: declare_settings)
        self._roots = parse_roots(str(self.get_parameter("allowed_roots").value))  # read-only: fixed at start
        # one executor thread; callbacks never block (fits, pushes: the runner's worker, which completes the awaited
        # futures); reentrant group: a call awaiting its fit must not hold up goals, calls, cancels (burst admitted)
        self._wake = self.create_guard_condition(lambda: None)
        self.log = NodeLog(self)  # the nodes' one logging helper (bounded lines, once per reason, tracebacks)
        self.book = JobBook()
        self.runner = JobRunner(self.book, self._run, self._wake.trigger, self.log)
        self._stop = self.runner.stop
        self._pusher = ParameterPusher(self, self._stop, self.log)
        q, answers = request_qos(), ReentrantCallbackGroup()
        self.action_server = ActionServer(
            self, CalibrateAction, ACTION_NAME, self._execute_goal, goal_callback=self._on_goal,
            handle_accepted_callback=self._on_accepted, cancel_callback=self._on_cancel, goal_service_qos_profile=q,
            result_service_qos_profile=q, cancel_service_qos_profile=q, feedback_pub_qos_profile=q,
            callback_group=answers)
        self.service = self.create_service(Calibrate, SERVICE_NAME, self._serve, qos_profile=q, callback_group=answers)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # both timers on the steady clock: with use_sim_time and no /clock, ROS time stands still and timers of
        # the node's default clock would never fire (no diagnostics, a queued goal's cancel never seen)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._diag_timer = self.create_timer(float(self.get_parameter("diagnostics_period").value),
                                             self.publish_diagnostics, clock=steady)
        self._queue_timer = self.create_timer(QUEUE_POLL_S, self.runner.pump, clock=steady)
        self.log.info(
            f"ready: action and service {self.service.service_name} (methods {', '.join(METHODS)}, "
            f"up to {self._max_queued()} queued; files read under {', '.join(map(str, self._roots))})")

    # ------------------------------------------------------------------ admission and queue

    def _max_queued(self) -> int:
        return int(self.get_parameter("max_queued").value)

    def _default_method(self) -> str:
        return str(self.get_parameter("default_method").value)

    def _busy_reason(self) -> str:
        """Why a new calibration cannot wait now ('' if it can); call with the book's lock held."""
        return self.book.busy_reason(self._stop.is_set(), self._max_queued())

    def _on_goal(self, goal: CalibrateAction.Goal) -> GoalResponse:
        with self.book.lock:
            reason = self._busy_reason()
            if reason:
                self.book.counts["rejected"] += 1
        if reason:
            self.log.reject("busy", f"goal rejected ({goal.method or self._default_method()} of {goal.bag_path!r}): "
                            f"{reason}", count=False)  # counted in goals_rejected
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_accepted(self, goal: ServerGoalHandle) -> None:
        try:
            request = request_from_goal(goal.request, self._default_method())
        except BaseException as exc:  # an accepted goal is always registered, so that it is always answered
            request = CalibrationRequest(bag=str(goal.request.bag_path), method=str(goal.request.method),
                                         error=f"invalid goal: {type(exc).__name__}: {exc}")
        job = Job(request, goal, bytes(goal.goal_id.uuid).hex()[:8])
        with self.book.lock:
            self.book.goals[bytes(goal.goal_id.uuid)] = job
            self.book.admit(job)
            ahead = len(self.book.queue) - 1 + (self.book.running is not None)
        if ahead:
            self._feedback(job, "queued", 0.0, f"queued: {ahead} calibration(s) ahead")
        self.runner.pump()

    def _on_cancel(self, goal: ServerGoalHandle) -> CancelResponse:
        job = self.book.goals.get(bytes(goal.goal_id.uuid))
        if job is None or job.done.done():
            return CancelResponse.REJECT
        self.log.info(f"goal {job.label}: cancel requested ({job.stage})")
        return CancelResponse.ACCEPT

    # ------------------------------------------------------------------ action and service

    async def _execute_goal(self, goal: ServerGoalHandle) -> CalibrateAction.Result:
        job = self.book.goals.get(bytes(goal.goal_id.uuid))
        if job is None:  # not expected: every accepted goal is registered first
            goal.abort()
            return CalibrateAction.Result(success=False, message="internal error: unknown goal")
        outcome: CalibrationOutcome = await job.done
        try:
            result = action_result(outcome, CalibrateAction.Result)
        except Exception as exc:  # the goal must end with a result that says what happened
            self.log.exception(f"goal {job.label}: its result could not be made")
            outcome = failed(ABORTED, f"internal error of the calibration node: {type(exc).__name__}: {exc}",
                             job.request)
            result = action_result(outcome, CalibrateAction.Result)
        self._conclude(job, outcome)
        return result

    async def _serve(self, request: Calibrate.Request, response: Calibrate.Response) -> Calibrate.Response:
        """The ``Calibrate`` service: the same queue and code path as a goal, answered when done; a repeated
        ``request_id`` is answered with the first request's outcome (never a second fit)."""
        rid = str(request.request_id)
        with self.book.lock:
            first = self.book.by_request_id(rid)
            if first is None:
                self.book.n_requests += 1
                label = f"request-{self.book.n_requests}" + (f" ({rid[:40]})" if rid else "")
                reason = self._busy_reason()
                if reason:
                    self.book.counts["rejected"] += 1
                else:
                    job = Job(request_from_service(request, self._default_method()), None, label)  # never raises
                    self.book.admit(job, rid)
        if first is not None:
            self.log.info(f"{first.label}: request id sent again: answered with its outcome "
                                   f"({'done' if first.done.done() else first.state}), not run again")
            return service_response(await first.done, response)
        if reason:
            self.log.reject("busy", f"{label} refused: busy: {reason}", count=False)  # counted in goals_rejected
            return service_response(failed(ABORTED, f"busy: {reason}; try again later"), response)
        self.runner.pump()
        outcome: CalibrationOutcome = await job.done
        self._conclude(job, outcome)
        return service_response(outcome, response)

    def _conclude(self, job: Job, outcome: CalibrationOutcome) -> None:
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
                self.log.error(f"goal {job.label}: cannot set its final state: {exc}")
        with self.book.lock:
            self.book.concluded(job, outcome)
        if outcome.status == ABORTED:
            self.log.warning(f"{job.label} {outcome.status}: {outcome.message}")
        else:
            self.log.info(f"{job.label} {outcome.status}: {outcome.message}")
        self.runner.pump()
        self.publish_diagnostics()

    # ------------------------------------------------------------------ the worker

    def _feedback(self, job: Job, stage: str, fraction: float, message: str = "") -> None:
        fraction = min(1.0, max(job.fraction, fraction))
        changed = stage != job.stage
        job.stage, job.fraction = stage, fraction
        if changed and job.state == "running":
            self.log.info(f"{job.label}: {stage} ({100 * fraction:.0f} %)")
        if job.goal is not None:
            elapsed = time.monotonic() - job.started if job.started else 0.0
            job.goal.publish_feedback(CalibrateAction.Feedback(
                stage=stage, fraction=fraction, message=message or f"{stage} ({100 * fraction:.0f} %)",
                elapsed=elapsed))

    def _run(self, job: Job) -> CalibrationOutcome:
        """One calibration, in the runner's worker thread (:func:`clm_ros.calibration_work.run_job`)."""
        return run_job(job, self._roots, self._stop, self._feedback, self.push_parameters, self.log,
                       self.publish_diagnostics)

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
        """The key-value pairs of the node's ``/diagnostics`` status (:meth:`JobBook.values`)."""
        with self.book.lock:
            return self.book.values()

    def publish_diagnostics(self) -> None:
        """Publish the node's status on ``/diagnostics`` (timer, and at every start and end of a calibration)."""
        level, message, values = status(self.diagnostics_values())
        publish_status(self, self._pub_diag, f"{self.get_fully_qualified_name()}: calibration", level, message,
                       values)

    # ------------------------------------------------------------------ shutdown

    def abandoned(self) -> bool:
        """True if a fit was abandoned at shutdown and its thread still runs (the fit's thread cannot be
        interrupted and would slow the interpreter's teardown down, holding the GIL for much of its work: the
        process ends at once, :func:`clm_ros.node_main.run_node`)."""
        return self.runner.abandoned()

    def drain(self, spin_until: Callable[[Callable[[], bool], float], None]) -> None:
        """After SIGINT/SIGTERM (:func:`clm_ros.node_main.run_node`): abort what waits, give the running fit
        :data:`SHUTDOWN_GRACE` s to stop, then :data:`FLUSH_S` s for the results to reach the clients
        (``spin_until`` returns early at a second signal)."""
        t_signal = time.monotonic()
        name = self._signals.name if self._signals is not None else "signal"
        self.log.info(f"{name}: shutting down")
        self.runner.begin_shutdown()
        busy = not self.runner.idle()
        spin_until(self.runner.idle, SHUTDOWN_GRACE)
        self.runner.abandon(SHUTDOWN_GRACE)
        if busy:  # let the results of what was running or waiting reach the clients
            spin_until(lambda: False, FLUSH_S)
        self.log.info(f"{name}: node stopped {time.monotonic() - t_signal:.3f} s after the signal")

    def destroy_node(self) -> None:
        """Stop the worker, then destroy the node."""
        self.runner.close()
        self.action_server.destroy()
        super().destroy_node()  # type: ignore[no-untyped-call]  # rclpy leaves Node.destroy_node unannotated


def main(args: list[str] | None = None) -> int:
    """Console entry point ``calibration_node`` (``args``: the command line, default ``sys.argv``): spin until
    SIGINT/SIGTERM (a SingleThreadedExecutor: it serves the action's goal handles); exit code 0 (also after a signal,
    within 2 s even mid-fit: a fit that does not stop within :data:`SHUTDOWN_GRACE` ends with the process,
    :meth:`CalibrationNode.abandoned`), 2 for an invalid parameter."""
    return run_node(CalibrationNode, args, NODE_NAME, executor_type=SingleThreadedExecutor)


if __name__ == "__main__":
    sys.exit(main())
