"""The track node falling behind and catching up, and the lag it reports (real DDS, real processes).

- a burst of 2 000 messages (a backlog at the node): every one answered exactly
  once, in order, identical to the offline computation, taken in batches;
- ``/diagnostics`` keep coming while a backlog is worked off;
- the diagnostics level follows ``lag_budget`` (WARN) and ``max_feedback_delay``
  (ERROR), the lag measured on the stamps' clock; sim-time stamps without
  ``/clock`` give "unavailable", not 1.8e9 s; with ``use_sim_time`` and
  ``/clock`` the lag is measured on sim time.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from builtin_interfaces.msg import Time
from driver import Driver, status_dict, track_node
from rosgraph_msgs.msg import Clock
from streams import encoded, frames, offline

from clm_core.io.messages import encode_wheel_loads
from clm_core.io.timebase import NS, ns_to_stamp


def test_burst_of_2000_answered_exactly_once_in_order_identical_to_offline(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    with track_node(ros_python, ros_domain_id, "diagnostics_period:=0.05") as run:
        drv = run.drv
        stream = frames(2000, 5 * NS)
        drv.burst(encoded(stream), expected_answers=2000, stopped_pid=run.proc.pid)  # the backlog: 2000 at once
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end:  # anything more would be a duplicate
            drv.spin(0.05)
        assert len(drv.sleepers) == 2000 and len(drv.wheels) == 2000
        assert [s.stamp_ns for s in drv.sleepers] == [t for t, _, _ in stream]  # once each, in order
        assert [w.stamp_ns for w in drv.wheels] == [t for t, _, _ in stream]
        for got, got_w, ref in zip(drv.sleepers, drv.wheels, offline(stream)):
            np.testing.assert_array_equal(got.soil_force, ref.soil_force)
            np.testing.assert_array_equal(got.rail_deflection, ref.rail_deflection)
            np.testing.assert_array_equal(got.sleeper_index, ref.sleeper_index)
            np.testing.assert_array_equal(got_w.rail_deflection, ref.wheel_deflection)
        d = drv.latest_diagnostics()
        assert d["received"] == d["accepted"] == d["published"] == "2000" and d["rejected"] == "0"
        assert int(d["largest_batch"]) > 1  # the backlog was taken in batches, not message by message
        assert int(d["batches"]) < 2000


def test_diagnostics_keep_coming_during_a_backlog(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    with track_node(ros_python, ros_domain_id, "diagnostics_period:=0.05") as run:
        drv = run.drv
        n = 5000
        drv.burst(encoded(frames(n, 5 * NS)), expected_answers=n, timeout=180)
        # by their content (0 < accepted < n: published while the backlog was worked off), not by when this
        # process took them: a driver starved on a loaded machine takes queued diagnostics after the last answer
        during = [status_dict(m) for _, m in drv.diagnostics]
        mid = [d for d in during if 0 < int(d["accepted"]) < n]
        # published by their own thread while the executor thread was working off the backlog
        assert len(mid) >= 2, [d["accepted"] for d in during]
        assert any(int(d["waiting"]) > 0 for d in mid), [d["waiting"] for d in mid]
        assert drv.latest_diagnostics()["accepted"] == str(n)


def _stream_on_ros_time(drv: Driver, n: int, age_ns: int) -> None:
    """``n`` frames 1 ms apart, each stamped ``age_ns`` before the moment it is sent (ROS time)."""
    last = [0]

    def stamp() -> int:
        last[0] = max(time.time_ns() - age_ns, last[0] + 1000)  # strictly increasing
        return last[0]

    msgs = (encode_wheel_loads(stamp(), "track", [0, 1], p, f) for _, p, f in frames(n, 0))
    drv.send(msgs, expected_answers=n, max_in_flight=5)


def test_diagnostics_level_follows_the_lag_budget(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    with track_node(ros_python, ros_domain_id, "diagnostics_period:=0.05") as run:
        drv = run.drv
        assert drv.set_double("lag_budget", 60.0).successful
        n0 = len(drv.diagnostics)
        _stream_on_ros_time(drv, 200, 0)
        drv.latest_diagnostics()
        # the diagnostics of periods with answers (a period without any reports lag nan)
        during = [status_dict(m) for _, m in drv.diagnostics[n0:]]
        answered = [x for x in during if math.isfinite(float(x["lag_median_s"]))]
        assert answered, during
        d = answered[-1]
        lag = float(d["lag_median_s"])
        assert 0 <= lag < 60 and "lag_budget" not in d["_message"], d  # well within a 60 s budget: no WARN
        # OK, unless the machine is so loaded that some answers came later than max_feedback_delay (ERROR, rightly)
        assert d["_level"] == "0" or (d["_level"] == "2" and "too late for the closed loop" in d["_message"]), d
        # a budget no real answer can meet: WARN, saying so
        assert drv.set_double("lag_budget", 1e-9).successful
        n0 = len(drv.diagnostics)
        _stream_on_ros_time(drv, 200, 0)
        levels = [status_dict(m) for _, m in drv.diagnostics[n0:]]
        warned = [x for x in levels if x["_level"] == "1"]
        assert warned and "lag_budget" in warned[0]["_message"], levels
        # answers older than max_feedback_delay (0.02 s): too late for the closed loop, ERROR
        assert drv.set_double("lag_budget", 60.0).successful
        t_next = time.monotonic() + 1.2  # stamps 1 s old must still come after the last accepted one
        while time.monotonic() < t_next:
            drv.spin(0.05)
        n0 = len(drv.diagnostics)
        _stream_on_ros_time(drv, 200, NS)  # stamped 1 s ago
        errors = [status_dict(m) for _, m in drv.diagnostics[n0:] if status_dict(m)["_level"] == "2"]
        assert errors and "too late for the closed loop" in errors[0]["_message"], errors
        assert float(errors[0]["lag_median_s"]) == pytest.approx(1.0, abs=0.5)


def test_lag_unavailable_with_sim_time_stamps_without_clock(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    with track_node(ros_python, ros_domain_id, "diagnostics_period:=0.05") as run:
        drv = run.drv
        drv.send(encoded(frames(100, 5 * NS)), expected_answers=100)  # sim time from 5 s: not ROS time
        d = drv.latest_diagnostics()
        assert d["lag_median_s"].startswith("unavailable: stamps are not on the node's clock"), d
        assert d["_level"] == "0" and "lag unavailable" in d["_message"]


def test_lag_on_sim_time_with_clock(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    with track_node(ros_python, ros_domain_id, "use_sim_time:=true", "diagnostics_period:=0.05") as run:
        drv = run.drv
        stream = frames(100, 5 * NS)
        drv.send(encoded(stream[:50]), expected_answers=50)  # no /clock yet
        d = drv.latest_diagnostics()
        assert d["lag_median_s"] == "unavailable: use_sim_time is set and no /clock has arrived", d
        clock = drv.node.create_publisher(Clock, "/clock", 10)
        drv.wait_for(lambda: clock.get_subscription_count() >= 1, 20, "the node on /clock")
        mark = len(drv.diagnostics)
        for t, p, f in stream[50:]:
            sec, nanosec = ns_to_stamp(t + 3 * 10**6)  # sim time runs 3 ms ahead of the stamps
            clock.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))
            drv.spin(0.002)
            drv.send([encode_wheel_loads(t, "track", [0, 1], p, f)], expected_answers=1)
        drv.latest_diagnostics()
        # the lag is over each diagnostics period (0.05 s): a period without answers says nan, one before the
        # first /clock says unavailable; every period with answers on sim time says 2-3 ms
        lags = [status_dict(m)["lag_median_s"] for _, m in drv.diagnostics[mark:]]
        measured = [float(x) for x in lags if not x.startswith("unavailable") and math.isfinite(float(x))]
        assert measured and all(0.0 <= x <= 0.01 for x in measured), lags  # 3 ms (2 ms if a /clock arrives late)
