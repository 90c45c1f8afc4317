"""Result records of the streaming solver: the state at one instant, blocks of steps, responses to frames.

:class:`Snapshot` is what :meth:`clm_core.solver.TrackSimulator.snapshot`
returns; :class:`Block` is what :meth:`clm_core.solver.TrackSimulator.advance`
hands to its callback, one per stretch of steps with the window in one
position; :class:`FrameResponses` is what
:meth:`clm_core.solver.TrackSimulator.advance_frames` returns, one row per
frame. All are frozen and hold fresh arrays (the receiver may keep them).
SI units, displacements and forces positive downwards.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from clm_core.arrays import Array, IntArray


@dataclass(frozen=True)
class SleeperFields:
    """The window's sleepers at one instant (positive downwards): what a snapshot and an online response share.

    Attributes
    ----------
    sleeper_index : (N,) int64 array
        Global sleeper indices of the window.
    sleeper_x : (N,) array
        Sleeper positions along the line [m].
    soil_force : (N,) array
        Soil reaction force under every sleeper [N]: the ballast force on the
        contact area, k_b (z_s - x_f) + d_b (v_s - v_f), compression positive.
    rail_deflection : (N,) array
        Rail deflection above every sleeper [m].
    sleeper_displacement : (N,) array
        Sleeper displacement [m].
    area_displacement : (N,) array
        Soil contact-area displacement [m] (zeros for a rigid soil).
    """

    sleeper_index: IntArray
    sleeper_x: Array
    soil_force: Array
    rail_deflection: Array
    sleeper_displacement: Array
    area_displacement: Array


@dataclass(frozen=True)
class Snapshot(SleeperFields):
    """State of the simulated track at one instant (copies; positive downwards).

    The sleeper fields of :class:`SleeperFields`, and:

    Attributes
    ----------
    t : float
        Time [s].
    wheel_positions : (n_w,) array
        Wheel positions [m] (NaN: wheel not on the track).
    wheel_forces : (n_w,) array
        Wheel forces [N] applied at ``t``.
    wheel_deflection : (n_w,) array
        Rail deflection under each wheel [m] (NaN for an absent wheel).
    wheel_velocity : (n_w,) array
        Rail velocity under each wheel [m/s] (material velocity).
    """

    t: float
    wheel_positions: Array
    wheel_forces: Array
    wheel_deflection: Array
    wheel_velocity: Array


@dataclass(frozen=True)
class Block:
    """Outputs of consecutive steps with the window in one position.

    Emitted by :meth:`clm_core.solver.TrackSimulator.advance` to its ``callback``; the arrays
    are fresh (the callback may keep them). ``k`` output instants, ``N``
    sleepers, ``W`` wheels.

    Attributes
    ----------
    first_sleeper : int
        Global index of column 0 of the sleeper arrays.
    sleeper_x : (N,) array
        Sleeper positions [m].
    t : (k,) array
        Output times [s].
    soil_force, rail_deflection, sleeper_displacement, area_displacement : (k, N) arrays
        As in :class:`Snapshot` [N], [m].
    wheel_positions, wheel_forces, wheel_deflection, wheel_velocity : (k, W) arrays
        As in :class:`Snapshot` [m], [N], [m], [m/s].
    peak_soil_force, peak_rail_deflection : (N,) arrays
        Running maxima over every step (not only output steps) since the
        sleeper entered the window or since
        :meth:`clm_core.solver.TrackSimulator.reset_peaks`,
        up to the end of the block [N], [m]. The block emitted just before a
        window shift holds the final values of the sleepers being dropped.
    peak_wheel_deflection : (W,) array
        Largest rail deflection under each wheel over every step of the block
        [m] (-inf for a wheel absent throughout).
    """

    first_sleeper: int
    sleeper_x: Array
    t: Array
    soil_force: Array
    rail_deflection: Array
    sleeper_displacement: Array
    area_displacement: Array
    wheel_positions: Array
    wheel_forces: Array
    wheel_deflection: Array
    wheel_velocity: Array
    peak_soil_force: Array
    peak_rail_deflection: Array
    peak_wheel_deflection: Array

    @property
    def sleeper_index(self) -> IntArray:
        """Global sleeper indices of the columns."""
        return np.arange(self.first_sleeper, self.first_sleeper + len(self.sleeper_x), dtype=np.int64)

    @classmethod
    def of_snapshot(
        cls, snap: Snapshot, first_sleeper: int, peak_soil_force: Array, peak_rail_deflection: Array
    ) -> Block:
        """A one-row block of a snapshot, with the running peaks [N], [m] of its window (copied)."""
        W = snap.wheel_positions.size
        return cls(
            first_sleeper=first_sleeper, sleeper_x=snap.sleeper_x, t=np.array([snap.t]),
            soil_force=snap.soil_force[None, :], rail_deflection=snap.rail_deflection[None, :],
            sleeper_displacement=snap.sleeper_displacement[None, :],
            area_displacement=snap.area_displacement[None, :],
            wheel_positions=snap.wheel_positions.reshape(1, W), wheel_forces=snap.wheel_forces.reshape(1, W),
            wheel_deflection=snap.wheel_deflection.reshape(1, W), wheel_velocity=snap.wheel_velocity.reshape(1, W),
            peak_soil_force=peak_soil_force.copy(), peak_rail_deflection=peak_rail_deflection.copy(),
            peak_wheel_deflection=np.where(np.isfinite(snap.wheel_deflection), snap.wheel_deflection, -np.inf),
        )


class FrameRule(IntEnum):
    """The value rules of a wheel-load frame, in the order they are checked; the code is the kernels' (0: none).

    The one list of them: the per-frame kernel
    (:func:`clm_core.solver.check_frame`, :meth:`clm_core.solver.TrackSimulator.advance_frames`) returns these
    codes and the online input policy (:data:`clm_core.online.policy.REASONS`) names each one's refusal.

    >>> FrameRule(3), int(FrameRule.SPAN)
    (<FrameRule.FORCE: 3>, 6)
    """

    NONE = 0
    """No rule broken."""
    NON_FINITE = 1
    """A position or force not finite, or an infinite speed."""
    TENSILE = 2
    """A force below ``-tensile`` [N]."""
    FORCE = 3
    """A force above the force bound [N]."""
    POSITION = 4
    """A ``|position|`` above its bound [m]."""
    SPEED = 5
    """A ``|speed|`` above its bound [m/s]."""
    SPAN = 6
    """The wheels span more than the window holds [m]."""


class FrameResponses(NamedTuple):
    """The responses to R frames of wheel loads (N sleepers, M wheel entries), and where the run stopped.

    A named tuple (cheap to build: one per call of the per-frame path).

    Returned by :meth:`clm_core.solver.TrackSimulator.advance_frames`. Rows
    ``0 .. done - 1`` hold the response of each frame done, at its response
    step; frame ``done`` (if ``done < R``) was refused (``status``, ``rule``,
    ``failure``), and the state is that after frame ``done - 1``.

    Attributes
    ----------
    first_sleeper : (R,) int64 array
        Global index of column 0 of each row's sleeper fields.
    sleepers : (4, R, N) array
        Per frame and sleeper: soil force [N], rail deflection, sleeper and
        contact-area displacement [m] (as in :class:`Snapshot`), in this order.
    wheels : (2, M) array
        Rail deflection [m] and velocity [m/s] under each wheel entry, at its
        position in its frame.
    done : int
        Frames done (all: R).
    failure : str
        Why frame ``done`` was refused, in words ("" when all are done).
    status : int
        How (:mod:`clm_core.solver._frame_kernel`): ``DONE`` (0, all done),
        ``STOP_SHIFT`` (its wheels could not be placed in the window part-way
        through its interval), ``STOP_RESPONSE`` (its response not finite or
        beyond the bounds), ``STOP_INVALID`` (it broke a value rule).
    rule : FrameRule
        With ``STOP_INVALID``: the value rule broken, else ``FrameRule.NONE``.
    wheel : int
        With ``STOP_INVALID``: the index in the frame of the wheel that broke
        the rule (-1: the frame as a whole).
    """

    first_sleeper: IntArray
    sleepers: Array
    wheels: Array
    done: int
    failure: str
    status: int = 0
    rule: FrameRule = FrameRule.NONE
    wheel: int = -1


__all__ = ["Block", "FrameResponses", "SleeperFields", "Snapshot"]
