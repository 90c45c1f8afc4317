"""Reading calibration records from rosbag2 bags (mcap or sqlite3).

Bags are opened with the suite's one reader, :class:`clm_core.io.bags.BagReader`
(what a bag is, count cross-checks, damaged chunks, ``allow_partial``); it
uses the message definitions stored in the bag, so the suite's own messages
(``clm_msgs``) and plain standard messages are read alike, with no ROS
installation. This module turns the messages into calibration records.

Values are taken from the field the channel map names, or from the default
field of the message type (:data:`DEFAULT_FIELDS`). A field path may index
arrays (``data[3]``). The time of a sample is ``header.stamp`` when the
message has a header (or ``stamp: header`` is asked), else the bag's log
time. A message whose field is an array of samples (``Float64MultiArray``
blocks) holds consecutive samples at the channel's ``sample_rate``, the
first one at the message's time. In ``clm_msgs/msg/SleeperResponse`` the
array entry of the channel's sleeper (``sleeper_index``) is taken.

Every failure becomes a :class:`~clm_core.calibration.errors.BagError` that
names the bag or topic: missing, truncated, corrupt or empty files, message
counts that disagree with the metadata, missing topics, a wheel-loads topic
of another type, messages without the field, and the checks of
:mod:`clm_core.calibration.signals`.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.calibration.channels import ChannelMap, ChannelSpec
from clm_core.calibration.errors import BagError, CalibrationError
from clm_core.calibration.signals import Recording, SamplingRules, Signal, common_grid
from clm_core.io.bags import BagReader
from clm_core.io.messages import WHEEL_LOADS
from clm_core.io.timebase import stamp_ns

#: Field read when the channel map gives none, by message type.
DEFAULT_FIELDS: Mapping[str, str] = {
    "geometry_msgs/msg/WrenchStamped": "wrench.force.z",
    "geometry_msgs/msg/Wrench": "force.z",
    "geometry_msgs/msg/Vector3Stamped": "vector.z",
    "geometry_msgs/msg/Vector3": "z",
    "geometry_msgs/msg/PointStamped": "point.z",
    "geometry_msgs/msg/AccelStamped": "accel.linear.z",
    "geometry_msgs/msg/TwistStamped": "twist.linear.z",
    "sensor_msgs/msg/Imu": "linear_acceleration.z",
    "std_msgs/msg/Float64": "data",
    "std_msgs/msg/Float32": "data",
    "std_msgs/msg/Float64MultiArray": "data",
    "std_msgs/msg/Float32MultiArray": "data",
}

_PART = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")


@dataclass(frozen=True)
class WheelLoadRecord:
    """Wheel loads read from ``clm_msgs/msg/WheelLoads`` messages.

    Attributes
    ----------
    t : (n_t,) array
        Times [s] from the recording's origin.
    wheel_ids : (n_w,) int array
        Wheel identifiers (``WheelLoad.id``), columns of the arrays below.
    positions : (n_t, n_w) array
        Contact positions along the line [m]; NaN where a wheel is absent.
    forces : (n_t, n_w) array
        Vertical forces [N], positive downwards; 0 where absent.
    """

    t: Array
    wheel_ids: NDArray[np.int64]
    positions: Array
    forces: Array


@dataclass(frozen=True)
class BagContents:
    """What was read from a bag for a calibration.

    Attributes
    ----------
    path : str
        The bag path.
    storage : str
        ``mcap`` or ``sqlite3``.
    recording : Recording
        Force and responses on one time grid.
    loads : WheelLoadRecord or None
        Wheel loads (pass-by).
    topics : mapping
        Every topic of the bag -> message type.
    damage : tuple of str
        With ``allow_partial``: what was missing or damaged (empty: complete).
    """

    path: str
    storage: str
    recording: Recording
    loads: WheelLoadRecord | None
    topics: Mapping[str, str]
    damage: tuple[str, ...] = field(default=())


def _resolve(msg: Any, path: str, where: str) -> Any:
    obj = msg
    for part in path.split("."):
        m = _PART.match(part)
        if not m:
            raise BagError(
                f"{where}: field path {path!r}: {part!r} is not a field name (use e.g. 'vector.z', 'data[2]')"
            )
        name, idx = m.group(1), m.group(2)
        if not hasattr(obj, name):
            fields = [f for f in getattr(obj, "__dataclass_fields__", {}) if not f.startswith("__")]
            raise BagError(f"{where}: the message has no field {path!r} ({name!r} missing; fields here: {fields})")
        obj = getattr(obj, name)
        if idx is not None:
            try:
                obj = obj[int(idx)]
            except (IndexError, TypeError):
                size = len(obj) if hasattr(obj, "__len__") else "?"
                raise BagError(f"{where}: field {path!r}: index {idx} out of range (array of {size})") from None
    return obj


def _stamp_ns(msg: Any) -> int | None:
    h = getattr(msg, "header", None)
    if getattr(h, "stamp", None) is None:
        return None
    return stamp_ns(h)


@contextmanager
def open_bag(bag_path: str | Path, allow_partial: bool = False) -> Iterator[BagReader]:
    """Open a bag with the suite's reader (:class:`clm_core.io.bags.BagReader`).

    Accepts a rosbag2 directory (``metadata.yaml`` + ``.mcap``/``.db3``), an
    ``.mcap`` or ``.db3`` file, or a directory with a single one and no metadata.

    Raises
    ------
    BagError
        Path missing; not a bag; truncated, corrupt or empty file.
    """
    reader = BagReader(bag_path, allow_partial=allow_partial)
    try:
        yield reader
    finally:
        reader.close()


def _messages(reader: BagReader, topics: set[str], p: Path) -> Iterator[tuple[str, str, int, Any]]:
    """Deserialized messages; a message that does not decode becomes a BagError."""
    for m in reader.messages(topics):
        try:
            msg = reader.deserialize(m.data, m.msgtype)
        except Exception as exc:
            raise BagError(
                f"bag {str(p)!r}: topic {m.topic}: a message at log time {m.log_ns} ns cannot be decoded as "
                f"{m.msgtype}: {exc} ({type(exc).__name__})"
            ) from None
        yield m.topic, m.msgtype, m.log_ns, msg


def read_bag(
    bag_path: str | Path,
    cmap: ChannelMap,
    rules: SamplingRules | None = None,
    need_force: bool = True,
    need_loads: bool = False,
    allow_partial: bool = False,
) -> BagContents:
    """Read the channels of a channel map from a bag and put them on one time grid.

    Parameters
    ----------
    bag_path : path
        rosbag2 directory or ``.mcap`` file.
    cmap : ChannelMap
        Which topics to read and how.
    rules : SamplingRules, optional
        Record checks (default :class:`SamplingRules`).
    need_force : bool
        The map must give a force channel (impact, receptance).
    need_loads : bool
        The map must give a wheel-loads topic (pass-by).
    allow_partial : bool
        Read what is left of a damaged bag (listed in ``BagContents.damage``)
        instead of raising.

    Returns
    -------
    BagContents

    Raises
    ------
    BagError
        Unreadable, empty or damaged bag (unless ``allow_partial``), missing
        topics, a loads topic that is not ``clm_msgs/msg/WheelLoads``,
        messages without the field, records failing the checks of :func:`clm_core.calibration.signals.check_signal`.
    CalibrationError
        The map lacks the force or loads entry the method needs.
    """
    rules = rules or SamplingRules()
    p = Path(bag_path)
    if need_force and cmap.force is None:
        raise CalibrationError(f"channel map {cmap.source}: no 'force' entry (the hammer force channel is needed)")
    if need_loads and not cmap.loads_topic:
        raise CalibrationError(f"channel map {cmap.source}: no 'loads' entry (the wheel-loads topic is needed)")
    specs: list[ChannelSpec] = ([cmap.force] if (need_force and cmap.force) else []) + list(cmap.channels)
    with open_bag(p, allow_partial) as reader:
        topics = {t: info.msgtype for t, info in reader.topics.items()}
        wanted = {s.topic for s in specs} | ({cmap.loads_topic} if need_loads and cmap.loads_topic else set())
        missing = sorted(wanted - set(topics))
        if missing:
            avail = ", ".join(f"{t} [{ty}]" for t, ty in sorted(topics.items())) or "none"
            raise BagError(
                f"bag {str(p)!r}: topic(s) {', '.join(missing)} not in the bag (channel map {cmap.source}); "
                f"topics in the bag: {avail}"
            )
        if need_loads and cmap.loads_topic and topics[cmap.loads_topic] != WHEEL_LOADS:
            raise BagError(
                f"bag {str(p)!r}: loads topic {cmap.loads_topic} carries {topics[cmap.loads_topic]}, expected "
                f"{WHEEL_LOADS} (channel map {cmap.source})"
            )
        by_topic: dict[str, list[ChannelSpec]] = {}
        for s in specs:
            by_topic.setdefault(s.topic, []).append(s)
        stamps: dict[int, list[int]] = {id(s): [] for s in specs}
        values: dict[int, list[Any]] = {id(s): [] for s in specs}
        load_rows: list[tuple[int, list[tuple[int, float, float]]]] = []
        counts = dict.fromkeys(wanted, 0)
        for topic, msgtype, log_ns, msg in _messages(reader, wanted, p):
            counts[topic] += 1
            if need_loads and topic == cmap.loads_topic:
                load_rows.append(_wheel_row(msg, log_ns, topic))
                if topic not in by_topic:
                    continue
            hdr = _stamp_ns(msg)
            for s in by_topic.get(topic, []):
                where = f"topic {topic} [{msgtype}]"
                path = s.field or DEFAULT_FIELDS.get(msgtype)
                if path is None:
                    raise BagError(
                        f"{where}: no default field for this message type; give 'field' in the channel map "
                        f"(types with defaults: {', '.join(DEFAULT_FIELDS)})"
                    )
                val = _resolve(msg, path, where)
                if s.stamp == "header" and hdr is None:
                    raise BagError(f"{where}: stamp: header asked but the message has no header")
                st = log_ns if (s.stamp == "log" or hdr is None) else hdr
                if hasattr(msg, "sleeper_index") and isinstance(val, np.ndarray) and s.location != "area":
                    idx = np.asarray(msg.sleeper_index)
                    hit = np.nonzero(idx == s.index)[0]
                    if hit.size == 0:
                        continue  # this message does not report the sleeper
                    val = val[hit[0]]
                stamps[id(s)].append(st)
                values[id(s)].append(val)
        for topic in sorted(wanted):
            if counts[topic] == 0:
                raise BagError(f"bag {str(p)!r}: topic {topic} has no messages (channel map {cmap.source})")
        storage = reader.storage
        damage = tuple(reader.report.damaged)
    origin = min(min(v) for v in stamps.values() if v) if any(stamps.values()) else 0
    if load_rows:
        origin = min(origin, min(r[0] for r in load_rows))
    signals: dict[int, Signal] = {}
    for s in specs:
        signals[id(s)] = _signal(s, stamps[id(s)], values[id(s)], origin)
    force_sig = signals[id(cmap.force)] if (need_force and cmap.force) else None
    resp = [signals[id(s)] for s in cmap.channels]
    rec = common_grid(force_sig, resp, rules, t_origin_ns=origin)
    loads = _wheel_record(load_rows, rec.t_origin_ns, cmap.loads_topic or "") if need_loads else None
    return BagContents(path=str(p), storage=storage, recording=rec, loads=loads, topics=topics, damage=damage)


def _signal(s: ChannelSpec, st: list[int], vals: list[Any], origin: int) -> Signal:
    name = f"topic {s.topic}" + (f" (field {s.field})" if s.field else "")
    if not st:
        raise BagError(f"{name}: no sample of {s.location} {s.index} in any message")
    first = vals[0]
    if isinstance(first, np.ndarray) or isinstance(first, (list, tuple)):
        if s.sample_rate is None:
            raise BagError(
                f"{name}: messages carry blocks of {len(first)} samples; give 'sample_rate' [Hz] in the channel "
                "map (the first sample of a block is at the message time)"
            )
        ts: list[Array] = []
        xs: list[Array] = []
        for t_ns, v in zip(st, vals):
            arr = np.asarray(v, dtype=float).ravel()
            ts.append((t_ns - origin) * 1e-9 + np.arange(arr.size) / s.sample_rate)
            xs.append(arr)
        t = np.concatenate(ts)
        x = np.concatenate(xs)
    else:
        try:
            x = np.asarray(vals, dtype=float)
        except (TypeError, ValueError):
            raise BagError(f"{name}: field value {first!r} is not a number") from None
        t = (np.asarray(st, dtype=np.int64) - origin).astype(float) * 1e-9
    order = np.argsort(t, kind="stable")  # messages may arrive out of stamp order
    return Signal(spec=s, t=t[order], values=x[order] * s.factor)


def _wheel_row(msg: Any, log_ns: int, topic: str) -> tuple[int, list[tuple[int, float, float]]]:
    wheels = getattr(msg, "wheels", None)
    if wheels is None:
        raise BagError(f"topic {topic}: expected clm_msgs/msg/WheelLoads messages (no 'wheels' field)")
    st = _stamp_ns(msg)
    return (log_ns if st is None else st, [(int(w.id), float(w.position), float(w.force)) for w in wheels])


def _wheel_record(rows: list[tuple[int, list[tuple[int, float, float]]]], origin: int, topic: str) -> WheelLoadRecord:
    if len(rows) < 2:
        raise BagError(f"topic {topic}: {len(rows)} WheelLoads message(s); need at least 2")
    rows = sorted(rows, key=lambda r: r[0])
    t = (np.array([r[0] for r in rows], dtype=np.int64) - origin).astype(float) * 1e-9
    if np.any(np.diff(t) <= 0):
        i = int(np.nonzero(np.diff(t) <= 0)[0][0])
        raise BagError(f"topic {topic}: two WheelLoads messages with the same stamp t = {t[i]:.6f} s")
    ids = sorted({w[0] for _, ws in rows for w in ws})
    if not ids:
        raise BagError(f"topic {topic}: no wheel in any WheelLoads message")
    col = {w: i for i, w in enumerate(ids)}
    P = np.full((t.size, len(ids)), np.nan)
    F = np.zeros((t.size, len(ids)))
    for k, (_, ws) in enumerate(rows):
        for wid, pos, force in ws:
            if not (np.isfinite(pos) and np.isfinite(force)):
                raise BagError(f"topic {topic}: wheel {wid} at t = {t[k]:.6f} s has position {pos} and force {force}")
            P[k, col[wid]] = pos
            F[k, col[wid]] = force
    return WheelLoadRecord(t=t, wheel_ids=np.array(ids, dtype=np.int64), positions=P, forces=F)
