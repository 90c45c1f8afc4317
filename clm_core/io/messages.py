"""``clm_msgs`` messages <-> domain data, rosbags flavour, and a numpy CDR codec.

Three parts, no rclpy anywhere (the rclpy flavour, ``clm_ros.conversions``,
is built on this module):

1. **Definitions and type store** (implemented in :mod:`clm_core.io._definitions`,
   re-exported here). The ``.msg``/``.srv``/``.action`` files of the
   ``clm_msgs`` package are the one source of truth. They are found, in this
   order, in ``<prefix>/share/clm_msgs`` for each prefix of
   ``AMENT_PREFIX_PATH`` and ``sys.prefix`` (what rosidl generated rclpy's
   classes from), in the source tree ``ros2_ws/src/clm_msgs``, and in the copy
   packaged with clm_core (``clm_core/io/interfaces/clm_msgs``, identical by
   test). :func:`typestore` is rosbags' Jazzy store plus every clm_msgs type
   (services as ``clm_msgs/srv/<Name>_Request``, ``_Response`` and
   ``_Event``; actions as ``clm_msgs/action/<Name>_Goal``, ``_Result``,
   ``_Feedback``, ``_FeedbackMessage`` and the ``_SendGoal_*`` /
   ``_GetResult_*`` service parts, as rosidl generates them);
   :func:`message_definition` gives the text rosbag2 embeds in a bag for a
   type: the ``.msg`` files *with their comments* (units, sign convention),
   dependencies appended as rosbag2 Jazzy's ``LocalMessageDefinitionSource``
   does.
2. **Message arrays.** :func:`sleeper_fields` / :func:`wheel_fields` (a
   response -> message arrays), and rosbags message builders. The online
   model's frame of a ``WheelLoads`` (as a message or as CDR bytes) is built
   one layer up, by :func:`clm_core.online.frame_from_msg` and
   :func:`clm_core.online.frame_from_cdr`.
3. **CDR codec** (XCDR1, as ROS 2 Jazzy puts on the wire): ``WheelLoads``,
   ``SleeperResponse`` and ``WheelRailResponse`` to and from numpy arrays
   with ``np.frombuffer`` and preallocated buffers, no per-element Python.
   Decoders accept trailing bytes (rclpy pads) and refuse truncation, absurd
   sequence lengths, a bad encapsulation, unterminated or non-UTF-8 strings
   and stamps outside ``builtin_interfaces/Time``, always with
   :class:`~clm_core.io.errors.MessageError`.

Units are SI; forces and displacements positive downwards (the ``.msg``
comments). Stamps are integer nanoseconds (:mod:`clm_core.io.timebase`).
"""

from __future__ import annotations

import functools
import struct
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.io._definitions import (
    PACKAGE,
    clm_types,
    interface_dir,
    message_definition,
    packaged_interface_dir,
    source_interface_dir,
    typestore,
)
from clm_core.io.errors import MessageError
from clm_core.io.timebase import INT32_MAX, INT32_MIN, NS, ns_to_stamp

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = [
    "PACKAGE",
    "SLEEPER_RESPONSE",
    "WHEEL_LOADS",
    "WHEEL_RAIL_RESPONSE",
    "ResponseArrays",
    "SleeperResponseData",
    "WheelLoadsData",
    "WheelRailResponseData",
    "clm_types",
    "decode_sleeper_response",
    "decode_wheel_loads",
    "decode_wheel_rail_response",
    "encode_sleeper_response",
    "encode_wheel_loads",
    "encode_wheel_rail_response",
    "header_msg",
    "interface_dir",
    "message_definition",
    "packaged_interface_dir",
    "response_msgs",
    "sleeper_fields",
    "source_interface_dir",
    "typestore",
    "wheel_fields",
    "wheel_loads_msg",
]

WHEEL_LOADS = "clm_msgs/msg/WheelLoads"
SLEEPER_RESPONSE = "clm_msgs/msg/SleeperResponse"
WHEEL_RAIL_RESPONSE = "clm_msgs/msg/WheelRailResponse"


# ============================================================================ domain data


