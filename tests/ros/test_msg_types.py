"""clm_msgs in rosbags (clm_core.io.messages) and in rclpy agree, byte for byte.

rosbags-serialised messages deserialize with rclpy and rclpy-serialised ones
with rosbags, field by field; the RIHS01 type hashes rosbags computes equal
the ones rosidl generated at build time.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip(
    "clm_msgs.msg",
    reason="clm_msgs is not importable from this python; build it with "
    "`bash scripts/setup_ros.sh VENV` (ROS 2 Jazzy wheels + interface package)",
)

from clm_msgs.action import Calibrate as CalibrateAction  # noqa: E402
from clm_msgs.msg import SleeperResponse, WheelLoads, WheelRailResponse  # noqa: E402
from clm_msgs.srv import Calibrate  # noqa: E402
from msgcheck import SLEEPER_FIELDS, WHEEL_RAIL_FIELDS, same_arrays, same_wheel_loads  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

from clm_core.io.messages import interface_dir, source_interface_dir, typestore  # noqa: E402

MESSAGES = ("WheelLoad", "WheelLoads", "SleeperResponse", "WheelRailResponse")


@pytest.fixture(scope="module")
def ts() -> Any:
    return typestore()


def _header(ts: Any, sec: int, nanosec: int, frame_id: str) -> Any:
    T = ts.types
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id)


def _wheel_loads(ts: Any, n: int) -> Any:
    T = ts.types
    wheels = [
        T["clm_msgs/msg/WheelLoad"](
            id=4_000_000_000 - i,  # near the uint32 limit
            position=-12.5 + 2.5 * i,
            force=1.0e5 + 123.456 * i,
            speed=math.nan if i == 1 else 33.3,
        )
        for i in range(n)
    ]
    return T["clm_msgs/msg/WheelLoads"](header=_header(ts, 1_700_000_000, 999_999_999, "line_A"), wheels=wheels)


def _sleeper_response(ts: Any, n: int) -> Any:
    rng = np.random.default_rng(7)
    return ts.types["clm_msgs/msg/SleeperResponse"](
        header=_header(ts, 12, 500, "line_B"),
        sleeper_index=np.arange(-2, n - 2, dtype=np.int64) * 1_000_000_007,
        position=np.linspace(-1.2, 0.6 * n, n),
        soil_force=rng.normal(5e4, 1e4, n),
        rail_deflection=rng.normal(1e-3, 1e-4, n),
        sleeper_displacement=rng.normal(8e-4, 1e-4, n),
        area_displacement=rng.normal(3e-4, 1e-4, n),
    )




@pytest.mark.parametrize("n", [0, 1, 6])
def test_wheel_loads_rosbags_to_rclpy_and_back(ts: Any, n: int) -> None:
    msg = _wheel_loads(ts, n)
    raw = bytes(ts.serialize_cdr(msg, "clm_msgs/msg/WheelLoads"))

    ros_msg = deserialize_message(raw, WheelLoads)
    same_wheel_loads(ros_msg, msg)

    # rclpy -> rosbags. Fast CDR leaves alignment padding uninitialised, so
    # compare decoded fields, not bytes.
    back = ts.deserialize_cdr(serialize_message(ros_msg), "clm_msgs/msg/WheelLoads")
    same_wheel_loads(back, msg)


@pytest.mark.parametrize("n", [1, 5, 200])
def test_sleeper_response_rosbags_to_rclpy_and_back(ts: Any, n: int) -> None:
    msg = _sleeper_response(ts, n)
    raw = bytes(ts.serialize_cdr(msg, "clm_msgs/msg/SleeperResponse"))

    ros_msg = deserialize_message(raw, SleeperResponse)
    same_arrays(ros_msg, msg, SLEEPER_FIELDS)
    assert list(ros_msg.sleeper_index) == [int(x) for x in msg.sleeper_index]

    back = ts.deserialize_cdr(serialize_message(ros_msg), "clm_msgs/msg/SleeperResponse")
    same_arrays(back, msg, SLEEPER_FIELDS)


def test_wheel_rail_response_rclpy_to_rosbags_and_back(ts: Any) -> None:
    ros_msg = WheelRailResponse()
    ros_msg.header.stamp.sec = 3
    ros_msg.header.frame_id = "line_C"
    ros_msg.wheel_id = [0, 1, 4_294_967_295]
    ros_msg.position = [1.0, 3.5, -2.0]
    ros_msg.rail_deflection = [1e-3, -2e-4, 0.0]
    ros_msg.rail_velocity = [0.01, -0.02, math.inf]

    msg = ts.deserialize_cdr(serialize_message(ros_msg), "clm_msgs/msg/WheelRailResponse")
    assert msg.wheel_id.dtype == np.uint32
    same_arrays(msg, ros_msg, WHEEL_RAIL_FIELDS)

    again = deserialize_message(bytes(ts.serialize_cdr(msg, "clm_msgs/msg/WheelRailResponse")), WheelRailResponse)
    same_arrays(again, ros_msg, WHEEL_RAIL_FIELDS)


def test_calibrate_service_parts(ts: Any) -> None:
    T = ts.types
    req = T["clm_msgs/srv/Calibrate_Request"](
        bag_path="/data/bag ü",
        method="receptance",
        options_yaml="f_max: 2000.0\n",
        push_to_node=True,
        target_node="/clm_track",
        request_id="batch-7 ü",
    )
    got = deserialize_message(bytes(ts.serialize_cdr(req, "clm_msgs/srv/Calibrate_Request")), Calibrate.Request)
    assert (got.bag_path, got.method, got.options_yaml, got.push_to_node, got.target_node, got.request_id) == (
        req.bag_path,
        req.method,
        req.options_yaml,
        req.push_to_node,
        req.target_node,
        req.request_id,
    )

    res = Calibrate.Response(
        success=False,
        message="bag has no topic /wheel_loads",
        parameters_yaml="",
        metrics_json=json.dumps({"rms": 1.5e-3}),
    )
    back = ts.deserialize_cdr(serialize_message(res), "clm_msgs/srv/Calibrate_Response")
    assert (back.success, back.message, back.parameters_yaml, back.metrics_json) == (
        res.success,
        res.message,
        res.parameters_yaml,
        res.metrics_json,
    )

    # Service introspection event (what `ros2 bag record` stores for services).
    info = T["service_msgs/msg/ServiceEventInfo"](
        event_type=1,
        stamp=T["builtin_interfaces/msg/Time"](sec=5, nanosec=6),
        client_gid=np.arange(16, dtype=np.uint8),
        sequence_number=42,
    )
    event = T["clm_msgs/srv/Calibrate_Event"](info=info, request=[req], response=[])
    got_event = deserialize_message(bytes(ts.serialize_cdr(event, "clm_msgs/srv/Calibrate_Event")), Calibrate.Event)
    assert got_event.info.sequence_number == 42
    assert list(got_event.info.client_gid) == list(range(16))
    assert [r.method for r in got_event.request] == ["receptance"]
    assert list(got_event.response) == []


def test_calibrate_action_parts(ts: Any) -> None:
    """The action's goal, feedback message and result: rosbags and rclpy give the same bytes."""
    T = ts.types
    goal = CalibrateAction.Goal(bag_path="/data/bag ü", method="receptance", fmax=400.0, fit=["kp", "ms"],
                                initial_names=["kp"], initial_values=[1.1e8], push_to_node=True,
                                target_node="/clm_track_node")
    assert math.isclose(goal.fmin, -1.0) and goal.compare is True and goal.n_areas == 0  # the .action defaults
    back = ts.deserialize_cdr(serialize_message(goal), "clm_msgs/action/Calibrate_Goal")
    assert (back.bag_path, back.method, back.fmax, back.fit, back.compare) == (
        "/data/bag ü", "receptance", 400.0, ["kp", "ms"], True)
    assert list(back.initial_values) == [1.1e8]
    fb = CalibrateAction.Impl.FeedbackMessage()
    fb.goal_id.uuid = list(range(16))
    fb.feedback = CalibrateAction.Feedback(stage="clm fit", fraction=0.6, message="fitting", elapsed=2.5)
    rb = ts.deserialize_cdr(serialize_message(fb), "clm_msgs/action/Calibrate_FeedbackMessage")
    assert list(rb.goal_id.uuid) == list(range(16)) and rb.feedback.stage == "clm fit"
    res = T["clm_msgs/action/Calibrate_GetResult_Response"](
        status=4,
        result=T["clm_msgs/action/Calibrate_Result"](
            success=True, message="ok", method="impact", model="clm", fmin=2.0, fmax=150.0, norm="weighted",
            names=["kf"], units=["N/m"], values=np.array([7.2e7]), std_error=np.array([6e5]),
            ci95_low=np.array([7.1e7]), ci95_high=np.array([7.3e7]), identifiable=np.array([True]),
            at_bound=np.array([False]), misfit=0.04, rms_residual=1.01, n_areas=41, fit_duration=1.5,
            warnings=[], parameters_yaml="soil: {}\n", push_requested=False, push_target="", push_accepted=False,
            push_reason="", metrics_json="{}"),
    )
    got = deserialize_message(bytes(ts.serialize_cdr(res, "clm_msgs/action/Calibrate_GetResult_Response")),
                              CalibrateAction.Impl.GetResultService.Response)
    assert got.status == 4 and list(got.result.names) == ["kf"] and list(got.result.ci95_high) == [7.3e7]
    assert list(got.result.identifiable) == [True] and got.result.n_areas == 41


