"""The vehicle node's plain-Python parts: its run plan, its train schedule, its watch on the answers.

No ROS here (unit-tested without a middleware, ``tests/ros/test_vehicle_schedule.py``):

- :func:`build_plan`: the run settings (parameter values by name) -> the
  vehicle and its timetable (:class:`VehiclePlan`): messages per train,
  steps per message, period. The track and soil parameter set comes from
  :func:`clm_core.online.model.model_params`, the rule of
  :meth:`clm_core.online.OnlineTrackModel.from_settings` (one rule for every
  model built from run settings);
- :class:`TrainSchedule`: when a train starts (``headway`` from start to
  start, or ``train_pause`` after the last one's end), how many an activation
  runs (``trains``, 0: no end), their numbers over the node's life;
- :class:`TrainRun`: one train: its vehicle (a copy of the plan's), the
  bytes of each message, the answers fed back to the vehicle's predictor
  (closed loop), its :class:`clm_ros.vehicle_counts.Counts`;
- :class:`AnswerWatch`: the messages not answered yet (stamp -> step, due
  time, send time) and the track node's silence. Silence is counted only
  while messages are outstanding, from the oldest one sent since the last
  answer, and from the vehicle's own resume: a message sent later than its
  due time by more than half the timeout means the vehicle itself stood
  still (a stopped process, a loaded machine) and is catching up, so the
  answers to what it sent before cannot have been taken yet. A vehicle that
  stood still never blames the track node; silence ends at the next answer.
"""

from __future__ import annotations

import copy
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from clm_core.errors import ClmError
from clm_core.io.errors import MessageError
from clm_core.io.messages import decode_wheel_rail_response, encode_wheel_loads
from clm_core.io.timebase import NS
from clm_core.online.model import model_params
from clm_core.vehicle.run import VehicleRunSpec, build_vehicle_run
from clm_core.vehicle.streaming import StreamingVehicle
from clm_ros.parameters import lookup
from clm_ros.vehicle_counts import Counts

#: Settings of the node's schedule that :func:`build_plan` checks (the others are checked when the run is built).
CHECKED = ("trains", "headway", "train_pause", "track_node", "answer_timeout", "exit_when_done")
#: Answers older than this are forgotten (a later answer counts as unmatched) [s].
FORGET_AFTER = 30.0


@dataclass(frozen=True)
class VehiclePlan:
    """A configured vehicle and its timetable (:func:`build_plan`).

    Attributes
    ----------
    template : StreamingVehicle
        The vehicle at rest, its compiled step loaded; each train runs a copy.
    substeps : int
        Vehicle time steps per message, ``1 / (rate dt)``.
    dt : float
        Time step [s].
    speed : float
        Train speed [m/s].
    n_messages : int
        Messages per train, ``duration * rate + 1``.
    period_ns : int
        Time between two messages [ns].
    max_delay_steps : int
        Oldest answer used as feedback, ``max_feedback_delay / dt`` [steps].
    """

    template: StreamingVehicle
    substeps: int
    dt: float
    speed: float
    n_messages: int
    period_ns: int
    max_delay_steps: int

    @property
    def n_wheels(self) -> int:
        """Wheels of the train."""
        return int(self.template.train.n_wheels)

    def wheel_ids(self) -> NDArray[np.uint32]:
        """The wheel ids of every message, ``0 .. n_wheels - 1``."""
        return np.arange(self.n_wheels, dtype=np.uint32)


def build_plan(values: Mapping[str, Any]) -> VehiclePlan:
    """The vehicle and timetable that the vehicle node's run settings describe.

    Parameters
    ----------
    values : mapping
        Run settings by name (:mod:`clm_core.settings`): ``vehicle``,
        ``cars``, ``speed`` [m/s], ``duration`` [s], ``rate`` [Hz], ``dt`` [s],
        ``start`` [m], ``irregularity``, ``seed``, ``wavelength_band``,
        ``max_feedback_delay`` [s] and the parameter set's (``track``,
        ``soil``, ``model``, ``params_file``; :func:`clm_core.online.model.model_params`). The schedule's
        settings among them (:data:`CHECKED`) are checked against their rules.

    Returns
    -------
    VehiclePlan

    Raises
    ------
    ClmError
        An invalid setting (naming it), or ``1 / (rate dt)`` not a whole number.
    """
    for name in CHECKED:
        if name in values:
            lookup(name).check(values[name])
    g = values.__getitem__
    spec = VehicleRunSpec(
        vehicle=g("vehicle"), cars=int(g("cars")), speed=float(g("speed")), duration=float(g("duration")),
        dt=float(g("dt")), start=float(g("start")), irregularity=g("irregularity"), seed=int(g("seed")),
        wavelength_band=g("wavelength_band"),
    )
    run = build_vehicle_run(spec, model_params(values))
    sim = run.simulation
    rate = float(g("rate"))
    sub = 1.0 / (rate * sim.dt)
    if abs(sub - round(sub)) > 1e-9 or round(sub) < 1:
        raise ClmError(f"rate = {rate:g} Hz and dt = {sim.dt:g} s: 1/(rate dt) = {sub:g} must be a whole number")
    return VehiclePlan(template=StreamingVehicle(sim),  # compiles or loads the step now, never in a train
                       substeps=int(round(sub)), dt=float(sim.dt), speed=float(sim.speed),
                       n_messages=int(round(run.duration * rate)) + 1, period_ns=int(round(NS / rate)),
                       max_delay_steps=int(float(g("max_feedback_delay")) / sim.dt))


