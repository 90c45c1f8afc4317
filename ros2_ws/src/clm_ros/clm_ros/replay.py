"""Offline replay: a wheel-load bag through the track node's code path, no middleware.

``clm replay IN_BAG --out OUT_BAG`` reads ``clm_msgs/WheelLoads`` messages
from a rosbag2 bag (mcap or sqlite3) with ``rosbags``, passes each through
:class:`clm_core.online.OnlineTrackModel` exactly as the track node does, and
writes a bag with the input messages (copied byte for byte) and the
responses (``sleeper_response``, ``wheel_rail_response``) stamped like their
inputs. Rejected messages are counted and reported, as in the node.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from clm_core.errors import InputError
from clm_core.online import OnlineTrackModel, Rejected
from clm_ros.conversions import frame_from_msg, rosbags_responses, stamp_ns
from clm_ros.errors import ClmRosError
from clm_ros.msg_types import typestore

WHEEL_LOADS = "clm_msgs/msg/WheelLoads"
SLEEPER = "clm_msgs/msg/SleeperResponse"
WHEEL_RAIL = "clm_msgs/msg/WheelRailResponse"


@dataclass
class ReplayStats:
    """What a replay did."""

    read: int = 0
    accepted: int = 0
    written: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else 0.0


def open_reader(path: str | Path) -> AnyReader:
    """Open a rosbag2 bag (directory or single .mcap/.db3) with a clear error if it is unreadable."""
    p = Path(path)
    if not p.exists():
        raise ClmRosError(f"bag {str(p)!r} not found")
    try:
        reader = AnyReader([p], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # rosbags raises several types for corrupt bags
        raise ClmRosError(f"bag {str(p)!r} cannot be read ({type(exc).__name__}: {exc})") from None
    return reader


def storage_plugin(name: str) -> StoragePlugin:
    """``mcap`` or ``sqlite3``."""
    try:
        return {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[name]
    except KeyError:
        raise ClmRosError(f"storage = {name!r}: one of mcap, sqlite3") from None


def replay_bag(
    in_bag: str | Path,
    out_bag: str | Path,
    model: OnlineTrackModel,
    topic: str | None = None,
    storage: str = "mcap",
    frame_id: str = "track",
    out_prefix: str = "",
    progress: Any = None,
) -> ReplayStats:
    """Run the wheel loads of ``in_bag`` through ``model``; write inputs and responses to ``out_bag``.

    Parameters
    ----------
    in_bag, out_bag : path
        Input bag; output bag directory (must not exist).
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
    """
    out = Path(out_bag)
    if out.exists():
        raise ClmRosError(f"output bag {str(out)!r} exists; choose a new path")
    ts = typestore()
    stats = ReplayStats()
    reader = open_reader(in_bag)
    try:
        conns = [c for c in reader.connections if c.msgtype == WHEEL_LOADS and (topic is None or c.topic == topic)]
        if not conns:
            have = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
            raise ClmRosError(
                f"bag {str(in_bag)!r}: no {WHEEL_LOADS} topic{f' {topic!r}' if topic else ''}; has {have}"
            )
        if len({c.topic for c in conns}) > 1:
            raise ClmRosError(
                f"bag {str(in_bag)!r}: several wheel-load topics {sorted({c.topic for c in conns})}; pass topic="
            )
        in_topic = conns[0].topic
        writer = Writer(out, version=8, storage_plugin=storage_plugin(storage))
        with writer:
            c_in = writer.add_connection(in_topic, WHEEL_LOADS, typestore=ts)
            c_s = writer.add_connection(f"{out_prefix}/sleeper_response", SLEEPER, typestore=ts)
            c_w = writer.add_connection(f"{out_prefix}/wheel_rail_response", WHEEL_RAIL, typestore=ts)
            w0 = time.perf_counter()
            sim_t = 0.0
            for conn, bag_t, raw in reader.messages(connections=conns):
                stats.read += 1
                writer.write(c_in, bag_t, raw)
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as exc:
                    raise ClmRosError(
                        f"bag {str(in_bag)!r}: message {stats.read} on {in_topic} cannot be decoded ({exc})"
                    ) from None
                before = model.sim.t
                try:
                    resp = model.process(frame_from_msg(msg))
                except Rejected as exc:
                    stats.rejected[exc.reason.value] += 1
                    continue
                except InputError as exc:  # pragma: no cover - process only raises Rejected
                    stats.rejected[str(exc)] += 1
                    continue
                if not resp.resynced:
                    sim_t += model.sim.t - before
                stats.accepted += 1
                t_ns = stamp_ns(msg.header)
                s, w = rosbags_responses(ts, resp, t_ns, frame_id)
                writer.write(c_s, bag_t, ts.serialize_cdr(s, SLEEPER))
                writer.write(c_w, bag_t, ts.serialize_cdr(w, WHEEL_RAIL))
                stats.written += 1
                if progress is not None:
                    progress(stats.read)
            stats.wall_time_s = time.perf_counter() - w0
            stats.sim_time_s = sim_t
    finally:
        reader.close()
    return stats
