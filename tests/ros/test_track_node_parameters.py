"""Run-time parameter changes of the track node: validated first, applied only when the whole set is valid.

The node validates a set in its on-set callback (a physics change must
build a stable model; nothing of the node changes there) and applies it in
its post-set callback (rclpy calls it only for a set that was accepted). A
refused atomic set changes nothing: not the parameters, not how the node
answers (every message, the same frame id), not the model's state (the
answers go on equal, bit for bit, to an offline model that never saw the
attempt).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clientnode import RESEND_QUERY
from clm_ros.conversions import rclpy_wheel_loads
from driver import track_node
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParametersAtomically

from clm_core.io.timebase import NS
from clm_core.online import OnlineTrackModel, WheelFrame

OFF = np.array([0.0, 3.0])


def _stream(n: int, first: int = 0) -> list[tuple[int, np.ndarray, np.ndarray]]:
    return [(5 * NS + k * 10**6, 30.0 - OFF + 30.0 * k * 1e-3, np.array([85e3, 85e3])) for k in range(first, n)]


def _msgs(stream: list[tuple[int, np.ndarray, np.ndarray]]) -> list[object]:
    return [rclpy_wheel_loads(t, [0, 1], p, f) for t, p, f in stream]


def _value(v: object) -> ParameterValue:
    if isinstance(v, bool):
        return ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=v)
    if isinstance(v, int):
        return ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=v)
    if isinstance(v, float):
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=v)
    return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=str(v))


def _set_atomically(drv, **values: object):  # type: ignore[no-untyped-def]
    req = SetParametersAtomically.Request(parameters=[Parameter(name=k.replace("__", "."), value=_value(v))
                                                      for k, v in values.items()])
    # the same values again are the same outcome: resent while unanswered (a lost answer must not fail the test)
    return drv.call(SetParametersAtomically, "set_parameters_atomically", req, resend_after=RESEND_QUERY).result


def _get(drv, *names: str) -> list[object]:  # type: ignore[no-untyped-def]
    vals = drv.call(GetParameters, "get_parameters", GetParameters.Request(names=list(names)),
                    resend_after=RESEND_QUERY).values
    return [{ParameterType.PARAMETER_INTEGER: v.integer_value, ParameterType.PARAMETER_DOUBLE: v.double_value,
             ParameterType.PARAMETER_STRING: v.string_value}[v.type] for v in vals]


def test_a_refused_parameter_set_changes_nothing(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    stream = _stream(60)
    ref = OnlineTrackModel.from_settings({"dt": 1e-4, "n_sleepers": 61})  # the node's defaults
    offline = [ref.process(WheelFrame.of(t, [0, 1], p, f)) for t, p, f in stream]
    with track_node(ros_python, ros_domain_id) as run:
        drv = run.drv
        drv.send(_msgs(stream[:30]), expected_answers=30)
        before = drv.latest_diagnostics()
        # two valid changes with an unstable one (negative soil damping): the set is refused as a whole
        r = _set_atomically(drv, publish_every=3, frame_id="elsewhere", max_gap=0.5, soil__dc=-400e3)
        assert not r.successful and "not positive semi-definite" in r.reason, r.reason
        assert _get(drv, "publish_every", "frame_id", "max_gap") == [1, "track", 1.0]
        drv.send(_msgs(stream[30:]), expected_answers=30)  # every message answered, as before the attempt
        assert len(drv.sleepers) == 60 and {s.frame_id for s in drv.sleepers} == {"track"}
        for got, want in zip(drv.sleepers, offline):  # the state went on: no restart, no new model
            assert got.stamp_ns == want.stamp_ns
            np.testing.assert_array_equal(np.asarray(got.soil_force), want.soil_force)
            np.testing.assert_array_equal(np.asarray(got.rail_deflection), want.rail_deflection)
        after = drv.latest_diagnostics()
        assert after["resyncs"] == before["resyncs"] and after["accepted"] == "60" and after["rejected"] == "0"


def test_an_accepted_set_is_applied_after_it_is_set(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    """Applied in the post-set callback: every 2nd message answered, under the new frame id."""
    with track_node(ros_python, ros_domain_id) as run:
        drv = run.drv
        drv.send(_msgs(_stream(10)), expected_answers=10)
        r = _set_atomically(drv, publish_every=2, frame_id="elsewhere")
        assert r.successful, r.reason
        drv.send(_msgs(_stream(30, first=10)), expected_answers=10)
        assert {s.frame_id for s in drv.sleepers[10:]} == {"elsewhere"}
        d = drv.latest_diagnostics()
        assert d["accepted"] == "30" and d["published"] == "20", d