class TrainSchedule:
    """Which train runs and when the next one starts.

    Parameters
    ----------
    trains : int
        Trains per activation (0: until deactivated).
    headway_ns : int
        Least time from one train's start to the next one's [ns].
    pause_ns : int
        Least time from one train's end to the next one's start [ns].

    Examples
    --------
    >>> s = TrainSchedule(trains=2, headway_ns=10, pause_ns=3)
    >>> s.activate(now=0); s.begin(now=0), s.complete()
    (1, False)
    >>> s.finish(now=4); s.next_start, s.trains_done, s.complete()
    (10, 1, False)
    >>> s.begin(now=10)
    2
    >>> s.finish(now=20); s.next_start, s.complete()
    (23, True)
    >>> s.activate(now=30); s.complete(), s.begin(now=30)
    (False, 3)
    """

    def __init__(self, trains: int, headway_ns: int, pause_ns: int) -> None:
        if trains < 0 or headway_ns < 0 or pause_ns < 0:
            raise ValueError(f"trains = {trains}, headway = {headway_ns} ns, pause = {pause_ns} ns: must be >= 0")
        self.trains, self.headway_ns, self.pause_ns = trains, headway_ns, pause_ns
        #: the current (or last) train, numbered from 1 over the node's life
        self.number = 0
        #: trains that ran to their end
        self.trains_done = 0
        #: when the current train started and when the next may start [ns, the caller's clock]
        self.started = self.next_start = 0
        self._first = 0  # the last train before the current activation

    def activate(self, now: int) -> None:
        """An activation: ``trains`` more trains, the first one at once."""
        self._first = self.number
        self.next_start = now

    def complete(self) -> bool:
        """True when the activation has run its ``trains`` trains (never with ``trains = 0``)."""
        return bool(self.trains) and self.number - self._first >= self.trains

    def first_of_activation(self) -> bool:
        """True while the activation's first train waits to start."""
        return self.number == self._first

    def begin(self, now: int) -> int:
        """A train starts at ``now``; its number."""
        self.number += 1
        self.started = now
        return self.number

    def finish(self, now: int) -> None:
        """The current train ended (not stopped) at ``now``: the next starts a headway after its start, and a
        pause after its end."""
        self.trains_done += 1
        self.next_start = max(self.started + self.headway_ns, now + self.pause_ns)


class AnswerWatch:
    """The messages not answered yet, and the track node's silence.

    Parameters
    ----------
    timeout_ns : int
        Silence after which the track node is taken as gone [ns].
    forget_ns : int, optional
        Age (by due time) after which an unanswered message is forgotten [ns].

    Examples
    --------
    >>> w = AnswerWatch(timeout_ns=100)
    >>> w.sent(stamp=1, step=0, due=0, now=0); w.silence_began(now=150)
    True
    >>> w.answer(stamp=1, now=160), w.silent
    ((0, 0), False)
    >>> w.silence_began(now=10_000)  # nothing outstanding: a vehicle at rest blames no one
    False
    """

    def __init__(self, timeout_ns: int, forget_ns: int = int(FORGET_AFTER * NS)) -> None:
        self.timeout_ns, self.forget_ns = timeout_ns, forget_ns
        #: stamp [ns] -> (vehicle step, due time, send time [ns]) of the messages not answered yet
        self.outstanding: dict[int, tuple[int, int, int]] = {}
        #: the track node has been silent for ``timeout_ns`` (until its next answer)
        self.silent = False
        self._last_answer = 0  # when the last answer was received [ns]
        self._resumed = 0  # when the vehicle last sent a message it was late with (it had stood still) [ns]

    def clear(self) -> None:
        """A new train: nothing outstanding, no silence."""
        self.outstanding.clear()
        self.silent = False

    def sent(self, stamp: int, step: int, due: int, now: int) -> None:
        """Message ``stamp`` (vehicle step ``step``, due at ``due``) was sent at ``now`` [ns]; later than ``due`` by
        more than half the timeout: the vehicle stood still and resumes (silence counts from here)."""
        self.outstanding[stamp] = (step, due, now)
        if now - due > self.timeout_ns // 2:
            self._resumed = now

    def answer(self, stamp: int, now: int) -> tuple[int, int] | None:
        """The answer to ``stamp`` came at ``now``: (step, due time) of its message, None if not outstanding.
        Any answer ends a silence (:attr:`silent` False)."""
        entry = self.outstanding.pop(stamp, None)
        if entry is None:
            return None
        self._last_answer = now
        self.silent = False
        return entry[0], entry[1]

    def silence_began(self, now: int) -> bool:
        """Forget messages older than ``forget_ns``; True once when the oldest message sent since the last answer
        and the vehicle's last resume has waited ``timeout_ns`` (then :attr:`silent` stays True until the next
        answer)."""
        out = self.outstanding
        old = now - self.forget_ns
        while out:
            first = next(iter(out))
            if out[first][1] >= old:
                break
            del out[first]
        if self.silent or not out:
            return False
        since = max(next(iter(out.values()))[2], self._last_answer, self._resumed)
        if now - since > self.timeout_ns:
            self.silent = True
            return True
        return False


