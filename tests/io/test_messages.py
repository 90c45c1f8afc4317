"""clm_core.io.messages: definitions, type store, domain conversions and the numpy CDR codec (no rclpy).

The codec is checked byte for byte against rosbags' own CDR serializer on
random messages (hypothesis), decoded back field for field, and fed
truncated, mutated and random bytes: the only error it may raise is
MessageError. The rclpy side of the round trip is tests/ros/test_cdr_rclpy.py.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clm_core.io import messages as msgs
from clm_core.io.errors import MessageError
from clm_core.io.timebase import NS

TS = msgs.typestore()
T = TS.types

# ------------------------------------------------------------------------------------------- definitions


def _defs(root: Path) -> dict[str, bytes]:
    files = sorted((*root.glob("msg/*.msg"), *root.glob("srv/*.srv"), *root.glob("action/*.action")))
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


def test_packaged_definitions_are_the_source_tree_ones() -> None:
    """The copy in clm_core/io/interfaces is byte for byte ros2_ws/src/clm_msgs (the one source of truth)."""
    src = _defs(msgs.source_interface_dir())
    assert src, "no definitions in the source tree"
    assert _defs(msgs.packaged_interface_dir()) == src


def test_interface_dir_order(tmp_path: Path) -> None:
    share = tmp_path / "share" / "clm_msgs" / "msg"
    share.mkdir(parents=True)
    (share / "WheelLoad.msg").write_text("uint32 id\n")
    assert msgs.interface_dir([tmp_path]) == tmp_path / "share" / "clm_msgs"
    assert msgs.interface_dir([tmp_path / "nothing"]) in (msgs.source_interface_dir(), msgs.packaged_interface_dir())
    types = msgs.clm_types(msgs.packaged_interface_dir())
    assert types == msgs.clm_types(msgs.source_interface_dir())
    assert {"clm_msgs/msg/WheelLoads", "clm_msgs/srv/Calibrate_Request", "clm_msgs/srv/Calibrate_Event"} <= set(types)
    # the action's parts, as rosidl generates them (feedback topic, goal and result services)
    assert {f"clm_msgs/action/Calibrate_{part}" for part in (
        "Goal", "Result", "Feedback", "FeedbackMessage", "SendGoal_Request", "SendGoal_Response", "SendGoal_Event",
        "GetResult_Request", "GetResult_Response", "GetResult_Event")} <= set(types)


def test_action_parts_in_the_store() -> None:
    """Goal, result and feedback of clm_msgs/action/Calibrate round-trip through rosbags' CDR."""
    goal = T["clm_msgs/action/Calibrate_Goal"](
        bag_path="b", method="impact", allow_partial=False, fmin=-1.0, fmax=140.0, norm="", model="",
        compare=True, n_areas=0, first_estimate="", interval="noise", fit=["kp", "kb"], soil="", n_sleepers=0,
        params_file="", channels="", initial_names=["kf"], initial_values=np.array([7e7]), max_nfev=0,
        options_yaml="", push_to_node=True, target_node="/clm_track_node",
    )
    uuid = T["unique_identifier_msgs/msg/UUID"](uuid=np.arange(16, dtype=np.uint8))
    req = T["clm_msgs/action/Calibrate_SendGoal_Request"](goal_id=uuid, goal=goal)
    back = TS.deserialize_cdr(TS.serialize_cdr(req, "clm_msgs/action/Calibrate_SendGoal_Request"),
                              "clm_msgs/action/Calibrate_SendGoal_Request")
    assert back.goal.fit == ["kp", "kb"] and back.goal.fmax == 140.0 and list(back.goal_id.uuid) == list(range(16))
    fb = T["clm_msgs/action/Calibrate_FeedbackMessage"](
        goal_id=uuid, feedback=T["clm_msgs/action/Calibrate_Feedback"](stage="clm fit", fraction=0.6, message="m",
                                                                         elapsed=1.5))
    back_fb = TS.deserialize_cdr(TS.serialize_cdr(fb, "clm_msgs/action/Calibrate_FeedbackMessage"),
                                 "clm_msgs/action/Calibrate_FeedbackMessage")
    assert (back_fb.feedback.stage, back_fb.feedback.fraction) == ("clm fit", 0.6)


def test_a_broken_definition_is_named(tmp_path: Path) -> None:
    (tmp_path / "msg").mkdir()
    (tmp_path / "msg" / "Bad.msg").write_text("float64[ x\n")
    with pytest.raises(MessageError, match=r"Bad.msg as clm_msgs/msg/Bad"):
        msgs.clm_types(tmp_path)
    with pytest.raises(MessageError, match=r"no msg/\*.msg files"):
        msgs.clm_types(tmp_path / "msg")
    (tmp_path / "msg" / "Bad.msg").write_text("float64 x\n")
    (tmp_path / "action").mkdir()
    (tmp_path / "action" / "Do.action").write_text("float64 x\n---\nbool ok\n")
    with pytest.raises(MessageError, match=r'Do.action: expected 2 "---" line\(s\), found 1'):
        msgs.clm_types(tmp_path)


