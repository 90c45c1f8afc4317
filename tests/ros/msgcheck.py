"""Field-by-field comparison of clm_msgs messages (rosbags or rclpy flavour) for the message and bag tests."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: Array fields of clm_msgs/SleeperResponse and clm_msgs/WheelRailResponse (as the .msg files define them).
SLEEPER_FIELDS = (
    "sleeper_index",
    "position",
    "soil_force",
    "rail_deflection",
    "sleeper_displacement",
    "area_displacement",
)
WHEEL_RAIL_FIELDS = ("wheel_id", "position", "rail_deflection", "rail_velocity")


def same_header(got: Any, want: Any) -> None:
    """Equal ``header`` (stamp and frame id)."""
    assert got.header.stamp.sec == want.header.stamp.sec
    assert got.header.stamp.nanosec == want.header.stamp.nanosec
    assert got.header.frame_id == want.header.frame_id


def same_wheel_loads(got: Any, want: Any) -> None:
    """Equal ``clm_msgs/WheelLoads`` (NaN speeds equal)."""
    same_header(got, want)
    assert len(got.wheels) == len(want.wheels)
    for g, w in zip(got.wheels, want.wheels, strict=True):
        assert (g.id, g.position, g.force) == (w.id, w.position, w.force)
        assert (math.isnan(g.speed) and math.isnan(w.speed)) or g.speed == w.speed


def same_arrays(got: Any, want: Any, fields: tuple[str, ...] = SLEEPER_FIELDS) -> None:
    """Equal header and array ``fields`` (values and dtypes)."""
    same_header(got, want)
    for name in fields:
        g = np.asarray(getattr(got, name))
        w = np.asarray(getattr(want, name))
        assert g.dtype == w.dtype, name
        np.testing.assert_array_equal(g, w, err_msg=name)