def _installed_share() -> Path:
    """share/clm_msgs of the installation rclpy imports clm_msgs from."""
    import clm_msgs

    # <prefix>/lib/pythonX.Y/site-packages/clm_msgs/__init__.py -> <prefix>
    prefix = Path(clm_msgs.__file__).resolve().parents[4]
    share = prefix / "share" / "clm_msgs"
    if not (share / "msg").is_dir():
        pytest.skip(f"no share/clm_msgs/msg next to {clm_msgs.__file__}")
    return share


def test_typestore_reads_the_installed_definitions() -> None:
    share = _installed_share()
    found = interface_dir([share.parents[1]])
    assert found == share
    if Path(sys.prefix).resolve() == share.parents[1].resolve():
        assert interface_dir().resolve() == share.resolve()


def test_installed_definitions_match_the_source_tree() -> None:
    """Fails when a .msg/.srv was edited but not rebuilt (rerun setup_ros.sh)."""
    share = _installed_share()
    src = source_interface_dir()
    pattern = ("msg/*.msg", "srv/*.srv", "action/*.action")
    src_files = sorted(p.relative_to(src) for g in pattern for p in src.glob(g))
    inst_files = sorted(p.relative_to(share) for g in pattern for p in share.glob(g))
    assert inst_files == src_files
    for rel in src_files:
        assert (share / rel).read_text() == (src / rel).read_text(), f"{rel} differs: rebuild clm_msgs"


