"""Offline replay: a wheel-load bag through the track node's code path, no middleware.

``clm replay IN_BAG --out OUT_BAG`` reads ``clm_msgs/WheelLoads`` messages
from a rosbag2 bag (mcap or sqlite3) with the suite's bag reader
(:class:`clm_core.io.bags.BagReader`: counts cross-checked against the
metadata, damaged chunks refused unless ``allow_partial``), decodes them with
the online edge of the track node (:func:`clm_core.online.answer`: the numpy
CDR codec, :meth:`~clm_core.online.OnlineTrackModel.process_batch` in
chunks, bit for bit what the track node computes message by message, and
the encoded answers), and writes a bag
(:class:`clm_core.io.bags.BagWriter`: it appears only when complete) with the
input messages (copied byte for byte) and the responses (``sleeper_response``,
``wheel_rail_response``) stamped like their inputs.

Refused messages (the input policy of :mod:`clm_core.online`; an undecodable
message is ``malformed``) are counted per cause. More of them than
``max_rejected`` allows end the replay with a :class:`ClmRosError` naming the
counts and the first refusal of each cause, and no output bag.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clm_core.io.bags import BagReader, BagWriter, default_qos
from clm_core.io.errors import BagError
from clm_core.io.messages import SLEEPER_RESPONSE, WHEEL_LOADS, WHEEL_RAIL_RESPONSE
from clm_core.io.timebase import NS
from clm_core.online import OnlineTrackModel, Rejected, answer
from clm_ros.errors import ClmRosError

WHEEL_RAIL = WHEEL_RAIL_RESPONSE
SLEEPER = SLEEPER_RESPONSE


#: Messages decoded and processed per call of the model (a chunk of the bag).
CHUNK = 256


@dataclass
class ReplayStats:
    """What a replay did."""

    read: int = 0
    accepted: int = 0
    written: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    first_rejections: dict[str, str] = field(default_factory=dict)
    """The first refusal of each cause (message number and reason)."""
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

    def refusals(self) -> str:
        """The refusals per cause, and the first of each: ``2 non_finite (first: ...); ...``."""
        return "; ".join(f"{n} {k} (first: {self.first_rejections.get(k, '')})"
                         for k, n in sorted(self.rejected.items()))


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
    max_rejected: int | None = None,
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
    max_rejected : int, optional
        Most refused messages allowed (None: any number); one more ends the
        replay with an error and no output.

    Raises
    ------
    ClmRosError
        Unreadable, empty or damaged input (unless ``allow_partial``), no
        wheel-load topic or one of another type, an existing output, more
        refused messages than ``max_rejected``.
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
                sim0 = model.stats.simulated_ns
                chunk: list[Any] = []
                for m in reader.messages([in_topic]):
                    chunk.append(m)
                    if len(chunk) == CHUNK:
                        _chunk(chunk, model, writer, (c_in, c_s, c_w), in_topic, frame_id, stats, max_rejected)
                        chunk = []
                        if progress is not None:
                            progress(stats.read)
                _chunk(chunk, model, writer, (c_in, c_s, c_w), in_topic, frame_id, stats, max_rejected)
                if progress is not None:
                    progress(stats.read)
                stats.sim_time_s = (model.stats.simulated_ns - sim0) / NS
                stats.wall_time_s = time.perf_counter() - w0
            stats.damage = list(reader.report.damaged)
    except BagError as exc:
        raise ClmRosError(str(exc)) from None
    return stats


def _chunk(chunk: list[Any], model: OnlineTrackModel, writer: BagWriter, conns: tuple[Any, Any, Any], in_topic: str,
           frame_id: str, stats: ReplayStats, max_rejected: int | None) -> None:
    """Decode and process a chunk of messages, write them and their responses in order."""
    c_in, c_s, c_w = conns
    answers = answer(model, [m.data for m in chunk], frame_id, topic=in_topic, first=stats.read + 1)
    for m, res in zip(chunk, answers):
        stats.read += 1
        writer.write(c_in, m.log_ns, m.data)
        if isinstance(res, Rejected):
            cause = res.reason.value
            stats.rejected[cause] += 1
            stats.first_rejections.setdefault(cause, f"message {stats.read}: {res}")
            if max_rejected is not None and sum(stats.rejected.values()) > max_rejected:
                raise ClmRosError(
                    f"{sum(stats.rejected.values())} of the first {stats.read} wheel-load messages refused, more "
                    f"than --max-rejected {max_rejected} allows: {stats.refusals()}; no output written"
                )
            continue
        stats.accepted += 1
        writer.write(c_s, m.log_ns, res.sleeper_response)
        writer.write(c_w, m.log_ns, res.wheel_rail_response)
        stats.written += 1