def _text(pkg: str, name: str) -> str:
    if pkg == "clm_msgs":
        return (msgs.interface_dir() / "msg" / f"{name}.msg").read_text()
    from clm_core.io._definitions import _own_text

    return _own_text(f"{pkg}/{name}", msgs.interface_dir().resolve())


def test_message_definition_is_rosbag2s_full_text_with_comments() -> None:
    """Root text verbatim, then each dependency once, sorted, depth first (rosbag2 Jazzy's layout)."""
    sep = "\n" + "=" * 80 + "\n"
    want = (
        _text("clm_msgs", "WheelLoads")
        + sep + "MSG: clm_msgs/WheelLoad\n" + _text("clm_msgs", "WheelLoad")
        + sep + "MSG: std_msgs/Header\n" + _text("std_msgs", "Header")
        + sep + "MSG: builtin_interfaces/Time\n" + _text("builtin_interfaces", "Time")
    )
    got = msgs.message_definition(msgs.WHEEL_LOADS)
    assert got == want
    # units and the sign convention travel with the data
    assert "positive DOWNWARDS" in got and "[N]" in got and "[m/s]" in got
    # rosbags reads it back to the same types and hashes
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(got, msgs.WHEEL_LOADS))
    assert store.hash_rihs01(msgs.WHEEL_LOADS) == TS.hash_rihs01(msgs.WHEEL_LOADS)
    for name in (msgs.SLEEPER_RESPONSE, msgs.WHEEL_RAIL_RESPONSE, "geometry_msgs/msg/WrenchStamped"):
        text = msgs.message_definition(name)
        s2 = get_typestore(Stores.EMPTY)
        s2.register(get_types_from_msg(text, name))
        assert s2.hash_rihs01(name) == TS.hash_rihs01(name), name
    with pytest.raises(MessageError, match="no definition of message type"):
        msgs.message_definition("nopkg/msg/Nothing")


# ------------------------------------------------------------------------------------------- domain data


def test_domain_conversions_from_a_real_response() -> None:
    from clm_core.online import OnlineTrackModel, WheelFrame, frame_from_msg
    from clm_core.params import load_model

    model = OnlineTrackModel(load_model("mevergnies", "mevergnies", "clm"), dt=1e-4, n_sleepers=21)
    t_ns = 1_700_000_000 * NS + 123_456_789
    msg = msgs.wheel_loads_msg(TS, t_ns, [7, 9], [6.0, 3.5], [8e4, 9e4], [25.0, 25.0], frame_id="line_A")
    frame = frame_from_msg(msg)
    assert isinstance(frame, WheelFrame)
    assert frame.stamp_ns == t_ns and frame.frame_id == "line_A"
    assert list(frame.ids) == [7, 9] and list(frame.forces) == [8e4, 9e4]
    resp = model.process(frame)
    s, w = msgs.response_msgs(TS, resp, t_ns, "line_A")
    sf, wf = msgs.sleeper_fields(resp), msgs.wheel_fields(resp)
    assert sf["sleeper_index"].dtype == np.int64 and wf["wheel_id"].dtype == np.uint32
    assert np.max(sf["soil_force"]) > 0  # compression positive, loads pressing down
    # the codec writes the same bytes as rosbags for these messages
    ours = msgs.encode_sleeper_response(t_ns, "line_A", *sf.values())
    assert bytes(TS.serialize_cdr(s, msgs.SLEEPER_RESPONSE)) == ours
    assert bytes(TS.serialize_cdr(w, msgs.WHEEL_RAIL_RESPONSE)) == msgs.encode_wheel_rail_response(
        t_ns, "line_A", *wf.values()
    )
    raw = bytes(TS.serialize_cdr(msg, msgs.WHEEL_LOADS))
    d = msgs.decode_wheel_loads(raw)
    assert (d.stamp_ns, d.frame_id, d.ids.tolist(), d.positions.tolist()) == (t_ns, "line_A", [7, 9], [6.0, 3.5])


# ------------------------------------------------------------------------------------------- codec

frame_ids = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12)
floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
stamps = st.integers(-(2**31) * NS, (2**31 - 1) * NS + NS - 1)
sizes = st.integers(0, 9)


def _f64(draw: Any, n: int) -> np.ndarray:
    return np.array(draw(st.lists(floats, min_size=n, max_size=n)), dtype=np.float64)


