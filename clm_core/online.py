"""Online processing of wheel-load frames: one code path for node, replay and CLI.

:class:`OnlineTrackModel` takes a stream of stamped wheel-load frames (what a
``clm_msgs/WheelLoads`` message carries), validates each at the edge, advances
the streaming simulator (:class:`clm_core.solver.TrackSimulator`) to the
frame's stamp and returns the response at that stamp. The ROS track node, the
offline bag replay (``clm replay``) and the tests all call
:meth:`OnlineTrackModel.process` / :meth:`OnlineTrackModel.process_batch`, so
"the node's output equals the offline computation" holds by construction.

Time is integer nanoseconds end to end: a frame's stamp is ``stamp_ns``, the
model counts whole steps of ``dt`` (a whole number of nanoseconds) from the
stamp of the frame that started the state, and the response to a frame is the
state at the last step at or before its stamp. A 1-ms frame at
``dt = 1e-4 s`` is always 10 steps, whatever the magnitude of the stamps.

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
``malformed``          refused at the edge before it became a frame
                       (undecodable message, header ``nanosec`` >= 1e9):
                       counted with :meth:`OnlineTrackModel.reject`
=====================  =====================================================

Handled, not refused: a wheel missing from a frame has left the track (no
load) and may come back under its id; a stamp more than ``max_gap`` s after
the last one (a jump far ahead) re-synchronises: the state restarts from
static equilibrium under the new loads at the new stamp (counted as
``resyncs``), instead of integrating a long silent gap. Between two frames the
wheel positions and forces are interpolated linearly in time between the two
stamps; a wheel that enters (or leaves) carries its new position and force
(or its absence) over the whole interval.
"""

from __future__ import annotations

import math
import operator
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.errors import InputError, ParameterError
from clm_core.io.timebase import NS
from clm_core.params import ModelParams
from clm_core.solver import TrackSimulator

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


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
    MALFORMED = "malformed"


class Rejected(InputError):
    """A frame was refused; ``reason`` says which rule, the message the values."""

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
    def of(
        cls,
        stamp_ns: int,
        ids: ArrayLike,
        positions: ArrayLike,
        forces: ArrayLike,
        speeds: ArrayLike | None = None,
        frame_id: str = "",
    ) -> WheelFrame:
        """Build from sequences (no value checks: that is :meth:`OnlineTrackModel.process`'s job).

        Raises
        ------
        TypeError
            ``stamp_ns`` is not an integer (seconds as a float are refused: time is integer ns).
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
class ResponseFrame:
    """The response to one accepted frame: flat arrays, ready for the message encoders.

    Attributes
    ----------
    stamp_ns : int
        The input frame's stamp [ns].
    sleeper_index : (N,) int64 array
        Global sleeper indices of the window.
    sleeper_x : (N,) array
        Sleeper positions along the line [m].
    soil_force : (N,) array
        Soil reaction force under each sleeper [N] (compression positive).
    rail_deflection, sleeper_displacement, area_displacement : (N,) arrays
        Rail deflection above each sleeper, sleeper and soil contact-area
        displacement [m] (positive downwards).
    wheel_ids : (n,) int64 array
        The input frame's wheel ids, in its order.
    wheel_positions : (n,) array
        Their positions [m].
    wheel_deflection, wheel_velocity : (n,) arrays
        Rail deflection [m] and velocity [m/s] under each wheel.
    resynced : bool
        True when this frame restarted the state (first frame or a jump).
    """

    stamp_ns: int
    sleeper_index: IntArray
    sleeper_x: Array
    soil_force: Array
    rail_deflection: Array
    sleeper_displacement: Array
    area_displacement: Array
    wheel_ids: IntArray
    wheel_positions: Array
    wheel_deflection: Array
    wheel_velocity: Array
    resynced: bool


@dataclass
class OnlineStats:
    """Counters of an :class:`OnlineTrackModel`, monotonic.

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


