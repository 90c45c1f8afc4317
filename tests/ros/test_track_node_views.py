"""The track node in the ROS ecosystem: QoS per REP 2003, fixed per-sleeper series, RViz markers (real DDS).

- a sensor-data (best-effort) wheel-load publisher gets answers (the node's
  subscription, "best available", follows it), a reliable one loses nothing
  (the burst test of test_track_node_realtime.py);
- QoS goes through rclpy's standard overrides: ``reliability:=reliable``
  forced on the subscription refuses a best-effort publisher, as asked;
- ``monitored_sleepers`` / ``monitored_positions``: entry i of
  ``monitored_sleepers`` is always the same sleeper (NaN while outside the
  window), equal to that sleeper's entry of the window answer;
- ``track_markers``: a MarkerArray of the window (sleepers coloured by soil
  force, the deflected rail) while someone watches.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clm_msgs.msg import SleeperResponse
from driver import SENSOR_QOS, track_node
from streams import encoded, frames, offline
from visualization_msgs.msg import Marker, MarkerArray

from clm_core.io.messages import decode_sleeper_response
from clm_core.io.timebase import NS


def test_best_effort_publisher_gets_answers(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    with track_node(ros_python, ros_domain_id, wheel_qos=None) as run:
        drv = run.drv
        # a sensor-data publisher appears after the node subscribed (reliably then: nobody else was there)
        drv.pub = drv.wheel_load_publisher(SENSOR_QOS)
        drv.wait_discovery()
        stream = frames(300, 5 * NS)
        drv.send(encoded(stream), expected_answers=300, max_in_flight=5, timeout=60)
        d = drv.latest_diagnostics()
        assert d["wheel_loads_reliability"] == "best_effort" and d["accepted"] == "300", d
        ref = offline(stream)
        got = {s.stamp_ns: s for s in drv.sleepers}
        for t, r in zip([t for t, _, _ in stream], ref):
            np.testing.assert_array_equal(got[t].soil_force, r.soil_force)
    # re-created when the best-effort publisher appeared; or best effort from the start, when a best-effort
    # publisher of an earlier test in this domain was still in the graph as the node subscribed
    assert "reliability reliable -> best_effort" in run.err or "/wheel_loads (best_effort)" in run.err, run.err


def test_qos_override_forces_reliable(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    with track_node(ros_python, ros_domain_id, "qos_overrides./wheel_loads.subscription.reliability:=reliable",
                    discover=False, wheel_qos=SENSOR_QOS) as run:
        drv = run.drv
        drv.wait_for(lambda: drv.node.count_subscribers("/wheel_loads") >= 1, 60, "the node subscribed")
        for m in encoded(frames(50, 5 * NS)):
            drv.pub.publish(m)  # type: ignore[union-attr]
        drv.spin(0.5)
        d = drv.latest_diagnostics()
        assert d["wheel_loads_reliability"] == "reliable" and d["received"] == "0", d
        assert drv.pub.get_subscription_count() == 0  # type: ignore[union-attr]  # incompatible: not matched
        assert drv.sleepers == []
    assert "incompatible QoS" in run.err, run.err


def test_monitored_series_keep_their_sleeper_and_markers(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    # sleepers 25 (left behind by the window), 60 (always inside) and 100 (reached by the window) by index, and
    # the one nearest 40.0 m (index 67 at 0.6 m spacing)
    stream = frames(800, 5 * NS)  # 24 m at 30 m/s: the window moves over the monitored sleepers
    with track_node(ros_python, ros_domain_id, "monitored_sleepers:=[25, 60, 100]", "monitored_positions:=40.0",
                    "markers_period:=0.05") as run:
        drv = run.drv
        series = drv.subscribe(SleeperResponse, "/monitored_sleepers", raw=True)
        markers: list[MarkerArray] = []
        marker_sub = drv.node.create_subscription(MarkerArray, "/track_markers", markers.append, 10)
        drv.wait_for(lambda: drv.node.count_publishers("/monitored_sleepers") >= 1, 20, "the series")
        drv.wait_for(lambda: marker_sub.get_publisher_count() >= 1, 20, "the markers")
        t_end = time.monotonic() + 1.0  # the node notices its watcher (every 0.25 s)
        while time.monotonic() < t_end:
            drv.spin(0.05)
        drv.send(encoded(stream), expected_answers=800)
        drv.wait_for(lambda: len(series) >= 800 and markers, 30, "every series message and markers")
    got = [decode_sleeper_response(b) for b in series]
    assert [g.stamp_ns for g in got] == [t for t, _, _ in stream]
    inside = np.zeros(4, dtype=int)
    for g, r in zip(got, offline(stream)):
        np.testing.assert_array_equal(g.sleeper_index, [25, 60, 100, 67])  # entry i: always the same sleeper
        np.testing.assert_allclose(g.position, [15.0, 36.0, 60.0, 40.2])
        for i, idx in enumerate(g.sleeper_index):
            where = np.nonzero(r.sleeper_index == idx)[0]
            if where.size:
                inside[i] += 1
                assert g.soil_force[i] == r.soil_force[where[0]]
                assert g.rail_deflection[i] == r.rail_deflection[where[0]]
            else:
                assert math.isnan(g.soil_force[i]) and math.isnan(g.rail_deflection[i])
    assert 0 < inside[0] < 800 and inside[1] == inside[3] == 800 and 0 < inside[2] < 800  # left, kept, reached
    m = markers[-1].markers
    assert [x.type for x in m] == [Marker.CUBE_LIST, Marker.LINE_STRIP]
    assert len(m[0].points) == len(m[0].colors) == 61 and len(m[1].points) == 61
    assert m[0].header.frame_id == "track"
    assert max(c.r for c in m[0].colors) == pytest.approx(1.0)  # the largest soil force in red
