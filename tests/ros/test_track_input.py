"""The track node's wheel-load input says its own subscription's side of discovery, never an old one's.

``wheel_load_publishers_matched`` (in ``/diagnostics`` and the latched ``track_status``) is the word a vehicle
waits for before it publishes (clm_ros.vehicle_link). After a deactivation it must say 0 at once, and a new
subscription must say its own count: until 2026-12-04 the count was refreshed only by the 0.25-s housekeeping,
so a node deactivated and activated again said 1 before its new subscription had matched anyone, and a writer
that trusted it lost 36 of 50 messages (a stress run of the ROS tests at 8d15678).

Real rclpy, real DDS on loopback: the input in one participant, a wheel-load writer in another.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

import rclpy
from clm_msgs.msg import WheelLoads
from clm_ros import qos
from clm_ros.diagnostics import Counters
from clm_ros.node_log import NodeLog
from clm_ros.node_main import StopSignals
from clm_ros.track_input import WheelLoadInput
from rclpy.context import Context
from rclpy.node import Node

from clm_core.online import OnlineStats


@pytest.fixture
def two_participants(ros_domain_id: int) -> Iterator[tuple[Node, Node]]:
    made: list[tuple[Context, Node]] = []
    for name in ("clm_track_node", "wheel_load_writer"):
        ctx = Context()
        rclpy.init(context=ctx, domain_id=ros_domain_id)
        made.append((ctx, rclpy.create_node(name, context=ctx)))
    try:
        yield made[0][1], made[1][1]
    finally:
        for ctx, node in made:
            node.destroy_node()
            rclpy.try_shutdown(context=ctx)


def _until(cond: Callable[[], bool], step: Callable[[], None], timeout: float, what: str) -> None:
    t_end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < t_end, f"{what} not within {timeout} s"
        step()
        time.sleep(0.02)


def test_matched_count_is_the_live_subscription_s_own(two_participants: tuple[Node, Node]) -> None:
    node, writer = two_participants
    inp = WheelLoadInput(node, Counters(), OnlineStats(), NodeLog(node), StopSignals(),
                         lambda raws: None, lambda reason, text: None)  # nothing is published: no answer owed
    pub = writer.create_publisher(WheelLoads, "wheel_loads", qos.wheel_loads_qos())
    assert inp.values()["wheel_load_publishers_matched"] == 0  # nothing subscribed yet
    inp.subscribe()
    _until(lambda: inp.matched_publishers == 1, lambda: inp.housekeeping(0), 20.0, "the writer matched")
    assert inp.values()["wheel_load_publishers_matched"] == 1
    # deactivation: no subscription, nothing matched, said at once (no housekeeping in between)
    inp.unsubscribe()
    assert inp.sub is None and inp.matched_publishers == 0
    assert inp.values()["wheel_load_publishers_matched"] == 0
    # activation: the new subscription's own count from its first moment, then its match once discovered
    inp.subscribe()
    assert inp.sub is not None
    assert inp.matched_publishers == inp.sub.get_publisher_count() <= 1
    _until(lambda: inp.matched_publishers == 1, lambda: inp.housekeeping(0), 20.0, "the writer matched again")
    _until(lambda: pub.get_subscription_count() == 1, lambda: None, 20.0, "the writer seeing one reader")
    inp.unsubscribe()
    assert inp.matched_publishers == 0
