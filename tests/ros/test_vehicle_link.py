"""The vehicle's wait for its own track node (:class:`clm_ros.vehicle_link.TrackLink`) over real DDS.

The track node stands in as plain rclpy endpoints in a context of its own
(what the vehicle sees of it on the graph: its ``wheel_loads`` reader, its
``wheel_rail_response`` writer and its latched ``track_status``), so that
the order in which they appear is the test's, not the discovery's.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

rclpy = pytest.importorskip("rclpy")

from clm_msgs.msg import WheelLoads, WheelRailResponse  # noqa: E402
from clm_ros.latched import TRACK_STATUS, LatchedStatus  # noqa: E402
from clm_ros.vehicle_link import DATA_QOS, TrackLink  # noqa: E402
from rclpy.context import Context  # noqa: E402

from tests.ros.conftest import DISCOVERY_TIMEOUT  # noqa: E402

NS = "/train_7"


@pytest.fixture
def contexts(ros_domain_id: int) -> Iterator[Callable[[], Context]]:
    """Contexts in the test's domain, on loopback, shut down at teardown."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    made: list[Context] = []

    def make() -> Context:
        ctx = Context()
        rclpy.init(context=ctx, domain_id=ros_domain_id)
        made.append(ctx)
        return ctx

    try:
        yield make
    finally:
        for ctx in made:
            rclpy.try_shutdown(context=ctx)


def _until(cond: Callable[[], Any], what: str, timeout: float = DISCOVERY_TIMEOUT) -> None:
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            pytest.fail(f"{what}: not within {timeout} s")
        time.sleep(0.01)


def _vehicle(ctx: Context) -> tuple[Any, TrackLink]:
    node = rclpy.create_node("clm_vehicle_node", namespace=NS, context=ctx)
    pub = node.create_publisher(WheelLoads, "wheel_loads", DATA_QOS)
    return node, TrackLink(node, pub, "clm_track_node", 1, start_signal=False)


def test_the_track_nodes_word_before_its_endpoints_are_seen_is_kept(contexts) -> None:  # type: ignore[no-untyped-def]
    """Its word (subscription matched), latched and sent once, came while its answer writer was not yet on the
    vehicle's graph: the wait must not throw it away (stress run 6 of 7: a vehicle waited its 30 s and gave up)."""
    vehicle, link = _vehicle(contexts())
    track = rclpy.create_node("clm_track_node", namespace=NS, context=contexts())
    track.create_subscription(WheelLoads, "wheel_loads", lambda _m: None, DATA_QOS)
    status = LatchedStatus(track, TRACK_STATUS, "track-soil model")
    assert status.update(0, "active", {"wheel_load_publishers_matched": 1})
    _until(lambda: vehicle.count_publishers(f"{NS}/{TRACK_STATUS}") >= 1 and link.pub.get_subscription_count() >= 1,
           "the track node's reader and status on the vehicle's graph")
    time.sleep(0.5)  # its latched word delivered to the waiting reader (reliable, on loopback)
    for _ in range(20):  # the vehicle looks while the answer writer is missing: not ready
        assert not link.track_ready()
        time.sleep(0.01)
    track.create_publisher(WheelRailResponse, "wheel_rail_response", DATA_QOS)
    _until(link.track_ready, "ready once the answer writer is seen")
    link.destroy()


def test_a_track_node_that_went_is_not_taken_at_its_old_word(contexts) -> None:  # type: ignore[no-untyped-def]
    """A track node that said it matched and went: the next one is awaited until it says so itself, and is
    taken when it does."""
    vehicle, link = _vehicle(contexts())
    old_ctx = contexts()

    def track_node(ctx: Context, matched: int) -> tuple[Any, LatchedStatus]:
        node = rclpy.create_node("clm_track_node", namespace=NS, context=ctx)
        node.create_subscription(WheelLoads, "wheel_loads", lambda _m: None, DATA_QOS)
        node.create_publisher(WheelRailResponse, "wheel_rail_response", DATA_QOS)
        status = LatchedStatus(node, TRACK_STATUS, "track-soil model")
        status.update(0, "active", {"wheel_load_publishers_matched": matched})
        return node, status

    old, _ = track_node(old_ctx, 1)
    _until(link.track_ready, "the first track node")
    old.destroy_node()
    rclpy.try_shutdown(context=old_ctx)
    _until(lambda: not link.track_ready(), "the first track node gone")
    _, status = track_node(contexts(), 0)  # there, but not subscribed yet by its own word
    _until(lambda: vehicle.count_publishers(f"{NS}/{TRACK_STATUS}") >= 1
           and vehicle.count_publishers(f"{NS}/wheel_rail_response") >= 1, "the second track node on the graph")
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        assert not link.track_ready(), "taken at the former track node's word"
        time.sleep(0.01)
    assert status.update(0, "active", {"wheel_load_publishers_matched": 1})
    _until(link.track_ready, "ready at the second track node's own word")
    link.destroy()
