"""A ``clm simulate`` time history as a bag of the suite's messages (``clm simulate --bag``).

Written with the bottom layer's one bag writer (:class:`clm_core.io.bags.BagWriter`)
and CDR codec (:mod:`clm_core.io.messages`), rosbags only, no middleware.
"""

from __future__ import annotations

import os

import numpy as np

from clm_core.io.bags import BagWriter
from clm_core.io.messages import (
    SLEEPER_RESPONSE,
    WHEEL_LOADS,
    WHEEL_RAIL_RESPONSE,
    encode_sleeper_response,
    encode_wheel_loads,
    encode_wheel_rail_response,
)
from clm_core.io.timebase import seconds_to_ns_array
from clm_core.outputs.history import TimeHistory

__all__ = ["write_history_bag"]


def write_history_bag(history: TimeHistory, path: str | os.PathLike[str], storage: str = "mcap",
                      frame_id: str = "track") -> int:
    """Write a ``clm simulate`` time history as a bag of the suite's messages.

    Topics ``/wheel_loads`` (``clm_msgs/WheelLoads``), ``/sleeper_response``
    (``clm_msgs/SleeperResponse``) and ``/wheel_rail_response``
    (``clm_msgs/WheelRailResponse``), one message each per output instant,
    stamped (and logged) at the simulation time. Absent wheels (NaN
    position) are left out; speeds are NaN (unknown).

    Parameters
    ----------
    history : TimeHistory
        ``t`` [s], wheel positions [m] and forces [N], sleeper fields of the
        window (``first_sleeper``, ``spacing`` [m], soil force [N],
        displacements [m]), rail deflection [m] and velocity [m/s] under the wheels.
    path : path-like
        New bag directory (must not exist).
    storage : {'mcap', 'sqlite3'}
    frame_id : str
        ``header.frame_id`` of every message.

    Returns
    -------
    int
        Messages per topic.
    """
    stamps = seconds_to_ns_array(history.t).tolist()
    n_s = history.soil_force.shape[1]
    with BagWriter(path, storage) as w:
        c_wl = w.add_topic("/wheel_loads", WHEEL_LOADS)
        c_s = w.add_topic("/sleeper_response", SLEEPER_RESPONSE)
        c_w = w.add_topic("/wheel_rail_response", WHEEL_RAIL_RESPONSE)
        for k, t_ns in enumerate(stamps):
            on = np.isfinite(history.wheel_position[k])
            ids = np.nonzero(on)[0].astype(np.uint32)
            pos = history.wheel_position[k, on]
            w.write(c_wl, t_ns, encode_wheel_loads(t_ns, frame_id, ids, pos, history.wheel_force[k, on]))
            gidx = history.first_sleeper[k] + np.arange(n_s, dtype=np.int64)
            w.write(c_s, t_ns, encode_sleeper_response(
                t_ns, frame_id, gidx, gidx * history.spacing, history.soil_force[k], history.rail_deflection[k],
                history.sleeper_displacement[k], history.area_displacement[k]))
            w.write(c_w, t_ns, encode_wheel_rail_response(
                t_ns, frame_id, ids, pos, history.wheel_deflection[k, on], history.wheel_velocity[k, on]))
    return len(stamps)
