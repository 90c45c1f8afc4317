"""The online edge: serialized wheel loads in, serialized responses out (decode -> process -> encode).

The one path of the track node, ``clm replay`` and the fleet's offline check
from the bytes of ``clm_msgs/WheelLoads`` messages to those of their
``clm_msgs/SleeperResponse`` and ``clm_msgs/WheelRailResponse`` answers:

1. :func:`decode`: each message with the numpy CDR codec
   (:func:`frame_from_cdr`); an undecodable one is
   refused (``malformed``) and counted by the model
   (:meth:`~clm_core.online.OnlineTrackModel.reject`);
2. :func:`respond`: every decoded frame through the model in one call
   (:meth:`~clm_core.online.OnlineTrackModel.process_batch`), and each
   response made an :class:`Answer`, whose two messages are serialized when
   first read (a node that publishes every n-th answer encodes only those);
3. :func:`answer`: both, for callers with nothing to do in between.

:func:`frame_from_cdr` and :func:`frame_from_msg` make the model's frame of
one ``WheelLoads`` (CDR bytes, or a decoded rclpy/rosbags message).

The results are in the order of the messages: an :class:`Answer` or the
:class:`~clm_core.online.Rejected` of each.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from clm_core.io.errors import MessageError
from clm_core.io.messages import decode_wheel_loads, encode_sleeper_response, encode_wheel_rail_response
from clm_core.io.timebase import stamp_ns
from clm_core.online.model import OnlineTrackModel
from clm_core.online.records import Reason, Rejected, ResponseFrame, WheelFrame


def frame_from_msg(msg: Any) -> WheelFrame:
    """``clm_msgs/WheelLoads`` (rclpy or rosbags) -> the online model's frame.

    Parameters
    ----------
    msg : WheelLoads
        Any flavour with ``header`` and ``wheels[].id/position/force/speed``.

    Returns
    -------
    clm_core.online.WheelFrame
        Stamp [ns] (integer), ids, positions [m], forces [N] (positive
        downwards), speeds [m/s], ``header.frame_id``.

    Raises
    ------
    MessageError
        A stamp outside ``builtin_interfaces/Time`` (``nanosec`` >= 1e9,
        ``sec`` outside int32): the message is malformed.
    """
    wheels = list(msg.wheels)
    return WheelFrame.of(
        stamp_ns(msg.header, check=True),
        [w.id for w in wheels],
        [w.position for w in wheels],
        [w.force for w in wheels],
        [w.speed for w in wheels],
        str(msg.header.frame_id),
    )


def frame_from_cdr(data: Any) -> WheelFrame:
    """Serialized ``clm_msgs/WheelLoads`` (CDR bytes, as on the wire or in a bag) -> the online model's frame.

    :func:`clm_core.io.messages.decode_wheel_loads` (numpy codec, no per-wheel Python) and the
    frame of its arrays: stamp [ns], ids (int64), positions [m], forces [N],
    speeds [m/s], ``header.frame_id``.

    Raises
    ------
    MessageError
        Truncated or malformed bytes, a header ``nanosec`` >= 1e9.
    """
    d = decode_wheel_loads(data)
    return WheelFrame(d.stamp_ns, d.ids.astype(np.int64), d.positions, d.forces, d.speeds, d.frame_id)


class Answer:
    """The answer to one accepted message: the response and its two messages (serialized when first read).

    Parameters
    ----------
    response : ResponseFrame
        The model's response to the message's frame.
    frame_id : str
        ``header.frame_id`` of both answers (their stamp is the input's).
    """

    __slots__ = ("_sleeper", "_wheel_rail", "frame_id", "response")

    def __init__(self, response: ResponseFrame, frame_id: str) -> None:
        self.response, self.frame_id = response, frame_id
        self._sleeper: bytes | None = None
        self._wheel_rail: bytes | None = None

    @property
    def stamp_ns(self) -> int:
        """Stamp of the input message and of both answers [ns]."""
        return self.response.stamp_ns

    @property
    def sleeper_response(self) -> bytes:
        """The serialized ``clm_msgs/SleeperResponse``: the window's sleepers (fields [N], [m])."""
        if self._sleeper is None:
            r = self.response
            self._sleeper = encode_sleeper_response(r.stamp_ns, self.frame_id, r.sleeper_index, r.sleeper_x,
                                                    r.soil_force, r.rail_deflection, r.sleeper_displacement,
                                                    r.area_displacement)
        return self._sleeper

    @property
    def wheel_rail_response(self) -> bytes:
        """The serialized ``clm_msgs/WheelRailResponse``: rail deflection [m] and velocity [m/s] under each wheel."""
        if self._wheel_rail is None:
            r = self.response
            # the ids came in as uint32 (decoded): the cast cannot overflow
            self._wheel_rail = encode_wheel_rail_response(r.stamp_ns, self.frame_id, r.wheel_ids.astype(np.uint32),
                                                          r.wheel_positions, r.wheel_deflection, r.wheel_velocity)
        return self._wheel_rail


def decode(model: OnlineTrackModel, raws: Sequence[Any], topic: str = "", first: int = 1
           ) -> tuple[list[WheelFrame], list[Rejected | None]]:
    """The frames of the decodable messages, and per message its refusal (None: decoded).

    Parameters
    ----------
    model : OnlineTrackModel
        Counts the refusals (``malformed``) with its others.
    raws : sequence of bytes-like
        Serialized ``clm_msgs/WheelLoads`` messages (CDR, as on the wire or in a bag).
    topic : str
        Where they came from, for the refusals' text.
    first : int
        Number of the first message (in the stream or bag), for the refusals' text.
    """
    frames: list[WheelFrame] = []
    refused: list[Rejected | None] = []
    on = f" on {topic}" if topic else ""
    for i, raw in enumerate(raws):
        try:
            frames.append(frame_from_cdr(raw))
        except MessageError as exc:
            refused.append(model.reject(Reason.MALFORMED, f"message {first + i}{on} cannot be decoded ({exc})"))
            continue
        refused.append(None)
    return frames, refused


def respond(model: OnlineTrackModel, frames: Sequence[WheelFrame], refused: Sequence[Rejected | None],
            frame_id: str = "track") -> list[Answer | Rejected]:
    """Process the decoded ``frames`` in one call; the answer or refusal of every message, in order.

    Parameters
    ----------
    model : OnlineTrackModel
        The processor (its state and counters move on).
    frames : sequence of WheelFrame
        The decoded frames, in order (:func:`decode`).
    refused : sequence of Rejected or None
        Per message, its refusal at decoding or None (one None per frame).
    frame_id : str
        ``header.frame_id`` of the answers.
    """
    results = iter(model.process_batch(frames) if frames else ())
    out: list[Answer | Rejected] = []
    for pre in refused:
        r = pre if pre is not None else next(results)
        out.append(r if isinstance(r, Rejected) else Answer(r, frame_id))
    return out


def answer(model: OnlineTrackModel, raws: Sequence[Any], frame_id: str = "track", topic: str = "", first: int = 1
           ) -> list[Answer | Rejected]:
    """Serialized wheel loads in, answers out: :func:`decode` then :func:`respond`.

    Parameters
    ----------
    model : OnlineTrackModel
        The processor.
    raws : sequence of bytes-like
        Serialized ``clm_msgs/WheelLoads`` messages, in order.
    frame_id : str
        ``header.frame_id`` of the answers.
    topic : str
        Where the messages came from (text of a ``malformed`` refusal).
    first : int
        Number of the first message (text of a ``malformed`` refusal).

    Returns
    -------
    list of Answer or Rejected
        One per message, in order.

    Examples
    --------
    >>> from clm_core.io.messages import decode_wheel_rail_response, encode_wheel_loads
    >>> from clm_core.online import OnlineTrackModel
    >>> model = OnlineTrackModel.from_settings({"n_sleepers": 31})
    >>> raws = [encode_wheel_loads(10**9 + k * 10**6, "train", [7], [0.1 * k], [100e3]) for k in range(3)]
    >>> out = answer(model, [*raws, b"junk"])
    >>> [type(a).__name__ for a in out]
    ['Answer', 'Answer', 'Answer', 'Rejected']
    >>> msg = decode_wheel_rail_response(out[2].wheel_rail_response)
    >>> msg.stamp_ns, msg.wheel_id.tolist(), bool(msg.rail_deflection[0] > 0)
    (1002000000, [7], True)
    >>> out[3].reason.value, model.stats.accepted, model.stats.rejected["malformed"]
    ('malformed', 3, 1)
    """
    frames, refused = decode(model, raws, topic, first)
    return respond(model, frames, refused, frame_id)


__all__ = ["Answer", "answer", "decode", "respond"]
