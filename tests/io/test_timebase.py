"""clm_core.io.timebase: integer nanoseconds and ROS stamps."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from clm_core.io.errors import MessageError
from clm_core.io.timebase import (
    INT32_MAX,
    INT32_MIN,
    NS,
    ns_to_seconds,
    ns_to_stamp,
    seconds_to_ns,
    seconds_to_ns_array,
    stamp_ns,
    stamp_to_ns,
)

T_NS = st.integers(INT32_MIN * NS, INT32_MAX * NS + NS - 1)


@given(T_NS)
def test_stamp_round_trip(t_ns: int) -> None:
    sec, nanosec = ns_to_stamp(t_ns)
    assert 0 <= nanosec < NS and INT32_MIN <= sec <= INT32_MAX
    assert stamp_to_ns(sec, nanosec) == t_ns
    header = SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec))
    assert stamp_ns(header) == stamp_ns(header, check=True) == t_ns


def test_negative_times_follow_the_ros_convention() -> None:
    assert ns_to_stamp(-1_700_000_000) == (-2, 300_000_000)  # -1.7 s
    assert ns_to_stamp(-1) == (-1, NS - 1)


def test_out_of_range_stamps_are_refused() -> None:
    with pytest.raises(MessageError, match=r"nanosec = 1000000000: must be in \[0, 1e9\)"):
        stamp_to_ns(1, NS)
    with pytest.raises(MessageError, match="int32"):
        stamp_to_ns(2**31, 0)
    with pytest.raises(MessageError, match="int32"):
        ns_to_stamp((INT32_MAX + 1) * NS)
    # without the check the arithmetic is kept as sent (what rclpy hands over)
    assert stamp_to_ns(1, 1_500_000_000, check=False) == 2_500_000_000
    header = SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=NS))
    assert stamp_ns(header) == NS
    with pytest.raises(MessageError):
        stamp_ns(header, check=True)


def test_seconds() -> None:
    assert seconds_to_ns(1e-3) == 1_000_000
    assert seconds_to_ns(1_700_000_000.000123) == 1_700_000_000_000_123_136  # float resolution, not more
    k = np.arange(10_000)
    np.testing.assert_array_equal(seconds_to_ns_array(k * 1e-4), k * 100_000)  # every 0.1 ms step exact
    assert ns_to_seconds(1_500_000) == 1.5e-3
    for bad in (float("nan"), float("inf")):
        with pytest.raises(MessageError, match="finite"):
            seconds_to_ns(bad)
        with pytest.raises(MessageError, match="finite"):
            seconds_to_ns_array([0.0, bad])
    with pytest.raises(MessageError):
        seconds_to_ns_array([1e10])


def test_lag_figures_against_sorting_by_hand() -> None:
    """The one lag summary: median and 99th percentile by sorting (linear interpolation between order statistics),
    the maximum, in seconds; receive times against stamps give the same figures as their differences."""
    from clm_core.io.timebase import lag_figures

    rng = np.random.default_rng(7)
    lags = rng.integers(50_000, 9_000_000, size=1001)  # [ns]
    srt = np.sort(lags) / 1e9
    # 1001 values: the median is the 501st; p99 is at rank 0.99 * 1000 = 990 exactly
    f = lag_figures(lags)
    assert f.n == 1001
    assert f.median_s == pytest.approx(srt[500], rel=1e-15)
    assert f.p99_s == pytest.approx(srt[990], rel=1e-15)
    assert f.max_s == srt[-1]
    stamps = rng.integers(0, 10**18, size=lags.size)
    assert lag_figures(stamps, received_ns=stamps + lags) == f
    assert f.named("vehicle_lag") == {"vehicle_lag_median_s": f.median_s, "vehicle_lag_p99_s": f.p99_s,
                                      "vehicle_lag_max_s": f.max_s}
    empty = lag_figures(np.zeros(0, dtype=np.int64))
    assert empty.n == 0 and all(np.isnan([empty.median_s, empty.p99_s, empty.max_s]))
