"""The track–soil node: wheel loads in, sleeper soil forces and rail deflections out, in real time.

A lifecycle node (``rclpy.lifecycle``, the semantics of ros2/demos
``lifecycle_py``) over plain-Python collaborators; it owns no physics:

- the model: :meth:`clm_core.online.OnlineTrackModel.from_settings` (the one
  factory of the node, ``clm replay`` and the fleet) on the node's parameters
  (:meth:`TrackNode._settings`);
- the data path: :class:`clm_ros.track_answers.AnswerPath` over
  :mod:`clm_core.online.edge` (decode -> process -> encode, the path of
  ``clm replay`` too: the answers are identical by construction);
- the subscription watch: :class:`clm_ros.track_input.WheelLoadInput` (QoS,
  peers, the stream's source, taking the messages);
- the status: :class:`clm_ros.track_status.TrackStatus`, published on
  ``/diagnostics`` by a thread of its own (on time during a backlog).

States: **unconfigured** (no model; parameters can be set, an invalid or
unstable physics set is refused with its reason); **configuring** (build,
validate and warm up the model: every JIT compilation and factorisation now,
so the first second of traffic is like any other; create the answer
publishers and views; an invalid set fails the transition, logged);
**inactive** (model ready, not subscribed); **activating** (enable the
publishers, then subscribe to ``wheel_loads``: **the subscription exists
exactly while the node is active**, a publisher's
``get_subscription_count()`` >= 1 means warmed up and answering, the signal
the vehicle node waits for); **active** (every message taken is answered on
``sleeper_response`` and ``wheel_rail_response``, stamped with the input's
stamp, or rejected and counted); **deactivating** (wheel loads still queued
are discarded unprocessed, counted as ``not_accepted``); **cleaning up**
(drop the model and the answer publishers); **finalized** (never answers
again).

With ``autostart`` (default true) it configures and activates itself. Parameters are validated in
the on-set callback (nothing changes there) and applied in the post-set callback: a physics change (a
model parameter, the input policy) swaps a new model in; the state restarts at the next message.

Run: ``python -m clm_ros.track_node --ros-args -p soil:=haren`` (``ros2 run clm_ros track_node``).
"""

from __future__ import annotations

import gc
import sys
import time
from typing import Any

from clm_msgs.msg import SleeperResponse, WheelRailResponse
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import State, TransitionCallbackReturn
from rclpy.parameter import Parameter
from visualization_msgs.msg import MarkerArray

from clm_core.errors import ClmError
from clm_core.online import OnlineStats, OnlineTrackModel
from clm_core.online.model import FACTORY_SETTINGS, MODEL_SETTINGS, PARAMS_SETTINGS
from clm_ros import qos
from clm_ros.conversions import rclpy_header
from clm_ros.diagnostics import Counters, DiagnosticsThread, LagMonitor, diagnostic_array
from clm_ros.latched import TRACK_STATUS, follow, matched_readers
from clm_ros.node_log import NodeLog, bounded
from clm_ros.node_main import StopSignals, freeze_heap, guard_change_state, run_node
from clm_ros.parameters import TRACK_NODE_SETTINGS, declare_model_parameters, declare_settings
from clm_ros.realtime import NOT_APPLIED, Scheduling
from clm_ros.track_answers import AnswerPath, raw_sender, warm_up
from clm_ros.track_input import WheelLoadInput
from clm_ros.track_status import TrackStatus
from clm_ros.track_views import MonitoredSleepers, monitored_indices, window_markers

NODE_NAME = "clm_track_node"

#: Seconds the node waits, before its answer publishers go (cleanup, shutdown, a stop signal), for every reader
#: to acknowledge the answers already published: a writer destroyed earlier takes the samples still in flight
#: with it (seen: 393 of 3438 wheel answers never arrived after a burst ended by ``shutdown``). Live readers on
#: one host acknowledge within a heartbeat (50 ms, clm_ros/fastdds_profile.xml); the bound is for a reader that
#: died silently (its middleware still counts it until its lease expires).
FLUSH_TIMEOUT = 0.5

_ANSWER_PUBLISHERS = ("_pub_s", "_pub_w", "_pub_mon", "_pub_markers")


