"""Time base of the suite: integer nanoseconds, and ROS stamps.

Time is carried as integer nanoseconds wherever it crosses an edge (message
stamps, bag log times), so that a response echoes its input's stamp exactly
and a 1 ms frame is 1 000 000 ns, not 0.001 s rounded. A ROS stamp
(``builtin_interfaces/Time``) is ``sec`` (int32) plus ``nanosec`` (uint32,
valid in [0, 1e9)); negative times have a negative ``sec`` and a positive
``nanosec`` (-1.7 s is ``{sec: -2, nanosec: 300000000}``).

This module is the only definition of :data:`NS`.
"""

from __future__ import annotations

import math
from typing import Any, Final, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.io.errors import MessageError

__all__ = [
    "INT32_MAX",
    "INT32_MIN",
    "NS",
    "LagFigures",
    "lag_figures",
    "ns_to_seconds",
    "ns_to_stamp",
    "seconds_to_ns",
    "seconds_to_ns_array",
    "stamp_ns",
    "stamp_to_ns",
]

#: Nanoseconds per second.
NS: Final = 1_000_000_000
#: Range of ``builtin_interfaces/Time.sec`` (int32) [s].
INT32_MIN: Final = -(2**31)
INT32_MAX: Final = 2**31 - 1


def stamp_to_ns(sec: int, nanosec: int, *, check: bool = True) -> int:
    """Integer nanoseconds of a ROS stamp.

    Parameters
    ----------
    sec : int
        Seconds [s] (``builtin_interfaces/Time.sec``, int32).
    nanosec : int
        Nanoseconds [ns] to add (``Time.nanosec``), valid in [0, 1e9).
    check : bool
        Refuse a stamp outside the ``Time`` definition (``nanosec`` >= 1e9 or
        negative, ``sec`` outside int32); False: plain arithmetic.

    Returns
    -------
    int
        ``sec * NS + nanosec`` [ns].

    Raises
    ------
    MessageError
        With ``check``: ``nanosec`` not in [0, 1e9) or ``sec`` not an int32.
    """
    if check:
        if not 0 <= nanosec < NS:
            raise MessageError(f"stamp nanosec = {nanosec}: must be in [0, 1e9) (builtin_interfaces/Time)")
        if not INT32_MIN <= sec <= INT32_MAX:
            raise MessageError(f"stamp sec = {sec}: must be an int32 (builtin_interfaces/Time)")
    return int(sec) * NS + int(nanosec)


def ns_to_stamp(t_ns: int) -> tuple[int, int]:
    """ROS stamp ``(sec, nanosec)`` of a time in integer nanoseconds.

    Parameters
    ----------
    t_ns : int
        Time [ns]; negative times give a negative ``sec`` and ``nanosec`` in [0, 1e9).

    Returns
    -------
    (int, int)
        ``sec`` [s] and ``nanosec`` [ns], ``t_ns == sec * NS + nanosec``.

    Raises
    ------
    MessageError
        ``sec`` does not fit the int32 of ``builtin_interfaces/Time``.
    """
    sec, nanosec = divmod(int(t_ns), NS)
    if not INT32_MIN <= sec <= INT32_MAX:
        raise MessageError(f"time {t_ns} ns: {sec} s does not fit the int32 sec of builtin_interfaces/Time")
    return sec, nanosec


def stamp_ns(header: Any, *, check: bool = False) -> int:
    """Integer nanoseconds of a message header's stamp.

    Parameters
    ----------
    header : object
        Anything with ``stamp.sec`` and ``stamp.nanosec`` (a ``std_msgs/Header``
        of rclpy or rosbags, or a ``builtin_interfaces/Time`` wrapped in one).
    check : bool
        As in :func:`stamp_to_ns`; off by default (the value is taken as sent).

    Returns
    -------
    int
        The stamp [ns].
    """
    st = header.stamp
    return stamp_to_ns(int(st.sec), int(st.nanosec), check=check)


