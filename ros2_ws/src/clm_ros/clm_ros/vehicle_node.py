"""Vehicle simulator node: a clm_core vehicle publishing its wheel loads in real time, train after train.

A lifecycle node (as ros2/demos ``lifecycle_py``); docs/ros-nodes.md, "Vehicle simulator node", says it all. Configure
builds the vehicle and its timetable (:func:`clm_ros.vehicle_schedule.build_plan`; an invalid set is refused with its
reason); activate runs ``trains`` trains (0: until deactivated) on a ``headway`` or ``train_pause`` apart
(:class:`clm_ros.vehicle_schedule.TrainSchedule`), each once its own track node is active and subscribed
(:class:`clm_ros.vehicle_link.TrackLink`), publishing ``clm_msgs/WheelLoads`` on ``wheel_loads`` at ``rate`` Hz for
``duration`` s stamped with their due times (``publish_clock``: simulation time, also on ``/clock``), then waiting
``ack_timeout`` for the answers; deactivate stops the train (its counts kept). Closed loop: the answers on
``wheel_rail_response`` correct the vehicle's track predictor (:class:`clm_ros.vehicle_schedule.TrainRun`; one older
than ``max_feedback_delay`` is counted, not used). Counts (:mod:`clm_ros.vehicle_counts`) go to ``/diagnostics`` and
the latched ``vehicle_status``. A track node that stops answering is reported when the oldest message sent since its
last answer has waited ``answer_timeout`` (:class:`clm_ros.vehicle_schedule.AnswerWatch`: a vehicle that itself stood
still never blames it); the train goes on on its predictor. SIGINT/SIGTERM: exit 0; ``exit_when_done``: exit 0 after
the last train. Everything runs in the spinning thread (:meth:`VehicleNode.serve_due`, between two executor turns).

Run: ``python -m clm_ros.vehicle_node --ros-args -p speed:=60.0`` (``ros2 run clm_ros vehicle_node``).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from typing import Any

from clm_msgs.msg import WheelLoads
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import State, TransitionCallbackReturn
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.time import Time
from rosgraph_msgs.msg import Clock

from clm_core.errors import ClmError
from clm_core.io.timebase import NS
from clm_ros.diagnostics import publish_status
from clm_ros.latched import VEHICLE_STATUS, LatchedStatus
from clm_ros.node_log import NodeLog
from clm_ros.node_main import freeze_heap, run_node
from clm_ros.parameters import START_SIGNAL, declare_settings
from clm_ros.realtime import NOT_APPLIED, Scheduling
from clm_ros.vehicle_counts import Counts, VehicleStatus
from clm_ros.vehicle_link import DATA_QOS, HANDSHAKE_TIMEOUT_NS, TrackLink
from clm_ros.vehicle_schedule import FORGET_AFTER, AnswerWatch, TrainRun, TrainSchedule, VehiclePlan, build_plan

__all__ = ["DATA_QOS", "FORGET_AFTER", "HANDSHAKE_TIMEOUT_NS", "NODE_NAME", "VehicleNode", "main"]

NODE_NAME = "clm_vehicle_node"

#: Run settings of the vehicle (clm_core.settings), read at configure.
RUN_SETTINGS = ("vehicle", "cars", "speed", "duration", "rate", "dt", "start", "irregularity", "seed",
                "wavelength_band", "track", "soil", "model", "params_file", "closed_loop")
#: The node's schedule and transport settings.
NODE_SETTINGS = ("trains", "headway", "train_pause", "track_node", "answer_timeout", "exit_when_done",
                 "publish_clock", "wait_for_subscribers", "discovery_timeout", "ack_timeout", "frame_id",
                 "max_feedback_delay", "diagnostics_period")


class VehicleNode(LifecycleNode):
    """Lifecycle node publishing the wheel loads of clm_core vehicles, one train after another (module docstring).

    Phases (:attr:`phase`): idle, wait (for the track node), ready (start signal awaited), run, answers (the last
    answers awaited), pause (between trains), done, stopped.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        # every parameter is read-only: a run is built at configure
        declare_settings(self, (*RUN_SETTINGS, *NODE_SETTINGS, "autostart", "realtime_priority", START_SIGNAL),
                         read_only=True)
        #: SCHED_FIFO priority asked of clm_ros.node_main.run_node, which sets ``scheduling`` to the outcome
        self.realtime_priority = int(self.p("realtime_priority"))
        self.scheduling: Scheduling = NOT_APPLIED
        #: None while the process should run; a number ends it with that exit code (clm_ros.node_main)
        self.exit_code: int | None = None
        self.plan: VehiclePlan | None = None
        self.run: TrainRun | None = None  # the current (or last) train
        self.schedule = TrainSchedule(0, 0, 0)
        self.watch = AnswerWatch(0)
        self.link: TrackLink | None = None
        self._pub: Any = None  # wheel_loads, and /clock with publish_clock
        self._clock_pub: Any = None
        self.finished = Counts()  # the trains before the current one
        self.status = VehicleStatus()  # phase, state, level; the /diagnostics and latched status builder
        self._k = self._deadline = self._wait_since = self._sim_ns = 0
        self._next: tuple[int, int, bytes] = (0, 0, b"")  # the next (or last) message: stamp, due time, bytes
        self._warned, self.closed_loop = False, False
        self.log = NodeLog(self)  # the nodes' one logging helper (bounded lines, once-only and throttled)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._latched = LatchedStatus(self, VEHICLE_STATUS, "vehicle simulator")
        self._diag_timer = self.create_timer(float(self.p("diagnostics_period")), self._publish_diagnostics)
        if self.p("autostart"):
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                self.exit_code = 2
            else:
                self.trigger_activate()

    def p(self, name: str) -> Any:
        """A parameter's value."""
        return self.get_parameter(name).value

    def on_configure(self, state: State) -> TransitionCallbackReturn:
        try:
            self.plan = plan = build_plan({name: self.p(name) for name in (*RUN_SETTINGS, *NODE_SETTINGS)})
        except (ClmError, ValueError, OSError) as exc:
            self.log.error(f"configure refused: {exc}")
            self.plan = None
            return TransitionCallbackReturn.FAILURE
        old, self.schedule = self.schedule, TrainSchedule(int(self.p("trains")), int(float(self.p("headway")) * NS),
                                                          int(float(self.p("train_pause")) * NS))
        self.schedule.number, self.schedule.trains_done = old.number, old.trains_done  # numbered over the node's life
        self.watch = AnswerWatch(int(float(self.p("answer_timeout")) * NS))
        self.closed_loop = bool(self.p("closed_loop"))
        qos = QoSOverridingOptions.with_default_policies()
        self._pub = self.create_lifecycle_publisher(WheelLoads, "wheel_loads", DATA_QOS, qos_overriding_options=qos)
        self._clock_pub = self.create_lifecycle_publisher(Clock, "/clock", 10) if self.p("publish_clock") else None
        self.link = TrackLink(self, self._pub, str(self.p("track_node")), int(self.p("wait_for_subscribers")),
                              bool(self.p("start_signal")))
        self._set_state("configured", DiagnosticStatus.OK)
        freeze_heap()  # the run's objects live until cleanup: no full collection of them during a train
        self.log.info(
            f"configured: {self.p('vehicle')} ({plan.n_wheels} wheels) at {plan.speed:g} m/s, {self.p('duration'):g} "
            f"s per train at {self.p('rate'):g} Hz, {plan.substeps} steps of {plan.dt:g} s per message; trains: "
            f"{self.p('trains') or 'until deactivated'}")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        ret = super().on_activate(state)
        self.schedule.activate(time.monotonic_ns())
        self._begin_wait()
        return ret

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self._halt("inactive")
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self._drop_entities()
        self.plan = self.run = None
        self._set_state("unconfigured", DiagnosticStatus.OK)
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        return self._drop_entities("finalized")

    def on_error(self, state: State) -> TransitionCallbackReturn:
        return self._drop_entities("unconfigured")

    def _drop_entities(self, halt: str = "") -> TransitionCallbackReturn:
        if halt:
            self._halt(halt)
        for p in (self._pub, self._clock_pub):
            if p is not None:
                self.destroy_lifecycle_publisher(p)
        if self.link is not None:
            self.link.destroy()
        self._pub = self._clock_pub = self.link = None
        return TransitionCallbackReturn.SUCCESS

    def _halt(self, state: str) -> None:
        """Stop the schedule (the train that runs is reported as stopped)."""
        if self.status.phase in ("run", "answers"):
            self._finish_train(stopped=True)
        self.status.phase = "idle"
        self._set_state(state, DiagnosticStatus.OK)
        self._publish_diagnostics()

    def stop(self) -> None:
        """The process is ending (SIGINT, SIGTERM or ``exit_when_done``): stop the schedule."""
        self._halt(self.status.text if self.status.phase == "done" else "stopped")

    def _set_state(self, text: str, level: Any) -> None:
        self.status.set(text, level)
        self._latch()

    def _latch(self) -> None:
        """Publish the control-plane state (phase, train, its start and end, the last train's figures) latched."""
        self._latched.update(*self.status.latched({"train": self.schedule.number,
                                                   "trains_done": self.schedule.trains_done}))

    def serve_due(self) -> float:
        """Do what is due now; return how long the executor may wait for other work until the next action [s]."""
        try:
            self._take_answers()
            if self.status.phase == "run":
                return self._serve_train()
            if self.status.phase == "wait":
                return self._serve_wait()
            if self.status.phase == "answers":
                if self.watch.outstanding and time.monotonic_ns() < self._deadline:
                    return 0.005
                self._finish_train(stopped=False)
                return 0.0
            if self.status.phase == "pause":
                wait = self.schedule.next_start - time.monotonic_ns()
                if wait > 0:
                    return wait / NS
                self._begin_wait()
                return 0.0
        except Exception as exc:  # a failed train ends the schedule; the node stays up and says why
            self.status.failed(f"stopped: {exc}")
            self._latch()
            self.log.error(f"train {self.schedule.number} stopped: {exc}")
            self._publish_diagnostics()
        return 0.1

    def _begin_wait(self) -> None:
        if self.schedule.complete():
            self.status.phase = "done"
            self._set_state(f"done: {self.schedule.trains} train(s)", self.status.level)
            self._publish_diagnostics()
            if self.p("exit_when_done"):
                self.exit_code = 0
            return
        self.status.phase, self._wait_since, self._warned = "wait", time.monotonic_ns(), False
        self._set_state(f"train {self.schedule.number + 1}: waiting for {self.p('track_node') or 'a subscriber'}",
                        self.status.level)

    def _serve_wait(self) -> float:
        assert self.link is not None
        track = self.link.track_ready()  # the start signal is looked at (and readiness said) only after this
        start = (self.link.start_due() if self.schedule.first_of_activation() else True) if track else False
        if start is None:  # the start signal not given yet: say once that this train is ready
            text = f"train {self.schedule.number + 1}: ready, waiting for the start signal"
            if self.status.text != text:
                self.status.phase = "ready"
                self._set_state(text, self.status.level)
                self.status.phase = "wait"
        if track and start:
            if self._warned:
                self.log.info(f"{self.p('track_node') or 'a subscriber'} is there: train {self.schedule.number + 1}")
            self._start_train()
            return self._serve_train()
        timeout = float(self.p("discovery_timeout"))
        if not self._warned and time.monotonic_ns() - self._wait_since > timeout * NS:
            self._warned = True
            who = self.p("track_node") or "a subscriber"
            self._set_state(f"train {self.schedule.number + 1}: waiting for {who} for more than {timeout:g} s",
                            DiagnosticStatus.WARN)
            self.log.error(
                f"no {who} (active, subscribed to {self._pub.topic_name}, publishing "
                f"{self.link.answers.topic_name}) and {self.p('wait_for_subscribers')} matched reader(s) after "
                f"{timeout:g} s" + (": giving up" if self.p("exit_when_done") else "; still waiting"))
            if self.p("exit_when_done"):
                self.exit_code, self.status.phase = 3, "stopped"
        return 0.01

    def _start_train(self) -> None:
        assert self.plan is not None
        now = time.monotonic_ns()
        number = self.schedule.begin(now)
        self.finished = self.counts()[1]
        base = self._sim_ns if self._clock_pub is not None else self.get_clock().now().nanoseconds
        self.run = TrainRun(self.plan, base, now, str(self.p("frame_id")), self.closed_loop, self.watch)
        self.status.train_times = (time.time_ns(), 0)
        self.status.phase = "run"
        self._set_state(f"train {number}: running", DiagnosticStatus.OK)
        self._k, self._next = 0, self.run.message(0)
        self.log.info(f"train {number} starts: {self.plan.n_messages} messages")

    def _serve_train(self) -> float:
        now = time.monotonic_ns()
        stamp, due, data = self._next
        if now < due:
            return (due - now) / NS
        run, plan = self.run, self.plan
        assert run is not None and plan is not None
        c = run.counts
        if now - due > 2 * plan.period_ns:
            c.late += 1
        self.watch.sent(stamp, run.vehicle.k, due, now)
        try:
            if self._clock_pub is not None:
                self._clock_pub.publish(Clock(clock=Time(nanoseconds=stamp).to_msg()))
            self._pub.publish(data)
            c.published += 1
        except Exception as exc:  # never dies on a publish (a vanished peer, a context going down)
            c.publish_failed += 1
            self.log.warning(f"publish failed (counted, the train goes on): {exc}", key="publish_failed")
        self._k += 1
        if (self._k & 63) == 0 and self.watch.silence_began(now):
            t = self.watch.timeout_ns / NS
            self._set_state(self.status.text + f" (no answer for {t:g} s)", DiagnosticStatus.WARN)
            self.log.warning(
                f"no answer from the track node for {t:g} s (it may have died): the train goes on on its predictor "
                "alone, and uses the answers again when they return")
        if self._k >= plan.n_messages:
            run.end()
            self.status.phase, self._deadline = "answers", now + int(float(self.p("ack_timeout")) * NS)
            return 0.0
        self._next = run.message(self._k)
        return max(self._next[1] - time.monotonic_ns(), 0) / NS

    def _finish_train(self, stopped: bool) -> None:
        s = self.schedule
        c = self.run.end() if self.run is not None else Counts()
        self.watch.clear()  # a later answer is unmatched
        self.log.info(c.report(s.number, float(self.p("rate")), stopped))
        self.status.train_times = (self.status.train_times[0], time.time_ns())
        if stopped:
            return
        s.finish(time.monotonic_ns())
        self._sim_ns = self._next[0] + int(round(float(self.p("train_pause")) * NS))
        self.status.phase = "pause"
        self._set_state(f"train {s.number} done", self.status.level)
        self._publish_diagnostics(final=s.number)
        if s.complete():
            self._begin_wait()  # the schedule is complete: done

    def _take_answers(self) -> None:
        """Take every answer that has arrived (the middleware's reception time is each one's arrival)."""
        if self.link is None or self.run is None:
            return
        for raw, received in self.link.take_answers():
            was_silent = self.watch.silent
            problem = self.run.answer(raw, received)
            if problem:
                self.log.warning(problem, key="feedback_refused")
            if was_silent and not self.watch.silent:
                self.log.info("the track node answers again: its answers are used as feedback again")
                if self.status.level == DiagnosticStatus.WARN:
                    self._set_state(self.status.text.split(" (no answer")[0], DiagnosticStatus.OK)

    def counts(self) -> tuple[Counts, Counts]:
        """(current or last train, the node's life so far)."""
        train = self.run.counts if self.run is not None else Counts()
        return train, self.finished + train

    def _publish_diagnostics(self, final: int = 0) -> None:
        run = self.run
        head = {"state": self.status.text, "trains_done": self.schedule.trains_done, "train": self.schedule.number,
                "scheduling": self.scheduling.text}
        level, message, values = self.status.diagnostics(
            *self.counts(), run.recent_lags if run else (), run.vehicle.contact_lost_steps if run else 0,
            self.closed_loop, head, final)
        if final:
            self._latch()
        publish_status(self, self._pub_diag, f"{self.get_fully_qualified_name()}: vehicle simulator", level, message,
                       values)


def main(args: Sequence[str] | None = None) -> int:
    """Console entry point ``vehicle_node``: run the node until SIGINT, SIGTERM or its last train; exit."""
    # exit_now: a process of its own (not called from Python code) skips the interpreter's finalization
    return run_node(lambda _signals: VehicleNode(), args, NODE_NAME, exit_now=args is None)


if __name__ == "__main__":
    sys.exit(main())
