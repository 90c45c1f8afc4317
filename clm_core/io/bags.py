"""The one rosbag2 reader and the one writer of the suite (rosbags; no ROS installation needed).

Writer (:class:`BagWriter`)
    Format version 9, mcap (default) or sqlite3, as ``ros2 bag record`` of ROS 2
    Jazzy writes it (:mod:`clm_core.io._rosbag2`): ``ros_distro: jazzy``, the
    offered QoS profiles of every topic, the message definitions with their
    comments (:func:`clm_core.io.messages.message_definition`: units and the
    sign convention travel with the data), RIHS01 type hashes in the metadata
    and on the mcap channels, CRC-32 on mcap chunks. The bag is written in a
    hidden sibling directory ``.NAME.partial-XXXX`` and renamed to ``NAME``
    only when it is complete: an interrupted or failed run never leaves
    something that looks like a bag.

Reader (:class:`BagReader`): what a bag is
    The same rule for every tool (``clm replay``, ``clm play``, ``clm calibrate``,
    the calibration readers):

    - a rosbag2 directory with ``metadata.yaml`` (what ``ros2 bag record`` makes);
    - a directory without ``metadata.yaml`` holding exactly one ``.mcap`` or
      ``.db3`` file, or that storage file itself (``metadata.yaml`` is not
      required: the storage file has its own index and, when written by
      rosbag2 or this writer, its own copy of the metadata).

    Message counts are cross-checked against ``metadata.yaml`` and the
    storage file's index: a chunk that fails its CRC or cannot be
    decompressed, a chunk that yields fewer messages than its index lists,
    and a total that differs from the metadata are reported with the byte
    range and log times, and raise :class:`~clm_core.io.errors.BagError`
    unless ``allow_partial`` (then they are listed in :attr:`BagReader.report`
    and reading goes on with the next chunk). A bag without messages, a path
    that is not a bag and a topic of another message type than expected are
    errors too.
"""

from __future__ import annotations

import contextlib
import heapq
import os
import shutil
import stat
import uuid
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from clm_core.io.errors import BagError

if TYPE_CHECKING:
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection, Qos
    from rosbags.typesys.store import Typestore

    from clm_core.io._rosbag2 import Rosbag2Writer

__all__ = [
    "FORMAT_VERSION",
    "STORAGES",
    "BagMessage",
    "BagReader",
    "BagWriter",
    "ReadReport",
    "TopicInfo",
    "default_qos",
    "is_bag",
    "storage_of",
]

#: rosbag2 metadata format version written (ROS 2 Jazzy).
FORMAT_VERSION = 9
#: Storage plugins (``--storage``).
STORAGES = ("mcap", "sqlite3")
_SUFFIX = {".mcap": "mcap", ".db3": "sqlite3"}


def _check_storage(storage: str) -> str:
    if storage not in STORAGES:
        raise BagError(f"storage = {storage!r}: must be one of {', '.join(STORAGES)}")
    return storage


def default_qos(reliability: str = "reliable") -> list[Qos]:
    """Offered QoS of a topic published by the suite's nodes, as ``ros2 bag record`` would store it.

    Parameters
    ----------
    reliability : {'reliable', 'best_effort'}

    Returns
    -------
    list of rosbags.interfaces.Qos
        One profile: the given reliability, volatile, history ``unknown``
        and depth 0 (not carried by discovery), infinite deadline, lifespan
        and lease, automatic liveliness.
    """
    from clm_core.io._rosbag2 import qos_profile

    return [qos_profile(reliability)]


# ============================================================================ writer


def _quietly(release: Callable[[], object] | None) -> None:
    """Call ``release`` (a rosbags writer's abort, a reader's close) if given, ignoring any exception it raises."""
    if release is not None:
        with contextlib.suppress(Exception):
            release()