def test_rihs01_hashes_match_rosidl(ts: Any) -> None:
    """rosbags' RIHS01 hash of every clm_msgs type equals the one rosidl generated."""
    share = _installed_share()
    checked = []
    for path in sorted((*share.glob("msg/*.json"), *share.glob("srv/*.json"), *share.glob("action/*.json"))):
        for entry in json.loads(path.read_text())["type_hashes"]:
            name = entry["type_name"]
            if not name.startswith("clm_msgs/") or name not in ts.types:
                continue  # the pseudo-types clm_msgs/srv/Calibrate, clm_msgs/action/Calibrate_SendGoal ...
            if name.endswith("_Event"):
                # rosbags' Jazzy store declares service_msgs/ServiceEventInfo
                # client_gid as char[16], rosidl hashes it as uint8[16]: the
                # hashes of *_Event types differ (the CDR bytes do not).
                continue
            assert ts.hash_rihs01(name) == entry["hash_string"], name
            checked.append(name)
    for name in MESSAGES:
        assert f"clm_msgs/msg/{name}" in checked
    assert "clm_msgs/srv/Calibrate_Request" in checked
    assert "clm_msgs/srv/Calibrate_Response" in checked
    for part in ("Goal", "Result", "Feedback", "FeedbackMessage", "SendGoal_Request", "SendGoal_Response",
                 "GetResult_Request", "GetResult_Response"):
        assert f"clm_msgs/action/Calibrate_{part}" in checked
