"""The track–soil node: wheel loads in, sleeper soil forces and rail deflections out, in real time.

A lifecycle node (``rclpy.lifecycle``, the semantics of ros2/demos
``lifecycle_py``) wrapping :class:`clm_core.online.OnlineTrackModel`. It owns
no physics: it decodes messages at its edge, calls the core and encodes the
answers (``clm replay`` runs the same core offline: the outputs are
identical by construction).

States and what the node does in each:

- **unconfigured**: no model. Parameters can be set; an invalid or unstable
  physics set is refused with its reason here too.
- **configuring** (``configure``): build and validate the model, then warm it
  up: every JIT compilation (numba, cached on disk) and factorisation happens
  now, so the first second of traffic is like any other. Create the answer
  publishers (lifecycle publishers) and the live views. An invalid set fails
  the transition (back to unconfigured, the reason logged).
- **inactive**: model ready, not subscribed.
- **activating** (``activate``): enable the publishers, then subscribe to
  ``wheel_loads``. **The subscription exists exactly while the node is
  active**: a publisher's ``get_subscription_count()`` turning >= 1 means the
  node is warmed up and answering (the signal the vehicle node waits for).
- **active**: every message taken is decoded, validated and answered
  (``sleeper_response`` and ``wheel_rail_response``, stamped with the input's
  stamp), or rejected and counted.
- **deactivating**: stop accepting; wheel loads still queued are taken and
  discarded unprocessed (counted as ``not_accepted``: not accepted, so no
  answer is owed), then the subscription is destroyed.
- **cleaning up**: drop the model and the answer publishers.
- **shutting down** -> **finalized**: as deactivate + clean up; the node never
  answers again (its ``/diagnostics`` say ``finalized``).

With ``autostart`` (default true) it configures and activates itself.

One stream per topic: the messages are taken with their publisher's GID
(:mod:`clm_ros.track_input`, :mod:`clm_ros.sources`); the first publisher
heard is the stream's source, a second publisher's messages are refused
(``rejected.second_source``, ``/diagnostics`` WARN naming it) until the source
leaves the graph, then the next publisher heard takes over (a new stream).

The data path (one executor task): take everything waiting in the
subscription (drain), decode with the numpy CDR codec
(:mod:`clm_core.io.messages`), integrate through all of them in one go
(``process_batch``), encode both answers per accepted message and publish
the serialized bytes, in order. A malformed message is a rejection
(``malformed``), never an exception. ``/diagnostics`` are published by a
thread of their own (:mod:`clm_ros.diagnostics`), on time during a backlog.

Run: ``python -m clm_ros.track_node --ros-args -p soil:=haren -p dt:=1e-4`` (or
``ros2 run clm_ros track_node`` in a full ROS install).
"""

from __future__ import annotations

import gc
import math
import sys
import time
from typing import Any

import numpy as np
from clm_msgs.msg import SleeperResponse, WheelRailResponse
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.lifecycle import State, TransitionCallbackReturn
from visualization_msgs.msg import MarkerArray

from clm_core.errors import ClmError
from clm_core.io.errors import MessageError
from clm_core.io.messages import encode_sleeper_response, encode_wheel_rail_response, frame_from_cdr
from clm_core.io.timebase import NS
from clm_core.online import InputPolicy, OnlineStats, OnlineTrackModel, Reason, Rejected, ResponseFrame, WheelFrame
from clm_core.params import PARAMETER_DOCS, SOIL_MODELS, ModelParams, load_model, load_params_file
from clm_core.settings import ONLINE_POLICY
from clm_ros import qos
from clm_ros.conversions import rclpy_header
from clm_ros.diagnostics import (
    ERROR,
    OK,
    STALE,
    WARN,
    Counters,
    DiagnosticsThread,
    LagMonitor,
    diagnostic_array,
    lag_level,
    lag_values,
)
from clm_ros.latched import TRACK_STATUS, follow, matched_readers
from clm_ros.node_log import bounded
from clm_ros.node_main import StopSignals, freeze_heap, run_node
from clm_ros.parameters import declare_model_parameters, declare_settings
from clm_ros.realtime import NOT_APPLIED, Scheduling
from clm_ros.sources import GidSubscription, Sources
from clm_ros.track_input import TrackInput
from clm_ros.track_views import MonitoredSleepers, monitored_indices, window_markers