class TrainRun:
    """One train: its vehicle, its messages, the answers fed back, its counts.

    Parameters
    ----------
    plan : VehiclePlan
    base_ns : int
        Stamp of the first message [ns, ROS or simulation time]; message ``k`` is stamped ``base_ns + k period``.
    start_ns : int
        When the first message is due [ns, monotonic]; message ``k`` is due ``start_ns + k period``.
    frame_id : str
        Frame of the messages.
    closed_loop : bool
        Feed the answers back to the vehicle's track predictor.
    watch : AnswerWatch
        The messages not answered yet (cleared here: a new train).
    """

    def __init__(self, plan: VehiclePlan, base_ns: int, start_ns: int, frame_id: str, closed_loop: bool,
                 watch: AnswerWatch) -> None:
        self.plan, self.base_ns, self.start_ns, self.frame_id, self.closed_loop = (
            plan, base_ns, start_ns, frame_id, closed_loop)
        self.watch = watch
        watch.clear()
        self.vehicle: StreamingVehicle = copy.deepcopy(plan.template)
        self.counts = Counts()
        self.recent_lags: deque[int] = deque(maxlen=2000)  # the latest answer lags [ns]
        self.running = True  # False once the last message is out: a later answer feeds nothing
        self._ids, self._speeds = plan.wheel_ids(), np.full(plan.n_wheels, plan.speed)

    def message(self, k: int) -> tuple[int, int, bytes]:
        """Message ``k``: (stamp [ns], due time [monotonic ns], its CDR bytes), the vehicle advanced to its time
        (``k`` = 0, 1, 2, ... in turn; the model's CPU time counted)."""
        veh, c = self.vehicle, self.counts
        c0 = time.thread_time()
        P = veh.P.copy() if k == 0 else veh.advance(self.plan.substeps)
        c.model_cpu_s += time.thread_time() - c0
        c.model_messages += 1
        stamp = self.base_ns + k * self.plan.period_ns
        return (stamp, self.start_ns + k * self.plan.period_ns,
                encode_wheel_loads(stamp, self.frame_id, self._ids, veh.x, P, self._speeds))

    def answer(self, raw: bytes, now: int) -> str:
        """One answer (CDR bytes), received at ``now`` [monotonic ns], counted and, in closed loop while the train
        runs, fed back. Returns a problem to log once ('' if none)."""
        c = self.counts
        try:
            d = decode_wheel_rail_response(raw)
        except MessageError:
            c.malformed += 1
            return ""
        entry = self.watch.answer(d.stamp_ns, now)
        if entry is None:
            c.unmatched += 1
            return ""
        step, due = entry
        c.answered += 1
        c.lags_ns.append(now - due)
        self.recent_lags.append(now - due)
        if not self.running:  # after the last step an answer feeds nothing
            c.after_end += 1
            return ""
        veh, n = self.vehicle, self.plan.n_wheels
        if not self.closed_loop:
            return ""
        if veh.k - step > self.plan.max_delay_steps:
            c.stale += 1
            return ""
        ids, w = d.wheel_id, np.full(n, np.nan)
        if ids.size and int(ids.max()) < n:
            w[ids] = d.rail_deflection
        try:
            veh.set_track_response(step, w)
        except ClmError as exc:
            return f"track answer not used (counted): {exc}"
        c.used += 1
        return ""

    def end(self) -> Counts:
        """The last message is out (or the train is stopped): its counts with the contact losses."""
        self.running = False
        self.counts.contact_lost_steps = self.vehicle.contact_lost_steps
        return self.counts
