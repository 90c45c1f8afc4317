"""Online processing of wheel-load frames: one code path for node, replay and CLI.

:class:`OnlineTrackModel` takes a stream of stamped wheel-load frames (what a
``clm_msgs/WheelLoads`` message carries), validates each at the edge, advances
the streaming simulator (:class:`clm_core.solver.TrackSimulator`) to the
frame's stamp and returns the response at that stamp. The ROS track node, the
offline bag replay (``clm replay``) and the tests all call
:meth:`OnlineTrackModel.process`, so "the node's output equals the offline
computation" holds by construction.

Input policy (each refusal is an :class:`Rejected` with a :class:`Reason`,
counted, and leaves the state untouched):

=====================  =====================================================
reason                 rule
=====================  =====================================================
``non_finite``         a position or force is NaN or infinite
``tensile``            a force below ``-tensile_tolerance`` N (a wheel
                       cannot pull the rail; use 0 for a lifted wheel)
``size_mismatch``      ids, positions, forces (and speeds if given) differ
                       in length
``duplicate_id``       a wheel id appears twice in one frame
``unknown_id``         an id not in the wheel set (fixed by ``wheel_ids`` or
                       by the first accepted frame) when
                       ``accept_new_wheels`` is False
``stamp_not_increasing``  stamp <= the last accepted stamp
``outside_window``     the wheels do not fit in the simulated window (spread
                       longer than the window allows)
``empty``              a frame without wheels before the first accepted one
=====================  =====================================================

Handled, not refused: a wheel missing from a frame has left the track (no
load) and may come back under its id; a stamp more than ``max_gap`` s after
the last one (a jump far ahead) re-synchronises: the state restarts from
static equilibrium under the new loads at the new stamp (counted as
``resyncs``), instead of integrating a long silent gap. Between two frames the
wheel positions and forces are interpolated linearly; a wheel that enters
carries its new position and force over the whole interval.

The response is the state at the last time step at or before the stamp
(the stamp itself when stamps are multiples of ``dt``).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.errors import InputError, ParameterError
from clm_core.params import ModelParams
from clm_core.solver import Snapshot, TrackSimulator

Array = NDArray[np.float64]


class Reason(str, Enum):
    """Why a wheel-load frame was refused."""

    NON_FINITE = "non_finite"
    TENSILE = "tensile"
    SIZE_MISMATCH = "size_mismatch"
    DUPLICATE_ID = "duplicate_id"
    UNKNOWN_ID = "unknown_id"
    STAMP_NOT_INCREASING = "stamp_not_increasing"
    OUTSIDE_WINDOW = "outside_window"
    EMPTY = "empty"


class Rejected(InputError):
    """A frame was refused; ``reason`` says which rule, the message the values."""

    def __init__(self, reason: Reason, message: str) -> None:
        super().__init__(f"{reason.value}: {message}")
        self.reason = reason


@dataclass(frozen=True)
class WheelFrame:
    """Stamped wheel loads (one ``WheelLoads`` message).

    Attributes
    ----------
    stamp : float
        Time [s] (simulation or ROS time).
    ids : (n,) int array
        Wheel ids.
    positions : (n,) array
        Positions along the track [m].
    forces : (n,) array
        Vertical forces [N], positive downwards (pressing on the rail).
    speeds : (n,) array or None
        Wheel speeds [m/s] (NaN if unknown); informative only.
    """

    stamp: float
    ids: NDArray[np.int64]
    positions: Array
    forces: Array
    speeds: Array | None = None

    @classmethod
    def of(
        cls, stamp: float, ids: ArrayLike, positions: ArrayLike, forces: ArrayLike, speeds: ArrayLike | None = None
    ) -> WheelFrame:
        """Build from sequences (no validation: that is :meth:`OnlineTrackModel.process`'s job)."""
        return cls(
            float(stamp),
            np.asarray(ids, dtype=np.int64).ravel(),
            np.asarray(positions, dtype=float).ravel(),
            np.asarray(forces, dtype=float).ravel(),
            None if speeds is None else np.asarray(speeds, dtype=float).ravel(),
        )


@dataclass(frozen=True)
class ResponseFrame:
    """The response to one accepted frame.

    Attributes
    ----------
    stamp : float
        The input frame's stamp [s].
    sleepers : Snapshot
        Sleeper fields of the window (global indices, positions, soil forces,
        rail deflections, sleeper and area displacements).
    wheel_ids, wheel_positions, wheel_deflection, wheel_velocity : arrays
        Per wheel of the input frame, in its order: rail deflection [m] and
        velocity [m/s] under the wheel.
    resynced : bool
        True when this frame restarted the state (first frame or a jump).
    """

    stamp: float
    sleepers: Snapshot
    wheel_ids: NDArray[np.int64]
    wheel_positions: Array
    wheel_deflection: Array
    wheel_velocity: Array
    resynced: bool


@dataclass
class OnlineStats:
    """Counters of an :class:`OnlineTrackModel`."""

    accepted: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    resyncs: int = 0
    steps: int = 0

    @property
    def rejected_total(self) -> int:
        """All refused frames."""
        return sum(self.rejected.values())


class OnlineTrackModel:
    """Validate stamped wheel-load frames and answer each with the track response.

    Parameters
    ----------
    params : ModelParams
        Validated model (stability is checked by the simulator).
    dt : float
        Integration time step [s].
    n_sleepers : int
        Simulated window length in sleepers.
    elements_per_bay : int
        Rail elements per bay.
    max_gap : float
        A stamp gap above this [s] re-synchronises instead of integrating.
    wheel_ids : sequence of int, optional
        The known wheel set; default: the ids of the first accepted frame.
    accept_new_wheels : bool
        Accept ids not yet known (wheels entering) instead of refusing them.
    tensile_tolerance : float
        Forces down to ``-tensile_tolerance`` [N] are taken as 0.
    initial_state : {'static', 'rest'}
        State at the first frame and at re-synchronisation.
    lead_sleepers : int, optional
        Sleepers kept ahead of the foremost wheel (simulator default if None).
    """

    def __init__(
        self,
        params: ModelParams,
        dt: float = 1.0e-4,
        n_sleepers: int = 61,
        elements_per_bay: int = 2,
        max_gap: float = 1.0,
        wheel_ids: ArrayLike | None = None,
        accept_new_wheels: bool = False,
        tensile_tolerance: float = 1.0,
        initial_state: str = "static",
        lead_sleepers: int | None = None,
    ) -> None:
        if not (math.isfinite(max_gap) and max_gap > 0):
            raise ParameterError(f"max_gap = {max_gap}: must be a finite time > 0 s")
        if not (math.isfinite(tensile_tolerance) and tensile_tolerance >= 0):
            raise ParameterError(f"tensile_tolerance = {tensile_tolerance}: must be >= 0 N")
        if initial_state not in ("static", "rest"):
            raise ParameterError(f"initial_state = {initial_state!r}: one of static, rest")
        self.params = params
        self.dt = float(dt)
        self.n_sleepers = int(n_sleepers)
        self.elements_per_bay = int(elements_per_bay)
        self.max_gap = float(max_gap)
        self.accept_new_wheels = bool(accept_new_wheels)
        self.tensile_tolerance = float(tensile_tolerance)
        self.initial_state = initial_state
        # building the simulator validates the parameters (refuses unstable sets)
        self.lead_sleepers = lead_sleepers
        self.sim = self._new_simulator(0.0)
        self._slot: dict[int, int] = {}
        if wheel_ids is not None:
            for i in np.asarray(wheel_ids, dtype=np.int64).ravel():
                self._slot.setdefault(int(i), len(self._slot))
        self._fixed_set = wheel_ids is not None
        self._pos = np.zeros(0)  # per slot, NaN = off the track
        self._F = np.zeros(0)
        self.last_stamp: float | None = None
        self.epoch = 0.0  # simulation time = stamp - epoch (keeps float precision with wall-clock stamps)
        self.stats = OnlineStats()

    def _new_simulator(self, centre: float) -> TrackSimulator:
        return TrackSimulator(
            self.params,
            self.dt,
            self.n_sleepers,
            self.elements_per_bay,
            start_position=centre,
            lead_sleepers=self.lead_sleepers,
        )

    # ------------------------------------------------------------------ validation

    def _validate(self, fr: WheelFrame) -> None:
        n = fr.ids.size
        if fr.positions.size != n or fr.forces.size != n or (fr.speeds is not None and fr.speeds.size not in (0, n)):
            sizes = f"ids {n}, positions {fr.positions.size}, forces {fr.forces.size}"
            if fr.speeds is not None:
                sizes += f", speeds {fr.speeds.size}"
            raise Rejected(Reason.SIZE_MISMATCH, f"array lengths differ ({sizes}) at stamp {fr.stamp:.6f} s")
        if not math.isfinite(fr.stamp):
            raise Rejected(Reason.NON_FINITE, f"stamp = {fr.stamp}")
        if self.last_stamp is not None and fr.stamp <= self.last_stamp:
            raise Rejected(
                Reason.STAMP_NOT_INCREASING,
                f"stamp {fr.stamp:.6f} s is not after the last accepted {self.last_stamp:.6f} s",
            )
        if n == 0:
            if self.last_stamp is None:
                raise Rejected(Reason.EMPTY, f"no wheels in the first frame (stamp {fr.stamp:.6f} s)")
            return
        bad = ~(np.isfinite(fr.positions) & np.isfinite(fr.forces))
        if bad.any():
            i = int(np.argmax(bad))
            raise Rejected(
                Reason.NON_FINITE,
                f"wheel {int(fr.ids[i])}: position {fr.positions[i]}, force {fr.forces[i]} at stamp {fr.stamp:.6f} s",
            )
        if np.any(fr.forces < -self.tensile_tolerance):
            i = int(np.argmin(fr.forces))
            raise Rejected(
                Reason.TENSILE,
                f"wheel {int(fr.ids[i])}: force {fr.forces[i]:g} N < -{self.tensile_tolerance:g} N "
                "(forces are positive downwards; a wheel cannot pull the rail)",
            )
        uniq, counts = np.unique(fr.ids, return_counts=True)
        if np.any(counts > 1):
            raise Rejected(
                Reason.DUPLICATE_ID, f"wheel id {int(uniq[np.argmax(counts > 1)])} appears {counts.max()} times"
            )
        known = self._fixed_set or self.last_stamp is not None
        if known and not self.accept_new_wheels:
            unknown = [int(i) for i in fr.ids if int(i) not in self._slot]
            if unknown:
                raise Rejected(Reason.UNKNOWN_ID, f"wheel id(s) {unknown} not in the wheel set {sorted(self._slot)}")
        spread = float(fr.positions.max() - fr.positions.min())
        # one bay less than the nominal zone: the window moves by whole bays (clm_core.solver.Window.required)
        allowed = (self.n_sleepers - 2 - self.sim.lead_sleepers - self.sim.margin_sleepers) * self.params.track.spacing
        if spread > allowed:
            raise Rejected(
                Reason.OUTSIDE_WINDOW,
                f"wheels span {spread:.2f} m but the {self.n_sleepers}-sleeper window holds {allowed:.2f} m",
            )

    # ------------------------------------------------------------------ processing

    def _slots_for(self, fr: WheelFrame) -> tuple[Array, Array]:
        for i in fr.ids:
            self._slot.setdefault(int(i), len(self._slot))
        n = len(self._slot)
        pos = np.full(n, np.nan)
        F = np.zeros(n)
        idx = np.array([self._slot[int(i)] for i in fr.ids], dtype=np.int64)
        pos[idx] = fr.positions
        F[idx] = np.maximum(fr.forces, 0.0)
        return pos, F

    def process(self, frame: WheelFrame) -> ResponseFrame:
        """Validate ``frame``, advance to its stamp and return the response.

        Raises
        ------
        Rejected
            The frame breaks a rule of the input policy (module docstring);
            nothing changed.
        """
        slots_before = dict(self._slot)
        try:
            self._validate(frame)
            pos, F = self._slots_for(frame)
            resync = self.last_stamp is None or frame.stamp - self.last_stamp > self.max_gap
            if resync:
                self._restart(frame, pos, F)
            else:
                self._advance(frame, pos, F)
        except Rejected as exc:
            self._slot = slots_before  # a refused frame registers no wheel
            self.stats.rejected[exc.reason.value] += 1
            raise
        self.last_stamp = frame.stamp
        self._pos, self._F = pos, F
        self.stats.accepted += 1
        self.stats.resyncs += int(resync)
        return self._response(frame, resync)

    def _restart(self, fr: WheelFrame, pos: Array, F: Array) -> None:
        on = np.isfinite(pos)
        centre = float(np.mean(pos[on]))
        sim = self._new_simulator(centre)
        epoch = float(math.floor(fr.stamp))
        try:
            sim.initialize(pos, F, t0=fr.stamp - epoch, state=self.initial_state)  # type: ignore[arg-type]
        except InputError as exc:
            raise Rejected(Reason.OUTSIDE_WINDOW, str(exc)) from None
        self.sim = sim
        self.epoch = epoch

    def _advance(self, fr: WheelFrame, pos: Array, F: Array) -> None:
        t0 = float(self.last_stamp) - self.epoch  # type: ignore[arg-type]
        t1 = fr.stamp - self.epoch
        span = t1 - t0
        n_old = self._pos.size
        P0 = np.full(pos.size, np.nan)
        F0 = np.zeros(pos.size)
        P0[:n_old], F0[:n_old] = self._pos, self._F
        both = np.isfinite(P0) & np.isfinite(pos)

        t_before = self.sim.t
        try:
            if n_old == pos.size and np.array_equal(np.isfinite(P0), np.isfinite(pos)):
                # same wheels on the track: the simulator interpolates linearly (vectorised)
                self.sim.advance(t1, (pos, F))
            else:

                def loads(t: float) -> tuple[Array, Array]:
                    a = min(max((t - t0) / span, 0.0), 1.0)
                    P = pos.copy()
                    Fq = F.copy()
                    P[both] = P0[both] + a * (pos[both] - P0[both])
                    Fq[both] = F0[both] + a * (F[both] - F0[both])
                    return P, Fq

                self.sim.advance(t1, loads)
        except InputError as exc:
            raise Rejected(Reason.OUTSIDE_WINDOW, str(exc)) from None
        self.stats.steps += round((self.sim.t - t_before) / self.dt)

    def _response(self, fr: WheelFrame, resync: bool) -> ResponseFrame:
        snap = self.sim.snapshot()
        idx = np.array([self._slot[int(i)] for i in fr.ids], dtype=np.int64)
        return ResponseFrame(
            stamp=fr.stamp,
            sleepers=snap,
            wheel_ids=fr.ids.copy(),
            wheel_positions=fr.positions.copy(),
            wheel_deflection=np.asarray(snap.wheel_deflection)[idx] if idx.size else np.zeros(0),
            wheel_velocity=np.asarray(snap.wheel_velocity)[idx] if idx.size else np.zeros(0),
            resynced=resync,
        )