NODE_NAME = "clm_track_node"

#: Seconds the node waits, before its answer publishers go (cleanup, shutdown, a stop signal), for every reader
#: to acknowledge the answers already published: a writer destroyed earlier takes the samples still in flight
#: with it (seen: 393 of 3438 wheel answers never arrived after a burst ended by ``shutdown``). Live readers on
#: one host acknowledge within a heartbeat (50 ms, clm_ros/fastdds_profile.xml); the bound is for a reader that
#: died silently (its middleware still counts it until its lease expires).
FLUSH_TIMEOUT = 0.5

#: Settings whose change rebuilds the model (besides the model parameters ``<section>.<name>``).
_MODEL_SETTINGS = ("max_gap", "accept_new_wheels", *ONLINE_POLICY)


class TrackNode(TrackInput):
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
        # parameters generated from the run-settings schema (clm_core.settings, clm_ros.parameters)
        declare_settings(self, ("track", "soil", "model", "params_file", "dt", "n_sleepers", "elements_per_bay",
                                "lead_sleepers", "max_gap", "accept_new_wheels", *ONLINE_POLICY))
        declare_settings(self, ("publish_every", "frame_id", "diagnostics_period", "autostart", "lag_budget",
                                "max_feedback_delay", "monitored_sleepers", "monitored_positions",
                                "markers_period", "realtime_priority"))
        declare_model_parameters(self)  # every scalar model parameter, NaN = from the preset / file
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._guard_change_state()

        self._stop = stop or StopSignals()
        #: SCHED_FIFO priority asked of clm_ros.node_main.run_node, which sets ``scheduling`` to the outcome
        self.realtime_priority = int(self.get_parameter("realtime_priority").value)
        self.scheduling: Scheduling = NOT_APPLIED
        #: None while the process should run; 2: the model could not be configured at start (clm_ros.node_main)
        self.exit_code: int | None = None
        self.model: OnlineTrackModel | None = None
        self.stats = OnlineStats()  # the model's counters, carried from model to model for the node's life
        self.counters = Counters()
        self._logged: set[str] = set()
        self._state = "unconfigured"
        self._configure_error = ""
        self._pub_s: Any = None
        self._pub_w: Any = None
        self._pub_mon: Any = None
        self._pub_markers: Any = None
        self._monitor = MonitoredSleepers(np.zeros(0, dtype=np.int64), 1.0)
        self._sub: GidSubscription | None = None
        self._sources = Sources()  # which publisher of wheel_loads is the stream (clm_ros.sources)
        self._second_seen = 0
        self._accepting = False
        self._reliability = ""
        self._requested_reliability: Any = None
        self._recreate = False
        self._peers = (-1, -1)
        self._matched_publishers = 0  # wheel-load writers the subscription has matched (its own side of discovery)
        self._new_stream = False
        self._peer_lost = False
        self._last_markers = 0.0
        self._markers_period = 0.0
        self._markers_watched = False  # someone subscribes to track_markers (followed by the housekeeping)
        self._last_response: Any = None
        self._every = 1
        self._frame_id = "track"
        self._busy_s = 0.0  # wall time in the data path [s]
        self._cpu_s = 0.0  # CPU time of the executor thread in the data path [s]
        self._rtf = (0, 0.0, 0.0, 0)
        self._rejected_seen = 0
        self._ros_clock = self.get_clock()  # not self._clock: that is rclpy Node's own attribute
        self._sim_time = bool(self.get_parameter("use_sim_time").value)
        self._lag = LagMonitor(self._now_ns)
        # one /diagnostics publisher for the node's whole life (never one per configure)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(0.25, self._housekeeping, clock=Clock(clock_type=ClockType.STEADY_TIME))
        follow(self, TRACK_STATUS, "track-soil model", lambda: (0, self._state, {  # clm_ros.latched: readiness
            "state": self._state, "wheel_load_publishers_matched": self._matched_publishers,
            **matched_readers(sleeper_response=self._pub_s, wheel_rail_response=self._pub_w)}))
        self._diag = DiagnosticsThread(self._publish_diagnostics, float(self.get_parameter("diagnostics_period").value),
                                       lambda exc: self._log("warning", f"/diagnostics not published: {exc}"))
        if self.get_parameter("autostart").value:
            self.trigger_configure()
            if self.model is not None:
                self.trigger_activate()
            else:
                self.exit_code = 2
        self._diag.start()

    # ------------------------------------------------------------------ helpers

    def _guard_change_state(self) -> None:
        """Answer ``change_state`` with success = false for a transition the current state does not have
        (rclpy raises there, and the caller would wait for an answer forever)."""
        srv = getattr(self, "_service_change_state", None)
        if srv is None:
            return
        inner = srv.callback

        def guarded(request: Any, response: Any) -> Any:
            try:
                return inner(request, response)
            except Exception as exc:  # RCLError: no such transition from this state
                self._log("warning", f"transition {request.transition.id} {request.transition.label!r} refused in "
                          f"state {self._state}: {exc}")
                response.success = False
                return response

        srv.callback = guarded

    def _now_ns(self) -> int:
        """The clock the stamps are read on [ns]: sim time with use_sim_time (0 until /clock), else system time
        (what ROS time is without sim time, read without the cost of a Time object)."""
        if self._sim_time:
            return int(self._ros_clock.now().nanoseconds)
        return time.time_ns()

    # ------------------------------------------------------------------ model from parameters

    def _param_overrides(self, changes: dict[str, Any] | None = None) -> dict[str, float]:
        out: dict[str, float] = {}
        for name, (section, _, _) in PARAMETER_DOCS.items():
            key = f"{section}.{name}"
            v = changes[key] if changes and key in changes else self.get_parameter(key).value
            if v is not None and not (isinstance(v, float) and math.isnan(v)):
                out[name] = float(v)
        return out

    def build_params(self, changes: dict[str, Any] | None = None) -> ModelParams:
        """Validated ModelParams from the node parameters (plus pending ``changes``)."""
        g = self.get_parameter
        over = self._param_overrides(changes)
        if g("params_file").value:
            mp = load_params_file(g("params_file").value)
            return mp.override(**over) if over else mp
        model = g("model").value
        if model not in SOIL_MODELS:
            raise ClmError(f"model = {model!r}: one of {', '.join(SOIL_MODELS)}")
        return load_model(g("track").value, g("soil").value, model, over)

    def build_model(self, params: ModelParams, changes: dict[str, Any] | None = None,
                    stats: OnlineStats | None = None) -> OnlineTrackModel:
        """The online model (builds and factorises the simulator: refuses unstable sets); it counts into the
        node's counters unless given others (``stats``)."""

        def get(key: str) -> Any:
            return changes[key] if changes and key in changes else self.get_parameter(key).value

        lead = int(get("lead_sleepers"))
        return OnlineTrackModel(
            params,
            dt=float(get("dt")),
            n_sleepers=int(get("n_sleepers")),
            elements_per_bay=int(get("elements_per_bay")),
            max_gap=float(get("max_gap")),
            accept_new_wheels=bool(get("accept_new_wheels")),
            lead_sleepers=None if lead < 0 else lead,
            stats=stats if stats is not None else self.stats,
            policy=InputPolicy.from_settings({name: get(name) for name in ONLINE_POLICY}),
        )

    def _on_set_parameters(self, params: list[Any]) -> SetParametersResult:
        """Validate a physics change in every state; swap the model in when configured."""
        changes = {p.name: p.value for p in params}
        physics = {k: v for k, v in changes.items()
                   if ("." in k and k.split(".", 1)[1] in PARAMETER_DOCS) or k in _MODEL_SETTINGS}
        if "publish_every" in changes:
            self._every = int(changes["publish_every"])
        if "frame_id" in changes:
            self._frame_id = str(changes["frame_id"])
        if "use_sim_time" in changes:
            self._sim_time = bool(changes["use_sim_time"])
        if not physics:
            return SetParametersResult(successful=True)
        try:
            new_model = self.build_model(self.build_params(physics), physics)  # validates (stability too)
        except (ClmError, ValueError, OSError) as exc:
            self._log("warning", f"parameter update refused: {exc}")
            return SetParametersResult(successful=False, reason=bounded(str(exc)))
        if self.model is not None and self._state in ("inactive", "active"):
            self.model = new_model
            self._log("info", f"parameters updated ({', '.join(sorted(changes))}); the state restarts at the next "
                      "message")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ lifecycle

    def on_configure(self, state: State) -> TransitionCallbackReturn:
        """Build, validate and warm up the model; create the answer publishers."""
        g = self.get_parameter
        try:
            params = self.build_params()
            model = self.build_model(params)
            monitored = monitored_indices(str(g("monitored_sleepers").value), str(g("monitored_positions").value),
                                          params.track.spacing)
            self._warm_up(params)
        except (ClmError, ValueError, OSError) as exc:
            self._configure_error = bounded(str(exc))
            self._log("error", f"configure refused: {exc}")
            return TransitionCallbackReturn.FAILURE
        self.model = model
        self._configure_error = ""
        self._every = int(g("publish_every").value)
        self._frame_id = str(g("frame_id").value)
        opts = qos.overrides
        self._pub_s = self.create_lifecycle_publisher(SleeperResponse, "sleeper_response", qos.answers_qos(),
                                                      qos_overriding_options=opts())
        self._pub_w = self.create_lifecycle_publisher(WheelRailResponse, "wheel_rail_response", qos.answers_qos(),
                                                      qos_overriding_options=opts())
        self._monitor = MonitoredSleepers(monitored, params.track.spacing)
        if self._monitor:
            self._pub_mon = self.create_lifecycle_publisher(SleeperResponse, "monitored_sleepers", qos.view_qos(100),
                                                            qos_overriding_options=opts())
        self._markers_period = float(g("markers_period").value)
        if self._markers_period > 0:
            self._pub_markers = self.create_lifecycle_publisher(MarkerArray, "track_markers", qos.view_qos(1),
                                                                qos_overriding_options=opts())
        self._state = "inactive"
        self._log("info", f"configured: {params.name or 'parameter file'}, dt = {model.dt:g} s, window "
                  f"{model.n_sleepers} sleepers; compiled and factorised")
        return TransitionCallbackReturn.SUCCESS

    def _warm_up(self, params: ModelParams) -> None:
        """Run a throw-away copy of the model over a few frames: every kernel compiled (or loaded from the
        on-disk cache) and every operator factorised before the node is activated."""
        scratch = self.build_model(params, stats=OnlineStats())
        x = 10.0 * params.track.spacing
        frames = [WheelFrame.of(NS + k * 10**6, [0, 1], [x + 0.08 * k, x - 2.5 + 0.08 * k], [8e4, 8e4])
                  for k in range(4)]
        for resp in scratch.process_batch(frames[:1]) + scratch.process_batch(frames[1:]):
            if isinstance(resp, Rejected):
                raise ClmError(f"warm-up frame refused: {resp}")
            self._encode(resp)
            window_markers(resp, rclpy_header(resp.stamp_ns, self._frame_id))

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        """Enable the publishers, then subscribe (the node is ready when its subscription appears)."""
        ret = super().on_activate(state)
        if ret != TransitionCallbackReturn.SUCCESS:
            return ret
        freeze_heap()  # what exists now (model, kernels, modules) is not scanned while active: shorter collections
        self._subscribe()
        self._accepting = True
        self._state = "active"
        topic = self._sub.topic_name if self._sub is not None else "wheel_loads"
        self._log("info", f"active: subscribed to {topic} ({self._reliability})")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        """Stop accepting; discard (and count) what is still queued; unsubscribe."""
        self._unsubscribe()
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
        self._unsubscribe()
        if why:
            self._log("info" if state == "finalized" else "error", why)
        self._flush_answers()
        for name in ("_pub_s", "_pub_w", "_pub_mon", "_pub_markers"):
            pub = getattr(self, name)
            if pub is not None:
                self.destroy_lifecycle_publisher(pub)
                setattr(self, name, None)
        self.model = None
        self._last_response = None
        # the model frozen at activation would never be collected (its reference cycles stayed for good: ~200 kB
        # a configure / activate / cleanup cycle, issue 26.8); back under the collector, the next activation
        # freezes what lives then
        gc.unfreeze()
        gc.collect()
        self._state = state or "unconfigured"
        return TransitionCallbackReturn.SUCCESS

    # ------------------------------------------------------------------ data path

    def _decode(self, raws: list[bytes]) -> list[WheelFrame]:
        """Frames of the messages; an undecodable one is a rejection (``malformed``), counted by the model."""
        model = self.model
        assert model is not None
        frames: list[WheelFrame] = []
        for raw in raws:
            try:
                frames.append(frame_from_cdr(raw))
            except MessageError as exc:
                self._reject(model.reject(Reason.MALFORMED, str(exc)))
        return frames

    def _process(self, frames: list[WheelFrame]) -> list[ResponseFrame | Rejected] | None:
        """Every frame in one go, in order: a response or the refusal of each (None: a defect, logged)."""
        model = self.model
        assert model is not None
        if self._new_stream:
            self._new_stream = False
            if model.last_stamp_ns is not None:
                self.model = model = self.build_model(model.params)
                self._log("info", "wheel_loads: a new stream (every publisher had left): the state restarts")
        try:
            return model.process_batch(frames)
        except Exception as exc:  # a defect of the model: the frames are lost, counted, logged once
            self.counters.internal_errors += len(frames)
            self._log("error", f"internal error on {len(frames)} wheel-load message(s) (counted): {exc!r}",
                      once="internal_error")
            return None

    def _encode(self, r: ResponseFrame) -> tuple[bytes, bytes]:
        """Both answers to a response, serialized, stamped with the input's stamp."""
        fid, t = self._frame_id, r.stamp_ns
        return (
            encode_sleeper_response(t, fid, r.sleeper_index, r.sleeper_x, r.soil_force, r.rail_deflection,
                                    r.sleeper_displacement, r.area_displacement),
            # ids came in as uint32 (decoded): the cast cannot overflow
            encode_wheel_rail_response(t, fid, r.wheel_ids.astype(np.uint32), r.wheel_positions,
                                       r.wheel_deflection, r.wheel_velocity),
        )

    def _answer(self, raws: list[bytes]) -> None:
        """Decode, integrate and answer one chunk of messages, in order."""
        w0, c0 = time.perf_counter(), time.thread_time()
        c = self.counters
        c.received += len(raws)
        c.batches += 1
        c.largest_batch = max(c.largest_batch, len(raws))
        frames = self._decode(raws)
        if not frames:
            return
        self._lag.waiting(len(frames), frames[0].stamp_ns)
        results = self._process(frames)
        if results is None:
            self._lag.waiting(0, 0)
            return
        pub_s, pub_w, mon = _sender(self._pub_s), _sender(self._pub_w), self._monitor
        every = self._every
        stamps: list[int] = []
        for r in results:
            if isinstance(r, Rejected):
                self._reject(r)
                continue
            self._last_response = r
            if every > 1 and self.stats.accepted % every:
                continue
            s_bytes, w_bytes = self._encode(r)
            try:
                pub_s(s_bytes)
                pub_w(w_bytes)
                if mon:
                    self._pub_mon.publish(mon.encode(r.stamp_ns, self._frame_id, r))
            except Exception as exc:  # a context going down, a middleware error: counted, never fatal
                c.publish_failed += 1
                self._log("warning", f"an answer could not be published (counted as publish_failed): {exc}",
                          once="publish_failed")
                continue
            stamps.append(r.stamp_ns)
        c.published += len(stamps)
        self._lag.answered(stamps)
        self._lag.waiting(0, 0)
        self._busy_s += time.perf_counter() - w0
        self._cpu_s += time.thread_time() - c0
        if self._markers_watched:
            self._publish_markers()

    def _publish_markers(self) -> None:
        if not self._markers_watched or self._last_response is None:
            return
        now = time.monotonic()
        if now - self._last_markers < self._markers_period:
            return
        self._last_markers = now
        r = self._last_response
        header = rclpy_header(r.stamp_ns, self._frame_id)
        try:
            self._pub_markers.publish(window_markers(r, header))
        except Exception as exc:  # a view must never stop the answers
            self._log("warning", f"track_markers not published: {exc}", once="markers")

    # ------------------------------------------------------------------ diagnostics (own thread)

    def _publish_diagnostics(self) -> None:
        g = self.get_parameter
        budget, late = float(g("lag_budget").value), float(g("max_feedback_delay").value)
        lag = self._lag.summary(late)
        now = (self.stats.simulated_ns, self._busy_s, self._cpu_s, self.counters.received)
        d_sim, d_busy, d_cpu, d_msgs = (a - b for a, b in zip(now, self._rtf))
        self._rtf = now
        state = self._state
        rejected = self.stats.rejected_total + self.counters.internal_errors
        new_rejections, self._rejected_seen = rejected - self._rejected_seen, rejected
        second = sum(self._sources.refused.values())
        new_second, self._second_seen = second - self._second_seen, second
        if state == "active":
            level, message = lag_level(lag, budget, late)
            if new_second and level == OK:
                level, message = WARN, (f"second wheel-load source: {new_second} message(s) of "
                                        f"{len(self._sources.refused)} other publisher(s) refused in the last "
                                        f"period; answering only {self._sources.values()['wheel_load_source']}")
            elif level == OK and new_rejections:
                level, message = WARN, f"{new_rejections} wheel-load message(s) rejected in the last period"
        elif state == "finalized":
            level, message = STALE, "finalized: not answering"
        elif state == "unconfigured" and self._configure_error:
            level, message = ERROR, f"unconfigured: configure refused: {self._configure_error}"
        else:
            level, message = OK, f"{state}: not subscribed to wheel_loads"
        model = self.model
        values = {
            "state": state,
            **self.counters.values(self.stats),
            **lag_values(lag),
            "lag_budget_s": f"{budget:g}",
            "max_feedback_delay_s": f"{late:g}",
            "real_time_factor": f"{d_sim * 1e-9 / d_busy:.3f}" if d_busy > 0 else "nan",
            "data_path_cpu_us_per_message": f"{1e6 * d_cpu / d_msgs:.1f}" if d_msgs else "nan",
            "wheel_load_publishers": max(self._peers[0], 0),
            "wheel_load_publishers_matched": self._matched_publishers,
            **self._sources.values(),
            "answer_readers": max(self._peers[1], 0),
            "wheel_loads_reliability": self._reliability or "none",
            "scheduling": self.scheduling.text,
            "sim_time_s": f"{model.time_ns / NS:.6f}" if model is not None and model.time_ns is not None else "nan",
        }
        name = f"{self.get_fully_qualified_name()}: track-soil model"  # the namespace tells a fleet's pairs apart
        self._pub_diag.publish(diagnostic_array(name, level, message, values,
                                                self.get_clock().now().to_msg()))

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
            self._log("warning", f"answers not acknowledged by every reader within {timeout:g} s (a reader gone "
                      "without leaving the graph?); what it had not received is lost to it", once="unacked")
        return acked

    def drain(self, spin_until: Any) -> None:
        """After a stop signal (:func:`clm_ros.node_main.run_node`): stop taking wheel loads, then let the
        readers acknowledge the answers already published (at most :data:`FLUSH_TIMEOUT` s)."""
        self._accepting = False
        self._flush_answers()

    def destroy_node(self) -> None:
        """Stop the diagnostics thread, then destroy the node."""
        self._diag.stop()
        self._accepting = False
        super().destroy_node()  # type: ignore[no-untyped-call]  # rclpy leaves Node.destroy_node unannotated

    def counts(self) -> dict[str, Any]:
        """Every counter of the node's life, as in ``/diagnostics`` (for tests and the launcher)."""
        return self.counters.values(self.stats)


def _sender(pub: Any) -> Any:
    """The call that publishes serialized bytes on the lifecycle publisher ``pub``: while it is enabled, its
    rclpy publisher's ``publish_raw`` (what ``LifecyclePublisher.publish`` ends in, without its per-call
    wrapper, handle guard and type checks: ~1.5 us a message each); else ``pub.publish`` (which drops).

    Taken once per chunk in the executor thread, the thread that also destroys the publishers."""
    inner = getattr(pub, "_Publisher__publisher", None)
    if inner is None or not pub.is_activated:
        return pub.publish
    return inner.publish_raw


def main(args: list[str] | None = None) -> int:
    """Console entry point ``track_node``: exit 0 on SIGINT/SIGTERM (within 2 s, also under load), 2 when the
    model cannot be configured at start (:func:`clm_ros.node_main.run_node`)."""
    return run_node(TrackNode, args, NODE_NAME)


if __name__ == "__main__":
    sys.exit(main())