class ResponseArrays(Protocol):
    """What :func:`sleeper_fields`, :func:`wheel_fields` and :func:`response_msgs` read of a response.

    The online model's :class:`clm_core.online.ResponseFrame` is one (this
    layer names no type of the layers above it).
    """

    @property
    def sleeper_index(self) -> ArrayLike: ...
    @property
    def sleeper_x(self) -> ArrayLike: ...
    @property
    def soil_force(self) -> ArrayLike: ...
    @property
    def rail_deflection(self) -> ArrayLike: ...
    @property
    def sleeper_displacement(self) -> ArrayLike: ...
    @property
    def area_displacement(self) -> ArrayLike: ...
    @property
    def wheel_ids(self) -> ArrayLike: ...
    @property
    def wheel_positions(self) -> ArrayLike: ...
    @property
    def wheel_deflection(self) -> ArrayLike: ...
    @property
    def wheel_velocity(self) -> ArrayLike: ...


def sleeper_fields(resp: ResponseArrays) -> dict[str, NDArray[Any]]:
    """Array fields of a ``clm_msgs/SleeperResponse`` for a response.

    Returns
    -------
    dict
        ``sleeper_index`` (int64, global), ``position`` [m], ``soil_force`` [N],
        ``rail_deflection``, ``sleeper_displacement``, ``area_displacement`` [m]
        (float64; positive downwards), one entry per sleeper of the window.
    """
    return {
        "sleeper_index": np.asarray(resp.sleeper_index, dtype=np.int64),
        "position": np.asarray(resp.sleeper_x, dtype=np.float64),
        "soil_force": np.asarray(resp.soil_force, dtype=np.float64),
        "rail_deflection": np.asarray(resp.rail_deflection, dtype=np.float64),
        "sleeper_displacement": np.asarray(resp.sleeper_displacement, dtype=np.float64),
        "area_displacement": np.asarray(resp.area_displacement, dtype=np.float64),
    }


def wheel_fields(resp: ResponseArrays) -> dict[str, NDArray[Any]]:
    """Array fields of a ``clm_msgs/WheelRailResponse`` for a response.

    Returns
    -------
    dict
        ``wheel_id`` (uint32), ``position`` [m], ``rail_deflection`` [m],
        ``rail_velocity`` [m/s] (positive downwards), in the input frame's order.
    """
    return {
        "wheel_id": np.asarray(resp.wheel_ids, dtype=np.uint32),
        "position": np.asarray(resp.wheel_positions, dtype=np.float64),
        "rail_deflection": np.asarray(resp.wheel_deflection, dtype=np.float64),
        "rail_velocity": np.asarray(resp.wheel_velocity, dtype=np.float64),
    }


def header_msg(ts: Typestore, t_ns: int, frame_id: str) -> Any:
    """A ``std_msgs/Header`` rosbags message: stamp ``t_ns`` [ns], ``frame_id`` (rclpy flavour: ``rclpy_header``)."""
    sec, nanosec = ns_to_stamp(t_ns)
    T = ts.types
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id)


def wheel_loads_msg(
    ts: Typestore,
    t_ns: int,
    ids: ArrayLike,
    positions: ArrayLike,
    forces: ArrayLike,
    speeds: ArrayLike | None = None,
    frame_id: str = "track",
) -> Any:
    """A ``clm_msgs/WheelLoads`` rosbags message.

    Parameters
    ----------
    ts : Typestore
        A store with the clm_msgs types (:func:`typestore`).
    t_ns : int
        Stamp [ns].
    ids, positions, forces, speeds : array_like, shape (n,)
        Wheel ids, positions [m], forces [N] (positive downwards), speeds
        [m/s] (default NaN: unknown).
    frame_id : str
        Track line the positions refer to.
    """
    i = np.asarray(ids).ravel()
    p = np.asarray(positions, dtype=np.float64).ravel()
    f = np.asarray(forces, dtype=np.float64).ravel()
    v = np.full(i.size, np.nan) if speeds is None else np.asarray(speeds, dtype=np.float64).ravel()
    WheelLoad = ts.types["clm_msgs/msg/WheelLoad"]
    return ts.types[WHEEL_LOADS](
        header=header_msg(ts, t_ns, frame_id),
        wheels=[
            WheelLoad(id=int(a), position=float(b), force=float(c), speed=float(d))
            for a, b, c, d in zip(i.tolist(), p.tolist(), f.tolist(), v.tolist())
        ],
    )