@st.composite
def wheel_loads(draw: Any) -> tuple[int, str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    n = draw(sizes)
    ids = np.array(draw(st.lists(st.integers(0, 2**32 - 1), min_size=n, max_size=n)), dtype=np.uint32)
    return draw(stamps), draw(frame_ids), ids, _f64(draw, n), _f64(draw, n), _f64(draw, n)


def _rb_header(t_ns: int, frame_id: str) -> Any:
    sec, nsec = divmod(t_ns, NS)
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame_id)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()  # NaN payloads too


@settings(max_examples=150, deadline=None)
@given(wheel_loads())
def test_wheel_loads_codec_equals_rosbags(case: tuple[Any, ...]) -> None:
    t_ns, frame_id, ids, pos, force, speed = case
    msg = T[msgs.WHEEL_LOADS](
        header=_rb_header(t_ns, frame_id),
        wheels=[T["clm_msgs/msg/WheelLoad"](id=int(i), position=p, force=f, speed=v)
                for i, p, f, v in zip(ids.tolist(), pos.tolist(), force.tolist(), speed.tolist())],
    )
    ours = msgs.encode_wheel_loads(t_ns, frame_id, ids, pos, force, speed)
    assert ours == bytes(TS.serialize_cdr(msg, msgs.WHEEL_LOADS))
    d = msgs.decode_wheel_loads(ours)
    assert (d.stamp_ns, d.frame_id) == (t_ns, frame_id)
    assert _same(d.ids, ids) and _same(d.positions, pos) and _same(d.forces, force) and _same(d.speeds, speed)
    # big-endian CDR decodes to the same content
    big = msgs.decode_wheel_loads(bytes(TS.serialize_cdr(msg, msgs.WHEEL_LOADS, little_endian=False)))
    assert big.stamp_ns == t_ns and _same(big.ids, ids) and _same(big.speeds, speed)
    # trailing padding (as rclpy leaves it) is ignored
    assert _same(msgs.decode_wheel_loads(ours + b"\xaa" * 7).forces, force)


@st.composite
def sleeper_responses(draw: Any) -> tuple[Any, ...]:
    n = draw(sizes)
    idx = np.array(draw(st.lists(st.integers(-(2**63), 2**63 - 1), min_size=n, max_size=n)), dtype=np.int64)
    return (draw(stamps), draw(frame_ids), idx, *[_f64(draw, n) for _ in range(5)])


@settings(max_examples=150, deadline=None)
@given(sleeper_responses())
def test_sleeper_response_codec_equals_rosbags(case: tuple[Any, ...]) -> None:
    t_ns, frame_id, *arrays = case
    names = [f for f, _ in msgs._SLEEPER_SEQ]
    msg = T[msgs.SLEEPER_RESPONSE](header=_rb_header(t_ns, frame_id), **dict(zip(names, arrays)))
    ours = msgs.encode_sleeper_response(t_ns, frame_id, *arrays)
    assert ours == bytes(TS.serialize_cdr(msg, msgs.SLEEPER_RESPONSE))
    d = msgs.decode_sleeper_response(ours)
    assert (d.stamp_ns, d.frame_id) == (t_ns, frame_id)
    for name, a in zip(names, arrays):
        assert _same(getattr(d, name), a), name
    big = msgs.decode_sleeper_response(bytes(TS.serialize_cdr(msg, msgs.SLEEPER_RESPONSE, little_endian=False)))
    assert _same(big.sleeper_index, arrays[0]) and _same(big.area_displacement, arrays[-1])


@settings(max_examples=150, deadline=None)
@given(stamps, frame_ids, sizes, st.data())
def test_wheel_rail_response_codec_equals_rosbags(t_ns: int, frame_id: str, n: int, data: Any) -> None:
    ids = np.array(data.draw(st.lists(st.integers(0, 2**32 - 1), min_size=n, max_size=n)), dtype=np.uint32)
    arrays = [ids, *[_f64(data.draw, n) for _ in range(3)]]
    names = [f for f, _ in msgs._WHEEL_RAIL_SEQ]
    msg = T[msgs.WHEEL_RAIL_RESPONSE](header=_rb_header(t_ns, frame_id), **dict(zip(names, arrays)))
    ours = msgs.encode_wheel_rail_response(t_ns, frame_id, *arrays)
    assert ours == bytes(TS.serialize_cdr(msg, msgs.WHEEL_RAIL_RESPONSE))
    d = msgs.decode_wheel_rail_response(ours)
    assert all(_same(getattr(d, k), a) for k, a in zip(names, arrays))


def test_decoders_accept_unequal_lengths_as_sent() -> None:
    msg = T[msgs.WHEEL_RAIL_RESPONSE](header=_rb_header(5, "x"), wheel_id=np.array([1, 2, 3], dtype=np.uint32),
                                   position=np.array([1.0]), rail_deflection=np.array([]), rail_velocity=np.zeros(2))
    d = msgs.decode_wheel_rail_response(bytes(TS.serialize_cdr(msg, msgs.WHEEL_RAIL_RESPONSE)))
    assert [a.size for a in d[2:]] == [3, 1, 0, 2]