def _dt_ns(dt: float) -> int:
    """``dt`` [s] as a whole number of nanoseconds (refused otherwise)."""
    if not (math.isfinite(dt) and dt > 0):
        raise ParameterError(f"dt = {dt}: time step must be finite and > 0 s")
    n = round(dt * NS)
    if n < 1 or abs(dt * NS - n) > 1e-6 * dt * NS:
        raise ParameterError(f"dt = {dt!r} s: the online model needs a whole number of nanoseconds")
    return int(n)


class OnlineTrackModel:
    """Validate stamped wheel-load frames and answer each with the track response.

    Parameters
    ----------
    params : ModelParams
        Validated model (stability is checked by the simulator).
    dt : float
        Integration time step [s], a whole number of nanoseconds.
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
    stats : OnlineStats, optional
        Counters to carry on (a rebuilt model continues its predecessor's).
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
        stats: OnlineStats | None = None,
    ) -> None:
        if not (math.isfinite(max_gap) and max_gap > 0):
            raise ParameterError(f"max_gap = {max_gap}: must be a finite time > 0 s")
        if not (math.isfinite(tensile_tolerance) and tensile_tolerance >= 0):
            raise ParameterError(f"tensile_tolerance = {tensile_tolerance}: must be >= 0 N")
        if initial_state not in ("static", "rest"):
            raise ParameterError(f"initial_state = {initial_state!r}: one of static, rest")
        self.params = params
        self.dt_ns = _dt_ns(float(dt))
        self.dt = self.dt_ns / NS
        self.n_sleepers = int(n_sleepers)
        self.elements_per_bay = int(elements_per_bay)
        self.max_gap = float(max_gap)
        self.max_gap_ns = round(self.max_gap * NS)
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
        self.last_stamp_ns: int | None = None
        self.epoch_ns = 0  # stamp of the frame that started the state: step k is at epoch_ns + k dt_ns
        self._k = 0  # steps since epoch_ns
        self.stats = stats if stats is not None else OnlineStats()

    def _new_simulator(self, centre: float) -> TrackSimulator:
        return TrackSimulator(
            self.params,
            self.dt,
            self.n_sleepers,
            self.elements_per_bay,
            start_position=centre,
            lead_sleepers=self.lead_sleepers,
        )

    @property
    def time_ns(self) -> int | None:
        """Model time [ns]: the stamp of the last step integrated (None before the first frame)."""
        return None if self.last_stamp_ns is None else self.epoch_ns + self._k * self.dt_ns

    # ------------------------------------------------------------------ validation

    def _validate(self, fr: WheelFrame) -> None:
        n = fr.ids.size
        if fr.positions.size != n or fr.forces.size != n or (fr.speeds is not None and fr.speeds.size not in (0, n)):
            sizes = f"ids {n}, positions {fr.positions.size}, forces {fr.forces.size}"
            if fr.speeds is not None:
                sizes += f", speeds {fr.speeds.size}"
            raise Rejected(Reason.SIZE_MISMATCH, f"array lengths differ ({sizes}) at stamp {fr.stamp_ns} ns")
        if self.last_stamp_ns is not None and fr.stamp_ns <= self.last_stamp_ns:
            raise Rejected(
                Reason.STAMP_NOT_INCREASING,
                f"stamp {fr.stamp_ns} ns is not after the last accepted {self.last_stamp_ns} ns",
            )
        if n == 0:
            if self.last_stamp_ns is None:
                raise Rejected(Reason.EMPTY, f"no wheels in the first frame (stamp {fr.stamp_ns} ns)")
            return
        bad = ~(np.isfinite(fr.positions) & np.isfinite(fr.forces))
        if bad.any():
            i = int(np.argmax(bad))
            raise Rejected(
                Reason.NON_FINITE,
                f"wheel {int(fr.ids[i])}: position {fr.positions[i]}, force {fr.forces[i]} at stamp {fr.stamp_ns} ns",
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
        known = self._fixed_set or self.last_stamp_ns is not None
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
            nothing changed but the rejection count.
        """
        slots_before = dict(self._slot)
        try:
            self._validate(frame)
            pos, F = self._slots_for(frame)
            resync = self.last_stamp_ns is None or frame.stamp_ns - self.last_stamp_ns > self.max_gap_ns
            if resync:
                self._restart(frame, pos, F)
            else:
                self._advance(frame, pos, F)
        except Rejected as exc:
            self._slot = slots_before  # a refused frame registers no wheel
            self.stats.rejected[exc.reason.value] += 1
            raise
        self.last_stamp_ns = frame.stamp_ns
        self._pos, self._F = pos, F
        self.stats.accepted += 1
        self.stats.resyncs += int(resync)
        return self._response(frame, resync)

    def reject(self, reason: Reason, message: str) -> Rejected:
        """Count a message refused at the edge (e.g. ``malformed``: undecodable) and return its refusal.

        For the callers that decode messages (node, replay): the count goes
        with the model's other rejections; the state is untouched.
        """
        self.stats.rejected[reason.value] += 1
        return Rejected(reason, message)

    def process_batch(self, frames: Sequence[WheelFrame]) -> list[ResponseFrame | Rejected]:
        """Process ``frames`` in order: the response or the refusal of each.

        Identical, bit for bit, to calling :meth:`process` on each frame in
        turn (whatever the split of a stream into batches).
        """
        out: list[ResponseFrame | Rejected] = []
        for fr in frames:
            try:
                out.append(self.process(fr))
            except Rejected as exc:
                out.append(exc)
        return out

    def _restart(self, fr: WheelFrame, pos: Array, F: Array) -> None:
        on = np.isfinite(pos)
        centre = float(np.mean(pos[on]))
        sim = self._new_simulator(centre)
        try:
            sim.initialize(pos, F, t0=0.0, state=self.initial_state)  # type: ignore[arg-type]
        except InputError as exc:
            raise Rejected(Reason.OUTSIDE_WINDOW, str(exc)) from None
        self.sim = sim
        self.epoch_ns = fr.stamp_ns
        self._k = 0

    def _advance(self, fr: WheelFrame, pos: Array, F: Array) -> None:
        assert self.last_stamp_ns is not None
        tp = self.last_stamp_ns - self.epoch_ns  # previous frame [ns since epoch]
        tf = fr.stamp_ns - self.epoch_ns
        k_end = tf // self.dt_ns
        n = k_end - self._k
        if n <= 0:
            return
        n_old = self._pos.size
        P0 = np.full(pos.size, np.nan)
        F0 = np.zeros(pos.size)
        P0[:n_old], F0[:n_old] = self._pos, self._F
        both = np.isfinite(P0) & np.isfinite(pos)
        span = float(tf - tp)
        k0 = self._k
        dt_ns = self.dt_ns

        def loads(t: float) -> tuple[Array, Array]:
            # the step's time from its index (integer ns): no rounding of wall-clock stamps
            k = round(t / self.dt)
            a = (k * dt_ns - tp) / span
            P = pos.copy()
            Fq = F.copy()
            P[both] = P0[both] + a * (pos[both] - P0[both])
            Fq[both] = F0[both] + a * (F[both] - F0[both])
            return P, np.where(np.isfinite(P), Fq, 0.0)

        try:
            self.sim.advance(k_end * self.dt, loads)
        except InputError as exc:
            raise Rejected(Reason.OUTSIDE_WINDOW, str(exc)) from None
        self._k = k0 + n
        self.stats.steps += n
        self.stats.simulated_ns += n * dt_ns

    def _response(self, fr: WheelFrame, resync: bool) -> ResponseFrame:
        snap = self.sim.snapshot()
        idx = np.array([self._slot[int(i)] for i in fr.ids], dtype=np.int64)
        return ResponseFrame(
            stamp_ns=fr.stamp_ns,
            sleeper_index=snap.sleeper_index,
            sleeper_x=snap.sleeper_x,
            soil_force=snap.soil_force,
            rail_deflection=snap.rail_deflection,
            sleeper_displacement=snap.sleeper_displacement,
            area_displacement=snap.area_displacement,
            wheel_ids=fr.ids.copy(),
            wheel_positions=fr.positions.copy(),
            wheel_deflection=np.asarray(snap.wheel_deflection)[idx] if idx.size else np.zeros(0),
            wheel_velocity=np.asarray(snap.wheel_velocity)[idx] if idx.size else np.zeros(0),
            resynced=resync,
        )
