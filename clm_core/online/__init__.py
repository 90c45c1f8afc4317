"""Online processing of wheel-load frames: one code path for the track node, replay and the CLI.

:class:`OnlineTrackModel` takes a stream of stamped wheel-load frames
(:class:`WheelFrame`, what a ``clm_msgs/WheelLoads`` message carries),
validates each at the edge, integrates the track–soil model (Kouroussis et
al. 2011, :class:`clm_core.solver.TrackSimulator`) to the frame's stamp and
answers with the response at that stamp (:class:`ResponseFrame`).
:meth:`~OnlineTrackModel.process` takes one frame; :meth:`~OnlineTrackModel.process_batch`
every waiting frame in one go, bit for bit the same answers. The ROS track
node, ``clm replay`` and the tests all call them, so "the node's output
equals the offline computation" holds by construction, however the messages
were batched.

Use (what the node, ``clm replay`` and the fleet do; :mod:`clm_core.online.edge`)::

    model = OnlineTrackModel.from_settings(settings)   # the one factory: run settings by name
    for a in answer(model, waiting):                   # serialized clm_msgs/WheelLoads, one compiled call
        ...                                            # an Answer (a.sleeper_response, a.wheel_rail_response:
                                                       # bytes to publish) or a Rejected (counted)
    model = model.renewed()                            # a new stream: fresh state, the same counters

Time
----
Integer nanoseconds end to end: a frame's stamp is ``stamp_ns``; the model
counts whole steps of ``dt`` (a whole number of nanoseconds) from the stamp
of the frame that started the state; the response to a frame is the state at
the last step at or before its stamp, and the rail deflection and velocity
under each of its wheels at its position. A 1-ms frame at ``dt = 1e-4 s`` is
10 steps, whatever the magnitude of the stamps (wall-clock stamps held as
float seconds gave 9 or 11). Between two frames each wheel's position and
force are interpolated linearly in time; a wheel that enters (leaves) carries
its new values (its absence) over the whole interval; a wheel missing from a
frame has left the track and may come back under its id.

Input policy
------------
Every refusal is a :class:`Rejected` with a :class:`Reason`; it is counted
(``stats.rejected``) and changes nothing else: not the state, not the wheel
set, not the other counters (a refusal by the stream rules also updates the
candidate new stream below). Rules are checked in the order of the table
(the value rules before the stream rules); the bounds are
the settings of the "online input policy" section of :mod:`clm_core.settings`
(:class:`InputPolicy`), also ROS parameters of the node and options of
``clm replay``. Messages are bounded (lists show 8 items and say how many
more; at most 300 characters).

========================  ======================================================
reason                    rule
========================  ======================================================
``malformed``             not a frame: arrays of the wrong type or shape, a stamp
                          outside ``builtin_interfaces/Time`` (int32 seconds); at
                          the edge (:meth:`OnlineTrackModel.reject`): an
                          undecodable message, a header ``nanosec`` >= 1e9
``size_mismatch``         ids, positions, forces (and speeds if given) differ in
                          length
``too_many_wheels``       more than ``max_wheels`` wheels in the frame, or new ids
                          that would make the wheel set larger
``duplicate_id``          a wheel id twice in one frame
``unknown_id``            an id not in the wheel set (fixed by ``wheel_ids`` or by
                          the first accepted frame) when ``accept_new_wheels`` is
                          false (a candidate new stream, below)
``non_finite``            a position or force NaN or infinite, a speed infinite
                          (a NaN speed is "unknown")
``tensile``               a force below ``-tensile_tolerance`` N (a wheel cannot
                          pull the rail; forces down to it are taken as 0)
``implausible_force``     a force above ``max_wheel_force`` N
``implausible_position``  ``|position|`` above ``max_wheel_position`` m
``implausible_speed``     ``|speed|`` above ``max_wheel_speed`` m/s
``outside_window``        the wheels span more than the window holds (at the
                          frame, or part-way between two frames)
``stamp_not_increasing``  stamp <= the last accepted stamp, not (yet) a confirmed
                          new stream
``stamp_jump``            stamp more than ``max_gap`` after the last accepted one,
                          not (yet) a confirmed new stream
``implausible_response``  the response is not finite, or a soil force above
                          ``max_response_force`` N or a displacement above
                          ``max_response_displacement`` m: the frame is refused
                          and the state restored exactly
``empty``                 a frame without wheels to start the state from
========================  ======================================================

Stamps and streams: no single outlier can take the stream over. A stamp in
``(last, last + max_gap]`` continues the stream. A frame that passes the
value rules but is off that timeline (backwards, repeated, a jump ahead), or
that carries wheel ids foreign to the wheel set, is refused and remembered as
a *candidate new stream* (one stamp, one count, one key: the foreign ids);
the next such frame continues the candidate if its stamp is in
``(candidate, candidate + max_gap]`` with the same key, else it starts a new
one. When ``resync_confirm`` consecutive frames (>= 2, default 3) are on one
candidate, the last of them *re-synchronises*: the state restarts from static
equilibrium under its loads at its stamp (``resynced``, counted in
``stats.resyncs``), on its timeline and, with foreign ids, with its wheels as
the wheel set. An accepted frame drops the candidate; frames refused for
their values do not count. So a single far-future stamp, a stamp from the
past, a repeated stamp or one frame of foreign wheels is refused and the
valid stream flows on; a stream that really restarts (a simulator restarted
at t = 0, a recording replayed again, a clock jump, another vehicle) is
followed after ``resync_confirm`` frames; a gap longer than ``max_gap`` is
never integrated. The first frame starts the state and the wheel set.

The response: ``resync_confirm`` consecutive frames whose responses are
refused (``implausible_response``, e.g. after a frame accepted while its
response was still rising towards the bound) also re-synchronise at the last
of them, so a state gone bad cannot blind the model either. Wheels entering
while others jump so far that, interpolated, they would span more than the
window part-way, hold the frame's values over its interval (else every later
frame, interpolated from this one, would be refused).
"""

from __future__ import annotations

from clm_core.online.edge import Answer, answer, decode, frame_from_cdr, frame_from_msg, respond
from clm_core.online.model import (
    FACTORY_SETTINGS,
    MODEL_SETTINGS,
    PARAMS_SETTINGS,
    RUN_FRAMES,
    OnlineTrackModel,
    model_params,
)
from clm_core.online.policy import InputPolicy, Timeline
from clm_core.online.records import OnlineStats, Reason, Rejected, ResponseFrame, WheelFrame

__all__ = [
    "FACTORY_SETTINGS",
    "MODEL_SETTINGS",
    "PARAMS_SETTINGS",
    "RUN_FRAMES",
    "Answer",
    "InputPolicy",
    "OnlineStats",
    "OnlineTrackModel",
    "Reason",
    "Rejected",
    "ResponseFrame",
    "Timeline",
    "WheelFrame",
    "answer",
    "decode",
    "frame_from_cdr",
    "frame_from_msg",
    "model_params",
    "respond",
]
