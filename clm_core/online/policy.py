"""The online input policy: plausibility bounds, the value checks of a batch, and the stamp timeline.

- :class:`InputPolicy`: the bounds (settings of the "online input policy"
  section of :mod:`clm_core.settings`, one default everywhere);
- :func:`check_frame`: the value rules of a frame (non-finite, tensile,
  implausible force, position or speed, wheels spanning more than the window
  holds), compiled, the same rules the per-frame kernel applies to every
  frame it steps;
- :class:`Timeline`: which stamps continue the stream, which are refused,
  and when a new timeline is confirmed (the rules: :mod:`clm_core.online`);
- :func:`brief`: bounded text for lists in messages (log lines stay short).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from clm_core import settings
from clm_core.arrays import Array
from clm_core.errors import ParameterError
from clm_core.io.timebase import INT32_MAX, INT32_MIN, NS
from clm_core.online.records import Reason
from clm_core.solver import LIM_FORCE, LIM_POSITION, LIM_SPAN, LIM_SPEED, LIM_TENSILE, FrameRule
from clm_core.solver import check_frame as kernel_check_frame

#: Stamps representable as ``builtin_interfaces/Time`` (int32 seconds) [ns].
STAMP_MIN, STAMP_MAX = INT32_MIN * NS, INT32_MAX * NS + NS - 1
#: Longest text of a refusal or a listed value sequence in it (characters).
MESSAGE_CHARS = 300

#: The refusal of each value rule of the kernels (:class:`clm_core.solver.FrameRule`).
REASONS: dict[FrameRule, Reason] = {
    FrameRule.NON_FINITE: Reason.NON_FINITE,
    FrameRule.TENSILE: Reason.TENSILE,
    FrameRule.FORCE: Reason.IMPLAUSIBLE_FORCE,
    FrameRule.POSITION: Reason.IMPLAUSIBLE_POSITION,
    FrameRule.SPEED: Reason.IMPLAUSIBLE_SPEED,
    FrameRule.SPAN: Reason.OUTSIDE_WINDOW,
}
#: :data:`REASONS` indexed by the rule's code (``RULES[0]``, no rule broken: None), for the kernels' int codes.
RULES: tuple[Reason | None, ...] = tuple(REASONS.get(FrameRule(i)) for i in range(len(FrameRule)))


@dataclass(frozen=True)
class InputPolicy:
    """Plausibility bounds and stream rules of the online model (defaults: :mod:`clm_core.settings`).

    Attributes
    ----------
    max_wheel_force : float
        Largest wheel force accepted [N].
    max_wheel_position : float
        Largest ``|position|`` of a wheel [m].
    max_wheel_speed : float
        Largest ``|speed|`` of a wheel [m/s] (NaN: unknown, accepted).
    max_response_force : float
        Largest ``|soil force|`` in a response [N].
    max_response_displacement : float
        Largest ``|displacement|`` in a response, rail deflection under the
        wheels included [m].
    resync_confirm : int
        Consecutive frames on a new timeline that make it the stream's (>= 2).
    max_wheels : int
        Most wheels in a frame and in the wheel set.
    tensile_tolerance : float
        Forces down to ``-tensile_tolerance`` [N] are taken as 0.
    """

    max_wheel_force: float = field(default=float(settings.MAX_WHEEL_FORCE.default))  # type: ignore[arg-type]
    max_wheel_position: float = field(default=float(settings.MAX_WHEEL_POSITION.default))  # type: ignore[arg-type]
    max_wheel_speed: float = field(default=float(settings.MAX_WHEEL_SPEED.default))  # type: ignore[arg-type]
    max_response_force: float = field(default=float(settings.MAX_RESPONSE_FORCE.default))  # type: ignore[arg-type]
    max_response_displacement: float = field(
        default=float(settings.MAX_RESPONSE_DISPLACEMENT.default))  # type: ignore[arg-type]
    resync_confirm: int = field(default=int(settings.RESYNC_CONFIRM.default))  # type: ignore[arg-type]
    max_wheels: int = field(default=int(settings.MAX_WHEELS.default))  # type: ignore[arg-type]
    tensile_tolerance: float = 1.0

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "tensile_tolerance":
                v = float(self.tensile_tolerance)
                if not (np.isfinite(v) and v >= 0):
                    raise ParameterError(f"tensile_tolerance = {v}: must be a finite force >= 0 N")
            else:
                settings.setting(f.name).check(getattr(self, f.name))

    @classmethod
    def from_settings(cls, values: Mapping[str, Any]) -> InputPolicy:
        """The policy from run settings (names of :mod:`clm_core.settings`; the others take their default).

        Raises
        ------
        ParameterError
            A value outside its setting's range.
        """
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in names and v is not None})

    def limits(self, max_spread: float) -> Array:
        """The value rules as the kernels take them (``FrameLoads.limits``).

        Largest ``|position|`` [m], force [N], tensile force [N], ``|speed|``
        [m/s] and span of the wheels ``max_spread`` [m].
        """
        lim = np.empty(5)
        lim[[LIM_POSITION, LIM_FORCE, LIM_TENSILE, LIM_SPEED, LIM_SPAN]] = (
            self.max_wheel_position, self.max_wheel_force, self.tensile_tolerance, self.max_wheel_speed, max_spread)
        return lim


def check_frame(positions: Array, forces: Array, speeds: Array, limits: Array) -> tuple[Reason | None, int]:
    """The value rules of one frame: the first broken (None: none) and the wheel that breaks it.

    The same compiled rules as the per-frame kernel applies to the frames it
    steps (:func:`clm_core.solver.check_frame`; the rules: :class:`clm_core.solver.FrameRule`).

    Parameters
    ----------
    positions, forces : (n,) arrays
        Wheel positions [m] and forces [N].
    speeds : (0,) or (n,) array
        Wheel speeds [m/s] (NaN: unknown).
    limits : (5,) array
        :meth:`InputPolicy.limits`.

    Returns
    -------
    reason : Reason or None
        In the order non-finite, tensile, implausible force, position, speed,
        wheels spanning more than the window holds.
    wheel : int
        Index in the frame of the wheel that breaks it (-1: the frame as a whole).
    """
    rule, wheel = kernel_check_frame(positions, forces, speeds, limits)
    return RULES[rule], int(wheel)


#: Longest gap between two frames integrated step by step [ns] (0.1 s: 1 000 steps at dt = 1e-4 s, ~20 ms of CPU).
#: A frame further ahead but within ``max_gap`` re-synchronises instead (the state restarts from static equilibrium
#: under its loads at its stamp, one factorised solve; counted in ``resyncs``, its response flagged ``resynced``):
#: a frame 1 s ahead cost ~195 ms of CPU, 10 000 steps, and stalled every answer queued behind it (issue 26.10).
#: After 0.1 s the track's own dynamics (damping times of tens of ms) have died out: the equilibrium is what the
#: integration would have reached.
MAX_CATCH_UP_NS = NS // 10

#: What :meth:`Timeline.restore` puts back: last stamp, candidate stamp, its count and its key.
TimelineState = tuple[int | None, int | None, int, bytes]
#: The key of frames whose response was refused: consecutive ones restart the state (a state that went bad).
RESPONSE_KEY = b"response"


class Timeline:
    """Which stamps continue the stream, and when a new stream is confirmed (the rules of :mod:`clm_core.online`).

    Parameters
    ----------
    max_gap_ns : int
        Largest gap [ns] between consecutive frames of a timeline.
    confirm : int
        Consecutive frames on a new timeline that make it the stream's (>= 2).
    max_catch_up_ns : int, optional
        Longest gap integrated step by step [ns] (default :data:`MAX_CATCH_UP_NS`,
        at most ``max_gap_ns``): a frame further ahead, within ``max_gap``,
        re-synchronises (bounded work per message).

    Attributes
    ----------
    last : int or None
        The last accepted stamp [ns].
    candidate : int or None
        The last stamp of a candidate new stream [ns].
    count : int
        Frames of the candidate so far.
    key : bytes
        The candidate's wheel set when it is a new one (its ids as bytes;
        empty: the stream's wheel set).
    """

    ADVANCE, RESYNC = "advance", "resync"

    def __init__(self, max_gap_ns: int, confirm: int, max_catch_up_ns: int | None = None) -> None:
        self.max_gap_ns = int(max_gap_ns)
        self.confirm = int(confirm)
        self.max_catch_up_ns = min(self.max_gap_ns, MAX_CATCH_UP_NS if max_catch_up_ns is None else
                                   int(max_catch_up_ns))
        self.last: int | None = None
        self.candidate: int | None = None
        self.count = 0
        self.key = b""

    def state(self) -> TimelineState:
        """What :meth:`restore` puts back."""
        return self.last, self.candidate, self.count, self.key

    def restore(self, state: TimelineState) -> None:
        """Put back a :meth:`state`."""
        self.last, self.candidate, self.count, self.key = state

    def continues(self, stamp: int) -> bool:
        """Whether a frame stamped ``stamp`` [ns] continues the stream, integrated step by step: in
        ``(last, last + max_catch_up]``."""
        last = self.last
        return last is not None and last < stamp <= last + self.max_catch_up_ns

    def decide(self, stamp: int, key: bytes = b"", reason: Reason | None = None) -> str | Reason:
        """The fate of a valid frame stamped ``stamp`` [ns]; updates the candidate new stream.

        Parameters
        ----------
        stamp : int
            The frame's stamp [ns].
        key : bytes
            What makes the frame a candidate although its stamp continues
            the stream: its wheel ids (as bytes) when they are not the stream's
            wheel set, :data:`RESPONSE_KEY` when its response was refused;
            empty otherwise.
        reason : Reason, optional
            The refusal to return for a keyed candidate not (yet) confirmed.

        Returns
        -------
        str or Reason
            :attr:`ADVANCE` (it continues the stream), :attr:`RESYNC` (the
            first frame, or the one that confirms a new stream: a new timeline,
            or a new wheel set; also a frame more than ``max_catch_up`` but at most
            ``max_gap`` ahead) or the :class:`Reason` of its refusal. The
            caller reports an acceptance with :meth:`accepted`.
        """
        last = self.last
        if last is None:
            return self.RESYNC
        if not key and self.continues(stamp):
            return self.ADVANCE
        if not key and last < stamp <= last + self.max_gap_ns:  # ahead by more than the catch-up bound
            return self.RESYNC
        cand = self.candidate
        if cand is not None and cand < stamp <= cand + self.max_gap_ns and key == self.key:
            self.count += 1
        else:
            self.count = 1
        self.candidate, self.key = stamp, key
        if self.count >= self.confirm:
            return self.RESYNC
        if reason is not None:
            return reason
        return Reason.STAMP_JUMP if stamp > last else Reason.STAMP_NOT_INCREASING

    def accepted(self, stamp: int) -> None:
        """A frame stamped ``stamp`` [ns] was accepted: it is the stream's last; no candidate is left."""
        self.last = stamp
        self.candidate = None
        self.count = 0
        self.key = b""

    def why(self, stamp: int, reason: Reason) -> str:
        """The message of a refusal by :meth:`decide`."""
        of = f"frame {self.count} of the {self.confirm} that confirm a new stream"
        if reason is Reason.STAMP_JUMP:
            return (f"stamp {stamp} ns is {(stamp - (self.last or 0)) / NS:.6g} s after the last accepted "
                    f"{self.last} ns (max_gap {self.max_gap_ns / NS:g} s): a jump, {of}")
        if reason in (Reason.UNKNOWN_ID, Reason.IMPLAUSIBLE_RESPONSE):
            return of
        return f"stamp {stamp} ns is not after the last accepted {self.last} ns: {of}"


def brief(values: Iterable[Any], limit: int = 8) -> str:
    """``a, b, c, ... (N more)``: at most ``limit`` items of a sequence, for bounded messages."""
    items = list(values)
    text = ", ".join(str(v) for v in items[:limit])
    if len(items) > limit:
        text += f", ... ({len(items) - limit} more)"
    return text


def clip(text: str, limit: int = MESSAGE_CHARS) -> str:
    """``text`` cut to ``limit`` characters (with an ellipsis saying how many were cut)."""
    if len(text) <= limit:
        return text
    return f"{text[: limit - 30]}... ({len(text) - limit + 30} chars cut)"


__all__ = [
    "MAX_CATCH_UP_NS",
    "MESSAGE_CHARS",
    "REASONS",
    "RESPONSE_KEY",
    "RULES",
    "STAMP_MAX",
    "STAMP_MIN",
    "InputPolicy",
    "Timeline",
    "TimelineState",
    "brief",
    "check_frame",
    "clip",
]