def response_msgs(ts: Typestore, resp: ResponseArrays, t_ns: int, frame_id: str = "track") -> tuple[Any, Any]:
    """``(SleeperResponse, WheelRailResponse)`` rosbags messages of a response, stamped ``t_ns`` [ns]."""
    return (
        ts.types[SLEEPER_RESPONSE](header=header_msg(ts, t_ns, frame_id), **sleeper_fields(resp)),
        ts.types[WHEEL_RAIL_RESPONSE](header=header_msg(ts, t_ns, frame_id), **wheel_fields(resp)),
    )


# ============================================================================ CDR codec
#
# XCDR1 (plain CDR): a 4-byte encapsulation header (0x00 0x01 = little endian,
# 0x00 0x00 = big endian; two option bytes), then the fields, each aligned to
# its size relative to the end of the encapsulation header (offset 4 of the
# buffer). A string is a uint32 length counting a final NUL, then the bytes; a
# sequence is a uint32 count, then the elements (aligned once the first is).


class WheelLoadsData(NamedTuple):
    """A decoded ``clm_msgs/WheelLoads``: header and one array entry per wheel."""

    stamp_ns: int
    """``header.stamp`` [ns]."""
    frame_id: str
    """``header.frame_id``."""
    ids: NDArray[np.uint32]
    """Wheel ids."""
    positions: NDArray[np.float64]
    """Contact positions along the line [m]."""
    forces: NDArray[np.float64]
    """Vertical forces [N], positive downwards."""
    speeds: NDArray[np.float64]
    """Speeds along the track [m/s] (NaN: unknown)."""


class SleeperResponseData(NamedTuple):
    """A decoded ``clm_msgs/SleeperResponse`` (fields as in the message; SI, positive downwards)."""

    stamp_ns: int
    frame_id: str
    sleeper_index: NDArray[np.int64]
    position: NDArray[np.float64]
    soil_force: NDArray[np.float64]
    rail_deflection: NDArray[np.float64]
    sleeper_displacement: NDArray[np.float64]
    area_displacement: NDArray[np.float64]


class WheelRailResponseData(NamedTuple):
    """A decoded ``clm_msgs/WheelRailResponse`` (fields as in the message; SI, positive downwards)."""

    stamp_ns: int
    frame_id: str
    wheel_id: NDArray[np.uint32]
    position: NDArray[np.float64]
    rail_deflection: NDArray[np.float64]
    rail_velocity: NDArray[np.float64]


_ENCAPSULATION = {1: "<", 0: ">"}  # second byte of the representation id (first: 0)
_LE_HEADER = b"\x00\x01\x00\x00"
_HEAD = {o: struct.Struct(o + "iII") for o in "<>"}  # stamp.sec, stamp.nanosec, frame_id length (at offset 4)
_U32 = {o: struct.Struct(o + "I") for o in "<>"}
_HEAD_LE = struct.Struct("<4siII")
_F8, _I8, _U4 = np.dtype("<f8"), np.dtype("<i8"), np.dtype("<u4")
_DT: dict[str, np.dtype[Any]] = {"f8": _F8, "i8": _I8, "u4": _U4}
_BOUNDS = {"i8": (-(2**63), 2**63 - 1), "u4": (0, 2**32 - 1)}
_SLEEPER_SEQ = (
    ("sleeper_index", "i8"), ("position", "f8"), ("soil_force", "f8"), ("rail_deflection", "f8"),
    ("sleeper_displacement", "f8"), ("area_displacement", "f8"),
)
_WHEEL_RAIL_SEQ = (("wheel_id", "u4"), ("position", "f8"), ("rail_deflection", "f8"), ("rail_velocity", "f8"))
# one WheelLoad in a 32-byte slot: id at 0 (element 8-aligned) or at 4 (element at 4 mod 8; first element only)
_WHEEL = {
    o: np.dtype({"names": ["id", "id4", "position", "force", "speed"], "formats": [o + "u4", o + "u4"] + [o + "f8"] * 3,
                 "offsets": [0, 4, 8, 16, 24], "itemsize": 32})
    for o in "<>"
}


