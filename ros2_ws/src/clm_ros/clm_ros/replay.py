"""Offline replay: a wheel-load bag through the track node's code path, no middleware.

``clm replay IN_BAG --out OUT_BAG`` reads ``clm_msgs/WheelLoads`` messages
from a rosbag2 bag (mcap or sqlite3) with the suite's bag reader
(:class:`clm_core.io.bags.BagReader`: counts cross-checked against the
metadata, damaged chunks refused unless ``allow_partial``), passes each
through :class:`clm_core.online.OnlineTrackModel` exactly as the track node
does, and writes a bag (:class:`clm_core.io.bags.BagWriter`: it appears only
when complete) with the input messages (copied byte for byte) and the
responses (``sleeper_response``, ``wheel_rail_response``) stamped like their
inputs. Rejected messages are counted and reported, as in the node.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clm_core.errors import InputError
from clm_core.io.bags import BagReader, BagWriter, default_qos
from clm_core.io.errors import BagError, MessageError
from clm_core.io.messages import (
    SLEEPER_RESPONSE,
    WHEEL_LOADS,
    WHEEL_RAIL_RESPONSE,
    encode_sleeper_response,
    encode_wheel_rail_response,
    frame_from_msg,
    sleeper_fields,
    wheel_fields,
)
from clm_core.io.timebase import NS
from clm_core.online import OnlineTrackModel, Reason, Rejected
from clm_ros.errors import ClmRosError

WHEEL_RAIL = WHEEL_RAIL_RESPONSE
SLEEPER = SLEEPER_RESPONSE


@dataclass
class ReplayStats:
    """What a replay did."""

    read: int = 0
    accepted: int = 0
    written: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    expected: int = 0
    """Wheel-load messages the input bag's metadata lists."""
    damage: list[str] = field(default_factory=list)
    """With ``allow_partial``: what was missing or damaged in the input (empty: complete)."""

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else 0.0


def replay_bag(
    in_bag: str | Path,
    out_bag: str | Path,
    model: OnlineTrackModel,
    topic: str | None = None,
    storage: str = "mcap",
    frame_id: str = "track",
    out_prefix: str = "",
    progress: Any = None,
    allow_partial: bool = False,
) -> ReplayStats:
    """Run the wheel loads of ``in_bag`` through ``model``; write inputs and responses to ``out_bag``.

    Parameters
    ----------
    in_bag, out_bag : path
        Input bag; output bag directory (must not exist; it appears only when complete).
    model : OnlineTrackModel
        The processor (fresh, or continuing a stream).
    topic : str, optional
        Wheel-load topic; default: the only ``clm_msgs/msg/WheelLoads`` topic.
    storage : {'mcap', 'sqlite3'}
        Output storage.
    out_prefix : str
        Namespace of the response topics (``{prefix}/sleeper_response``).
    progress : callable, optional
        Called with the number of messages done.
    allow_partial : bool
        Replay what is left of a damaged input bag (listed in ``ReplayStats.damage``).

    Raises
    ------
    ClmRosError
        Unreadable, empty or damaged input (unless ``allow_partial``), no
        wheel-load topic or one of another type, an undecodable message, an
        existing output.
    """
    if Path(out_bag).exists():
        raise ClmRosError(f"output bag {str(out_bag)!r} exists; choose a new path")
    stats = ReplayStats()
    try:
        with BagReader(in_bag, allow_partial=allow_partial) as reader:
            in_topic = reader.find(WHEEL_LOADS, topic)
            info = reader.topics[in_topic]
            stats.expected = info.message_count
            with BagWriter(out_bag, storage) as writer:
                c_in = writer.add_topic(in_topic, WHEEL_LOADS, qos=list(info.qos) or default_qos())
                c_s = writer.add_topic(f"{out_prefix}/sleeper_response", SLEEPER_RESPONSE)
                c_w = writer.add_topic(f"{out_prefix}/wheel_rail_response", WHEEL_RAIL_RESPONSE)
                w0 = time.perf_counter()
                _run(reader, writer, model, stats, in_topic, (c_in, c_s, c_w), frame_id, progress)
                stats.wall_time_s = time.perf_counter() - w0
            stats.damage = list(reader.report.damaged)
    except BagError as exc:
        raise ClmRosError(str(exc)) from None
    return stats


def _run(reader: BagReader, writer: BagWriter, model: OnlineTrackModel, stats: ReplayStats, in_topic: str,
         conns: tuple[Any, Any, Any], frame_id: str, progress: Any) -> None:
    c_in, c_s, c_w = conns
    sim0 = model.stats.simulated_ns
    for m in reader.messages([in_topic]):
        stats.read += 1
        writer.write(c_in, m.log_ns, m.data)
        try:
            msg = reader.deserialize(m.data, m.msgtype)
        except Exception as exc:
            raise ClmRosError(
                f"bag {str(reader.path)!r}: message {stats.read} on {in_topic} cannot be decoded ({exc})"
            ) from None
        try:
            frame = frame_from_msg(msg)
        except MessageError as exc:
            stats.rejected[model.reject(Reason.MALFORMED, str(exc)).reason.value] += 1
            continue
        try:
            resp = model.process(frame)
        except Rejected as exc:
            stats.rejected[exc.reason.value] += 1
            continue
        except InputError as exc:  # pragma: no cover - process only raises Rejected
            stats.rejected[str(exc)] += 1
            continue
        stats.accepted += 1
        t_ns = resp.stamp_ns
        s, w = sleeper_fields(resp), wheel_fields(resp)
        writer.write(c_s, m.log_ns, encode_sleeper_response(t_ns, frame_id, *s.values()))
        writer.write(c_w, m.log_ns, encode_wheel_rail_response(t_ns, frame_id, *w.values()))
        stats.written += 1
        if progress is not None:
            progress(stats.read)
    stats.sim_time_s = (model.stats.simulated_ns - sim0) / NS
