"""The track node with a sim clock behind its stamps: negative lags are a warning, never OK (issue 26, item 9).

``use_sim_time`` with a ``/clock`` that stopped 10 s before the wheel-load
stamps (a simulator paused, a clock publisher gone): every answer is
"published" 10 s before its stamp's time. The node's ``/diagnostics`` said OK
with lags of -10 s; now WARN, the message names the clock, and the smallest
lag is shown (``lag_min_s``). Once the clock runs with the stamps again, OK.

Also (issue 26, item 10): a parameter the node does not have is refused with its name.
"""

from __future__ import annotations

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from diagnostic_msgs.msg import DiagnosticStatus
from driver import status_dict, track_node
from rosgraph_msgs.msg import Clock
from streams import encoded, frames

from clm_core.io.timebase import NS

WARN_LEVEL = DiagnosticStatus.WARN[0] if isinstance(DiagnosticStatus.WARN, bytes) else int(DiagnosticStatus.WARN)


def _clock(ns: int) -> Clock:
    return Clock(clock=type(Clock().clock)(sec=ns // NS, nanosec=ns % NS))


def test_negative_lag_from_a_stopped_clock_is_a_warning(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    """Was quarantined (issue 26.9: no WARN seen in the full ROS suite, passed alone). Cause: the test published
    its stopped clock ONCE, and rclpy's /clock subscription is best effort with depth 1: the sample is lost
    when the node's reader has not matched the writer yet (discovery is two-sided) or on a loaded machine.
    Without a clock the node cannot measure lags ("unavailable", no answers_in_period): no WARN ever. Now the
    stopped clock is published until the node's clock shows it (its /diagnostics stamps), as a paused
    simulator keeps publishing; and the node holds the clock-behind WARN as a state (periods without answers
    keep it) until an answer shows the clock caught up."""
    t0 = 1000 * NS
    with track_node(ros_python, ros_domain_id, "use_sim_time:=true") as run:
        drv = run.drv
        clock = drv.node.create_publisher(Clock, "/clock", 10)
        drv.wait_for(lambda: clock.get_subscription_count() >= 1, 30, "the node's /clock subscription")

        def on_stopped_clock() -> bool:
            clock.publish(_clock(t0))  # ... and the clock stops there (published again: /clock is best effort)
            return any(msg.header.stamp.sec == t0 // NS for _, msg in drv.diagnostics[-3:])

        drv.wait_for(on_stopped_clock, 30, "the node's clock at the stopped /clock")
        stream = frames(300, t0 + 10 * NS)  # stamps 10 s ahead of the stopped clock
        drv.send(encoded(stream[:200]), expected_answers=200)

        def warned() -> bool:
            for _, st in reversed(drv.diagnostics):
                d = status_dict(st)
                if d.get("answers_in_period", "0") != "0":
                    return d["_level"] == str(WARN_LEVEL) and \
                        "negative lag" in d["_message"] and "clock is behind" in d["_message"] and \
                        float(d["lag_min_s"]) < -9.0
            return False

        drv.wait_for(warned, 30, "a WARN for negative lags")
        # a state, not one sample: the periods after the answers (none in them) still say WARN, clock behind
        n = len(drv.diagnostics)
        drv.wait_for(lambda: len(drv.diagnostics) >= n + 3, 30, "three more /diagnostics")
        for _, st in drv.diagnostics[n:]:
            d = status_dict(st)
            assert d["_level"] == str(WARN_LEVEL) and "clock is behind" in d["_message"], d
            assert d["clock_behind_stamps"] == "true", d
        # the clock catches up with the stamps: OK again. It runs ahead of each frame's stamp by 50 frames, as a
        # simulator's clock is past the time of the data it sent: /clock and /wheel_loads are two topics with no
        # order between them, and with the clock at the stamp exactly, a late or lost /clock sample (best effort)
        # left the node's clock 6 ms behind one frame (a stress run beside the CI, load 4-5)
        lead = 50 * (stream[1][0] - stream[0][0])
        clock.publish(_clock(stream[199][0] + lead))
        for t, m in zip(stream[200:], encoded(stream[200:])):
            clock.publish(_clock(t[0] + lead))
            drv.pub.publish(m)
            drv.spin(0.002)
        drv.wait_answers(300, 300, 60)

        final = [status_dict(st) for _, st in drv.diagnostics]

        def settled() -> bool:
            final[:] = [status_dict(st) for _, st in drv.diagnostics]
            return any(d.get("received") == "300" and d.get("answers_in_period", "0") != "0" for d in final)

        drv.wait_for(settled, 30, "diagnostics of the last answers")
        d = next(d for d in reversed(final) if d.get("answers_in_period", "0") != "0")
        assert float(d["lag_min_s"]) > -1.0 and "negative lag" not in d["_message"], d


def test_undeclared_parameter_refusal_names_it(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    """A parameter the node does not have is refused with its name (issue 26.10: rclpy said 'parameter(s): []');
    the node keeps every value and answers."""
    with track_node(ros_python, ros_domain_id, discover=False) as run:
        r = run.drv.set_double("soil.kff", 7e7)
        assert not r.successful and "undeclared parameter(s): ['soil.kff']" in r.reason, r.reason
        assert run.drv.set_double("soil.kf", 7e7).successful