SAMPLES = {
    "WheelLoads": (msgs.decode_wheel_loads,
                   msgs.encode_wheel_loads(3 * NS + 5, "trå", [1, 2, 3], [1.0, 2, 3], [4.0, 5, 6])),
    "SleeperResponse": (msgs.decode_sleeper_response,
                        msgs.encode_sleeper_response(7, "t", np.arange(5), *[np.ones(5)] * 5)),
    "WheelRailResponse": (msgs.decode_wheel_rail_response,
                          msgs.encode_wheel_rail_response(7, "", [4, 5], [1.0, 2.0], [0.0, 0.0], [1.0, 1.0])),
}


@pytest.mark.parametrize("name", SAMPLES)
def test_every_truncation_is_refused(name: str) -> None:
    decode, data = SAMPLES[name]
    decode(data)
    for k in range(len(data)):
        with pytest.raises(MessageError, match=name):
            decode(data[:k])


def _count_offset(data: bytes) -> int:
    slen = struct.unpack_from("<I", data, 12)[0]
    pos = 16 + slen
    return pos + (-pos & 3)


@pytest.mark.parametrize("name", SAMPLES)
@pytest.mark.parametrize("count", [6, 1000, 2**31, 2**32 - 1])
def test_absurd_sequence_lengths_are_refused(name: str, count: int) -> None:
    decode, data = SAMPLES[name]
    bad = bytearray(data)
    struct.pack_into("<I", bad, _count_offset(data), count)
    with pytest.raises(MessageError, match=r"claims \d+ elements"):
        decode(bytes(bad))


def test_malformed_headers_are_named() -> None:
    decode, data = SAMPLES["WheelLoads"]
    with pytest.raises(MessageError, match="encapsulation 00070000"):
        decode(b"\x00\x07" + data[2:])
    with pytest.raises(MessageError, match="nanosec = 1000000000"):
        decode(data[:8] + struct.pack("<I", NS) + data[12:])
    no_nul = bytearray(data)
    no_nul[16 + struct.unpack_from("<I", data, 12)[0] - 1] = ord("x")
    with pytest.raises(MessageError, match="not NUL-terminated"):
        decode(bytes(no_nul))
    bad_utf8 = bytearray(data)
    bad_utf8[16] = 0xFF
    with pytest.raises(MessageError, match="not UTF-8"):
        decode(bytes(bad_utf8))
    with pytest.raises(MessageError, match="bytes-like"):
        decode(12345)
    with pytest.raises(MessageError, match=r"frame_id of 4294967295 bytes"):
        decode(data[:12] + struct.pack("<I", 2**32 - 1) + data[16:])


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=200), st.sampled_from(sorted(SAMPLES)))
def test_random_bytes_give_a_message_error_or_a_message(blob: bytes, name: str) -> None:
    decode, _ = SAMPLES[name]
    for data in (blob, b"\x00\x01\x00\x00" + blob):
        try:
            decode(data)
        except MessageError:
            pass


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(sorted(SAMPLES)), st.data())
def test_mutated_messages_give_a_message_error_or_a_message(name: str, data: Any) -> None:
    decode, good = SAMPLES[name]
    bad = bytearray(good)
    for _ in range(data.draw(st.integers(1, 4))):
        bad[data.draw(st.integers(0, len(bad) - 1))] = data.draw(st.integers(0, 255))
    try:
        decode(bytes(bad))
    except MessageError:
        pass


def test_encoders_refuse_what_the_message_cannot_hold() -> None:
    with pytest.raises(MessageError, match="different lengths"):
        msgs.encode_wheel_loads(0, "", [1, 2], [1.0], [1.0, 2.0])
    with pytest.raises(MessageError, match="different lengths"):
        msgs.encode_sleeper_response(0, "", [1, 2], *[np.ones(2)] * 4, np.ones(3))
    for ids in ([-1], [2**32], [1.5]):
        with pytest.raises(MessageError, match="range of uint32"):
            msgs.encode_wheel_rail_response(0, "", ids, [1.0], [1.0], [1.0])
    with pytest.raises(MessageError, match="int32 sec"):
        msgs.encode_wheel_loads(2**31 * NS, "", [], [], [])
    assert msgs.decode_wheel_loads(msgs.encode_wheel_loads(-1, "", [], [], [])).stamp_ns == -1
    speeds = msgs.decode_wheel_loads(msgs.encode_wheel_loads(0, "", [3], [1.0], [2.0])).speeds
    assert math.isnan(speeds[0])  # unknown speed