class BagWriter:
    """Write a rosbag2 bag (format version 9) to a temporary directory; rename it when complete.

    Parameters
    ----------
    path : path-like
        The bag directory to create; must not exist.
    storage : {'mcap', 'sqlite3'}
        Storage plugin.
    compress : bool
        zstd chunk compression (mcap only).
    typestore : Typestore, optional
        Type store for :meth:`add_topic` and :meth:`write_msg` (default: the
        ROS 2 Jazzy store with the clm_msgs types).

    Examples
    --------
    >>> with BagWriter(tmp / "bag") as bag:                        # doctest: +SKIP
    ...     c = bag.add_topic("/wheel_loads", "clm_msgs/msg/WheelLoads")
    ...     bag.write(c, t_ns, raw_cdr_bytes)

    Notes
    -----
    Files written into :attr:`directory` before the writer closes (a channel
    map, a README) move with the bag. On an exception inside ``with`` the
    temporary directory is removed and nothing appears at ``path``.
    """

    def __init__(self, path: str | os.PathLike[str], storage: str = "mcap", *, compress: bool = False,
                 typestore: Typestore | None = None) -> None:
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin

        from clm_core.io._rosbag2 import Rosbag2Writer

        self.path = Path(path)
        self.storage = _check_storage(storage)
        if self.path.exists() or self.path.is_symlink():
            raise BagError(f"output bag {str(self.path)!r} exists; choose a new path")
        if not self.path.name or self.path.name in (".", ".."):
            raise BagError(f"output bag {str(self.path)!r}: not a directory name")
        if compress and storage != "mcap":
            raise BagError("compress: zstd chunk compression needs storage 'mcap'")
        self._ts = typestore
        self._defs: dict[str, tuple[str, str]] = {}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.parent / f".{self.path.name}.partial-{uuid.uuid4().hex[:8]}"
        self._tmp.mkdir()
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer: Rosbag2Writer | None = Rosbag2Writer(self._tmp / self.path.name, plugin)
        if compress:
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        try:
            self._writer.open()
        except BaseException:
            self._writer = None
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        self.counts: Counter[str] = Counter()
        self._topic: dict[int, str] = {}

    @property
    def directory(self) -> Path:
        """Where the bag is being written (moves to :attr:`path` on :meth:`close`)."""
        return self._tmp / self.path.name

    @property
    def typestore(self) -> Typestore:
        """The type store used for definitions, hashes and :meth:`write_msg`."""
        if self._ts is None:
            from clm_core.io.messages import typestore

            self._ts = typestore()
        return self._ts

    def _live(self) -> Rosbag2Writer:
        if self._writer is None:
            raise BagError(f"bag {str(self.path)!r}: the writer is closed")
        return self._writer

    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] | None = None) -> Connection:
        """Declare a topic; return its connection for :meth:`write`.

        Parameters
        ----------
        topic : str
            Topic name, e.g. ``'/wheel_loads'``.
        msgtype : str
            ``pkg/msg/Name`` known to the type store.
        qos : sequence of rosbags.interfaces.Qos, optional
            Offered QoS profiles of the topic's publishers (default
            :func:`default_qos`: one reliable publisher; empty: none offered).
        """
        from clm_core.io.messages import message_definition

        ts = self.typestore
        if msgtype not in ts.types:
            raise BagError(f"bag {str(self.path)!r}: topic {topic}: type {msgtype!r} unknown to the type store")
        if msgtype not in self._defs:
            self._defs[msgtype] = (message_definition(msgtype), ts.hash_rihs01(msgtype))
        msgdef, rihs01 = self._defs[msgtype]
        offered = list(default_qos() if qos is None else qos)
        conn = self._live().add_connection(topic, msgtype, msgdef=msgdef, rihs01=rihs01, offered_qos_profiles=offered)
        self._topic[conn.id] = topic
        return conn

    def write(self, conn: Connection, t_ns: int, data: bytes | memoryview) -> None:
        """Write one serialized (CDR) message with log time ``t_ns`` [ns]."""
        self._live().write(conn, int(t_ns), data)
        self.counts[self._topic[conn.id]] += 1

    def write_msg(self, conn: Connection, t_ns: int, msg: Any) -> None:
        """Serialize a rosbags message with the type store and write it."""
        self.write(conn, t_ns, self.typestore.serialize_cdr(msg, conn.msgtype))

    def close(self) -> Path:
        """Finish the bag (metadata, index) and move it to :attr:`path`; return that path."""
        writer = self._live()
        self._writer = None
        try:
            writer.close()
            if self.path.exists():
                raise BagError(f"output bag {str(self.path)!r} appeared while writing; the new bag is not moved")
            os.replace(self._tmp / self.path.name, self.path)
        finally:
            shutil.rmtree(self._tmp, ignore_errors=True)
        return self.path

    def abort(self) -> None:
        """Drop the bag: nothing is left at :attr:`path` nor in the temporary directory."""
        writer, self._writer = self._writer, None
        _quietly(None if writer is None else writer.abort)  # the directory is removed anyway
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


# ============================================================================ reader


class TopicInfo(NamedTuple):
    """A topic of a bag."""

    name: str
    msgtype: str
    message_count: int
    """Messages the bag's metadata lists [-]."""
    qos: tuple[Qos, ...]
    """Offered QoS profiles recorded for the topic."""


class BagMessage(NamedTuple):
    """One message of a bag, still serialized."""

    topic: str
    msgtype: str
    log_ns: int
    """Log (receive) time [ns]."""
    data: bytes


