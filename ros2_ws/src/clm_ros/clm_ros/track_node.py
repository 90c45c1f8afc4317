"""The track–soil node: wheel loads in, sleeper soil forces and rail deflections out.

A lifecycle node (``rclpy.lifecycle``) wrapping :class:`clm_core.online.OnlineTrackModel`:

- configure: read the parameters, build and validate the model (an invalid or
  unstable set is refused with its reason and the node stays unconfigured);
- activate: subscribe to ``wheel_loads`` and publish, for every accepted
  message, a ``clm_msgs/SleeperResponse`` on ``sleeper_response`` and a
  ``clm_msgs/WheelRailResponse`` on ``wheel_rail_response``, stamped with the
  input's stamp (simulation time), plus ``/diagnostics`` every
  ``diagnostics_period`` s.

With ``autostart`` (default true) it configures and activates itself; users
with a lifecycle manager set ``autostart:=false``. The node owns no physics:
it converts messages at its edge and calls the core (``clm replay`` runs the
same core offline, so the outputs are identical by construction).

Run: ``python -m clm_ros.track_node --ros-args -p soil:=haren -p dt:=1e-4`` (or
``ros2 run clm_ros track_node`` in a full ROS install).
"""

from __future__ import annotations

import math
import sys
import time
from collections import deque
from typing import Any

import numpy as np
import rclpy
from clm_msgs.msg import SleeperResponse, WheelLoads, WheelRailResponse
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import State, TransitionCallbackReturn
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from clm_core.errors import ClmError
from clm_core.io.errors import MessageError
from clm_core.io.messages import frame_from_msg
from clm_core.io.timebase import NS
from clm_core.online import InputPolicy, OnlineTrackModel, Reason, Rejected
from clm_core.params import (
    PARAMETER_DOCS,
    SOIL_MODELS,
    ModelParams,
    load_model,
    load_params_file,
)
from clm_core.settings import ONLINE_POLICY
from clm_ros.conversions import rclpy_responses
from clm_ros.parameters import declare_model_parameters, declare_settings

NODE_NAME = "clm_track_node"


def qos_profile(depth: int, reliability: str) -> QoSProfile:
    """QoS for the data topics: keep-all (``depth`` 0, the default: nothing is dropped, a slow
    subscriber slows the publisher down) or keep-last ``depth``; reliable or best effort."""
    rel = ReliabilityPolicy.RELIABLE if reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT
    if depth <= 0:
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=rel)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=rel)


