"""The track node's two ways of waiting for wheel loads (``answer_loop``) answer alike, over real DDS.

``executor``: a thread waits on the subscription's arrival eventfd and hands
the executor a task; ``waitset``: the process's loop
(:func:`clm_ros.node_main.run_node`) waits on that fd itself and answers in
its own thread, serving the executor in between. Both: every message
answered, bit for bit the offline model's; the node's services (lifecycle,
parameters) answer while wheel loads flow; a deactivate / activate cycle
resubscribes (a new fd) and answers again; SIGTERM ends the process with
exit code 0 (checked by :func:`driver.track_node`). CPU per message of each:
benchmarks/node_cpu.py.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clm_ros.conversions import rclpy_wheel_loads
from driver import track_node

from clm_core.io.timebase import NS
from clm_core.online import OnlineTrackModel, WheelFrame

OFF = np.array([0.0, 3.0])


def _stream(n: int, t0_ns: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
    return [(t0_ns + k * 10**6, 30.0 - OFF + 30.0 * k * 1e-3, np.array([85e3, 85e3])) for k in range(n)]


@pytest.mark.parametrize("loop", ["executor", "waitset"])
def test_both_loops_answer_bit_for_bit_and_serve_the_node(ros_python, ros_domain_id, loop) -> None:  # type: ignore[no-untyped-def]
    stream = _stream(350, 5 * NS)
    ref = OnlineTrackModel.from_settings({"dt": 1e-4, "n_sleepers": 61})
    offline = [ref.process(WheelFrame.of(t, [0, 1], p, f)) for t, p, f in stream]
    with track_node(ros_python, ros_domain_id, f"answer_loop:={loop}") as run:
        drv = run.drv
        msgs = [rclpy_wheel_loads(t, [0, 1], p, f) for t, p, f in stream]
        drv.send(msgs[:150], expected_answers=150)
        assert drv.set_double("lag_budget", 0.5).successful  # a service answered between wheel loads
        drv.send(msgs[150:300], expected_answers=150)
        # a new subscription (and arrival fd) after deactivate / activate: the stream goes on, answered
        assert drv.transition("deactivate") and drv.transition("activate")
        drv.wait_discovery()
        drv.send(msgs[300:], expected_answers=50)
        assert len(drv.sleepers) == 350 and len(drv.wheels) == 350
        for got, want in zip(drv.sleepers, offline):
            assert got.stamp_ns == want.stamp_ns
            np.testing.assert_array_equal(np.asarray(got.soil_force), want.soil_force)
            np.testing.assert_array_equal(np.asarray(got.rail_deflection), want.rail_deflection)
        for got, want in zip(drv.wheels, offline):
            np.testing.assert_array_equal(np.asarray(got.rail_deflection), want.wheel_deflection)
        d = drv.latest_diagnostics()
        assert d["accepted"] == "350" and d["published"] == "350" and d["rejected"] == "0", d