def _buffer(data: Any, what: str) -> tuple[memoryview, str]:
    try:
        mv = memoryview(data)
        if mv.format != "B" or mv.ndim != 1:
            mv = mv.cast("B")
    except TypeError:
        raise MessageError(f"{what}: expected bytes-like serialized data, got {type(data).__name__}") from None
    if len(mv) < 16:
        raise MessageError(f"{what}: truncated: {len(mv)} bytes, a CDR header and stamp need at least 16")
    order = _ENCAPSULATION.get(mv[1]) if mv[0] == 0 else None
    if order is None:
        raise MessageError(f"{what}: encapsulation {bytes(mv[0:4]).hex()} is not plain CDR (00 01 or 00 00)")
    return mv, order


def _decode_header(mv: memoryview, order: str, what: str) -> tuple[int, str, int]:
    sec, nanosec, slen = _HEAD[order].unpack_from(mv, 4)
    if nanosec >= NS:
        raise MessageError(f"{what}: header.stamp.nanosec = {nanosec}: must be in [0, 1e9) (builtin_interfaces/Time)")
    end = 16 + slen
    if end > len(mv):
        raise MessageError(f"{what}: truncated: frame_id of {slen} bytes at offset 16, buffer of {len(mv)} bytes")
    if slen == 0:
        return sec * NS + nanosec, "", end
    if mv[end - 1] != 0:
        raise MessageError(f"{what}: header.frame_id ({slen} bytes) is not NUL-terminated")
    try:
        return sec * NS + nanosec, str(mv[16 : end - 1], "utf-8"), end
    except UnicodeDecodeError as exc:
        raise MessageError(f"{what}: header.frame_id is not UTF-8 ({exc.reason} at byte {exc.start})") from None


def _count(mv: memoryview, order: str, pos: int, what: str, name: str, size: int) -> tuple[int, int, int]:
    """(count, first element offset, end offset) of a sequence whose count is at ``pos`` (unaligned)."""
    pos += -pos & 3
    if pos + 4 > len(mv):
        raise MessageError(f"{what}: truncated: no length of {name} at offset {pos} (buffer of {len(mv)} bytes)")
    (n,) = _U32[order].unpack_from(mv, pos)
    start = pos + 4
    if n and size == 8:
        start += (4 - start) & 7
    end = start + n * size
    if end > len(mv):
        raise MessageError(
            f"{what}: {name} claims {n} elements ({n * size} bytes from offset {start}) but the buffer has "
            f"{max(len(mv) - start, 0)} bytes left: truncated or malformed"
        )
    return n, start, end


def _decode_arrays(data: Any, fields: tuple[tuple[str, str], ...], what: str) -> tuple[Any, ...]:
    mv, order = _buffer(data, what)
    t_ns, frame_id, pos = _decode_header(mv, order, what)
    out: list[Any] = [t_ns, frame_id]
    for name, code in fields:
        size = int(code[1])
        n, start, pos = _count(mv, order, pos, what, name, size)
        out.append(np.frombuffer(mv, order + code, n, start).astype(code))
    return tuple(out)


def decode_wheel_loads(data: Any) -> WheelLoadsData:
    """Decode a serialized ``clm_msgs/WheelLoads`` into arrays.

    Parameters
    ----------
    data : bytes-like
        CDR bytes as on the wire, in a bag or from a raw subscription;
        trailing bytes after the last element are ignored.

    Returns
    -------
    WheelLoadsData
        ``stamp_ns`` [ns], ``frame_id``, ``ids`` (uint32), ``positions`` [m],
        ``forces`` [N], ``speeds`` [m/s] (float64, new arrays).

    Raises
    ------
    MessageError
        Truncated or malformed bytes.
    """
    what = "WheelLoads"
    mv, order = _buffer(data, what)
    t_ns, frame_id, pos = _decode_header(mv, order, what)
    pos += -pos & 3
    if pos + 4 > len(mv):
        raise MessageError(f"{what}: truncated: no length of wheels at offset {pos} (buffer of {len(mv)} bytes)")
    (n,) = _U32[order].unpack_from(mv, pos)
    start = pos + 4
    shifted = (start - 4) & 7  # 4: the first element starts at 4 mod 8 (no padding before its position)
    base = start - shifted
    if base + 32 * n > len(mv):
        raise MessageError(
            f"{what}: wheels claims {n} elements (up to {32 * n} bytes from offset {start}) but the buffer has "
            f"{len(mv) - start} bytes left: truncated or malformed"
        )
    rec = np.frombuffer(mv, _WHEEL[order], n, base)
    ids = rec["id"].astype(np.uint32)
    if n and shifted:
        ids[0] = rec["id4"][0]
    return WheelLoadsData(
        t_ns, frame_id, ids, rec["position"].astype(np.float64), rec["force"].astype(np.float64),
        rec["speed"].astype(np.float64),
    )


