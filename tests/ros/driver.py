"""An in-process ROS client that drives a track node running in another process.

Publishes wheel loads with flow control (at most ``max_in_flight`` messages
ahead of the responses), collects ``SleeperResponse``, ``WheelRailResponse``
and ``/diagnostics``, waits on discovery (never on fixed sleeps).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from typing import Any

import rclpy
from clm_msgs.msg import SleeperResponse, WheelLoads, WheelRailResponse
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


class Driver:
    """Talk to a track node over DDS in ``domain_id`` (loopback only)."""

    def __init__(self, domain_id: int, ns: str = "") -> None:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = rclpy.create_node("clm_test_driver", context=self.ctx)
        self.exec = SingleThreadedExecutor(context=self.ctx)
        self.exec.add_node(self.node)
        self.pub = self.node.create_publisher(WheelLoads, f"{ns}/wheel_loads", QOS)
        self.sleepers: list[Any] = []
        self.wheels: list[Any] = []
        self.diagnostics: list[Any] = []
        self.node.create_subscription(SleeperResponse, f"{ns}/sleeper_response", self.sleepers.append, QOS)
        self.node.create_subscription(WheelRailResponse, f"{ns}/wheel_rail_response", self.wheels.append, QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 10)

    def spin(self, seconds: float = 0.01) -> None:
        self.exec.spin_once(timeout_sec=seconds)

    def wait_for(self, cond: Any, timeout: float, what: str) -> None:
        t0 = time.monotonic()
        while not cond():
            if time.monotonic() - t0 > timeout:
                raise TimeoutError(f"{what} not within {timeout} s")
            self.spin(0.02)

    def wait_discovery(self, timeout: float = 20.0) -> None:
        self.wait_for(
            lambda: (
                self.pub.get_subscription_count() >= 1
                and self.node.count_publishers("sleeper_response")
                + self.node.count_publishers(self.pub.topic_name.replace("wheel_loads", "sleeper_response"))
                >= 1
            ),
            timeout,
            "discovery of the track node",
        )

    def send(self, msgs: Iterable[Any], expected_answers: int, max_in_flight: int = 50, timeout: float = 60.0) -> None:
        """Publish ``msgs`` keeping at most ``max_in_flight`` unanswered; wait for ``expected_answers`` answers."""
        sent = 0
        base = len(self.sleepers)
        base_w = len(self.wheels)
        t0 = time.monotonic()
        for m in msgs:
            while sent - (len(self.sleepers) - base) >= max_in_flight and time.monotonic() - t0 < timeout:
                self.spin(0.005)
            self.pub.publish(m)
            sent += 1
            self.spin(0)
        self.wait_for(
            lambda: len(self.sleepers) - base >= expected_answers and len(self.wheels) - base_w >= expected_answers,
            timeout,
            f"{expected_answers} responses",
        )

    def latest_diagnostics(self, timeout: float = 10.0) -> dict[str, str]:
        n = len(self.diagnostics)
        self.wait_for(lambda: len(self.diagnostics) > n, timeout, "a /diagnostics message")
        st = self.diagnostics[-1].status[0]
        level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
        return {kv.key: kv.value for kv in st.values} | {"_level": str(level), "_message": st.message}

    def close(self) -> None:
        self.exec.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
