"""rosbag2 Jazzy file details for :mod:`clm_core.io.bags`: metadata layout, QoS strings, storage plugins.

What ``ros2 bag record`` of ROS 2 Jazzy writes, and rosbags (0.11) does not:

- ``metadata.yaml`` in rosbag2's key order and yaml-cpp's block style, with
  ``ros_distro: jazzy`` and, per topic, the offered QoS profiles as a YAML
  list (format version 9: enum names, e.g. ``reliability: reliable``);
- the same metadata embedded in the storage file (mcap metadata record
  ``rosbag2`` / ``serialized_metadata``; sqlite3 ``metadata`` table) and
  ``ros_distro`` in the sqlite3 ``schema`` table;
- on every mcap channel the metadata ``offered_qos_profiles`` (the string
  ``YAML::Dump`` gives for the list) and ``topic_type_hash`` (RIHS01);
- the CRC-32 of every mcap chunk, so that a damaged chunk is detected.

The storage subclasses reach into rosbags' writer classes (``McapWriter``,
``Sqlite3Writer``); tests/io check the files they produce with independent
readers (``mcap``, ``mcap-ros2-support``, sqlite3).
"""

from __future__ import annotations

import json
import re
from binascii import crc32
from collections.abc import Mapping, Sequence
from io import BytesIO
from typing import TYPE_CHECKING, Any, cast