@dataclass
class ReadReport:
    """What a reading pass found (counts per topic, damage).

    Attributes
    ----------
    expected : dict
        Topic -> messages listed by ``metadata.yaml`` (or the file's index).
    read : collections.Counter
        Topic -> messages read.
    damaged : list of str
        One line per damaged chunk or read failure (byte range, log times, messages lost).
    notes : list of str
        E.g. that ``metadata.yaml`` is missing.
    """

    path: str
    expected: dict[str, int] = field(default_factory=dict)
    read: Counter[str] = field(default_factory=Counter)
    damaged: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        """True when every topic read gave the count its metadata lists and nothing was damaged."""
        return not self.damaged and all(self.read.get(t, 0) == n for t, n in self.expected.items())

    def mismatches(self) -> dict[str, tuple[int, int]]:
        """Topic -> (read, expected) where they differ."""
        return {t: (self.read.get(t, 0), n) for t, n in self.expected.items() if self.read.get(t, 0) != n}

    def summary(self) -> str:
        """One paragraph for a log or an error message."""
        parts = [f"{t}: read {r} of {n}" for t, (r, n) in sorted(self.mismatches().items())]
        return "; ".join(parts + self.damaged) or "complete"


def is_bag(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is a bag under the one rule of the module docstring (what :class:`BagReader` opens)."""
    try:
        _bag_target(Path(path))
    except BagError:
        return False
    return True


def _kind(p: Path) -> str:
    """What ``p`` is when it is neither a regular file nor a directory ('' when it is one of those)."""
    mode = p.stat().st_mode
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return ""
    return "a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else \
        "a socket" if stat.S_ISSOCK(mode) else "not a regular file"


def _bag_target(p: Path) -> tuple[Path, str, bool]:
    """(path to open, storage, has metadata.yaml) under the one rule of the module docstring.

    Only regular files are ever opened: a FIFO, a device (``/dev/zero``) or a socket, as the bag or inside a
    bag directory, is refused before anything reads it (it could block for ever or never end).
    """
    if not p.exists():
        raise BagError(f"bag {str(p)!r} not found: the path does not exist")
    kind = _kind(p)
    if kind:
        raise BagError(f"bag {str(p)!r}: not a rosbag2 bag ({kind}, not a directory or an .mcap or .db3 file)")
    if p.is_file():
        if p.suffix not in _SUFFIX:
            raise BagError(
                f"bag {str(p)!r}: not a rosbag2 bag (a directory with metadata.yaml, or an .mcap or .db3 file)"
            )
        return p, _SUFFIX[p.suffix], False
    for f in p.iterdir():
        kind = _kind(f) if f.name == "metadata.yaml" or f.suffix in _SUFFIX else ""
        if kind:
            raise BagError(f"bag {str(p)!r}: {f.name} is {kind}, not a regular file (never read)")
    if (p / "metadata.yaml").is_file():
        files = [f for f in p.iterdir() if f.suffix in _SUFFIX]
        return p, _SUFFIX[files[0].suffix] if files else "mcap", True
    files = sorted(f for f in p.iterdir() if f.suffix in _SUFFIX)
    if len(files) != 1:
        what = f"{len(files)} .mcap/.db3 files" if files else "no .mcap/.db3 file"
        raise BagError(f"bag {str(p)!r}: not a rosbag2 bag (no metadata.yaml, and {what})")
    return files[0], _SUFFIX[files[0].suffix], False


class BagReader:
    """Read a rosbag2 bag (mcap or sqlite3), cross-checking message counts; see the module docstring.

    Parameters
    ----------
    path : path-like
        Bag directory, or an ``.mcap`` / ``.db3`` file.
    allow_partial : bool
        Report damaged chunks and missing messages in :attr:`report` and go
        on, instead of raising :class:`BagError`.
    default_typestore : Typestore, optional
        Types for bags without embedded definitions (default: the ROS 2 Jazzy
        store with the clm_msgs types).

    Raises
    ------
    BagError
        Not found, not a bag, unreadable (truncated, corrupt), or no messages.
    """

    def __init__(self, path: str | os.PathLike[str], *, allow_partial: bool = False,
                 default_typestore: Typestore | None = None) -> None:
        from rosbags.highlevel import AnyReader

        from clm_core.io.messages import typestore

        self.path = Path(path)
        target, self.storage, self.has_metadata = _bag_target(self.path)
        self.allow_partial = allow_partial
        self.report = ReadReport(str(self.path))
        if not self.has_metadata:
            self.report.notes.append(f"no metadata.yaml: counts checked against {target.name}'s own index")
        self._reader: AnyReader | None = AnyReader([target], default_typestore=default_typestore or typestore())
        try:
            self._reader.open()
        except Exception as exc:  # rosbags raises several types for damaged files
            self._reader = None
            why = " ".join(str(exc).split())[:300]  # one line: a YAML error spans several, with the file's text
            raise BagError(
                f"bag {str(self.path)!r} cannot be opened: {why} ({type(exc).__name__}); the file is truncated, "
                "corrupt or not a rosbag2 bag, so it cannot be read (an interrupted mcap recording can often be "
                "repaired with `mcap recover`)"
            ) from None
        self.topics: dict[str, TopicInfo] = {}
        for c in self._reader.connections:
            old = self.topics.get(c.topic)
            qos = tuple(getattr(c.ext, "offered_qos_profiles", ()))
            self.topics[c.topic] = TopicInfo(c.topic, c.msgtype, c.msgcount + (old.message_count if old else 0), qos)
        self.message_count = sum(t.message_count for t in self.topics.values())
        try:
            if self.message_count == 0:
                have = ", ".join(sorted(self.topics)) or "no topics"
                raise BagError(f"bag {str(self.path)!r} is empty: it holds no messages ({have})")
            self._check_storage_counts()
        except BaseException:
            self.close()
            raise

    # -------------------------------------------------------------- access

    @property
    def typestore(self) -> Typestore:
        """Types of the bag (its embedded definitions, or the default store)."""
        return self._open_reader().typestore

    def _open_reader(self) -> AnyReader:
        if self._reader is None:
            raise BagError(f"bag {str(self.path)!r}: the reader is closed")
        return self._reader

    def close(self) -> None:
        """Release the files."""
        reader, self._reader = self._reader, None
        _quietly(None if reader is None else reader.close)  # closing a damaged file must not mask the real error

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def deserialize(self, data: bytes, msgtype: str) -> Any:
        """Decode CDR bytes as ``msgtype`` with the bag's types."""
        return self.typestore.deserialize_cdr(data, msgtype)

    def require(self, topic: str, msgtype: str) -> TopicInfo:
        """The topic, checked to exist and carry ``msgtype``.

        Raises
        ------
        BagError
            The topic is absent, carries another type (named), or has no messages.
        """
        info = self.topics.get(topic)
        if info is None:
            have = ", ".join(f"{t} [{i.msgtype}]" for t, i in sorted(self.topics.items()))
            raise BagError(f"bag {str(self.path)!r}: no topic {topic}; topics in the bag: {have}")
        if info.msgtype != msgtype:
            raise BagError(f"bag {str(self.path)!r}: topic {topic} carries {info.msgtype}, expected {msgtype}")
        if info.message_count == 0:
            raise BagError(f"bag {str(self.path)!r}: topic {topic} has no messages")
        return info

    def find(self, msgtype: str, topic: str | None = None) -> str:
        """The topic carrying ``msgtype``: ``topic`` checked by :meth:`require`, or the only one of that type.

        Raises
        ------
        BagError
            None or several topics of the type, or ``topic`` of another type.
        """
        if topic is not None:
            return self.require(topic, msgtype).name
        hits = sorted(t for t, i in self.topics.items() if i.msgtype == msgtype)
        if not hits:
            have = sorted(f"{t} ({i.msgtype})" for t, i in self.topics.items())
            raise BagError(f"bag {str(self.path)!r}: no {msgtype} topic; has {have}")
        if len(hits) > 1:
            raise BagError(f"bag {str(self.path)!r}: several {msgtype} topics {hits}; choose one")
        return self.require(hits[0], msgtype).name

    # -------------------------------------------------------------- reading

    def _storages(self) -> list[Any]:
        out: list[Any] = []
        for r in self._open_reader().readers:
            st = getattr(r, "storage", None)
            out += list(getattr(st, "storages", None) or [st])
        return [s for s in out if s is not None]

    def _check_storage_counts(self) -> None:
        """metadata.yaml against the storage files' own counts (messages missing before any reading)."""
        if not self.has_metadata:
            return
        file_counts: Counter[str] = Counter()
        for s in self._storages():
            for c in getattr(s, "connections", []):
                file_counts[c.topic] += int(c.msgcount)
        for t, info in self.topics.items():
            if file_counts.get(t, 0) != info.message_count:
                line = (f"{t}: metadata.yaml lists {info.message_count} messages, the {self.storage} file's index "
                        f"{file_counts.get(t, 0)}")
                self._damage(line)

    def _damage(self, line: str) -> None:
        self.report.damaged.append(line)
        if not self.allow_partial:
            raise BagError(f"bag {str(self.path)!r} is damaged: {line}; --allow-partial reads what is left")

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
        """Messages of the given topics (default all) in log-time order, still serialized.

        When the iteration ends, the counts read are checked against the
        metadata (:attr:`report`); damage raises :class:`BagError` unless
        ``allow_partial``.
        """
        want = set(self.topics) if topics is None else set(topics)
        unknown = sorted(want - set(self.topics))
        if unknown:
            raise BagError(f"bag {str(self.path)!r}: no topic {', '.join(unknown)}; has {sorted(self.topics)}")
        self.report.read = Counter()
        self.report.expected = {t: self.topics[t].message_count for t in want}
        conns = [c for c in self._open_reader().connections if c.topic in want]
        for storage in self._storages():
            yield from self._storage_messages(storage, conns)
        lost = self.report.mismatches()
        if lost:
            line = "; ".join(f"{t}: read {r} of the {n} messages listed" for t, (r, n) in sorted(lost.items()))
            if not self.allow_partial:
                raise BagError(f"bag {str(self.path)!r} is damaged: {line}; --allow-partial reads what is left")
            if not self.report.damaged:
                self.report.damaged.append(line)

    def _storage_messages(self, storage: Any, conns: list[Connection]) -> Iterator[BagMessage]:
        sconn = {
            sc.id: c for sc in storage.connections for c in conns if (c.topic, c.msgtype) == (sc.topic, sc.msgtype)
        }
        if not sconn:
            return
        chunks = getattr(storage, "chunks", None)
        try:
            from rosbags.rosbag2.storage_mcap import msgsrc
        except ImportError:  # pragma: no cover - another rosbags layout: no chunk-wise recovery
            chunks = None
        if chunks:
            gens = [self._chunk(storage, i, ch, sconn, msgsrc) for i, ch in enumerate(chunks)
                    if any(ch.channel_count.get(cid, 0) for cid in sconn)]
            for t_ns, _i, _k, conn, data in heapq.merge(*gens):
                if conn is not None and data is not None:
                    self.report.read[conn.topic] += 1
                    yield BagMessage(conn.topic, conn.msgtype, t_ns, bytes(data))
            return
        it = storage.messages([sc for sc in storage.connections if sc.id in sconn])
        while True:
            try:
                sc, t_ns, data = next(it)
            except StopIteration:
                return
            except Exception as exc:
                self._damage(f"reading stopped after {sum(self.report.read.values())} messages: {exc} "
                             f"({type(exc).__name__})")
                return
            conn = sconn[sc.id]
            self.report.read[conn.topic] += 1
            yield BagMessage(conn.topic, conn.msgtype, t_ns, bytes(data))

    def _chunk(self, storage: Any, idx: int, chunk: Any, sconn: dict[int, Connection],
               msgsrc: Any) -> Iterator[tuple[int, int, int, Connection | None, bytes | None]]:
        """One mcap chunk: its messages, or a damage line (CRC, decompression, fewer than indexed)."""
        yield chunk.message_start_time, idx, -1, None, None  # merge order without reading the chunk yet
        where = (f"chunk {idx + 1} of {len(storage.chunks)} (bytes {chunk.chunk_start_offset}.."
                 f"{chunk.chunk_start_offset + chunk.chunk_length}, log time {chunk.message_start_time}.."
                 f"{chunk.message_end_time} ns)")
        listed = {sconn[cid].topic: n for cid, n in chunk.channel_count.items() if cid in sconn and n}
        src = msgsrc(chunk, {cid: sc for sc in storage.connections if (cid := sc.id) in sconn},
                     chunk.message_start_time, chunk.message_end_time + 1, storage.bio)
        try:
            next(src)
            msgs = list(src)
        except Exception as exc:
            lost = ", ".join(f"{n} on {t}" for t, n in sorted(listed.items()))
            self._damage(f"{where} cannot be read ({exc}); {lost} lost")
            return
        got: Counter[str] = Counter()
        for k, m in enumerate(msgs):
            conn = sconn[m.connection.id]
            got[conn.topic] += 1
            yield m.timestamp, idx, k, conn, m.data
        short = {t: (got.get(t, 0), n) for t, n in listed.items() if got.get(t, 0) != n}
        if short:
            lost = ", ".join(f"{t}: {g} of {n}" for t, (g, n) in sorted(short.items()))
            self._damage(f"{where} is damaged: it yields {lost} indexed messages")


def storage_of(path: str | os.PathLike[str]) -> str:
    """``'mcap'`` or ``'sqlite3'``: the storage of a bag (same rule as :class:`BagReader`)."""
    return _bag_target(Path(path))[1]