class TrackNode(LifecycleNode):
    """Lifecycle node running the streaming track–soil model on wheel-load messages.

    Parameters
    ----------
    stop : StopSignals, optional
        Stop requests (signals) checked between chunks of a long backlog.
    **kwargs
        Passed to ``rclpy.lifecycle.Node``.
    """

    def __init__(self, stop: StopSignals | None = None, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        # the factory's settings (clm_core.online.model.FACTORY_SETTINGS) and the node's own (clm_ros.parameters)
        declare_settings(self, (*PARAMS_SETTINGS, *MODEL_SETTINGS, *TRACK_NODE_SETTINGS))
        declare_model_parameters(self)  # every scalar model parameter, NaN = from the preset / file
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self.log = NodeLog(self)
        guard_change_state(self, self.log, lambda: self._state)
        #: SCHED_FIFO priority asked of clm_ros.node_main.run_node, which sets ``scheduling`` to the outcome
        self.realtime_priority = int(self._p("realtime_priority"))
        self.scheduling: Scheduling = NOT_APPLIED
        #: None while the process should run; 2: the model could not be configured at start (clm_ros.node_main)
        self.exit_code: int | None = None
        self.stats = OnlineStats()  # the model's counters, carried from model to model for the node's life
        self.counters = Counters()
        self.path: AnswerPath | None = None
        self._state = "unconfigured"
        self._configure_error = ""
        self._pub_s: Any = None
        self._pub_w: Any = None
        self._pub_mon: Any = None
        self._pub_markers: Any = None
        self._markers_watched = False  # someone subscribes to track_markers (followed by the housekeeping)
        self._last_markers = 0.0
        self._ros_clock = self.get_clock()  # not self._clock: that is rclpy Node's own attribute
        self._sim_time = bool(self._p("use_sim_time"))
        self._lag = LagMonitor(self._now_ns)
        self.input = WheelLoadInput(self, self.counters, self.stats, self.log, stop or StopSignals(), self._answer,
                                    lambda reason, text: self.path.reject(reason, text) if self.path else None,
                                    doorbell=self._p("answer_loop") == "executor")
        if self._p("answer_loop") == "waitset":  # the wait-set loop's hooks (clm_ros.node_main._spin)
            self.wait_fd, self.serve_fd = self.input.arrival_fd, self.input.serve_arrivals
        self._status = TrackStatus(self.input)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)  # for life, not per configure
        self.create_timer(0.25, self._housekeeping, clock=Clock(clock_type=ClockType.STEADY_TIME))
        follow(self, TRACK_STATUS, "track-soil model", lambda: (0, self._state, {  # clm_ros.latched: readiness
            "state": self._state, "wheel_load_publishers_matched": self.input.matched_publishers,
            **matched_readers(sleeper_response=self._pub_s, wheel_rail_response=self._pub_w)}))
        self._diag = DiagnosticsThread(self._publish_diagnostics, float(self._p("diagnostics_period")),
                                       self._diag_failed)
        if self._p("autostart"):
            self.trigger_configure()
            if self.path is not None:
                self.trigger_activate()
            else:
                self.exit_code = 2
        self._diag.start()

    def _p(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _diag_failed(self, exc: BaseException) -> None:
        self.log.warning(f"/diagnostics not published: {exc}")

    def _now_ns(self) -> int:
        """The clock the stamps are read on [ns]: sim time with use_sim_time (0 until /clock), else system time
        (what ROS time is without sim time, read without the cost of a Time object)."""
        return int(self._ros_clock.now().nanoseconds) if self._sim_time else time.time_ns()

    # ------------------------------------------------------------------ model from parameters

    def _settings(self, changes: dict[str, Any] | None = None) -> dict[str, Any]:
        """The factory's settings (:data:`~clm_core.online.model.FACTORY_SETTINGS`) from the node's parameters,
        with pending ``changes`` over them."""
        out = {name: self._p(name) for name in FACTORY_SETTINGS}
        out.update((k, v) for k, v in (changes or {}).items() if k in out)
        return out

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Validate a change, changing nothing: a physics change must build a model (stability too)."""
        changes = {p.name: p.value for p in params}
        if any(k in FACTORY_SETTINGS for k in changes):
            try:
                OnlineTrackModel.from_settings(self._settings(changes), stats=OnlineStats())
            except (ClmError, ValueError, OSError) as exc:
                self.log.warning(f"parameter update refused: {exc}")
                return SetParametersResult(successful=False, reason=bounded(str(exc)))
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, params: list[Parameter]) -> None:
        """Apply a change (validated by :meth:`_on_set_parameters`, now set)."""
        names = {p.name for p in params}
        self._sim_time = bool(self._p("use_sim_time"))
        path = self.path
        if path is None:
            return
        path.every, path.frame_id = int(self._p("publish_every")), str(self._p("frame_id"))
        if names & set(FACTORY_SETTINGS) and self._state in ("inactive", "active"):
            path.model = OnlineTrackModel.from_settings(self._settings(), stats=self.stats)
            self.log.info(f"parameters updated ({', '.join(sorted(names))}); the state restarts at the next message")

    # ------------------------------------------------------------------ lifecycle

    def on_configure(self, state: State) -> TransitionCallbackReturn:
        """Build, validate and warm up the model; create the answer publishers."""
        frame_id = str(self._p("frame_id"))
        try:
            model = OnlineTrackModel.from_settings(self._settings(), stats=self.stats)
            spacing = model.params.track.spacing
            monitor = MonitoredSleepers(monitored_indices(str(self._p("monitored_sleepers")),
                                                          str(self._p("monitored_positions")), spacing), spacing)
            for r in warm_up(OnlineTrackModel.from_settings(model.settings, params=model.params), frame_id):
                window_markers(r, rclpy_header(r.stamp_ns, frame_id))
        except (ClmError, ValueError, OSError) as exc:
            self._configure_error = bounded(str(exc))
            self.log.error(f"configure refused: {exc}")
            return TransitionCallbackReturn.FAILURE
        self._configure_error = ""
        self.path = AnswerPath(model, self.counters, self._lag, self.log, frame_id, int(self._p("publish_every")),
                               monitor)
        opts = qos.overrides
        self._pub_s = self.create_lifecycle_publisher(SleeperResponse, "sleeper_response", qos.answers_qos(),
                                                      qos_overriding_options=opts())
        self._pub_w = self.create_lifecycle_publisher(WheelRailResponse, "wheel_rail_response", qos.answers_qos(),
                                                      qos_overriding_options=opts())
        if monitor:
            self._pub_mon = self.create_lifecycle_publisher(SleeperResponse, "monitored_sleepers", qos.view_qos(100),
                                                            qos_overriding_options=opts())
        if float(self._p("markers_period")) > 0:
            self._pub_markers = self.create_lifecycle_publisher(MarkerArray, "track_markers", qos.view_qos(1),
                                                                qos_overriding_options=opts())
        self._state = "inactive"
        self.log.info(f"configured: {model.params.name or 'parameter file'}, dt = {model.dt:g} s, window "
                      f"{model.n_sleepers} sleepers; compiled and factorised")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        """Enable the publishers, then subscribe (the node is ready when its subscription appears)."""
        ret = super().on_activate(state)
        if ret != TransitionCallbackReturn.SUCCESS:
            return ret
        freeze_heap()  # what exists now (model, kernels, modules) is not scanned while active: shorter collections
        self.input.subscribe()
        self.input.accepting = True
        self._state = "active"
        topic = self.input.sub.topic_name if self.input.sub is not None else "wheel_loads"
        self.log.info(f"active: subscribed to {topic} ({self.input.reliability})")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        """Stop accepting; discard (and count) what is still queued; unsubscribe."""
        self.input.unsubscribe()
        self._state = "inactive"
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        """Drop the model and the publishers."""
        return self._release()

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        """From any primary state: unsubscribe, drop everything; the node never answers again."""
        return self._release("finalized", "finalized: no wheel loads are taken any more")

    def on_error(self, state: State) -> TransitionCallbackReturn:
        """A transition raised: release everything and go back to unconfigured."""
        return self._release("unconfigured", "a transition failed; the node is unconfigured")

    def _release(self, state: str = "", why: str = "") -> TransitionCallbackReturn:
        """Unsubscribe (counting what is queued), drop the model and the publishers; now in ``state``."""
        self.input.unsubscribe()
        if why:
            (self.log.info if state == "finalized" else self.log.error)(why)
        self._flush_answers()
        for name in _ANSWER_PUBLISHERS:
            pub = getattr(self, name)
            if pub is not None:
                self.destroy_lifecycle_publisher(pub)
                setattr(self, name, None)
        self.path = None
        # the model frozen at activation would never be collected (its reference cycles stayed for good: ~200 kB
        # a configure / activate / cleanup cycle, issue 26.8); back under the collector, the next activation
        # freezes what lives then
        gc.unfreeze()
        gc.collect()
        self._state = state or "unconfigured"
        return TransitionCallbackReturn.SUCCESS

    # ------------------------------------------------------------------ data path, views, housekeeping

    def _answer(self, raws: list[bytes]) -> None:
        """Answer one chunk of messages, in order (:class:`clm_ros.track_answers.AnswerPath`)."""
        path = self.path
        assert path is not None  # accepting only while active
        if self.input.new_stream:
            self.input.new_stream, path.new_stream = False, True
        mon = self._pub_mon
        path.run(raws, raw_sender(self._pub_s), raw_sender(self._pub_w), mon.publish if mon is not None else None)
        if self._markers_watched:
            self._publish_markers()

    def _publish_markers(self) -> None:
        path, now = self.path, time.monotonic()
        r = path.last_response if path is not None else None
        if path is None or r is None or now - self._last_markers < float(self._p("markers_period")):
            return
        self._last_markers = now
        try:
            self._pub_markers.publish(window_markers(r, rclpy_header(r.stamp_ns, path.frame_id)))
        except Exception as exc:  # a view must never stop the answers
            self.log.warning(f"track_markers not published: {exc}", key="markers")

    def _housekeeping(self) -> None:
        """Every 0.25 s on the executor thread: who watches the markers; the input follows its peers."""
        markers = self._pub_markers
        self._markers_watched = markers is not None and markers.get_subscription_count() > 0
        self.input.housekeeping(self._pub_w.get_subscription_count() if self._pub_w is not None else 0)

    def _publish_diagnostics(self) -> None:
        """The status (:class:`clm_ros.track_status.TrackStatus`) on ``/diagnostics`` (diagnostics thread)."""
        budget, late = float(self._p("lag_budget")), float(self._p("max_feedback_delay"))
        level, message, values = self._status.build(self._state, self._configure_error, self.path,
                                                    self._lag.summary(late), budget, late, self.scheduling.text)
        name = f"{self.get_fully_qualified_name()}: track-soil model"  # the namespace tells a fleet's pairs apart
        self._pub_diag.publish(diagnostic_array(name, level, message, values, self.get_clock().now().to_msg()))

    def _flush_answers(self, timeout: float = FLUSH_TIMEOUT) -> bool:
        """Wait up to ``timeout`` s in all until every reader has acknowledged every answer published (the
        answer topics and the monitored sleepers); False, logged, if one has not (a reader gone silently)."""
        deadline = time.monotonic() + timeout
        acked = True
        for pub in (self._pub_s, self._pub_w, self._pub_mon):
            if pub is not None:
                left = max(deadline - time.monotonic(), 0.0)
                acked = pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and acked
        if not acked:
            self.log.warning(f"answers not acknowledged by every reader within {timeout:g} s (a reader gone without "
                             "leaving the graph?); what it had not received is lost to it", key="unacked")
        return acked

    def drain(self, spin_until: Any) -> None:
        """After a stop signal (:func:`clm_ros.node_main.run_node`): stop taking wheel loads, then let the
        readers acknowledge the answers already published (at most :data:`FLUSH_TIMEOUT` s)."""
        self.input.accepting = False
        self._flush_answers()

    def destroy_node(self) -> None:
        """Stop the diagnostics thread, then destroy the node."""
        self._diag.stop()
        self.input.accepting = False
        super().destroy_node()  # type: ignore[no-untyped-call]  # rclpy leaves Node.destroy_node unannotated

    def counts(self) -> dict[str, Any]:
        """Every counter of the node's life, as in ``/diagnostics`` (for tests and the launcher)."""
        return self.counters.values(self.stats)


def main(args: list[str] | None = None) -> int:
    """Console entry point ``track_node``: exit 0 on SIGINT/SIGTERM (within 2 s, also under load), 2 when the
    model cannot be configured at start (:func:`clm_ros.node_main.run_node`)."""
    return run_node(TrackNode, args, NODE_NAME)


if __name__ == "__main__":
    sys.exit(main())
