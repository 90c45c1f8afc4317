"""ROS parameters generated from the run-settings schema (clm_ros.parameters).

- descriptors carry the schema's description, unit, range and read-only flag;
- an integer for a real-valued parameter is taken (issue 12.8): on the command
  line (``-p track.kb:=60000000``) and through the parameter service, as
  ``ros2 param set /clm_track_node track.kb 60000000`` sends it;
- values outside the schema are refused with its message.
"""

from __future__ import annotations

import math
import time

import pytest

pytest.importorskip("rclpy")

import rclpy
from clientnode import RESEND_QUERY
from clm_ros.parameters import NODE_SETTINGS, declare_model_parameters, declare_settings, descriptor
from clm_ros.reliable_client import answered
from rcl_interfaces.msg import ParameterType
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter

from clm_core.settings import SETTINGS


@pytest.fixture
def context(ros_domain_id: int):  # type: ignore[no-untyped-def]
    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain_id)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


def test_descriptors_from_the_schema() -> None:
    d = descriptor(SETTINGS["speed"])
    assert "[m/s]" in d.description and "default 83.33 m/s" in d.description and not d.read_only
    assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (0.0, 150.0)
    assert descriptor(SETTINGS["dt"]).read_only  # structural: fixed once the model is built
    d = descriptor(SETTINGS["lead_sleepers"])
    assert (d.integer_range[0].from_value, d.integer_range[0].to_value) == (-1, 4000)  # -1: automatic
    assert "a third of the window" in d.description and "unset: -1" in d.description
    d = descriptor(SETTINGS["model"])
    assert d.additional_constraints == "one of rigid, winkler, lysmer, clm"
    assert not descriptor(SETTINGS["max_gap"]).read_only and not descriptor(NODE_SETTINGS["frame_id"]).read_only
    assert descriptor(SETTINGS["max_gap"], read_only=True).read_only


def test_integers_for_doubles_and_schema_checks_in_process(context: Context) -> None:
    node = Node("clm_param_probe", context=context, parameter_overrides=[
        Parameter("speed", value=60), Parameter("track.kb", value=60000000), Parameter("n_sleepers", value=81)])
    try:
        declare_settings(node, ("speed", "n_sleepers", "max_gap", "storage", "wavelength_band"), read_only=False)
        declare_model_parameters(node)
        for name, value in (("speed", 60.0), ("track.kb", 60e6)):
            p = node.get_parameter(name)
            assert p.type_ == Parameter.Type.DOUBLE and p.value == value, name
        assert node.get_parameter("n_sleepers").value == 81
        assert math.isnan(node.get_parameter("soil.kf").value)  # unset: from the preset
        ok = node.set_parameters([Parameter("max_gap", value=2), Parameter("track.kb", value=50000000)])
        assert all(r.successful for r in ok), [r.reason for r in ok]
        assert node.get_parameter("max_gap").type_ == Parameter.Type.DOUBLE and node.get_parameter("max_gap").value == 2
        refused = node.set_parameters([Parameter("speed", value=-5.0), Parameter("storage", value="zip"),
                                       Parameter("wavelength_band", value="50,1"), Parameter("speed", value="fast")])
        assert [r.successful for r in refused] == [False] * 4
        assert "out of range" in refused[0].reason
        assert refused[1].reason == "storage = 'zip': must be one of mcap, sqlite3"
        assert refused[2].reason.startswith("wavelength_band = '50,1': need 0 < LMIN < LMAX")
        assert "Wrong parameter type" in refused[3].reason
        assert node.get_parameter("speed").value == 60.0
    finally:
        node.destroy_node()


NODE = "import sys\nfrom clm_ros.track_node import main\nsys.exit(main(sys.argv))\n"


def test_track_node_takes_integers_for_doubles(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    from driver import Driver
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterValue
    from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters

    proc = ros_python.spawn(NODE, ["--ros-args", "-p", "track.kb:=60000000", "-p", "max_gap:=2"],
                            name="track_node_int")
    drv = Driver(ros_domain_id)
    try:
        def call(srv_type, name, req):  # type: ignore[no-untyped-def]
            cli = drv.node.create_client(srv_type, f"/clm_track_node/{name}")
            drv.wait_for(cli.service_is_ready, 90, name)  # the node compiles its kernels at start
            def until(done, seconds):  # type: ignore[no-untyped-def]
                end = time.monotonic() + seconds
                while not done() and time.monotonic() < end:
                    drv.spin(0.02)

            # queries and sets of the same value: resent while unanswered (a lost answer must not fail the test)
            return answered(cli, req, until, 60, RESEND_QUERY)

        got = call(GetParameters, "get_parameters", GetParameters.Request(names=["track.kb", "max_gap"]))
        assert [(v.type, v.double_value) for v in got.values] == [
            (ParameterType.PARAMETER_DOUBLE, 60e6), (ParameterType.PARAMETER_DOUBLE, 2.0)]
        # what `ros2 param set /clm_track_node track.kb 50000000` sends: an INTEGER
        req = SetParameters.Request(parameters=[ParameterMsg(name="track.kb", value=ParameterValue(
            type=ParameterType.PARAMETER_INTEGER, integer_value=50000000))])
        r = call(SetParameters, "set_parameters", req).results[0]
        assert r.successful, r.reason
        got = call(GetParameters, "get_parameters", GetParameters.Request(names=["track.kb"]))
        assert (got.values[0].type, got.values[0].double_value) == (ParameterType.PARAMETER_DOUBLE, 50e6)
        d = call(DescribeParameters, "describe_parameters", DescribeParameters.Request(names=["dt", "track.kb"]))
        assert "[s]" in d.descriptors[0].description and d.descriptors[0].read_only
        assert d.descriptors[0].floating_point_range[0].to_value == pytest.approx(1e-2)
        assert "ballast stiffness" in d.descriptors[1].description and "[N/m]" in d.descriptors[1].description
    finally:
        drv.close()
    proc.terminate()
    ros_python.wait(proc, 20)