def seconds_to_ns(t: float) -> int:
    """Seconds to the nearest integer nanosecond.

    Parameters
    ----------
    t : float
        Time [s]; must be finite.

    Returns
    -------
    int
        ``round(t * 1e9)`` [ns].

    Raises
    ------
    MessageError
        ``t`` is not finite.
    """
    x = float(t)
    if not np.isfinite(x):
        raise MessageError(f"time t = {x} s: must be finite")
    return int(round(x * NS))


def seconds_to_ns_array(t: ArrayLike) -> NDArray[np.int64]:
    """Seconds to the nearest integer nanoseconds, element-wise.

    Parameters
    ----------
    t : array_like of float
        Times [s]; must be finite and within +-9.2e9 s (int64 ns).

    Returns
    -------
    ndarray of int64
        ``round(t * 1e9)`` [ns], the shape of ``t``.

    Raises
    ------
    MessageError
        A time is not finite or overflows int64 nanoseconds.
    """
    x = np.asarray(t, dtype=np.float64)
    if not np.all(np.isfinite(x)) or (x.size and float(np.max(np.abs(x))) >= 9.2e9):
        raise MessageError("times [s]: must be finite and within +-9.2e9 s to fit int64 nanoseconds")
    return np.round(x * NS).astype(np.int64)


def ns_to_seconds(t_ns: int) -> float:
    """Integer nanoseconds to float seconds (for display and plotting).

    Parameters
    ----------
    t_ns : int
        Time [ns].

    Returns
    -------
    float
        ``t_ns / 1e9`` [s] (float: microsecond resolution is lost beyond ~100 days).
    """
    return int(t_ns) / NS


class LagFigures(NamedTuple):
    """Median, 99th percentile and maximum of a set of lags [s] (NaN for none): the suite's one lag summary.

    Attributes
    ----------
    n : int
        Lags summarised.
    median_s, p99_s, max_s : float
        Median, 99th percentile (linear interpolation, ``numpy.percentile``)
        and largest lag [s].
    """

    n: int
    median_s: float
    p99_s: float
    max_s: float

    def named(self, prefix: str = "lag") -> dict[str, float]:
        """The figures as ``{prefix}_median_s``, ``{prefix}_p99_s``, ``{prefix}_max_s`` (``summary.json`` keys)."""
        return {f"{prefix}_median_s": self.median_s, f"{prefix}_p99_s": self.p99_s, f"{prefix}_max_s": self.max_s}


def lag_figures(lags_ns: ArrayLike, received_ns: ArrayLike | None = None) -> LagFigures:
    """The lag figures of lags in integer nanoseconds, or of receive times against stamps.

    Parameters
    ----------
    lags_ns : array_like of int
        Lags [ns]; with ``received_ns``: the stamps [ns] of the messages.
    received_ns : array_like of int, optional
        When each message (or its answer) was received [ns], on the stamps'
        clock: the lags are ``received_ns - lags_ns``.

    Returns
    -------
    LagFigures
        In seconds; NaN figures when there are no lags.

    Examples
    --------
    >>> lag_figures([1_000_000, 2_000_000, 4_000_000])
    LagFigures(n=3, median_s=0.002, p99_s=0.00396, max_s=0.004)
    >>> lag_figures([10, 20], received_ns=[1_000_010, 3_000_020]).named()
    {'lag_median_s': 0.002, 'lag_p99_s': 0.00298, 'lag_max_s': 0.003}
    >>> lag_figures([]).n, math.isnan(lag_figures([]).median_s)
    (0, True)
    """
    a = np.asarray(lags_ns, dtype=np.int64).ravel()
    if received_ns is not None:
        a = np.asarray(received_ns, dtype=np.int64).ravel() - a
    if not a.size:
        return LagFigures(0, math.nan, math.nan, math.nan)
    s = a / NS
    return LagFigures(int(s.size), float(np.median(s)), float(np.percentile(s, 99)), float(s.max()))
