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
set, not the other counters (only a stamp refusal also updates the candidate
timeline below). Rules are checked in the order of the table; the bounds are
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
``non_finite``            a position or force NaN or infinite, a speed infinite
                          (a NaN speed is "unknown")
``tensile``               a force below ``-tensile_tolerance`` N (a wheel cannot
                          pull the rail; forces down to it are taken as 0)
``implausible_force``     a force above ``max_wheel_force`` N
``implausible_position``  ``|position|`` above ``max_wheel_position`` m
``implausible_speed``     ``|speed|`` above ``max_wheel_speed`` m/s
``duplicate_id``          a wheel id twice in one frame
``unknown_id``            an id not in the wheel set (fixed by ``wheel_ids`` or by
                          the first accepted frame) when ``accept_new_wheels`` is
                          false
``outside_window``        the wheels span more than the window holds (at the
                          frame, or part-way between two frames)
``stamp_not_increasing``  stamp <= the last accepted stamp, not (yet) a confirmed
                          new timeline
``stamp_jump``            stamp more than ``max_gap`` after the last accepted one,
                          not (yet) a confirmed new timeline
``implausible_response``  the response is not finite, or a soil force above
                          ``max_response_force`` N or a displacement above
                          ``max_response_displacement`` m: the frame is refused
                          and the state restored exactly
``empty``                 a frame without wheels to start the state from
========================  ======================================================

Stamps: no single outlier can take over the stream. A stamp in
``(last, last + max_gap]`` continues the stream. Any other stamp of a frame
that passes the other rules (backwards, equal, or a jump ahead) is refused
and remembered as a *candidate new timeline*; the next such frame continues
the candidate if its stamp is in ``(candidate, candidate + max_gap]``, else
it starts a new candidate. When ``resync_confirm`` consecutive frames (>= 2,
default 3) are on one candidate timeline, the last of them *re-synchronises*:
the state restarts from static equilibrium under its loads at its stamp
(``resynced``, counted in ``stats.resyncs``) and its timeline is the
stream's. An accepted frame on the current timeline drops the candidate. So
a single far-future stamp, a stamp from the past or a repeated stamp is
refused and the valid stream flows on; a stream that really restarts (a
simulator restarted at t = 0, a recording replayed again, a jump of the
clock) is followed after ``resync_confirm`` frames; a gap longer than
``max_gap`` is never integrated. The first frame starts the state. The
candidate is the only memory of refused frames (one stamp and a count).
"""

from __future__ import annotations

from clm_core.online.model import RUN_FRAMES, OnlineTrackModel
from clm_core.online.policy import InputPolicy, Timeline
from clm_core.online.records import OnlineStats, Reason, Rejected, ResponseFrame, WheelFrame

__all__ = [
    "RUN_FRAMES",
    "InputPolicy",
    "OnlineStats",
    "OnlineTrackModel",
    "Reason",
    "Rejected",
    "ResponseFrame",
    "Timeline",
    "WheelFrame",
]
