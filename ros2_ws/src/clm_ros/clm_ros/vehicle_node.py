"""Vehicle simulator node: a clm_core vehicle publishing its wheel loads in real time, train after train.

A lifecycle node (``rclpy.lifecycle``, as ros2/demos ``lifecycle_py``) a user
can leave running:

- configure: read the parameters, build the vehicle run
  (:func:`clm_core.vehicle.run.build_vehicle_run`) and the streaming vehicle
  (:class:`clm_core.vehicle.streaming.StreamingVehicle`, its compiled step
  loaded or compiled now, never during a train); an invalid set is refused
  with its reason and the node stays unconfigured;
- activate: run ``trains`` trains (0: until deactivated), one after another
  (``train_pause`` between them) or on a ``headway`` from start to start.
  Each train waits for its own track node, active and subscribed
  (:mod:`clm_ros.readiness`: its endpoints in this namespace, every known
  reader matched, its latched ``track_status`` saying it matched this node),
  plus ``wait_for_subscribers`` matched readers (and, with ``start_signal``,
  the supervisor's start time); only
  then its clock starts, so its first second is like any other. It publishes
  ``clm_msgs/WheelLoads`` on ``wheel_loads`` at ``rate`` Hz for ``duration``
  simulated seconds, each stamped with its due time (ROS time; with
  ``publish_clock`` simulation time, also published on ``/clock``), then waits
  up to ``ack_timeout`` for the answers;
- deactivate stops the train at once (its counts are kept); cleanup drops the
  run; shutdown stops everything.

Closed loop (``closed_loop``): the track node's answers on
``wheel_rail_response`` correct the vehicle's track predictor (the rail
deflection under the wheels, low-passed); an answer older than
``max_feedback_delay`` is not used, and counted. Counted per train and for
the node's life, published on ``/diagnostics`` every ``diagnostics_period``
and at the end of each train: messages published, answered, used as
feedback, too late, late publishes (> 2 periods), contact losses, the model's
CPU time per message, the lag of the answers (receive time - due time of the
message, from the first message on).

Faults: a track node that dies is noticed after ``answer_timeout`` without
an answer (logged once, /diagnostics WARN); the train goes on, on the
predictor alone, and the answers are used again when a track node returns.
Publishing never blocks (reliable, keep-last 5000: a reader that died is
never waited for). SIGINT or SIGTERM: a clean exit 0 (:mod:`clm_ros.node_main`).
``exit_when_done``: the process exits (0) after its last train, as a launch
file wants it.

The node owns no physics (clm_core) and converts messages with the numpy
CDR codec of :mod:`clm_core.io.messages` (raw publish and subscription).
It is also the reference client for external simulators: wait for the track
node, publish one ``WheelLoads`` per sample with increasing stamps, read
``WheelRailResponse``.

Run: ``python -m clm_ros.vehicle_node --ros-args -p speed:=60.0`` (``ros2 run
clm_ros vehicle_node`` in a full ROS install).
"""

from __future__ import annotations

import copy
import sys
import time
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
import rclpy
from clm_msgs.msg import WheelLoads, WheelRailResponse
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import State, TransitionCallbackReturn
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Int64

from clm_core.errors import ClmError
from clm_core.io.errors import MessageError
from clm_core.io.messages import decode_wheel_rail_response, encode_wheel_loads
from clm_core.io.timebase import NS
from clm_core.params import load_model, load_params_file
from clm_core.vehicle.run import VehicleRunSpec, build_vehicle_run
from clm_core.vehicle.streaming import StreamingVehicle
from clm_ros.bag_tools import take_raw
from clm_ros.diagnostics import publish_status
from clm_ros.latched import LATCHED_QOS, TRACK_STATUS, VEHICLE_STATUS, LatchedStatus
from clm_ros.node_main import freeze_heap, run_node
from clm_ros.parameters import declare_settings, lookup
from clm_ros.readiness import START_AT, START_SIGNAL, all_matched, owned
from clm_ros.realtime import NOT_APPLIED, Scheduling
from clm_ros.vehicle_counts import Counts

NODE_NAME = "clm_vehicle_node"

#: Run settings of the vehicle (clm_core.settings), read at configure.
RUN_SETTINGS = ("vehicle", "cars", "speed", "duration", "rate", "dt", "start", "irregularity", "seed",
                "wavelength_band", "track", "soil", "model", "params_file", "closed_loop")