class TrackNode(LifecycleNode):
    """Lifecycle node running the streaming track–soil model on wheel-load messages."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        # parameters generated from the run-settings schema (clm_core.settings, clm_ros.parameters)
        declare_settings(self, ("track", "soil", "model", "params_file", "dt", "n_sleepers", "elements_per_bay",
                                "lead_sleepers", "max_gap", "accept_new_wheels", *ONLINE_POLICY))
        declare_settings(self, ("publish_every", "qos_depth", "qos_reliability", "frame_id", "diagnostics_period",
                                "autostart"))
        # every scalar model parameter, NaN = take it from the preset / file
        declare_model_parameters(self)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.model: OnlineTrackModel | None = None
        self._pub_s: Any = None
        self._pub_w: Any = None
        self._pub_diag: Any = None
        self._sub: Any = None
        self._timer: Any = None
        self._logged: set[str] = set()
        self._lags: deque[float] = deque(maxlen=10000)
        self._proc_wall = 0.0
        self._proc_sim = 0.0
        self._published = 0
        self._received = 0
        self._accepted_since = 0
        if self.get_parameter("autostart").value:
            self.trigger_configure()
            if self.model is not None:
                self.trigger_activate()

    # ------------------------------------------------------------------ model from parameters

    def _param_overrides(self, changes: dict[str, float] | None = None) -> dict[str, float]:
        out: dict[str, float] = {}
        for name, (section, _, _) in PARAMETER_DOCS.items():
            key = f"{section}.{name}"
            v = changes[key] if changes and key in changes else self.get_parameter(key).value
            if v is not None and not (isinstance(v, float) and math.isnan(v)):
                out[name] = float(v)
        return out

    def build_params(self, changes: dict[str, float] | None = None) -> ModelParams:
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

    def build_model(self, params: ModelParams, changes: dict[str, Any] | None = None) -> OnlineTrackModel:
        """The online model (builds and factorises the simulator: refuses unstable sets)."""

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
            stats=self.model.stats if self.model is not None else None,  # counters monotonic over the node's life
            policy=InputPolicy.from_settings({name: get(name) for name in ONLINE_POLICY}),
        )

    def _on_set_parameters(self, params: list[Any]) -> SetParametersResult:
        changes = {p.name: p.value for p in params}
        physics = {k: v for k, v in changes.items() if k.split(".", 1)[-1] in PARAMETER_DOCS and "." in k}
        rebuild = physics or {"max_gap", "accept_new_wheels", *ONLINE_POLICY} & changes.keys()
        if self.model is None or not rebuild:
            if "qos_reliability" in changes and changes["qos_reliability"] not in ("reliable", "best_effort"):
                return SetParametersResult(successful=False, reason="qos_reliability: one of reliable, best_effort")
            return SetParametersResult(successful=True)
        try:
            new_params = self.build_params({k: float(v) for k, v in physics.items()})
            new_model = self.build_model(new_params, changes)
        except (ClmError, ValueError) as exc:
            self.get_logger().warning(f"parameter update refused: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        self.model = new_model
        self.get_logger().info(f"parameters updated ({', '.join(sorted(changes))}); state restarts at the next message")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ lifecycle

    def on_configure(self, state: State) -> TransitionCallbackReturn:
        try:
            params = self.build_params()
            self.model = self.build_model(params)
        except (ClmError, ValueError, OSError) as exc:
            self.get_logger().error(f"configure refused: {exc}")
            self.model = None
            return TransitionCallbackReturn.FAILURE
        qos = qos_profile(int(self.get_parameter("qos_depth").value), str(self.get_parameter("qos_reliability").value))
        self._pub_s = self.create_lifecycle_publisher(SleeperResponse, "sleeper_response", qos)
        self._pub_w = self.create_lifecycle_publisher(WheelRailResponse, "wheel_rail_response", qos)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._qos = qos
        self.get_logger().info(
            f"configured: {params.name or 'parameter file'}, dt = {self.model.dt:g} s, "
            f"window {self.model.n_sleepers} sleepers"
        )
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        self._sub = self.create_subscription(WheelLoads, "wheel_loads", self._on_wheel_loads, self._qos)
        self._timer = self.create_timer(
            float(self.get_parameter("diagnostics_period").value), self._publish_diagnostics
        )
        return super().on_activate(state)

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        if self._sub is not None:
            self.destroy_subscription(self._sub)
            self._sub = None
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self.model = None
        for p in (self._pub_s, self._pub_w):
            if p is not None:
                self.destroy_lifecycle_publisher(p)
        self._pub_s = self._pub_w = None
        return TransitionCallbackReturn.SUCCESS

    # ------------------------------------------------------------------ data path

    def _on_wheel_loads(self, msg: WheelLoads) -> None:
        model = self.model
        if model is None:
            return
        self._received += 1
        try:
            frame = frame_from_msg(msg)
        except MessageError as exc:
            self._log_rejection(model.reject(Reason.MALFORMED, str(exc)))
            return
        t_ns = frame.stamp_ns
        sim_before = model.stats.simulated_ns
        w0 = time.perf_counter()
        try:
            resp = model.process(frame)
        except Rejected as exc:
            self._log_rejection(exc)
            return
        self._proc_wall += time.perf_counter() - w0
        self._proc_sim += (model.stats.simulated_ns - sim_before) / NS
        if resp.resynced and model.stats.accepted > 1 and "resync" not in self._logged:
            self._logged.add("resync")
            self.get_logger().warning(f"stamp jump: state re-synchronised at t = {frame.stamp_ns / NS:.6f} s")
        every = int(self.get_parameter("publish_every").value)
        self._accepted_since += 1
        if self._accepted_since % every:
            return
        s, w = rclpy_responses(resp, t_ns, str(self.get_parameter("frame_id").value))
        self._pub_s.publish(s)
        self._pub_w.publish(w)
        self._published += 1
        now_ns = self.get_clock().now().nanoseconds
        self._lags.append((now_ns - t_ns) / 1e9)

    def _log_rejection(self, exc: Rejected) -> None:
        cause = exc.reason.value
        if cause not in self._logged:
            self._logged.add(cause)
            self.get_logger().warning(
                f"wheel loads rejected ({cause}; logged once per cause, counted in /diagnostics): {exc}"
            )

    def _publish_diagnostics(self) -> None:
        model = self.model
        if model is None or self._pub_diag is None:
            return
        st = model.stats
        lags = np.asarray(self._lags) if self._lags else np.zeros(1)
        rtf = self._proc_sim / self._proc_wall if self._proc_wall > 0 else 0.0
        values = {
            "received": st.accepted + st.rejected_total,
            "accepted": st.accepted,
            "published": self._published,
            "rejected": st.rejected_total,
            **{f"rejected.{k}": v for k, v in sorted(st.rejected.items())},
            "resyncs": st.resyncs,
            "real_time_factor": f"{rtf:.3f}",
            "lag_median_s": f"{float(np.median(lags)):.6f}",
            "lag_p99_s": f"{float(np.percentile(lags, 99)):.6f}",
            "sim_time_s": f"{(model.time_ns or 0) / NS:.6f}",
        }
        level = DiagnosticStatus.OK
        message = "running"
        if st.rejected_total:
            level, message = DiagnosticStatus.WARN, f"{st.rejected_total} message(s) rejected"
        if 0 < rtf < 1.0:
            level, message = DiagnosticStatus.WARN, f"slower than real time (RTF {rtf:.2f})"
        status = DiagnosticStatus(
            level=level,
            name=f"{self.get_name()}: track-soil model",
            message=message,
            hardware_id="clm_core",
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
        )
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._pub_diag.publish(arr)

    def stats(self) -> dict[str, Any]:
        """Counters (for tests and the launcher)."""
        st = self.model.stats if self.model else None
        return {
            "received": self._received,
            "published": self._published,
            "accepted": st.accepted if st else 0,
            "rejected": dict(st.rejected) if st else {},
        }


def main(args: list[str] | None = None) -> int:
    """Console entry point ``track_node``."""
    rclpy.init(args=args)
    node = None
    try:
        node = TrackNode()
        if node.model is None and node.get_parameter("autostart").value:
            return 2
        # rclpy's EventsExecutor costs ~30 % less CPU per message than the
        # SingleThreadedExecutor; its spin() delivered no callback to this node on the
        # Jazzy wheels, a spin_once loop does (measured: benchmarks/node_lag.py).
        executor = EventsExecutor()
        executor.add_node(node)
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