def decode_sleeper_response(data: Any) -> SleeperResponseData:
    """Decode a serialized ``clm_msgs/SleeperResponse`` (arrays may differ in length, as sent).

    Raises
    ------
    MessageError
        Truncated or malformed bytes.
    """
    return SleeperResponseData(*_decode_arrays(data, _SLEEPER_SEQ, "SleeperResponse"))


def decode_wheel_rail_response(data: Any) -> WheelRailResponseData:
    """Decode a serialized ``clm_msgs/WheelRailResponse`` (arrays may differ in length, as sent).

    Raises
    ------
    MessageError
        Truncated or malformed bytes.
    """
    return WheelRailResponseData(*_decode_arrays(data, _WHEEL_RAIL_SEQ, "WheelRailResponse"))


def _header_bytes(t_ns: int, frame_id: str, what: str) -> tuple[int, int, bytes]:
    sec, nanosec = divmod(t_ns, NS)
    if not INT32_MIN <= sec <= INT32_MAX:
        raise MessageError(f"{what}: stamp {t_ns} ns: {sec} s does not fit the int32 sec of builtin_interfaces/Time")
    return sec, nanosec, frame_id.encode("utf-8")


def _as(values: ArrayLike, code: str, what: str, name: str) -> NDArray[Any]:
    a = np.asarray(values)
    dt = _DT[code]
    if a.dtype == dt and a.ndim == 1:
        return a
    a = a.ravel()
    if code[0] in "iu" and a.dtype != dt and a.size:
        lo, hi = _BOUNDS[code]
        if a.dtype.kind not in "iu" or int(a.min()) < lo or int(a.max()) > hi:
            raise MessageError(f"{what}.{name}: values must be integers in the range of {dt.name}")
    return np.ascontiguousarray(a, dtype=dt)


@functools.lru_cache(maxsize=1024)
def _separators(slen: int, n: int, sizes: tuple[int, ...]) -> tuple[bytes, ...]:
    """Bytes between the frame_id text and each array, and between arrays: NUL, padding, count, padding."""
    pos = 16 + slen - 1  # end of the frame_id text (its NUL comes next)
    out = []
    lead = b"\x00"
    for size in sizes:
        end = pos + len(lead)
        pad = -end & 3
        start = end + pad + 4
        pad8 = (4 - start) & 7 if n and size == 8 else 0
        out.append(lead + bytes(pad) + _U32["<"].pack(n) + bytes(pad8))
        pos = start + pad8 + n * size
        lead = b""
    return tuple(out)


def _encode_arrays(t_ns: int, frame_id: str, arrays: list[ArrayLike], fields: tuple[tuple[str, str], ...],
                   what: str) -> bytes:
    sec, nanosec, fb = _header_bytes(t_ns, frame_id, what)
    cols = [_as(a, code, what, name) for a, (name, code) in zip(arrays, fields)]
    n = cols[0].size
    for c in cols:
        if c.size != n:
            raise MessageError(f"{what}: arrays of different lengths {[c.size for c in cols]}: one entry per element")
    seps = _separators(len(fb) + 1, n, tuple(c.itemsize for c in cols))
    parts: list[Any] = [_HEAD_LE.pack(_LE_HEADER, sec, nanosec, len(fb) + 1), fb]
    for sep, c in zip(seps, cols):
        parts += (sep, c)
    return b"".join(parts)


