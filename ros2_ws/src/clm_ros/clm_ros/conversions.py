"""rclpy flavour of the message conversions, built on :mod:`clm_core.io.messages`.

The domain side (``WheelLoads`` -> the online model's frame, a response ->
message arrays) and the rosbags flavour live in the core
(:mod:`clm_core.io.messages`); this module only builds the rclpy classes of
``clm_msgs``. Stamps are integer nanoseconds (:mod:`clm_core.io.timebase`),
so that a response echoes its input's stamp exactly.
"""

from __future__ import annotations

import array
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from clm_core.io.messages import encode_wheel_loads, sleeper_fields, wheel_fields
from clm_core.io.timebase import ns_to_stamp
from clm_core.online import ResponseFrame

__all__ = ["rclpy_header", "rclpy_responses", "rclpy_wheel_loads"]


def rclpy_header(t_ns: int, frame_id: str) -> Any:
    """``std_msgs/Header`` (rclpy) stamped ``t_ns`` [ns]."""
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header

    sec, nanosec = ns_to_stamp(t_ns)
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def rclpy_wheel_loads(t_ns: int, ids: ArrayLike, positions: ArrayLike, forces: ArrayLike,
                      speeds: ArrayLike | None = None, frame_id: str = "track") -> Any:
    """A ``clm_msgs/WheelLoads`` (rclpy): ids, positions [m], forces [N] (downwards), speeds [m/s] (default NaN).

    Serialized by the core's codec (:func:`clm_core.io.messages.encode_wheel_loads`: its checks, one wheel
    per entry) and read back as the rclpy class.

    Raises
    ------
    clm_core.io.errors.MessageError
        Arrays of different lengths, ids outside uint32, a stamp outside int32 seconds.
    """
    from clm_msgs.msg import WheelLoads
    from rclpy.serialization import deserialize_message

    return deserialize_message(encode_wheel_loads(t_ns, frame_id, ids, positions, forces, speeds), WheelLoads)


_TYPECODE = {np.dtype(np.float64): "d", np.dtype(np.int64): "q", np.dtype(np.uint32): "I"}


def _array(v: np.ndarray) -> array.array[Any]:
    """numpy -> array.array of the matching type code: rclpy takes it without per-element checks."""
    a = array.array(_TYPECODE[v.dtype])
    a.frombytes(np.ascontiguousarray(v).tobytes())
    return a


def rclpy_responses(resp: ResponseFrame, t_ns: int, frame_id: str = "track") -> tuple[Any, Any]:
    """(SleeperResponse, WheelRailResponse) rclpy messages for a response, stamped ``t_ns`` [ns].

    Arrays go in as ``array.array`` (a memory copy): lists would be checked
    element by element by the generated setters (~0.1 ms per message).
    """
    from clm_msgs.msg import SleeperResponse, WheelRailResponse

    s = SleeperResponse(header=rclpy_header(t_ns, frame_id))
    for k, v in sleeper_fields(resp).items():
        setattr(s, k, _array(v))
    w = WheelRailResponse(header=rclpy_header(t_ns, frame_id))
    for k, v in wheel_fields(resp).items():
        setattr(w, k, _array(v))
    return s, w