from rosbags.interfaces import (
    ConnectionExtRosbag2,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.rosbag2.storage_mcap import Channel, McapWriter, write_channel, write_string
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer

if TYPE_CHECKING:
    from pathlib import Path

    from rosbags.interfaces import Connection

__all__ = ["ROS_DISTRO", "Rosbag2Writer", "emit_yaml", "infinite", "qos_dicts", "qos_profile", "qos_yaml"]

#: ROS distribution recorded in the metadata.
ROS_DISTRO = "jazzy"
#: RMW_DURATION_INFINITE as rosbag2 writes it (sec, nsec).
_INFINITE = (9223372036, 854775807)
_PLAIN = re.compile(r"[A-Za-z0-9_/.][A-Za-z0-9_/.\-]*")
_YAML_WORDS = frozenset({"true", "false", "yes", "no", "on", "off", "null", "y", "n"})


def infinite() -> QosTime:
    """RMW_DURATION_INFINITE (what the middleware reports for an unset deadline, lifespan, lease)."""
    return QosTime(*_INFINITE)


def qos_profile(
    reliability: str = "reliable",
    durability: str = "volatile",
    history: str = "unknown",
    depth: int = 0,
) -> Qos:
    """An offered QoS profile as ``ros2 bag record`` stores it for a publisher discovered on the graph.

    Parameters
    ----------
    reliability : {'reliable', 'best_effort'}
    durability : {'volatile', 'transient_local'}
    history : {'unknown', 'keep_last', 'keep_all'}
        Discovery does not carry history and depth: recorded profiles say
        ``unknown`` and 0.
    depth : int
        Keep-last depth [-].

    Returns
    -------
    rosbags.interfaces.Qos
        With infinite deadline, lifespan and liveliness lease, automatic liveliness.
    """
    return Qos(
        history=QosHistory[history.upper()],
        depth=int(depth),
        reliability=QosReliability[reliability.upper()],
        durability=QosDurability[durability.upper()],
        deadline=infinite(),
        lifespan=infinite(),
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=infinite(),
        avoid_ros_namespace_conventions=False,
    )


def qos_dicts(profiles: Sequence[Qos]) -> list[dict[str, Any]]:
    """QoS profiles as rosbag2 format version 9 encodes them (enum names in lower case)."""
    return [
        {
            "history": q.history.name.lower(),
            "depth": int(q.depth),
            "reliability": q.reliability.name.lower(),
            "durability": q.durability.name.lower(),
            "deadline": {"sec": q.deadline.sec, "nsec": q.deadline.nsec},
            "lifespan": {"sec": q.lifespan.sec, "nsec": q.lifespan.nsec},
            "liveliness": q.liveliness.name.lower(),
            "liveliness_lease_duration": {
                "sec": q.liveliness_lease_duration.sec,
                "nsec": q.liveliness_lease_duration.nsec,
            },
            "avoid_ros_namespace_conventions": bool(q.avoid_ros_namespace_conventions),
        }
        for q in profiles
    ]


def _scalar(v: Any) -> str:
    if v is None:
        return "~"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    s = str(v)
    if s and _PLAIN.fullmatch(s) and s.lower() not in _YAML_WORDS and not re.fullmatch(r"[-+.\d][\d._eE+-]*", s):
        return s
    return json.dumps(s, ensure_ascii=False)  # a YAML double-quoted scalar


def _lines(obj: Any, indent: int) -> list[str]:
    pad = " " * indent
    out: list[str] = []
    if isinstance(obj, Mapping):
        for k, v in obj.items():
            if isinstance(v, Mapping) and v:
                out += [f"{pad}{k}:", *_lines(v, indent + 2)]
            elif isinstance(v, list) and v:
                out += [f"{pad}{k}:", *_lines(v, indent + 2)]
            else:
                out.append(f"{pad}{k}: {_empty(v)}")
        return out
    for item in obj:
        nested = isinstance(item, (Mapping, list)) and item
        sub = _lines(item, indent + 2) if nested else [" " * (indent + 2) + _empty(item)]
        out.append(f"{pad}- {sub[0][indent + 2 :]}")
        out += sub[1:]
    return out


def _empty(v: Any) -> str:
    if isinstance(v, Mapping):
        return "{}"
    if isinstance(v, list):
        return "[]"
    return _scalar(v)


def emit_yaml(obj: Mapping[str, Any] | list[Any]) -> str:
    """Block-style YAML as yaml-cpp emits it (rosbag2's metadata.yaml), no final newline."""
    if not obj:
        return _empty(obj)
    return "\n".join(_lines(obj, 0))


def qos_yaml(profiles: Sequence[Qos]) -> str:
    """The ``offered_qos_profiles`` string of an mcap channel / sqlite3 topic (``YAML::Dump`` of the list)."""
    return emit_yaml(qos_dicts(profiles))


# --------------------------------------------------------------------------- storage plugins


class _McapStorage(McapWriter):
    """rosbags' mcap writer plus type hashes and QoS strings on channels, chunk CRCs, Jazzy metadata."""

    metadata_text: str | None = None

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        _ = offered_qos_profiles
        ext = cast("ConnectionExtRosbag2", connection.ext)
        meta = BytesIO()
        write_string(meta, "offered_qos_profiles")
        write_string(meta, qos_yaml(ext.offered_qos_profiles))
        write_string(meta, "topic_type_hash")
        write_string(meta, connection.digest)
        self.channels.append(
            Channel(connection.id, connection.msgtype, connection.topic, ext.serialization_format, meta.getvalue())
        )
        self.channel_stats[connection.id] = 0
        write_channel(self.chunk.bio, self.channels[-1], self.schemas)

    def close_chunk(self) -> None:
        crc = crc32(self.chunk.bio.getbuffer())
        start = self.bio.tell()  # the chunk record is the next thing written
        super().close_chunk()
        end = self.bio.tell()
        self.bio.seek(start + 1 + 8 + 24)  # opcode, record length, start/end time, uncompressed size
        self.bio.write(crc.to_bytes(4, "little"))
        self.bio.seek(end)

    def close(self, version: int, metadata: str) -> None:
        super().close(version, self.metadata_text or metadata)


class _Sqlite3Storage(Sqlite3Writer):
    """rosbags' sqlite3 writer with rosbag2 Jazzy's QoS strings and distribution."""

    SQLITE_SCHEMA = Sqlite3Writer.SQLITE_SCHEMA.replace("'rosbags'", f"'{ROS_DISTRO}'")
    metadata_text: str | None = None

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        _ = offered_qos_profiles
        ext = cast("ConnectionExtRosbag2", connection.ext)
        super().add_connection(connection, qos_yaml(ext.offered_qos_profiles))

    def close(self, version: int, metadata: str) -> None:
        super().close(version, self.metadata_text or metadata)


class Rosbag2Writer(Writer):
    """rosbags' Writer (format version 9) with the storage plugins above and rosbag2's metadata.yaml."""

    STORAGE_PLUGINS = {StoragePlugin.MCAP: _McapStorage, StoragePlugin.SQLITE3: _Sqlite3Storage}  # noqa: RUF012

    def __init__(self, path: Path, storage_plugin: StoragePlugin) -> None:
        super().__init__(path, version=9, storage_plugin=storage_plugin)

    def metadata(self) -> dict[str, Any]:
        """The bag's metadata (rosbag2's ``BagMetadata``, key order of its YAML encoder)."""
        assert self.storage is not None
        name = self.storage.path.name
        count = sum(self.counts.values())
        start = self.min_timestamp
        duration = max(0, self.max_timestamp - self.min_timestamp)
        topics = [
            {
                "topic_metadata": {
                    "name": c.topic,
                    "type": c.msgtype,
                    "serialization_format": cast("ConnectionExtRosbag2", c.ext).serialization_format,
                    "offered_qos_profiles": qos_dicts(cast("ConnectionExtRosbag2", c.ext).offered_qos_profiles),
                    "type_description_hash": c.digest,
                },
                "message_count": self.counts[c.id],
            }
            for c in self.connections
        ]
        return {
            "version": self.version,
            "storage_identifier": self.storage_plugin.name.lower(),
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [name],
            "files": [
                {
                    "path": name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": count,
                }
            ],
            "custom_data": dict(self.custom_data) or None,
            "ros_distro": ROS_DISTRO,
        }

    def close(self) -> None:
        """Close the storage (with the embedded metadata) and write metadata.yaml as rosbag2 does."""
        meta = self.metadata()
        storage = cast("_McapStorage | _Sqlite3Storage", self.storage)
        storage.metadata_text = emit_yaml(meta)
        super().close()
        self.metapath.write_text(emit_yaml({"rosbag2_bagfile_information": meta}), encoding="utf-8")