#: The node's schedule and transport settings.
NODE_SETTINGS = ("trains", "headway", "train_pause", "track_node", "answer_timeout", "exit_when_done",
                 "publish_clock", "wait_for_subscribers", "discovery_timeout", "ack_timeout", "frame_id",
                 "max_feedback_delay", "diagnostics_period")

#: Data topics: reliable, keep-last 5000 (5 s at 1 kHz): nothing is lost for a reader that keeps up within
#: 5 s, and a reader that died never blocks publishing (keep-all would, then fail). Overridable through the
#: standard QoS parameters, e.g. ``qos_overrides./wheel_loads.publisher.depth``.
DATA_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000, reliability=ReliabilityPolicy.RELIABLE)

#: How long a train waits, once the track node is on the graph and matched, for the track node's own word that
#: its subscription has matched this node's publisher, when the track node has no latched status
#: (``track_status``, :mod:`clm_ros.latched`): not a clm track node; a clm track node's word is always awaited [ns].
HANDSHAKE_TIMEOUT_NS = 5 * NS
#: Answers older than this are forgotten (a later answer counts as unmatched) [s].
FORGET_AFTER = 30.0


class VehicleNode(LifecycleNode):
    """Lifecycle node publishing the wheel loads of clm_core vehicles, one train after another.

    Everything runs in the thread that spins the node: :meth:`serve_due` (called
    by :func:`clm_ros.node_main.run_node` between two turns of the executor)
    takes the answers that have arrived, publishes the message that is due,
    computes the next one and says how long the executor may wait for other
    work (services, timers) until then. No second thread, so no lock and no
    hand-over of the interpreter between threads; one wake-up per message.
    The answers' subscription belongs to a helper node
    (``<name>_answers``, same namespace) that no executor spins: the node takes
    them itself, with the middleware's reception times.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        # parameters generated from the run-settings schema (clm_core.settings, clm_ros.parameters); a run is
        # built at configure: every parameter is read-only
        declare_settings(self, RUN_SETTINGS, read_only=True)
        declare_settings(self, NODE_SETTINGS, read_only=True)
        declare_settings(self, ("autostart", "realtime_priority"), read_only=True)
        declare_settings(self, (START_SIGNAL,), read_only=True)
        #: SCHED_FIFO priority asked of clm_ros.node_main.run_node, which sets ``scheduling`` to the outcome
        self.realtime_priority = int(self.p("realtime_priority"))
        self.scheduling: Scheduling = NOT_APPLIED
        #: None while the process should run; a number ends it with that exit code (clm_ros.node_main)
        self.exit_code: int | None = None
        self._template: StreamingVehicle | None = None
        self.vehicle: StreamingVehicle | None = None
        self._pub: Any = None
        self._clock_pub: Any = None
        self._sub: Any = None
        self._answers_node: Any = None
        self._diag_sub: Any = None
        self._handshake: int | None = None  # the track node's matched wheel-load publishers (None: not said)
        self._graph_ready_since = 0  # monotonic ns since the track node is on the graph and matched (0: not)
        self.closed_loop = False  # (the parameter, read at configure)
        self._diag_mark = (0, 0)  # (published, too late) of the train at the last diagnostics
        # one /diagnostics publisher and timer for the node's life, in every state
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # the control-plane facts (ready, running, train done with its counts) as a latched status (clm_ros.latched)
        self._latched = LatchedStatus(self, VEHICLE_STATUS, "vehicle simulator")
        self._final_values: dict[str, Any] = {}  # the last finished train's figures, as reported at its end
        self._train_times = (0, 0)  # system clock [ns] of the current / last train's start and end
        self._start_sub: Any = None
        self._start_at: int | None = None  # the supervisor's start time [ns, system clock] (start_signal)
        self._diag_timer = self.create_timer(float(self.p("diagnostics_period")), self._publish_diagnostics)
        #: stamp [ns] -> (vehicle step, due time [monotonic ns]) of the messages not answered yet
        self.sent: dict[int, tuple[int, int]] = {}
        self.train = Counts()
        self.finished = Counts()  # the trains before the current one
        self.trains_done = 0
        self.state_text = "unconfigured"
        self.level = DiagnosticStatus.OK
        self._recent_lags: deque[float] = deque(maxlen=2000)
        self._phase = "idle"  # idle, wait, run, answers, pause, done, stopped
        self._number = 0  # the current train (1-based, over the node's life)
        self._first_of_activation = 0
        self._k = 0  # the next message of the train
        self._deadline = 0  # monotonic ns of the next action
        self._wait_since = 0
        self._warned = False
        self._next_start = 0
        self._started = 0
        self._sim_ns = 0
        self._base_ns = 0
        self._start_ns = 0
        self._data = b""
        self._t_ns = 0
        self._last_answer = 0
        self._silent = False
        self._model_error = ""
        if self.get_parameter("autostart").value:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                self.exit_code = 2
            else:
                self.trigger_activate()

    def p(self, name: str) -> Any:
        """A parameter's value."""
        return self.get_parameter(name).value

    # ------------------------------------------------------------------ lifecycle

    def on_configure(self, state: State) -> TransitionCallbackReturn:
        try:
            self._build()
        except (ClmError, ValueError, OSError) as exc:
            self.get_logger().error(f"configure refused: {exc}")
            self._template = None
            return TransitionCallbackReturn.FAILURE
        qos = QoSOverridingOptions.with_default_policies()
        self._pub = self.create_lifecycle_publisher(WheelLoads, "wheel_loads", DATA_QOS, qos_overriding_options=qos)
        self._clock_pub = self.create_lifecycle_publisher(Clock, "/clock", 10) if self.p("publish_clock") else None
        # the answers are taken by the node itself when it serves the timetable (serve_due), not by the executor: one
        # wake-up per message instead of two; their subscription belongs to a helper node that no executor spins
        self._answers_node = rclpy.create_node(f"{self.get_name()}_answers", namespace=self.get_namespace(),
                                               context=self.context)
        self._sub = self._answers_node.create_subscription(WheelRailResponse, "wheel_rail_response", _ignore,
                                                           DATA_QOS, qos_overriding_options=qos, raw=True)
        # the track node's latched status, taken by the node itself while a train waits (see _track_subscribed)
        self._diag_sub = self._answers_node.create_subscription(DiagnosticArray, TRACK_STATUS, _ignore, LATCHED_QOS)
        if self.p("start_signal"):
            self._start_sub = self._answers_node.create_subscription(Int64, START_AT, _ignore, LATCHED_QOS)
        self._set_state("configured", DiagnosticStatus.OK)
        freeze_heap()  # the run's objects live until cleanup: no full collection of them during a train
        self.get_logger().info(
            f"configured: {self.p('vehicle')} ({self.n_wheels} wheels) at {self.speed:g} m/s, {self.p('duration'):g} s "
            f"per train at {self.p('rate'):g} Hz, {self.substeps} steps of {self.dt:g} s per message; trains: "
            f"{self.p('trains') or 'until deactivated'}"
        )
        return TransitionCallbackReturn.SUCCESS

    def _build(self) -> None:
        for name in ("trains", "headway", "train_pause", "track_node", "answer_timeout", "exit_when_done"):
            lookup(name).check(self.p(name))
        g = self.p
        params = load_params_file(g("params_file")) if g("params_file") else load_model(g("track"), g("soil"),
                                                                                          g("model"))
        spec = VehicleRunSpec(
            vehicle=g("vehicle"), cars=int(g("cars")), speed=float(g("speed")), duration=float(g("duration")),
            dt=float(g("dt")), start=float(g("start")), irregularity=g("irregularity"), seed=int(g("seed")),
            wavelength_band=g("wavelength_band"),
        )
        run = build_vehicle_run(spec, params)
        sim = run.simulation
        rate = float(g("rate"))
        sub = 1.0 / (rate * sim.dt)
        if abs(sub - round(sub)) > 1e-9 or round(sub) < 1:
            raise ClmError(f"rate = {rate:g} Hz and dt = {sim.dt:g} s: 1/(rate dt) = {sub:g} must be a whole number")
        self.substeps = int(round(sub))
        self.dt = sim.dt
        self.speed = float(sim.speed)
        self.n_messages = int(round(run.duration * rate)) + 1
        self.period_ns = int(round(NS / rate))
        self._template = StreamingVehicle(sim)  # compiles or loads the step now, not in a train
        self.n_wheels = self._template.train.n_wheels
        self.ids = np.arange(self.n_wheels, dtype=np.uint32)
        self.speeds = np.full(self.n_wheels, self.speed)
        self.max_delay_steps = int(float(g("max_feedback_delay")) / sim.dt)
        self.closed_loop = bool(g("closed_loop"))
        self.frame_id = str(g("frame_id"))
        self.answer_timeout_ns = int(float(g("answer_timeout")) * NS)

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        ret = super().on_activate(state)
        self._first_of_activation = self._number  # trains are numbered over the node's life
        self._next_start = time.monotonic_ns()
        self._begin_wait()
        return ret

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self._halt("inactive")
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self._drop_entities()
        self._template = self.vehicle = None
        self._set_state("unconfigured", DiagnosticStatus.OK)
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        self._halt("finalized")
        self._drop_entities()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: State) -> TransitionCallbackReturn:
        self._halt("unconfigured")
        self._drop_entities()
        return TransitionCallbackReturn.SUCCESS

    def _drop_entities(self) -> None:
        for p in (self._pub, self._clock_pub):
            if p is not None:
                self.destroy_lifecycle_publisher(p)
        if self._answers_node is not None:
            self._answers_node.destroy_node()
        self._pub = self._clock_pub = self._sub = self._diag_sub = self._start_sub = self._answers_node = None

    def _halt(self, state: str) -> None:
        """Stop the schedule (the train that runs is reported as stopped)."""
        if self._phase in ("run", "answers"):
            self._finish_train(stopped=True)
        self._phase = "idle"
        self._set_state(state, DiagnosticStatus.OK)
        self._publish_diagnostics()

    def stop(self) -> None:
        """The process is ending (SIGINT, SIGTERM or ``exit_when_done``): stop the schedule."""
        self._halt(self.state_text if self._phase == "done" else "stopped")

    def _set_state(self, text: str, level: int) -> None:
        self.state_text, self.level = text, level
        self._latch()

    def _latch(self) -> None:
        """Publish the control-plane state (phase, train, its start and end, the last train's figures) latched."""
        latched = getattr(self, "_latched", None)
        if latched is None:  # (a state set before the publisher exists)
            return
        values = {"phase": getattr(self, "_phase", "idle"), "state": self.state_text,
                  "train": getattr(self, "_number", 0), "trains_done": getattr(self, "trains_done", 0),
                  "train.start_ns": self._train_times[0], "train.end_ns": self._train_times[1],
                  **self._final_values}
        latched.update(DiagnosticStatus.ERROR if getattr(self, "_model_error", "") else self.level, self.state_text,
                       values)

    # ------------------------------------------------------------------ the schedule

    def serve_due(self) -> float:
        """Do what is due now; return how long the executor may wait for other work until the next action [s]."""
        try:
            self._take_answers()
            phase = self._phase
            if phase == "run":
                return self._serve_train()
            if phase == "wait":
                return self._serve_wait()
            if phase == "answers":
                return self._serve_answers()
            if phase == "pause":
                wait = self._next_start - time.monotonic_ns()
                if wait <= 0:
                    self._begin_wait()
                    return 0.0
                return wait / NS
        except Exception as exc:  # a failed train ends the schedule; the node stays up and says why
            self._model_error = str(exc)
            self._phase = "stopped"
            self._set_state(f"stopped: {exc}", DiagnosticStatus.ERROR)
            self.get_logger().error(f"train {self._number} stopped: {exc}")
            self._publish_diagnostics()
        return 0.1

    def _begin_wait(self) -> None:
        trains = int(self.p("trains"))
        if trains and self._number - self._first_of_activation >= trains:
            self._phase = "done"
            self._set_state(f"done: {trains} train(s)", self.level)
            self._publish_diagnostics()
            if self.p("exit_when_done"):
                self.exit_code = 0
            return
        self._phase = "wait"
        self._wait_since = time.monotonic_ns()
        self._warned = False
        self._set_state(f"train {self._number + 1}: waiting for {self.p('track_node') or 'a subscriber'}",
                        self.level)

    def _track_ready(self) -> bool:
        """The track node is active and subscribed: its subscription and answering publisher matched, on this
        node's side and on its own (:meth:`_track_subscribed`)."""
        pub, sub = self._pub, self._sub
        if pub is None or sub is None or pub.get_subscription_count() < int(self.p("wait_for_subscribers")):
            return False
        name = str(self.p("track_node"))
        if not name:
            return True
        readers = self.get_subscriptions_info_by_topic(pub.topic_name)
        writers = self.get_publishers_info_by_topic(sub.topic_name)
        ns = self.get_namespace()
        if not (sub.get_publisher_count() >= 1 and any(owned(r, name, ns) for r in readers)
                and any(owned(w, name, ns) for w in writers) and all_matched(pub, readers)):
            # gone, or not there yet: ask again when back, and forget what a former track node said
            self._graph_ready_since, self._handshake = 0, None
            for _ in take_raw(self._diag_sub):
                pass
            return False
        return self._track_subscribed(name)

    def _track_subscribed(self, name: str) -> bool:
        """The track node says (``wheel_load_publishers_matched`` >= 1 in its latched ``track_status``) that its
        subscription has matched this node's publisher (discovery is two-sided: wheel loads published before
        it may never reach a volatile reader). A track node without that status (not a clm one) is taken at its
        graph entry after :data:`HANDSHAKE_TIMEOUT_NS`.
        """
        status = f"{self.get_namespace().rstrip('/')}/{name}: "
        for raw, _ in take_raw(self._diag_sub):
            for st in deserialize_message(raw, DiagnosticArray).status:
                if st.name.startswith(status):
                    said = next((kv.value for kv in st.values if kv.key == "wheel_load_publishers_matched"), "")
                    self._handshake = int(said) if said.isdigit() else -1
        now = time.monotonic_ns()
        if not self._graph_ready_since:
            self._graph_ready_since = now
        if self._handshake is not None:
            return self._handshake != 0
        if self._diag_sub.get_publisher_count():  # a clm track node: its latched word comes, however late
            return False
        return now - self._graph_ready_since > HANDSHAKE_TIMEOUT_NS

    def _start_due(self) -> bool:
        """``start_signal``: the first train of an activation starts at the supervisor's start time (latched
        ``start_at``); the node says once that it is ready and waits for it."""
        if self._start_sub is None or self._number > self._first_of_activation:
            return True
        for raw, _ in take_raw(self._start_sub):
            self._start_at = int(deserialize_message(raw, Int64).data)
        if self._start_at is None:
            text = f"train {self._number + 1}: ready, waiting for the start signal"
            if self.state_text != text:
                self._phase = "ready"
                self._set_state(text, self.level)
                self._phase = "wait"
            return False
        return time.time_ns() >= self._start_at

    def _serve_wait(self) -> float:
        if self._track_ready() and self._start_due():
            if self._warned:
                self.get_logger().info(f"{self.p('track_node') or 'a subscriber'} is there: train "
                                       f"{self._number + 1} starts")
            self._start_train()
            return self._serve_train()
        timeout = float(self.p("discovery_timeout"))
        if not self._warned and time.monotonic_ns() - self._wait_since > timeout * NS:
            self._warned = True
            who = self.p("track_node") or "a subscriber"
            self._set_state(f"train {self._number + 1}: waiting for {who} for more than {timeout:g} s",
                            DiagnosticStatus.WARN)
            self.get_logger().error(
                f"no {who} (active, subscribed to {self._pub.topic_name}, publishing {self._sub.topic_name}) and "
                f"{self.p('wait_for_subscribers')} matched reader(s) after {timeout:g} s"
                + (": giving up" if self.p("exit_when_done") else "; still waiting"))
            if self.p("exit_when_done"):
                self.exit_code = 3
                self._phase = "stopped"
        return 0.01

    def _start_train(self) -> None:
        assert self._template is not None
        self._number += 1
        self.finished = self.finished + self.train
        self.train = Counts()
        self.sent.clear()
        self.vehicle = copy.deepcopy(self._template)
        self._recent_lags.clear()
        self._silent = False
        self._train_times = (time.time_ns(), 0)
        self._phase = "run"
        self._set_state(f"train {self._number}: running", DiagnosticStatus.OK)
        self._started = time.monotonic_ns()
        self._base_ns = self._sim_ns if self._clock_pub is not None else self.get_clock().now().nanoseconds
        self._start_ns = time.monotonic_ns()
        self._last_answer = self._start_ns
        self._k = 0
        self._prepare(0)
        self._phase = "run"
        self.get_logger().info(f"train {self._number} starts: {self.n_messages} messages")

    def _prepare(self, k: int) -> None:
        """Compute message ``k``: the vehicle advanced to its time, its bytes."""
        veh = self.vehicle
        assert veh is not None
        c0 = time.thread_time()
        P = veh.P.copy() if k == 0 else veh.advance(self.substeps)
        self.train.model_cpu_s += time.thread_time() - c0
        self.train.model_messages += 1
        self._t_ns = self._base_ns + k * self.period_ns
        self._data = encode_wheel_loads(self._t_ns, self.frame_id, self.ids, veh.x, P, self.speeds)
        self._deadline = self._start_ns + k * self.period_ns

    def _serve_train(self) -> float:
        now = time.monotonic_ns()
        if now < self._deadline:
            return (self._deadline - now) / NS
        c = self.train
        if now - self._deadline > 2 * self.period_ns:
            c.late += 1
        veh = self.vehicle
        assert veh is not None
        self.sent[self._t_ns] = (veh.k, self._deadline)
        try:
            if self._clock_pub is not None:
                self._clock_pub.publish(Clock(clock=Time(nanoseconds=self._t_ns).to_msg()))
            self._pub.publish(self._data)
            c.published += 1
        except Exception as exc:  # never dies on a publish (a vanished peer, a context going down)
            c.publish_failed += 1
            if c.publish_failed == 1:
                self.get_logger().warning(f"publish failed (counted, the train goes on): {exc}")
        self._k += 1
        if (self._k & 63) == 0:
            self._watch_answers(now)
        if self._k >= self.n_messages:
            c.contact_lost_steps = veh.contact_lost_steps
            self._phase = "answers"
            self._deadline = now + int(float(self.p("ack_timeout")) * NS)
            return 0.0
        self._prepare(self._k)
        return max(self._deadline - time.monotonic_ns(), 0) / NS

    def _watch_answers(self, now: int) -> None:
        old = now - int(FORGET_AFTER * NS)
        sent = self.sent
        while sent:
            first = next(iter(sent))
            if sent[first][1] >= old:
                break
            del sent[first]
        if not self._silent and now - self._last_answer > self.answer_timeout_ns:
            self._silent = True
            self._set_state(self.state_text + f" (no answer for {self.answer_timeout_ns / NS:g} s)",
                            DiagnosticStatus.WARN)
            self.get_logger().warning(
                f"no answer from the track node for {self.answer_timeout_ns / NS:g} s (it may have died): the train "
                "goes on on its predictor alone, and uses the answers again when they return")

    def _serve_answers(self) -> float:
        if self.sent and time.monotonic_ns() < self._deadline:
            return 0.005
        self._finish_train(stopped=False)
        return 0.0

    def _finish_train(self, stopped: bool) -> None:
        c = self.train
        if self.vehicle is not None:
            c.contact_lost_steps = self.vehicle.contact_lost_steps
        self.sent.clear()
        self._report(self._number, c, stopped)
        self._train_times = (self._train_times[0], time.time_ns())
        if stopped:
            return
        self.trains_done += 1
        self._next_start = max(self._started + int(float(self.p("headway")) * NS),
                               time.monotonic_ns() + int(float(self.p("train_pause")) * NS))
        self._sim_ns = self._t_ns + int(round(float(self.p("train_pause")) * NS))
        self._phase = "pause"
        self._set_state(f"train {self._number} done", self.level)
        self._publish_diagnostics(final=self._number)
        trains = int(self.p("trains"))
        if trains and self._number - self._first_of_activation >= trains:
            self._begin_wait()  # the schedule is complete: done

    def _report(self, number: int, c: Counts, stopped: bool) -> None:
        lag = c.lag_figures()
        used = 100.0 * c.used / c.published if c.published else 0.0
        self.get_logger().info(
            f"train {number}{' (stopped)' if stopped else ''}: published {c.published} wheel-load messages at "
            f"{self.p('rate')} Hz ({c.late} late by > 2 periods), {c.answered} answered ({c.used} used as "
            f"feedback, {c.stale} too late, {c.after_end} after the last step); contact lost in "
            f"{c.contact_lost_steps} wheel-steps; vehicle model {c.model_us():.0f} us per message; feedback "
            f"{used:.1f} %, "
            + (f"answer lag median {1e3 * lag['lag_median_s']:.2f} ms, p99 {1e3 * lag['lag_p99_s']:.2f} ms, max "
               f"{1e3 * lag['lag_max_s']:.2f} ms" if c.answered else "no answer")
        )

    # ------------------------------------------------------------------ answers

    def _take_answers(self) -> None:
        """Take every answer that has arrived (the middleware's reception time is each one's arrival)."""
        if self._sub is None:
            return
        offset = time.time_ns() - time.monotonic_ns()  # system clock -> monotonic
        for raw, received in take_raw(self._sub):
            self._on_response(raw, received - offset if received else time.monotonic_ns())

    def _on_response(self, raw: bytes, now: int) -> None:
        """One answer, received at ``now`` [monotonic ns]."""
        c = self.train
        try:
            d = decode_wheel_rail_response(raw)
        except MessageError:
            c.malformed += 1
            return
        entry = self.sent.pop(d.stamp_ns, None)
        veh = self.vehicle
        if entry is None or veh is None:
            c.unmatched += 1
            return
        step, due = entry
        c.answered += 1
        lag = (now - due) / NS
        c.lags.append(lag)
        self._recent_lags.append(lag)
        self._last_answer = now
        if self._silent:
            self._silent = False
            self.get_logger().info("the track node answers again: its answers are used as feedback again")
            if self.level == DiagnosticStatus.WARN:
                self._set_state(self.state_text.split(" (no answer")[0], DiagnosticStatus.OK)
        if self._phase != "run":  # after the last step an answer feeds nothing
            c.after_end += 1
            return
        if not self.closed_loop:
            return
        if veh.k - step > self.max_delay_steps:
            c.stale += 1
            return
        ids = d.wheel_id
        w = np.full(self.n_wheels, np.nan)
        if ids.size and int(ids.max()) < self.n_wheels:
            w[ids] = d.rail_deflection
        try:
            veh.set_track_response(step, w)
            c.used += 1
        except ClmError as exc:
            self.get_logger().warning(f"track answer not used (counted): {exc}", once=True)

    # ------------------------------------------------------------------ diagnostics

    def counts(self) -> tuple[Counts, Counts]:
        """(current or last train, the node's life so far)."""
        return self.train, self.finished + self.train

    def _publish_diagnostics(self, final: int = 0) -> None:
        c, life = self.counts()
        lags = np.asarray(self._recent_lags) if self._recent_lags else np.full(1, np.nan)
        values: dict[str, Any] = {
            "state": self.state_text,
            "trains_done": self.trains_done,
            "train": self._number,
            "train.published": c.published,
            "train.answered": c.answered,
            "train.feedback_used": c.used,
            "train.feedback_total": c.published,
            "train.too_late": c.stale,
            "train.after_last_step": c.after_end,
            "train.late_publishes": c.late,
            "train.contact_lost_steps": self.vehicle.contact_lost_steps if self.vehicle is not None else 0,
            "train.model_us_per_message": f"{c.model_us():.1f}",
            "recent_lag_median_s": f"{float(np.median(lags)):.6f}",
            "recent_lag_p99_s": f"{float(np.percentile(lags, 99)):.6f}",
            "published": life.published,
            "answered": life.answered,
            "feedback_used": life.used,
            "too_late": life.stale,
            "unmatched": life.unmatched,
            "malformed": life.malformed,
            "late_publishes": life.late,
            "publish_failed": life.publish_failed,
            "scheduling": self.scheduling.text,
        }
        if final:
            values["final_train"] = final
            values.update({f"train.{k}": f"{v:.6f}" for k, v in c.lag_figures().items()})
            self._final_values = {k: v for k, v in values.items() if k.startswith("train.") or k in (
                "final_train", "scheduling")}
            self._latch()
        level, message = (DiagnosticStatus.ERROR if self._model_error else self.level), self.state_text
        # the closed loop is open in effect when answers come too late: more than 1 % of the messages published
        # since the last diagnostics
        published, stale = c.published - self._diag_mark[0], c.stale - self._diag_mark[1]
        self._diag_mark = (c.published, c.stale) if c.published >= self._diag_mark[0] else (0, 0)
        if level == DiagnosticStatus.OK and self.closed_loop and published >= 100 and stale > 0.01 * published:
            level = DiagnosticStatus.WARN
            message += f" ({stale} of the last {published} answers too late for the closed loop)"
        publish_status(self, self._pub_diag, f"{self.get_fully_qualified_name()}: vehicle simulator", level, message,
                       values)


def _ignore(_raw: bytes) -> None:
    """Callback of the answers' subscription, never called: no executor spins its node."""


def main(args: Sequence[str] | None = None) -> int:
    """Console entry point ``vehicle_node``: run the node until SIGINT, SIGTERM or its last train; exit."""
    # exit_now: a process of its own (not called from Python code) skips the interpreter's finalization
    return run_node(lambda _signals: VehicleNode(), args, NODE_NAME, exit_now=args is None)


if __name__ == "__main__":
    sys.exit(main())
