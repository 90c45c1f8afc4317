"""What goes in and out of the online model: frames, responses, refusals and counters.

:class:`WheelFrame` is one ``clm_msgs/WheelLoads`` message (integer
nanosecond stamp), :class:`ResponseFrame` the answer to one accepted frame
(flat arrays, ready for the CDR encoders of :mod:`clm_core.io.messages`),
:class:`Rejected` the refusal of one frame with its :class:`Reason`, and
:class:`OnlineStats` the model's counters. SI units; forces and
displacements positive downwards.
"""

from __future__ import annotations

import operator
from collections import Counter
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike

from clm_core.arrays import Array, IntArray
from clm_core.errors import InputError
from clm_core.solver.records import SleeperFields


class Reason(str, Enum):
    """Why a wheel-load frame was refused (the rules: :mod:`clm_core.online`)."""

    MALFORMED = "malformed"
    SIZE_MISMATCH = "size_mismatch"
    TOO_MANY_WHEELS = "too_many_wheels"
    EMPTY = "empty"
    NON_FINITE = "non_finite"
    TENSILE = "tensile"
    IMPLAUSIBLE_FORCE = "implausible_force"
    IMPLAUSIBLE_POSITION = "implausible_position"
    IMPLAUSIBLE_SPEED = "implausible_speed"
    DUPLICATE_ID = "duplicate_id"
    UNKNOWN_ID = "unknown_id"
    OUTSIDE_WINDOW = "outside_window"
    STAMP_NOT_INCREASING = "stamp_not_increasing"
    STAMP_JUMP = "stamp_jump"
    IMPLAUSIBLE_RESPONSE = "implausible_response"
    SECOND_SOURCE = "second_source"  # a second publisher on the topic (told apart at the edge, clm_ros.sources)


class Rejected(InputError):
    """A frame was refused; ``reason`` says which rule, the message the values (bounded in length)."""

    def __init__(self, reason: Reason, message: str) -> None:
        super().__init__(f"{reason.value}: {message}")
        self.reason = reason


@dataclass(frozen=True)
class WheelFrame:
    """Stamped wheel loads (one ``clm_msgs/WheelLoads`` message).

    Attributes
    ----------
    stamp_ns : int
        Stamp [ns] (simulation or ROS time), integer nanoseconds.
    ids : (n,) int64 array
        Wheel ids.
    positions : (n,) array
        Positions along the track [m].
    forces : (n,) array
        Vertical forces [N], positive downwards (pressing on the rail).
    speeds : (n,) array or None
        Wheel speeds [m/s] (NaN if unknown).
    frame_id : str
        ``header.frame_id`` (the track line the positions refer to).
    """

    stamp_ns: int
    ids: IntArray
    positions: Array
    forces: Array
    speeds: Array | None = None
    frame_id: str = ""

    @classmethod
    def of(cls, stamp_ns: int, ids: ArrayLike, positions: ArrayLike, forces: ArrayLike,
           speeds: ArrayLike | None = None, frame_id: str = "") -> WheelFrame:
        """Build from sequences (no value checks: that is :meth:`OnlineTrackModel.process`'s job).

        Raises
        ------
        TypeError
            ``stamp_ns`` is not an integer (seconds as a float are refused:
            time is integer nanoseconds).
        """
        return cls(
            operator.index(stamp_ns),
            np.asarray(ids, dtype=np.int64).ravel(),
            np.asarray(positions, dtype=float).ravel(),
            np.asarray(forces, dtype=float).ravel(),
            None if speeds is None else np.asarray(speeds, dtype=float).ravel(),
            frame_id,
        )


@dataclass(frozen=True)
class ResponseFrame(SleeperFields):
    """The response to one accepted frame: flat arrays, ready for the message encoders.

    The sleeper fields of :class:`clm_core.solver.records.SleeperFields`
    (``sleeper_index``, ``sleeper_x``: read-only, may be shared between
    responses; ``soil_force`` [N], ``rail_deflection``,
    ``sleeper_displacement``, ``area_displacement`` [m]), and:

    Attributes
    ----------
    stamp_ns : int
        The input frame's stamp [ns].
    wheel_ids : (n,) int64 array
        The input frame's wheel ids, in its order.
    wheel_positions : (n,) array
        Their positions [m].
    wheel_deflection, wheel_velocity : (n,) arrays
        Rail deflection [m] and velocity [m/s] under each wheel, at its
        position, at the response step.
    resynced : bool
        True when this frame (re)started the state (first frame, or a new
        stream confirmed).
    """

    stamp_ns: int
    wheel_ids: IntArray
    wheel_positions: Array
    wheel_deflection: Array
    wheel_velocity: Array
    resynced: bool

    @classmethod
    def _of(cls, stamp_ns: int, sleeper_index: IntArray, sleeper_x: Array, soil_force: Array, rail_deflection: Array,
            sleeper_displacement: Array, area_displacement: Array, wheel_ids: IntArray, wheel_positions: Array,
            wheel_deflection: Array, wheel_velocity: Array, resynced: bool) -> ResponseFrame:
        """The same record as the constructor, built without its per-field ``object.__setattr__`` (0.6 against 1.5
        us: one per answered frame)."""
        r = object.__new__(cls)
        r.__dict__.update(stamp_ns=stamp_ns, sleeper_index=sleeper_index, sleeper_x=sleeper_x, soil_force=soil_force,
                          rail_deflection=rail_deflection, sleeper_displacement=sleeper_displacement,
                          area_displacement=area_displacement, wheel_ids=wheel_ids, wheel_positions=wheel_positions,
                          wheel_deflection=wheel_deflection, wheel_velocity=wheel_velocity, resynced=resynced)
        return r


@dataclass
class OnlineStats:
    """Counters of an :class:`~clm_core.online.OnlineTrackModel`, monotonic.

    Hand them to a rebuilt model (``OnlineTrackModel(..., stats=old.stats)``,
    e.g. after a parameter update) so that they count over a node's life.

    Attributes
    ----------
    accepted : int
        Frames accepted (each answered).
    rejected : Counter of str
        Frames refused, per :class:`Reason` value.
    resyncs : int
        Accepted frames that (re)started the state.
    steps : int
        Time steps integrated.
    simulated_ns : int
        Simulated time integrated [ns] (steps times their ``dt``; the jump of
        a resync is not integrated and not counted).
    """

    accepted: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    resyncs: int = 0
    steps: int = 0
    simulated_ns: int = 0

    @property
    def rejected_total(self) -> int:
        """All refused frames."""
        return sum(self.rejected.values())


__all__ = ["OnlineStats", "Reason", "Rejected", "ResponseFrame", "WheelFrame"]
