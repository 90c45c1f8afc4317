"""Vehicle simulator node: the clm_core vehicle publishing wheel loads in real time.

Publishes ``clm_msgs/WheelLoads`` on ``wheel_loads`` at ``rate`` Hz (1 kHz by
default), each stamped with its simulation time (ROS time of the start plus
k / rate, or sim time from 0 with ``publish_clock``, which also publishes
``/clock``). With ``closed_loop`` it subscribes to ``wheel_rail_response``
and uses the track's rail deflection under the wheels
(:class:`clm_core.vehicle.streaming.StreamingVehicle`); otherwise it runs on
the quasi-static track compliance.

It is also the reference client for external simulators: wait for the
track node (``wait_for_subscribers``), publish one ``WheelLoads`` per
sample with increasing stamps, read ``WheelRailResponse``.

When ``duration`` has been simulated it waits (``ack_timeout``) for the
track's answers to every message, logs the counts and exits 0.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Any

import numpy as np
import rclpy
from clm_msgs.msg import WheelLoads, WheelRailResponse
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from clm_core.errors import ClmError
from clm_core.io.timebase import NS, stamp_ns
from clm_core.params import load_model, load_params_file
from clm_core.vehicle.run import VehicleRunSpec, build_vehicle_run
from clm_core.vehicle.streaming import StreamingVehicle
from clm_ros.conversions import rclpy_wheel_loads
from clm_ros.parameters import declare_settings

NODE_NAME = "clm_vehicle_node"


class VehicleNode(Node):
    """Publishes the wheel loads of a clm_core vehicle at a fixed rate."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        # parameters generated from the run-settings schema (clm_core.settings, clm_ros.parameters); the run is
        # built once, at start: every parameter is read-only
        declare_settings(self, ("vehicle", "cars", "speed", "duration", "rate", "dt", "start", "irregularity", "seed",
                                "wavelength_band", "track", "soil", "model", "params_file", "closed_loop"),
                         read_only=True)
        declare_settings(self, ("publish_clock", "wait_for_subscribers", "discovery_timeout", "ack_timeout",
                                "frame_id", "max_feedback_delay"), read_only=True)
        g = lambda n: self.get_parameter(n).value  # noqa: E731
        params = (
            load_params_file(g("params_file")) if g("params_file") else load_model(g("track"), g("soil"), g("model"))
        )
        spec = VehicleRunSpec(
            vehicle=g("vehicle"), cars=int(g("cars")), speed=float(g("speed")), duration=float(g("duration")),
            dt=float(g("dt")), start=float(g("start")), irregularity=g("irregularity"), seed=int(g("seed")),
            wavelength_band=g("wavelength_band"),
        )
        run = build_vehicle_run(spec, params)
        sim, duration, self.settings = run.simulation, run.duration, run.settings
        rate = float(g("rate"))
        sub = 1.0 / (rate * sim.dt)
        if abs(sub - round(sub)) > 1e-9 or round(sub) < 1:
            raise ClmError(f"rate = {rate:g} Hz and dt = {sim.dt:g} s: 1/(rate dt) = {sub:g} must be a whole number")
        self.substeps = int(round(sub))
        self.n_messages = int(round(duration * rate))
        self.period_ns = int(round(NS / rate))
        self.vehicle = StreamingVehicle(sim)
        self.ids = np.arange(self.vehicle.train.n_wheels)
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(WheelLoads, "wheel_loads", qos)
        self.clock_pub = self.create_publisher(Clock, "/clock", 10) if g("publish_clock") else None
        self.sent: dict[int, int] = {}  # stamp -> vehicle step
        self.answered = 0
        self.closed_loop = bool(g("closed_loop"))
        self.lock = threading.Lock()
        self.spinner: threading.Thread | None = None
        self.spinning = False
        self.max_delay_steps = int(float(g("max_feedback_delay")) / sim.dt)
        self.stale = 0
        self.used = 0
        self.create_subscription(WheelRailResponse, "wheel_rail_response", self._on_response, qos)

    def _on_response(self, msg: WheelRailResponse) -> None:
        self.answered += 1
        with self.lock:
            step = self.sent.pop(stamp_ns(msg.header), None)
        if step is None or not self.closed_loop:
            return
        ids = np.asarray(msg.wheel_id, dtype=np.int64)
        w = np.full(self.ids.size, np.nan)
        if ids.size and ids.max() < w.size:
            w[ids] = np.asarray(msg.rail_deflection)
        if self.vehicle.k - step > self.max_delay_steps:
            self.stale += 1
            return
        if np.all(np.isfinite(w)):
            self.used += 1
            try:
                with self.lock:
                    self.vehicle.set_track_response(step, w)
            except ClmError as exc:
                self.get_logger().warning(f"track response ignored: {exc}", once=True)

    def run(self, executor: Any) -> int:
        """Wait for subscribers, publish in real time, wait for the answers; return the exit code."""
        g = lambda n: self.get_parameter(n).value  # noqa: E731
        t0 = time.monotonic()
        while self.pub.get_subscription_count() < int(g("wait_for_subscribers")):
            if time.monotonic() - t0 > float(g("discovery_timeout")):
                self.get_logger().error(
                    f"no {g('wait_for_subscribers')} subscriber(s) on wheel_loads after {g('discovery_timeout')} s"
                )
                return 3
            executor.spin_once(timeout_sec=0.02)
        # answers are taken by the executor in a thread of their own; this loop only
        # computes, sleeps and publishes (an rclpy spin_once costs too much to poll at 1 kHz)
        self.spinning = True

        def spin() -> None:
            while self.spinning and rclpy.ok():
                executor.spin_once(timeout_sec=0.05)

        self.spinner = threading.Thread(target=spin, daemon=True)
        self.spinner.start()
        base_ns = 0 if self.clock_pub else self.get_clock().now().nanoseconds
        start = time.monotonic()
        frame = str(g("frame_id"))
        late = 0
        busy = 0.0
        for k in range(self.n_messages + 1):
            c0 = time.perf_counter()
            with self.lock:
                P = self.vehicle.P.copy() if k == 0 else self.vehicle.advance(self.substeps)
            busy += time.perf_counter() - c0
            t_ns = base_ns + k * self.period_ns
            due = start + k * self.period_ns / NS
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            elif -wait > 2 * self.period_ns / NS:
                late += 1
            if self.clock_pub is not None:
                self.clock_pub.publish(Clock(clock=rclpy.time.Time(nanoseconds=t_ns).to_msg()))
            x = self.vehicle.positions()
            with self.lock:
                self.sent[t_ns] = self.vehicle.k
            self.pub.publish(
                rclpy_wheel_loads(t_ns, self.ids, x, P, np.full(self.ids.size, self.vehicle.sim.speed), frame)
            )
        t1 = time.monotonic()
        while self.answered < self.n_messages + 1 and time.monotonic() - t1 < float(g("ack_timeout")):
            time.sleep(0.01)
        self.get_logger().info(
            f"published {self.n_messages + 1} wheel-load messages at {g('rate')} Hz ({late} late by > 2 periods), "
            f"{self.answered} answered ({self.used} used as feedback, {self.stale} too late); "
            f"contact lost in {self.vehicle.contact_lost_steps} wheel-steps; vehicle model "
            f"{1e6 * busy / (self.n_messages + 1):.0f} us per message"
        )
        return 0


def main(args: list[str] | None = None) -> int:
    """Console entry point ``vehicle_node``."""
    rclpy.init(args=args)
    code = 0
    node = None
    try:
        node = VehicleNode()
        ex = EventsExecutor()
        ex.add_node(node)
        code = node.run(ex)
        node.spinning = False
        if node.spinner is not None:
            node.spinner.join(timeout=2.0)
    except ClmError as exc:
        print(f"clm_vehicle_node: error: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
