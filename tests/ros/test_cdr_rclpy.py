"""The numpy CDR codec (clm_core.io.messages) against rclpy's own serializer, and the rclpy conversions.

Bytes from our encoders deserialize in rclpy to the same fields; bytes from
rclpy's ``serialize_message`` decode with ours to the same arrays. rclpy may
append uninitialised bytes after a message with an empty sequence (it
returns the RMW's estimated size), so content is compared, never bytes.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.ros

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clm_msgs.msg import SleeperResponse, WheelLoads, WheelRailResponse  # noqa: E402
from clm_ros.conversions import rclpy_header, rclpy_responses, rclpy_wheel_loads  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

from clm_core.io import messages as msgs  # noqa: E402
from clm_core.io.timebase import NS, stamp_ns  # noqa: E402

frame_ids = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=10)
floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
stamps = st.integers(-(2**31) * NS, (2**31 - 1) * NS + NS - 1)


def _arr(draw: Any, n: int) -> np.ndarray:
    return np.array(draw(st.lists(floats, min_size=n, max_size=n)), dtype=np.float64)


def _eq(a: Any, b: Any) -> None:
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@settings(max_examples=100, deadline=None)
@given(stamps, frame_ids, st.integers(0, 8), st.data())
def test_wheel_loads_both_ways(t_ns: int, frame_id: str, n: int, data: Any) -> None:
    ids = np.array(data.draw(st.lists(st.integers(0, 2**32 - 1), min_size=n, max_size=n)), dtype=np.uint32)
    pos, force, speed = (_arr(data.draw, n) for _ in range(3))
    ours = msgs.encode_wheel_loads(t_ns, frame_id, ids, pos, force, speed)
    msg = deserialize_message(ours, WheelLoads)
    assert stamp_ns(msg.header) == t_ns and msg.header.frame_id == frame_id
    _eq([w.id for w in msg.wheels], ids)
    _eq([w.position for w in msg.wheels], pos)
    _eq([w.force for w in msg.wheels], force)
    _eq([w.speed for w in msg.wheels], speed)
    d = msgs.decode_wheel_loads(serialize_message(msg))
    assert (d.stamp_ns, d.frame_id) == (t_ns, frame_id)
    _eq(d.ids, ids)
    _eq(d.positions, pos)
    _eq(d.forces, force)
    _eq(d.speeds, speed)


@settings(max_examples=100, deadline=None)
@given(stamps, frame_ids, st.integers(0, 70), st.data())
def test_responses_both_ways(t_ns: int, frame_id: str, n: int, data: Any) -> None:
    idx = np.array(data.draw(st.lists(st.integers(-(2**63), 2**63 - 1), min_size=n, max_size=n)), dtype=np.int64)
    s_arrays = [idx, *(_arr(data.draw, n) for _ in range(5))]
    msg = deserialize_message(msgs.encode_sleeper_response(t_ns, frame_id, *s_arrays), SleeperResponse)
    assert stamp_ns(msg.header) == t_ns and msg.header.frame_id == frame_id
    for (name, _), a in zip(msgs._SLEEPER_SEQ, s_arrays):
        _eq(getattr(msg, name), a)
    back = msgs.decode_sleeper_response(serialize_message(msg))
    for (name, _), a in zip(msgs._SLEEPER_SEQ, s_arrays):
        _eq(getattr(back, name), a)
    m = min(n, 6)
    w_arrays = [idx[:m].astype(np.uint64).astype(np.uint32), *(a[:m] for a in s_arrays[1:4])]
    wmsg = deserialize_message(msgs.encode_wheel_rail_response(t_ns, frame_id, *w_arrays), WheelRailResponse)
    for (name, _), a in zip(msgs._WHEEL_RAIL_SEQ, w_arrays):
        _eq(getattr(wmsg, name), a)
    wback = msgs.decode_wheel_rail_response(serialize_message(wmsg))
    assert wback.stamp_ns == t_ns
    for (name, _), a in zip(msgs._WHEEL_RAIL_SEQ, w_arrays):
        _eq(getattr(wback, name), a)


def test_empty_sequences_from_rclpy_decode_despite_trailing_bytes() -> None:
    """The pitfall of ros2-from-pip.md: rclpy pads messages with empty sequences; our decoder ignores it."""
    raw = serialize_message(WheelRailResponse(header=rclpy_header(5 * NS + 1, "ü")))
    d = msgs.decode_wheel_rail_response(raw)
    assert d.stamp_ns == 5 * NS + 1 and d.frame_id == "ü" and all(a.size == 0 for a in d[2:])
    assert msgs.decode_wheel_loads(serialize_message(WheelLoads())).ids.size == 0


def test_rclpy_conversions_round_trip() -> None:
    from clm_core.online import OnlineTrackModel, frame_from_msg
    from clm_core.params import load_model

    t_ns = 1_795_311_577 * NS + 12_847_207
    msg = rclpy_wheel_loads(t_ns, [0, 1], [6.0, 3.5], [8e4, 9e4], frame_id="track")
    assert stamp_ns(msg.header) == t_ns and math.isnan(msg.wheels[0].speed)
    frame = frame_from_msg(deserialize_message(serialize_message(msg), WheelLoads))
    assert frame.stamp_ns == t_ns and list(frame.positions) == [6.0, 3.5]
    model = OnlineTrackModel(load_model("mevergnies", "mevergnies", "clm"), dt=1e-4, n_sleepers=21)
    resp = model.process(frame)
    s, w = rclpy_responses(resp, t_ns, "track")
    ds = msgs.decode_sleeper_response(serialize_message(s))
    dw = msgs.decode_wheel_rail_response(serialize_message(w))
    assert ds.stamp_ns == dw.stamp_ns == t_ns
    for k, v in msgs.sleeper_fields(resp).items():
        _eq(getattr(ds, k), v)
    for k, v in msgs.wheel_fields(resp).items():
        _eq(getattr(dw, k), v)
    # the codec's bytes and rclpy's message carry the same content
    ours = deserialize_message(msgs.encode_sleeper_response(t_ns, "track", *msgs.sleeper_fields(resp).values()),
                               SleeperResponse)
    _eq(ours.soil_force, s.soil_force)
