"""Messages <-> clm_core data, in one place (round-trip tested).

Works with both message flavours: rclpy classes (``clm_msgs.msg``) and
rosbags dataclasses (from :func:`clm_ros.msg_types.typestore`); both have the
same field names. Stamps are carried as integer nanoseconds so that a
response echoes its input's stamp exactly.
"""

from __future__ import annotations

import array
from typing import Any

import numpy as np

from clm_core.online import ResponseFrame, WheelFrame

NS = 1_000_000_000


def stamp_ns(header: Any) -> int:
    """Header stamp as integer nanoseconds."""
    return int(header.stamp.sec) * NS + int(header.stamp.nanosec)


def frame_from_msg(msg: Any) -> WheelFrame:
    """``clm_msgs/WheelLoads`` (rclpy or rosbags) -> :class:`WheelFrame` (stamp in s)."""
    wheels = list(msg.wheels)
    return WheelFrame.of(
        stamp_ns(msg.header) / NS,
        [w.id for w in wheels],
        [w.position for w in wheels],
        [w.force for w in wheels],
        [w.speed for w in wheels],
    )


def sleeper_fields(resp: ResponseFrame) -> dict[str, np.ndarray]:
    """Array fields of a ``clm_msgs/SleeperResponse`` for a response."""
    s = resp.sleepers
    return {
        "sleeper_index": np.asarray(s.sleeper_index, dtype=np.int64),
        "position": np.asarray(s.sleeper_x, dtype=np.float64),
        "soil_force": np.asarray(s.soil_force, dtype=np.float64),
        "rail_deflection": np.asarray(s.rail_deflection, dtype=np.float64),
        "sleeper_displacement": np.asarray(s.sleeper_displacement, dtype=np.float64),
        "area_displacement": np.asarray(s.area_displacement, dtype=np.float64),
    }


def wheel_fields(resp: ResponseFrame) -> dict[str, np.ndarray]:
    """Array fields of a ``clm_msgs/WheelRailResponse`` for a response."""
    return {
        "wheel_id": np.asarray(resp.wheel_ids, dtype=np.uint32),
        "position": np.asarray(resp.wheel_positions, dtype=np.float64),
        "rail_deflection": np.asarray(resp.wheel_deflection, dtype=np.float64),
        "rail_velocity": np.asarray(resp.wheel_velocity, dtype=np.float64),
    }


# ---------------------------------------------------------------- rclpy flavour


def rclpy_header(t_ns: int, frame_id: str) -> Any:
    """std_msgs/Header (rclpy) with the given stamp."""
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header

    return Header(stamp=Time(sec=t_ns // NS, nanosec=t_ns % NS), frame_id=frame_id)


def rclpy_wheel_loads(
    t_ns: int, ids: Any, positions: Any, forces: Any, speeds: Any = None, frame_id: str = "track"
) -> Any:
    """Build a ``clm_msgs/WheelLoads`` (rclpy)."""
    from clm_msgs.msg import WheelLoad, WheelLoads

    sp = [float("nan")] * len(ids) if speeds is None else speeds
    return WheelLoads(
        header=rclpy_header(t_ns, frame_id),
        wheels=[
            WheelLoad(id=int(i), position=float(p), force=float(f), speed=float(v))
            for i, p, f, v in zip(ids, positions, forces, sp)
        ],
    )


_TYPECODE = {np.dtype(np.float64): "d", np.dtype(np.int64): "q", np.dtype(np.uint32): "I"}


def _array(v: np.ndarray) -> array.array[Any]:
    """numpy -> array.array of the matching type code: rclpy takes it without per-element checks."""
    a = array.array(_TYPECODE[v.dtype])
    a.frombytes(np.ascontiguousarray(v).tobytes())
    return a


def rclpy_responses(resp: ResponseFrame, t_ns: int, frame_id: str = "track") -> tuple[Any, Any]:
    """(SleeperResponse, WheelRailResponse) rclpy messages for a response, stamped ``t_ns``.

    Arrays go in as ``array.array`` (a memory copy): lists would be checked
    element by element by the generated setters (~0.1 ms per message).
    """
    from clm_msgs.msg import SleeperResponse, WheelRailResponse

    h = rclpy_header(t_ns, frame_id)
    s = SleeperResponse(header=h)
    for k, v in sleeper_fields(resp).items():
        setattr(s, k, _array(v))
    w = WheelRailResponse(header=rclpy_header(t_ns, frame_id))
    for k, v in wheel_fields(resp).items():
        setattr(w, k, _array(v))
    return s, w


# ---------------------------------------------------------------- rosbags flavour


def _rb_header(ts: Any, t_ns: int, frame_id: str) -> Any:
    Time = ts.types["builtin_interfaces/msg/Time"]
    Header = ts.types["std_msgs/msg/Header"]
    return Header(stamp=Time(sec=t_ns // NS, nanosec=t_ns % NS), frame_id=frame_id)


def rosbags_wheel_loads(
    ts: Any, t_ns: int, ids: Any, positions: Any, forces: Any, speeds: Any = None, frame_id: str = "track"
) -> Any:
    """Build a ``clm_msgs/WheelLoads`` rosbags dataclass."""
    WheelLoad = ts.types["clm_msgs/msg/WheelLoad"]
    WheelLoads = ts.types["clm_msgs/msg/WheelLoads"]
    sp = [float("nan")] * len(ids) if speeds is None else speeds
    return WheelLoads(
        header=_rb_header(ts, t_ns, frame_id),
        wheels=[
            WheelLoad(id=int(i), position=float(p), force=float(f), speed=float(v))
            for i, p, f, v in zip(ids, positions, forces, sp)
        ],
    )


def rosbags_responses(ts: Any, resp: ResponseFrame, t_ns: int, frame_id: str = "track") -> tuple[Any, Any]:
    """(SleeperResponse, WheelRailResponse) rosbags dataclasses for a response."""
    S = ts.types["clm_msgs/msg/SleeperResponse"]
    W = ts.types["clm_msgs/msg/WheelRailResponse"]
    return (
        S(header=_rb_header(ts, t_ns, frame_id), **sleeper_fields(resp)),
        W(header=_rb_header(ts, t_ns, frame_id), **wheel_fields(resp)),
    )
