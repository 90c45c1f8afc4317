"""The online track model: validate stamped wheel-load frames, integrate through them, answer each.

:class:`OnlineTrackModel` is the one code path of the track node, ``clm
replay`` and the tests (rules and time base: :mod:`clm_core.online`). A batch
of frames goes through three stages:

1. *prepare*: the structure of every frame (stamp, sizes, array types) and
   the value rules of all of them in one compiled pass
   (:func:`clm_core.online.policy.check_values`);
2. *plan*: in order, each frame's wheel ids (slots of the wheel set) and its
   fate on the stamp timeline (:class:`clm_core.online.policy.Timeline`):
   continue the stream, restart it, or be refused;
3. *run*: the frames that continue the stream go to the compiled per-frame
   path of the simulator (:meth:`clm_core.solver.TrackSimulator.advance_frames`)
   in runs of at most :data:`RUN_FRAMES`; a frame whose response fails its
   check is refused there, the state put back, and planning resumes after it.

Counters are updated when a stretch of frames is settled, so a refused frame
changes nothing but its rejection count. A frame alone and the same frame in
a batch take the same path through the same kernel: the answers do not
depend on how a stream is split into batches.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.arrays import Array, IntArray
from clm_core.checks import positive
from clm_core.errors import InputError, ParameterError
from clm_core.io.timebase import NS
from clm_core.online import policy as rules
from clm_core.online.policy import InputPolicy, Timeline, TimelineState, check_frame, clip
from clm_core.online.records import OnlineStats, Reason, Rejected, ResponseFrame, WheelFrame
from clm_core.params import ModelParams, model_from_settings
from clm_core.settings import MODEL_PARAMETERS, ONLINE_POLICY, setting
from clm_core.solver import STOP_INVALID, STOP_SHIFT, FrameLoads, FrameResponses, TrackSimulator

#: Frames per kernel run at most (bounds the output buffers and the work redone after a refused response).
RUN_FRAMES = 256
#: The run settings of the model itself (:mod:`clm_core.settings`): the window, the stream rules, the input policy.
MODEL_SETTINGS: tuple[str, ...] = ("dt", "n_sleepers", "elements_per_bay", "lead_sleepers", "max_gap",
                                   "accept_new_wheels", "initial_state", *ONLINE_POLICY)
#: The run settings of the parameter set (:func:`model_params`; ``<section>.<name>`` overrides besides).
PARAMS_SETTINGS: tuple[str, ...] = ("track", "soil", "model", "params_file")
#: Every run setting :meth:`OnlineTrackModel.from_settings` reads: what a node declares and hands it.
FACTORY_SETTINGS: tuple[str, ...] = (*PARAMS_SETTINGS, *MODEL_PARAMETERS, *MODEL_SETTINGS)
_F8, _I8 = np.dtype(np.float64), np.dtype(np.int64)


def _dt_ns(dt: float) -> int:
    """``dt`` [s] as a whole number of nanoseconds (refused otherwise)."""
    dt = positive("dt", dt, unit="s")
    n = round(dt * NS)
    if n < 1 or abs(dt * NS - n) > 1e-3:
        raise ParameterError(f"dt = {dt!r} s: the online model needs a whole number of nanoseconds")
    return int(n)


def _setting_values(values: Mapping[str, Any], names: Sequence[str]) -> dict[str, Any]:
    """The named settings of ``values``, checked (the schema's default for a missing one).

    A ROS parameter's stand-in for "unset" (``-1``, NaN, ``""``) and None both
    mean the automatic value of an automatic setting.
    """
    return {n: setting(n).from_ros(values[n]) if n in values else setting(n).default for n in names}


def model_params(values: Mapping[str, Any]) -> ModelParams:
    """The validated parameter set that run settings describe: the one rule of the node, replay and fleet.

    Parameters
    ----------
    values : mapping
        Run settings by name (:mod:`clm_core.settings`; other keys are
        ignored, a missing setting takes its default): ``track``, ``soil``,
        ``model`` presets or files, or a full ``params_file`` that replaces
        them; and per-parameter overrides ``<section>.<name>`` (``track.kb``
        [N/m], ...; None or NaN: not overridden).

    Returns
    -------
    ModelParams

    Raises
    ------
    ParameterError
        A setting outside its range or choices, an unknown preset, a bad
        parameter value.
    """
    v = _setting_values(values, PARAMS_SETTINGS)
    over = {key.split(".", 1)[1]: x for key, s in MODEL_PARAMETERS.items()
            if key in values and (x := s.from_ros(values[key])) is not None}
    return model_from_settings(v["track"], v["soil"], v["model"], v["params_file"], over)


def _vector(a: Any, dtype: np.dtype[Any]) -> NDArray[Any]:
    """``a`` as a 1-D, C-contiguous, writable array of ``dtype`` (a copy only when needed)."""
    if isinstance(a, np.ndarray) and a.dtype == dtype and a.ndim == 1 and a.flags.c_contiguous and a.flags.writeable:
        return a
    v = np.array(a, dtype=dtype)
    if v.ndim != 1:
        raise ValueError(f"shape {v.shape}: one value per wheel expected")
    return v


class _Prepared:
    """A frame that passed the structural checks: its arrays as the kernels take them."""

    __slots__ = ("forces", "frame", "ids", "positions", "speeds", "stamp")

    def __init__(self, frame: WheelFrame, stamp: int, ids: IntArray, positions: Array, forces: Array,
                 speeds: Array) -> None:
        self.frame, self.stamp, self.ids, self.positions, self.forces, self.speeds = (
            frame, stamp, ids, positions, forces, speeds)


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
        Largest stamp gap [s] integrated; a larger one is a jump (refused
        until confirmed, see ``policy.resync_confirm``).
    wheel_ids : sequence of int, optional
        The known wheel set; default: the ids of the first accepted frame.
    accept_new_wheels : bool
        Accept ids not yet known (wheels entering) instead of refusing them.
    initial_state : {'static', 'rest'}
        State at the first frame and at re-synchronisation.
    lead_sleepers : int, optional
        Sleepers kept ahead of the foremost wheel (simulator default if None).
    stats : OnlineStats, optional
        Counters to carry on (a rebuilt model continues its predecessor's).
    policy : InputPolicy, optional
        Plausibility bounds and stream rules (default: the settings' defaults).

    Raises
    ------
    ParameterError
        Bad sizes, time step, ``max_gap``, ``wheel_ids`` (not integers) or policy.
    StabilityError
        A parameter set whose time integration would not be stable.

    Examples
    --------
    Two wheels 3 m apart at 30 m/s, a frame every millisecond (the first
    frame starts the state; stamps in integer nanoseconds):

    >>> from clm_core.online import OnlineTrackModel, Reason, WheelFrame
    >>> from clm_core.params import load_model
    >>> model = OnlineTrackModel(load_model("mevergnies", "mevergnies", "clm"), dt=1e-4, n_sleepers=41)
    >>> frames = [WheelFrame(10**9 + k * 10**6, [1, 2], [30.0 + 0.03 * k, 27.0 + 0.03 * k], [85e3, 85e3])
    ...           for k in range(5)]
    >>> out = model.process_batch(frames)
    >>> [r.stamp_ns - 10**9 for r in out], model.stats.steps  # 10 steps of 0.1 ms per frame
    ([0, 1000000, 2000000, 3000000, 4000000], 40)
    >>> bad = model.process_batch([WheelFrame(10**9 + 5 * 10**6, [1, 2], [30.15, 27.15], [85e3, float("nan")])])
    >>> bad[0].reason is Reason.NON_FINITE, model.stats.steps  # refused, nothing changed
    (True, 40)
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
        initial_state: str = "static",
        lead_sleepers: int | None = None,
        stats: OnlineStats | None = None,
        policy: InputPolicy | None = None,
    ) -> None:
        max_gap = positive("max_gap", max_gap, unit="s")
        if initial_state not in ("static", "rest"):
            raise ParameterError(f"initial_state = {initial_state!r}: one of static, rest")
        self.params = params
        self.policy = policy if policy is not None else InputPolicy()
        self.dt_ns = _dt_ns(dt)
        self.dt = self.dt_ns / NS
        self.n_sleepers = int(n_sleepers)
        self.elements_per_bay = int(elements_per_bay)
        self.max_gap = float(max_gap)
        self.accept_new_wheels = bool(accept_new_wheels)
        self.initial_state = initial_state
        self.lead_sleepers = lead_sleepers
        # building the simulator validates the parameters (refuses unstable sets)
        self.sim = TrackSimulator(params, self.dt, self.n_sleepers, self.elements_per_bay,
                                  lead_sleepers=lead_sleepers)
        self.timeline = Timeline(round(self.max_gap * NS), self.policy.resync_confirm)
        self._slot: dict[int, int] = {}
        self._slot_ids: list[int] = []
        # the previous accepted frame's wheels per slot (capacity grows; NaN: absent)
        self._pos = np.full(8, np.nan)
        self._F = np.zeros(8)
        if wheel_ids is not None:
            ids = np.asarray(wheel_ids)
            if ids.size and not np.issubdtype(ids.dtype, np.integer):
                raise ParameterError(f"wheel_ids = {wheel_ids!r}: must be integers")
            for i in ids.astype(np.int64).ravel().tolist():
                if i not in self._slot:
                    self._register(i)
        self._fixed_set = wheel_ids is not None
        self.epoch_ns = 0  # stamp of the frame that started the state: step k is at epoch_ns + k dt_ns
        self.stats = stats if stats is not None else OnlineStats()
        # one wheel check per set of ids (the frames of a stream carry the same ids): (bytes, slots, slot count)
        self._ids_key: tuple[bytes, IntArray, int] | None = None
        self._sleepers: dict[int, tuple[IntArray, Array]] = {}
        spacing = params.track.spacing
        # one bay less than the nominal zone: the window moves by whole bays (clm_core.solver.Window.required)
        self._max_spread = (self.n_sleepers - 2 - self.sim.lead_sleepers - self.sim.margin_sleepers) * spacing
        self._limits = self.policy.limits(self._max_spread)
        self._no_speeds = np.zeros(0)
        ints = self._ints1 = np.zeros(7, dtype=np.int64)  # ticks, k_end, offsets, soffsets of a single frame
        self._ints1_views = (ints[0:2], ints[2:3], ints[3:5], ints[5:7])
        self._warm_up()

    @classmethod
    def from_settings(cls, values: Mapping[str, Any] | None = None, *, params: ModelParams | None = None,
                      stats: OnlineStats | None = None) -> OnlineTrackModel:
        """The model that run settings describe: the one factory of the track node, ``clm replay`` and the fleet.

        Parameters
        ----------
        values : mapping, optional
            Run settings by name (:mod:`clm_core.settings`; other keys are
            ignored, a missing one takes its default, a ROS stand-in for
            "unset" or None its automatic value): the parameter set
            (:func:`model_params`: ``track``, ``soil``, ``model``,
            ``params_file``, ``<section>.<name>`` overrides) and the model's
            own :data:`MODEL_SETTINGS` (``dt`` [s], ``n_sleepers``,
            ``elements_per_bay``, ``lead_sleepers``, ``max_gap`` [s],
            ``accept_new_wheels``, ``initial_state``, the input policy).
        params : ModelParams, optional
            The parameter set, if already built (then the parameter settings
            of ``values`` are not read).
        stats : OnlineStats, optional
            Counters to carry on (a rebuilt model continues its predecessor's).

        Returns
        -------
        OnlineTrackModel

        Raises
        ------
        ParameterError
            A setting outside its range or choices (naming it), a bad preset.
        StabilityError
            A parameter set whose time integration would not be stable.

        Examples
        --------
        >>> from clm_core.online import OnlineTrackModel, WheelFrame
        >>> model = OnlineTrackModel.from_settings({"track": "mevergnies", "dt": 1e-4, "n_sleepers": 31})
        >>> model.n_sleepers, model.dt_ns, model.settings["max_gap"]
        (31, 100000, 1.0)
        >>> r = model.process(WheelFrame(10**9, [0], [0.0], [100e3]))
        >>> r.stamp_ns, r.wheel_ids.tolist(), bool(r.wheel_deflection[0] > 0)
        (1000000000, [0], True)
        """
        values = {} if values is None else values
        v = _setting_values(values, MODEL_SETTINGS)
        return cls(
            params if params is not None else model_params(values),
            dt=v["dt"], n_sleepers=v["n_sleepers"], elements_per_bay=v["elements_per_bay"], max_gap=v["max_gap"],
            accept_new_wheels=v["accept_new_wheels"], initial_state=v["initial_state"],
            lead_sleepers=v["lead_sleepers"], stats=stats, policy=InputPolicy.from_settings(v),
        )

    @property
    def settings(self) -> dict[str, Any]:
        """The model's own run settings (:data:`MODEL_SETTINGS`), as :meth:`from_settings` takes them."""
        pol = self.policy
        return {"dt": self.dt, "n_sleepers": self.n_sleepers, "elements_per_bay": self.elements_per_bay,
                "lead_sleepers": self.lead_sleepers, "max_gap": self.max_gap,
                "accept_new_wheels": self.accept_new_wheels, "initial_state": self.initial_state,
                **{n: getattr(pol, n) for n in ONLINE_POLICY}}

    def renewed(self) -> OnlineTrackModel:
        """A fresh model of the same parameters and settings, counting into the same counters (a new stream)."""
        return type(self).from_settings(self.settings, params=self.params, stats=self.stats)

    # ------------------------------------------------------------------ state

    @property
    def last_stamp_ns(self) -> int | None:
        """Stamp [ns] of the last accepted frame (None before the first)."""
        return self.timeline.last

    @property
    def time_ns(self) -> int | None:
        """Model time [ns]: the time of the last step integrated (None before the first frame)."""
        return None if self.timeline.last is None else self.epoch_ns + self.sim.steps * self.dt_ns

    def _register(self, wheel_id: int) -> int:
        slot = len(self._slot_ids)
        self._slot[wheel_id] = slot
        self._slot_ids.append(wheel_id)
        if slot >= self._pos.size:
            grow = max(8, self._pos.size)
            self._pos = np.concatenate([self._pos, np.full(grow, np.nan)])
            self._F = np.concatenate([self._F, np.zeros(grow)])
        return slot

    def _unregister(self, n_slots: int) -> None:
        """Forget the wheels registered after the first ``n_slots`` (by a frame that was then refused)."""
        for wheel_id in self._slot_ids[n_slots:]:
            del self._slot[wheel_id]
        del self._slot_ids[n_slots:]
        if self._ids_key is not None and self._ids_key[2] > n_slots:
            self._ids_key = None
        self._pos[n_slots:] = np.nan
        self._F[n_slots:] = 0.0

    def _warm_up(self) -> None:
        """Compile (or load from the cache) the kernels of the frame path with this model's types."""
        e = np.zeros(0)
        i0 = np.zeros(1, dtype=np.int64)
        check_frame(e, e, e, self._limits)
        self.sim.advance_frames(self._loads(i0, np.zeros(0, dtype=np.int64), i0, np.zeros(0, dtype=np.int64), e, e, e,
                                            i0, 0))

    # ------------------------------------------------------------------ public API

    def reject(self, reason: Reason, message: str) -> Rejected:
        """Count a message refused at the edge (e.g. ``malformed``: undecodable) and return its refusal.

        For the callers that decode messages (node, replay): the count goes
        with the model's other rejections; the state is untouched.
        """
        self.stats.rejected[reason.value] += 1
        return Rejected(reason, clip(message))

    def process(self, frame: WheelFrame) -> ResponseFrame:
        """Validate ``frame``, advance to its stamp and return the response.

        Raises
        ------
        Rejected
            The frame breaks a rule of the input policy (:mod:`clm_core.online`);
            nothing changed but the rejection count.
        """
        r = self.process_batch((frame,))[0]
        if isinstance(r, Rejected):
            raise r
        return r

    def process_batch(self, frames: Sequence[WheelFrame]) -> list[ResponseFrame | Rejected]:
        """Process ``frames`` in order: the response or the refusal of each.

        Identical, bit for bit, to calling :meth:`process` on each frame in
        turn, whatever the split of a stream into batches.
        """
        out: list[ResponseFrame | Rejected | None] = [None] * len(frames)
        prep = self._prepare(frames, out)
        i = 0
        while i < len(frames):
            i = self._settle(prep, out, i)
        return out  # type: ignore[return-value]  # every entry is settled

    # ------------------------------------------------------------------ 1. prepare

    def _prepare(self, frames: Sequence[WheelFrame], out: list[Any]) -> list[_Prepared | None]:
        """The structure of every frame: stamp, array types and sizes (None: refused, in ``out``)."""
        prep: list[_Prepared | None] = [None] * len(frames)
        maxw = self.policy.max_wheels
        for g, fr in enumerate(frames):
            try:
                stamp = operator.index(fr.stamp_ns)
                ids = _vector(fr.ids, _I8)
                pos = _vector(fr.positions, _F8)
                F = _vector(fr.forces, _F8)
                sp = self._no_speeds if fr.speeds is None else _vector(fr.speeds, _F8)
            except (TypeError, ValueError, OverflowError, AttributeError) as exc:
                out[g] = Rejected(Reason.MALFORMED, clip(f"frame of {type(fr).__name__}: {exc}"))
                continue
            if not rules.STAMP_MIN <= stamp <= rules.STAMP_MAX:
                out[g] = Rejected(Reason.MALFORMED, f"stamp {stamp} ns is outside builtin_interfaces/Time (int32 s)")
            elif pos.size != ids.size or F.size != ids.size or sp.size not in (0, ids.size):
                out[g] = Rejected(Reason.SIZE_MISMATCH, f"array lengths differ (ids {ids.size}, positions {pos.size},"
                                  f" forces {F.size}, speeds {sp.size}) at stamp {stamp} ns")
            elif ids.size > maxw:
                out[g] = Rejected(Reason.TOO_MANY_WHEELS, f"{ids.size} wheels in one frame (max_wheels {maxw})")
            else:
                prep[g] = _Prepared(fr, stamp, ids, pos, F, sp)
        return prep

    def _value_message(self, reason: Reason, p: _Prepared, w: int) -> str:
        pol = self.policy
        at = f"at stamp {p.stamp} ns"
        if reason is Reason.OUTSIDE_WINDOW:
            spread = float(p.positions.max() - p.positions.min())
            return (f"wheels span {spread:.6g} m but the {self.n_sleepers}-sleeper window holds "
                    f"{self._max_spread:.2f} m {at}")
        wid = int(p.ids[w]) if 0 <= w < p.ids.size else w
        x, f = (p.positions[w], p.forces[w]) if 0 <= w < p.positions.size else (math.nan, math.nan)
        if reason is Reason.NON_FINITE:
            sp = p.speeds[w] if 0 <= w < p.speeds.size else math.nan
            return f"wheel {wid}: position {x} m, force {f} N, speed {sp} m/s {at}"
        if reason is Reason.TENSILE:
            return (f"wheel {wid}: force {f:g} N < -{pol.tensile_tolerance:g} N {at} (forces are positive "
                    "downwards; a wheel cannot pull the rail)")
        if reason is Reason.IMPLAUSIBLE_FORCE:
            return f"wheel {wid}: force {f:g} N > max_wheel_force {pol.max_wheel_force:g} N {at}"
        if reason is Reason.IMPLAUSIBLE_POSITION:
            return f"wheel {wid}: position {x:g} m beyond max_wheel_position {pol.max_wheel_position:g} m {at}"
        return f"wheel {wid}: speed {p.speeds[w]:g} m/s beyond max_wheel_speed {pol.max_wheel_speed:g} m/s {at}"

    # ------------------------------------------------------------------ 2. plan

    def _slots(self, p: _Prepared) -> IntArray | Rejected:
        """The wheel slots of a frame's ids (registering new wheels), or the refusal of its ids."""
        ids = p.ids
        key = ids.tobytes()
        cached = self._ids_key
        if cached is not None and cached[0] == key and cached[2] <= len(self._slot_ids):
            return cached[1]
        id_list = ids.tolist()
        if len(set(id_list)) != len(id_list):
            seen: set[int] = set()
            dup = next(i for i in id_list if i in seen or seen.add(i))  # type: ignore[func-returns-value]
            return Rejected(Reason.DUPLICATE_ID, f"wheel id {dup} appears {id_list.count(dup)} times at stamp "
                            f"{p.stamp} ns")
        new = [i for i in id_list if i not in self._slot]
        if new:
            known = self._fixed_set or self.timeline.last is not None
            if known and not self.accept_new_wheels:
                return Rejected(Reason.UNKNOWN_ID, f"wheel id(s) {rules.brief(new)} not in the wheel set "
                                f"{rules.brief(sorted(self._slot))} at stamp {p.stamp} ns")
            if len(self._slot_ids) + len(new) > self.policy.max_wheels:
                return Rejected(Reason.TOO_MANY_WHEELS, f"{len(new)} new wheel id(s) ({rules.brief(new)}) would make "
                                f"the wheel set larger than max_wheels {self.policy.max_wheels}")
            for i in new:
                self._register(i)
        slots = np.array([self._slot[i] for i in id_list], dtype=np.int64)
        self._ids_key = (key, slots, int(slots.max()) + 1 if slots.size else 0)
        return slots

    def _settle(self, prep: list[_Prepared | None], out: list[Any], i: int) -> int:
        """Plan frames from ``i`` on, run the ones that continue the stream, settle them; the next frame."""
        run: list[tuple[int, IntArray]] = []
        before: list[tuple[TimelineState, int]] = []  # planning state before each
        tl = self.timeline
        g = i
        while g < len(prep) and len(run) < RUN_FRAMES:
            p = prep[g]
            if p is None:
                g += 1
                continue
            state = (tl.state(), len(self._slot_ids))
            slots = self._slots(p)
            key = b""
            if isinstance(slots, Rejected):
                if slots.reason is not Reason.UNKNOWN_ID or self._fixed_set:
                    out[g] = slots
                    g += 1
                    continue
                key = p.ids.tobytes()  # a candidate new wheel set (a new stream, confirmed like a new timeline)
            if not key and tl.continues(p.stamp):
                before.append(state)
                run.append((g, slots))  # type: ignore[arg-type]
                tl.accepted(p.stamp)  # its value rules are checked in the kernel, before it is stepped
            else:  # off the timeline, new wheels, or the first frame: the value rules first, then the stream rules
                reason, w = check_frame(p.positions, p.forces, p.speeds, self._limits)
                fate = tl.decide(p.stamp, key, Reason.UNKNOWN_ID if key else None) if reason is None else reason
                if fate is Timeline.RESYNC and run:  # run what is planned first; this frame is planned again
                    tl.restore(state[0])
                    self._unregister(state[1])
                    break
                if fate is Timeline.RESYNC:
                    out[g] = self._resync(p, None if key else slots, state)  # type: ignore[arg-type]
                    self._count(out, i, g + 1)
                    return g + 1
                self._unregister(state[1])
                if reason is not None:
                    out[g] = Rejected(reason, self._value_message(reason, p, w))
                elif fate is Reason.UNKNOWN_ID:
                    out[g] = Rejected(fate, clip(f"{str(slots).split(': ', 1)[1]}; {tl.why(p.stamp, fate)}"))
                else:
                    out[g] = Rejected(fate, tl.why(p.stamp, fate))  # type: ignore[arg-type]
            g += 1
        if run:
            done, res = self._run(prep, run, out)
            if done < len(run):
                gf = run[done][0]
                tl.restore(before[done][0])
                self._unregister(before[done][1])
                out[gf] = self._refused_in_run(prep[gf], res, before[done])  # type: ignore[arg-type]
                g = gf + 1
        self._count(out, i, g)
        return g

    def _refused_in_run(self, p: _Prepared, res: FrameResponses, state: tuple[TimelineState, int]
                        ) -> ResponseFrame | Rejected:
        """The frame at which a run stopped: refused; but ``resync_confirm`` consecutive frames whose responses
        are refused restart the state at the last of them (a state gone bad does not blind the model)."""
        refusal = self._refusal(res, p)
        if refusal.reason is not Reason.IMPLAUSIBLE_RESPONSE:
            return refusal
        tl = self.timeline
        fate = tl.decide(p.stamp, rules.RESPONSE_KEY, Reason.IMPLAUSIBLE_RESPONSE)
        if fate is not Timeline.RESYNC:
            return Rejected(refusal.reason, clip(f"{str(refusal).split(': ', 1)[1]}; {tl.why(p.stamp, fate)}"))  # type: ignore[arg-type]
        slots = self._slots(p)
        assert not isinstance(slots, Rejected)  # the frame's ids were accepted when it was planned
        return self._resync(p, slots, state)

    def _refusal(self, res: FrameResponses, p: _Prepared) -> Rejected:
        """The refusal of the frame at which the kernel stopped."""
        if res.status == STOP_INVALID:
            reason = rules.RULES[res.rule]
            assert reason is not None
            return Rejected(reason, self._value_message(reason, p, res.wheel))
        reason = Reason.OUTSIDE_WINDOW if res.status == STOP_SHIFT else Reason.IMPLAUSIBLE_RESPONSE
        return Rejected(reason, clip(f"{res.failure} (stamp {p.stamp} ns)"))

    def _count(self, out: list[Any], a: int, b: int) -> None:
        st = self.stats
        for r in out[a:b]:
            if isinstance(r, Rejected):
                st.rejected[r.reason.value] += 1
            else:
                st.accepted += 1
                st.resyncs += int(r.resynced)

    # ------------------------------------------------------------------ 3. run

    def _loads(self, ticks: IntArray, k_end: IntArray, offsets: IntArray, slots: IntArray, positions: Array,
               forces: Array, speeds: Array, soffsets: IntArray, W: int) -> FrameLoads:
        return FrameLoads(ticks, k_end, self.dt_ns, offsets, slots, positions, forces, speeds, soffsets, self._limits,
                          self._pos[:W], self._F[:W])

    def _advance(self, loads: FrameLoads) -> FrameResponses:
        pol = self.policy
        return self.sim.advance_frames(loads, pol.max_response_force, pol.max_response_displacement)

    def _run(self, prep: list[_Prepared | None], run: list[tuple[int, IntArray]], out: list[Any]
             ) -> tuple[int, FrameResponses]:
        """The frames of ``run`` through the compiled path; the frames done and the kernel's result."""
        ps: list[_Prepared] = [prep[g] for g, _ in run]  # type: ignore[misc]
        R = len(run)
        epoch, dt = self.epoch_ns, self.dt_ns
        if R == 1:  # (a buffer of the model: the kernel's inputs live only for the call)
            p = ps[0]
            tick, n = p.stamp - epoch, p.positions.size
            ints = self._ints1
            ints[0], ints[1], ints[2], ints[4], ints[6] = self._prev_tick, tick, tick // dt, n, p.speeds.size
            ticks, k_end, offsets, soffsets = self._ints1_views
            slots, P, F, S = run[0][1], p.positions, p.forces, p.speeds
            bounds = [0, n]
        else:
            ticks = np.array([self._prev_tick] + [p.stamp - epoch for p in ps], dtype=np.int64)
            k_end = ticks[1:] // dt
            slots = np.concatenate([s for _, s in run])
            P = np.concatenate([p.positions for p in ps])
            F = np.concatenate([p.forces for p in ps])
            S = np.concatenate([p.speeds for p in ps])
            offsets = np.zeros(R + 1, dtype=np.int64)
            np.cumsum([p.positions.size for p in ps], out=offsets[1:])
            soffsets = np.zeros(R + 1, dtype=np.int64)
            np.cumsum([p.speeds.size for p in ps], out=soffsets[1:])
            bounds = offsets.tolist()
        k0 = self.sim.steps
        res = self._advance(self._loads(ticks, k_end, offsets, slots, P, F, S, soffsets, len(self._slot_ids)))
        done = res.done
        for r in range(done):
            out[run[r][0]] = self._response(ps[r], res, r, bounds[r], bounds[r + 1], False)
        if done:
            self._prev_tick = int(ticks[done])
            steps = self.sim.steps - k0
            self.stats.steps += steps
            self.stats.simulated_ns += steps * self.dt_ns
        return done, res

    _prev_tick = 0  # the last accepted frame's stamp relative to the epoch [ns]

    def _resync(self, p: _Prepared, slots: IntArray | None, state: tuple[TimelineState, int]
                ) -> ResponseFrame | Rejected:
        """(Re)start the state at frame ``p``: the first frame, or one that confirms a new stream.

        ``slots`` None: the frame's ids become the wheel set (a new stream of other wheels).
        """
        old_ids = list(self._slot_ids)
        sim = self.sim
        saved, saved_pos, saved_F = sim.checkpoint(), self._pos.copy(), self._F.copy()
        if slots is None:
            self._unregister(0)
            slots = np.array([self._register(i) for i in p.ids.tolist()], dtype=np.int64)
        W = len(self._slot_ids)
        P = np.full(W, np.nan)
        F = np.zeros(W)
        P[slots] = p.positions
        F[slots] = np.maximum(p.forces, 0.0)
        try:
            if p.positions.size == 0:
                raise InputError("no wheels: nothing to start from")
            sim.initialize(P, F, t0=0.0, state=self.initial_state, centre=float(np.mean(p.positions)))  # type: ignore[arg-type]
            self._pos[:W], self._F[:W] = P, F
            res = self._advance(self._loads(np.zeros(2, dtype=np.int64), np.zeros(1, dtype=np.int64),
                                            np.array([0, slots.size], dtype=np.int64), slots, p.positions, p.forces,
                                            p.speeds, np.array([0, p.speeds.size], dtype=np.int64), W))
            refusal = None if res.done else self._refusal(res, p)
        except InputError as exc:
            refusal = Rejected(Reason.EMPTY if p.positions.size == 0 else Reason.OUTSIDE_WINDOW,
                               clip(f"{exc} (stamp {p.stamp} ns)"))
        if refusal is not None:
            sim.rollback(saved)
            self._unregister(0)
            for i in old_ids:
                self._register(i)
            self._pos, self._F = saved_pos, saved_F
            self.timeline.restore(state[0])
            return refusal
        self.epoch_ns = p.stamp
        self._prev_tick = 0
        self.timeline.accepted(p.stamp)
        return self._response(p, res, 0, 0, slots.size, True)

    def _response(self, p: _Prepared, res: FrameResponses, r: int, a: int, b: int, resynced: bool) -> ResponseFrame:
        first = int(res.first_sleeper[r])
        sl = self._sleepers.get(first)
        if sl is None:
            if len(self._sleepers) > 64:
                self._sleepers.clear()
            idx = np.arange(first, first + self.n_sleepers, dtype=np.int64)
            x: Array = idx.astype(np.float64) * self.params.track.spacing
            idx.flags.writeable = False
            x.flags.writeable = False
            sl = self._sleepers[first] = (idx, x)
        s, w = res.sleepers, res.wheels
        return ResponseFrame._of(p.stamp, sl[0], sl[1], s[0, r], s[1, r], s[2, r], s[3, r], p.ids.copy(),
                                 p.positions.copy(), w[0, a:b], w[1, a:b], resynced)


__all__ = ["FACTORY_SETTINGS", "MODEL_SETTINGS", "PARAMS_SETTINGS", "RUN_FRAMES", "OnlineTrackModel", "model_params"]