def encode_sleeper_response(
    stamp: int,
    frame_id: str,
    sleeper_index: ArrayLike,
    position: ArrayLike,
    soil_force: ArrayLike,
    rail_deflection: ArrayLike,
    sleeper_displacement: ArrayLike,
    area_displacement: ArrayLike,
) -> bytes:
    """Serialize a ``clm_msgs/SleeperResponse`` (little-endian CDR) from arrays.

    Parameters
    ----------
    stamp : int
        ``header.stamp`` [ns].
    frame_id : str
        ``header.frame_id`` (UTF-8).
    sleeper_index : array_like of int, shape (n,)
        Global sleeper indices (int64).
    position, soil_force, rail_deflection, sleeper_displacement, area_displacement : array_like, shape (n,)
        Position [m], soil force [N], displacements [m] (float64; positive downwards).

    Returns
    -------
    bytes
        What rosbags' ``serialize_cdr`` gives for the same message.

    Raises
    ------
    MessageError
        Arrays of different lengths, non-integer indices, a stamp outside int32 seconds.
    """
    arrays = [sleeper_index, position, soil_force, rail_deflection, sleeper_displacement, area_displacement]
    return _encode_arrays(stamp, frame_id, arrays, _SLEEPER_SEQ, "SleeperResponse")


def encode_wheel_rail_response(
    stamp: int, frame_id: str, wheel_id: ArrayLike, position: ArrayLike, rail_deflection: ArrayLike,
    rail_velocity: ArrayLike,
) -> bytes:
    """Serialize a ``clm_msgs/WheelRailResponse`` (little-endian CDR) from arrays.

    Parameters
    ----------
    stamp : int
        ``header.stamp`` [ns].
    frame_id : str
        ``header.frame_id``.
    wheel_id : array_like of int, shape (n,)
        Wheel ids (uint32).
    position, rail_deflection, rail_velocity : array_like, shape (n,)
        Position [m], rail deflection [m], rail velocity [m/s] under each wheel (positive downwards).

    Returns
    -------
    bytes

    Raises
    ------
    MessageError
        Arrays of different lengths, ids outside uint32, a stamp outside int32 seconds.
    """
    arrays = [wheel_id, position, rail_deflection, rail_velocity]
    return _encode_arrays(stamp, frame_id, arrays, _WHEEL_RAIL_SEQ, "WheelRailResponse")


def encode_wheel_loads(
    stamp: int, frame_id: str, ids: ArrayLike, positions: ArrayLike, forces: ArrayLike,
    speeds: ArrayLike | None = None,
) -> bytes:
    """Serialize a ``clm_msgs/WheelLoads`` (little-endian CDR) from arrays.

    Parameters
    ----------
    stamp : int
        ``header.stamp`` [ns].
    frame_id : str
        ``header.frame_id``.
    ids : array_like of int, shape (n,)
        Wheel ids (uint32).
    positions, forces, speeds : array_like, shape (n,)
        Positions [m], forces [N] (positive downwards), speeds [m/s] (default NaN).

    Returns
    -------
    bytes

    Raises
    ------
    MessageError
        Arrays of different lengths, ids outside uint32, a stamp outside int32 seconds.
    """
    what = "WheelLoads"
    sec, nanosec, fb = _header_bytes(stamp, frame_id, what)
    i = _as(ids, "u4", what, "ids")
    n = i.size
    cols = [_as(positions, "f8", what, "positions"), _as(forces, "f8", what, "forces"),
            _as(np.full(n, np.nan) if speeds is None else speeds, "f8", what, "speeds")]
    if any(c.size != n for c in cols):
        raise MessageError(f"{what}: arrays of different lengths {[n] + [c.size for c in cols]}: one entry per wheel")
    cpos = 16 + len(fb) + 1
    cpos += -cpos & 3
    start = cpos + 4
    shifted = (start - 4) & 7
    base = start - shifted
    buf = bytearray(base + 32 * n if n else start)
    if n:
        rec = np.frombuffer(buf, _WHEEL["<"], n, base)
        rec["position"], rec["force"], rec["speed"] = cols
        if shifted:  # the first id sits after the count, in the padding of its slot
            rec["id"][1:] = i[1:]
            rec["id4"][0] = i[0]
        else:
            rec["id"] = i
    _HEAD_LE.pack_into(buf, 0, _LE_HEADER, sec, nanosec, len(fb) + 1)
    buf[16 : 16 + len(fb)] = fb
    _U32["<"].pack_into(buf, cpos, n)
    return bytes(buf)
