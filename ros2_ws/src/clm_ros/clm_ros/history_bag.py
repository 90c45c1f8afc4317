"""Write a ``clm simulate`` time history as a rosbag2 bag (the suite's own messages).

Topics: ``/wheel_loads`` (``clm_msgs/WheelLoads``), ``/sleeper_response``
(``clm_msgs/SleeperResponse``) and ``/wheel_rail_response``
(``clm_msgs/WheelRailResponse``), one message each per output instant,
stamped with the simulation time. Absent wheels (NaN position) are left out
of the messages. Only ``rosbags`` is needed (no rclpy).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer

from clm_core.io.history import TimeHistory
from clm_ros.errors import ClmRosError
from clm_ros.msg_types import typestore
from clm_ros.replay import storage_plugin

NS = 1_000_000_000


def write_history_bag(history: TimeHistory, path: str | Path, storage: str = "mcap", frame_id: str = "track") -> int:
    """Write ``history`` to the bag directory ``path`` (must not exist); return the messages per topic."""
    out = Path(path)
    if out.exists():
        raise ClmRosError(f"output bag {str(out)!r} exists; choose a new path")
    ts = typestore()
    T = ts.types
    N = history.soil_force.shape[1]
    with Writer(out, version=8, storage_plugin=storage_plugin(storage)) as w:
        c_wl = w.add_connection("/wheel_loads", "clm_msgs/msg/WheelLoads", typestore=ts)
        c_s = w.add_connection("/sleeper_response", "clm_msgs/msg/SleeperResponse", typestore=ts)
        c_w = w.add_connection("/wheel_rail_response", "clm_msgs/msg/WheelRailResponse", typestore=ts)
        for k, t in enumerate(history.t):
            t_ns = int(round(float(t) * NS))

            def header(t_ns: int = t_ns) -> object:
                return T["std_msgs/msg/Header"](
                    stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // NS, nanosec=t_ns % NS), frame_id=frame_id
                )

            on = np.isfinite(history.wheel_position[k])
            ids = np.nonzero(on)[0].astype(np.uint32)
            wl = T["clm_msgs/msg/WheelLoads"](
                header=header(),
                wheels=[
                    T["clm_msgs/msg/WheelLoad"](
                        id=int(i),
                        position=float(history.wheel_position[k, i]),
                        force=float(history.wheel_force[k, i]),
                        speed=float("nan"),
                    )
                    for i in ids
                ],
            )
            gidx = history.first_sleeper[k] + np.arange(N, dtype=np.int64)
            s = T["clm_msgs/msg/SleeperResponse"](
                header=header(),
                sleeper_index=gidx,
                position=gidx * history.spacing,
                soil_force=np.ascontiguousarray(history.soil_force[k]),
                rail_deflection=np.ascontiguousarray(history.rail_deflection[k]),
                sleeper_displacement=np.ascontiguousarray(history.sleeper_displacement[k]),
                area_displacement=np.ascontiguousarray(history.area_displacement[k]),
            )
            wr = T["clm_msgs/msg/WheelRailResponse"](
                header=header(),
                wheel_id=ids,
                position=np.ascontiguousarray(history.wheel_position[k, on]),
                rail_deflection=np.ascontiguousarray(history.wheel_deflection[k, on]),
                rail_velocity=np.ascontiguousarray(history.wheel_velocity[k, on]),
            )
            w.write(c_wl, t_ns, ts.serialize_cdr(wl, "clm_msgs/msg/WheelLoads"))
            w.write(c_s, t_ns, ts.serialize_cdr(s, "clm_msgs/msg/SleeperResponse"))
            w.write(c_w, t_ns, ts.serialize_cdr(wr, "clm_msgs/msg/WheelRailResponse"))
    return len(history.t)
