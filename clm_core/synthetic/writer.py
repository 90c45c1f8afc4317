"""Synthetic records written as calibration bags (the one bag writer, :class:`clm_core.io.bags.BagWriter`).

A bag directory holds the rosbag2 bag (mcap by default, zstd chunk
compression; sqlite3 as an option), the channel map (``channels.yaml``) and
the known values (``truth.yaml``, or ``reference.yaml`` for the rigorous
reference bags of :mod:`clm_core.synthetic.reference`). Message styles of the
impact and receptance channels:

- ``stamped`` (default): ``geometry_msgs/msg/WrenchStamped`` (force,
  ``wrench.force.z``) and ``geometry_msgs/msg/Vector3Stamped`` (responses,
  ``vector.z``), one message per sample and channel, ``header.stamp`` =
  acquisition time, log time 0.15 ms later;
- ``float64``: ``std_msgs/msg/Float64`` per sample (time = bag log time);
- ``block``: ``std_msgs/msg/Float64MultiArray`` blocks of ``block_size``
  samples (first sample at the log time, ``sample_rate`` in the map).

Pass-by records use the suite's messages, ``clm_msgs/msg/WheelLoads`` and
``clm_msgs/msg/SleeperResponse`` (the type store of :mod:`clm_core.io.messages`;
no ROS installation needed).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from clm_core.calibration.channels import ChannelMap, ChannelSpec, parse_channel_map, spec_dict
from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.signals import Signal
from clm_core.io.bags import BagWriter
from clm_core.io.errors import BagError
from clm_core.io.messages import (
    SLEEPER_RESPONSE,
    WHEEL_LOADS,
    encode_sleeper_response,
    encode_wheel_loads,
    header_msg,
)
from clm_core.io.timebase import seconds_to_ns, seconds_to_ns_array
from clm_core.synthetic.records import SyntheticRecord, add_noise

Storage = Literal["mcap", "sqlite3"]
Style = Literal["stamped", "float64", "block"]

#: Bag time [ns] of t = 0 in synthetic bags.
T0_NS = 1_700_000_000_000_000_000
#: Log time after the acquisition stamp of ``stamped`` messages [ns].
_LOG_DELAY_NS = 150_000


@dataclass(frozen=True)
class BagFormat:
    """How a record is written as a bag.

    Attributes
    ----------
    storage : {'mcap', 'sqlite3'}
        Storage plugin; mcap chunks are zstd-compressed when ``compress``.
    style : {'stamped', 'float64', 'block'}
        Message style of impact/receptance channels (module docstring).
    block_size : int
        Samples per ``Float64MultiArray`` block.
    compress : bool
        zstd chunk compression (mcap only).

    Raises
    ------
    CalibrationError
        Unknown storage or style.
    """

    storage: Storage = "mcap"
    style: Style = "stamped"
    block_size: int = 100
    compress: bool = True

    def __post_init__(self) -> None:
        if self.storage not in ("mcap", "sqlite3"):
            raise CalibrationError(f"storage = {self.storage!r}: must be 'mcap' or 'sqlite3'")
        if self.style not in ("stamped", "float64", "block"):
            raise CalibrationError(f"style = {self.style!r}: must be stamped, float64 or block")


@dataclass(frozen=True)
class SyntheticBag:
    """A written synthetic bag.

    Attributes
    ----------
    path : Path
        rosbag2 directory.
    channels : Path
        Channel map (``channels.yaml`` in the bag directory).
    truth : Path
        Known values (``truth.yaml`` in the bag directory).
    record : SyntheticRecord
        What was written.
    """

    path: Path
    channels: Path
    truth: Path
    record: SyntheticRecord


def channel_map_for(rec: SyntheticRecord, style: Style = "stamped") -> ChannelMap:
    """The channel map describing a record written with :func:`write_bag`."""
    def entry(s: ChannelSpec, with_loc: bool) -> dict[str, Any]:
        if style == "block" and rec.method != "passby":
            s = replace(s, sample_rate=float(rec.settings["fs_hz"]))
        return spec_dict(s, with_loc)

    data: dict[str, Any] = {"format": "clm-calibration-channels/1", "test": rec.method}
    if rec.force is not None:
        data["force"] = entry(rec.force.spec, False)
    if rec.loads is not None:
        data["loads"] = {"topic": "/clm/wheel_loads"}
    data["channels"] = [entry(s.spec, True) for s in rec.responses]
    return parse_channel_map(data, "<synthetic>")


def plain(o: Any) -> Any:
    """Numpy scalars and arrays inside mappings and sequences -> plain Python (for YAML)."""
    if isinstance(o, dict):
        return {str(k): plain(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [plain(v) for v in o]
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return o


def write_record(
    rec: SyntheticRecord, path: str | Path, fmt: BagFormat, files: Mapping[str, str] | None = None
) -> Path:
    """Write a record as a bag directory with ``channels.yaml`` and the given extra text files.

    Parameters
    ----------
    rec : SyntheticRecord
        What to write (values in SI units; written in each channel's unit).
    path : path
        New bag directory (must not exist); it appears only when complete.
    fmt : BagFormat
        Storage, message style, block size, compression.
    files : mapping name -> text, optional
        More files for the bag directory (``truth.yaml``, ``reference.yaml``).

    Returns
    -------
    Path
        The bag directory.
    """
    out = Path(path)
    if out.exists():
        raise CalibrationError(f"bag {str(out)!r} exists; choose a new path")
    cmap = channel_map_for(rec, fmt.style)
    try:
        with BagWriter(out, fmt.storage, compress=fmt.storage == "mcap" and fmt.compress) as writer:
            if rec.method == "passby":
                _write_passby(writer, rec)
            else:
                for sig in ([rec.force] if rec.force is not None else []) + list(rec.responses):
                    _write_channel(writer, sig, fmt.style, fmt.block_size)
            (writer.directory / "channels.yaml").write_text(
                "# Channel map of this bag (format: docs/calibration.md)\n"
                + yaml.safe_dump(cmap.to_dict(), sort_keys=False)
            )
            for name, text in (files or {}).items():
                (writer.directory / name).write_text(text, encoding="utf-8")
    except BagError as exc:
        raise CalibrationError(str(exc)) from None
    return out


def write_bag(
    rec: SyntheticRecord,
    path: str | Path,
    storage: Storage = "mcap",
    style: Style = "stamped",
    block_size: int = 100,
    compress: bool = True,
) -> SyntheticBag:
    """Write a synthetic record as a rosbag2 bag with ``channels.yaml`` and ``truth.yaml``.

    Parameters
    ----------
    rec : SyntheticRecord
        What to write (values in SI units; written in each channel's unit).
    path : path
        New bag directory (must not exist).
    storage, style, block_size, compress
        The :class:`BagFormat` (storage plugin, message style, samples per
        block, zstd compression of mcap chunks).

    Returns
    -------
    SyntheticBag

    Raises
    ------
    CalibrationError
        The bag path exists, or bad storage/style.
    """
    fmt = BagFormat(storage, style, block_size, compress)
    truth = {
        "method": rec.method,
        "generator": "clm_core.synthetic",
        "truth": plain(dict(rec.truth)),
        "settings": plain(dict(rec.settings)),
        "storage": storage,
        "style": style if rec.method != "passby" else "clm_msgs",
    }
    text = "# Known values this synthetic bag was generated from (SI units)\n" + yaml.safe_dump(truth, sort_keys=False)
    out = write_record(rec, path, fmt, {"truth.yaml": text})
    return SyntheticBag(out, out / "channels.yaml", out / "truth.yaml", rec)


def _write_channel(writer: BagWriter, sig: Signal, style: str, block_size: int) -> None:
    ts = writer.typestore
    T = ts.types
    spec = sig.spec
    raw = sig.values / spec.factor  # SI -> recorded unit
    stamps = T0_NS + seconds_to_ns_array(sig.t)
    frame = spec.topic.strip("/").replace("/", "_")
    if style == "stamped":
        V3 = T["geometry_msgs/msg/Vector3"]
        if spec.quantity == "force":
            conn = writer.add_topic(spec.topic, "geometry_msgs/msg/WrenchStamped")
            W, zero = T["geometry_msgs/msg/Wrench"], V3(x=0.0, y=0.0, z=0.0)
            for st, v in zip(stamps.tolist(), raw.tolist()):
                wrench = W(force=V3(x=0.0, y=0.0, z=v), torque=zero)
                msg = T[conn.msgtype](header=header_msg(ts, st, frame), wrench=wrench)
                writer.write_msg(conn, st + _LOG_DELAY_NS, msg)
        else:
            conn = writer.add_topic(spec.topic, "geometry_msgs/msg/Vector3Stamped")
            for st, v in zip(stamps.tolist(), raw.tolist()):
                msg = T[conn.msgtype](header=header_msg(ts, st, frame), vector=V3(x=0.0, y=0.0, z=v))
                writer.write_msg(conn, st + _LOG_DELAY_NS, msg)
    elif style == "float64":
        conn = writer.add_topic(spec.topic, "std_msgs/msg/Float64")
        for st, v in zip(stamps.tolist(), raw.tolist()):
            writer.write_msg(conn, st, T[conn.msgtype](data=v))
    else:
        conn = writer.add_topic(spec.topic, "std_msgs/msg/Float64MultiArray")
        lay, dim = T["std_msgs/msg/MultiArrayLayout"], T["std_msgs/msg/MultiArrayDimension"]
        for i in range(0, raw.size, block_size):
            blk = raw[i : i + block_size]
            msg = T[conn.msgtype](layout=lay(dim=[dim(label="samples", size=blk.size, stride=blk.size)], data_offset=0),
                                  data=np.ascontiguousarray(blk, dtype=np.float64))
            writer.write_msg(conn, int(stamps[i]), msg)


def _write_passby(writer: BagWriter, rec: SyntheticRecord) -> None:
    assert rec.loads is not None
    L = rec.loads
    cw = writer.add_topic("/clm/wheel_loads", WHEEL_LOADS)
    cs = writer.add_topic("/clm/sleeper_response", SLEEPER_RESPONSE)
    speed = float(rec.settings.get("speed_m_per_s", math.nan))
    for k in range(L.t.size):
        st = T0_NS + seconds_to_ns(L.t[k])
        on = np.isfinite(L.positions[k])
        writer.write(cw, st, encode_wheel_loads(st, "line", L.wheel_ids[on], L.positions[k, on], L.forces[k, on],
                                                np.full(int(on.sum()), speed)))
    sleepers = sorted({s.spec.index for s in rec.responses})
    fields = ("rail_deflection", "sleeper_displacement", "area_displacement", "soil_force")
    t = rec.responses[0].t
    vals = {f: np.full((t.size, len(sleepers)), np.nan) for f in fields}
    for s in rec.responses:
        vals[s.spec.field or "rail_deflection"][:, sleepers.index(s.spec.index)] = s.values / s.spec.factor
    idx = np.asarray(sleepers, dtype=np.int64)
    pos = idx * float(rec.truth["track"]["spacing"])
    for k in range(t.size):
        st = T0_NS + seconds_to_ns(t[k])
        data = encode_sleeper_response(st, "line", idx, pos, vals["soil_force"][k], vals["rail_deflection"][k],
                                       vals["sleeper_displacement"][k], vals["area_displacement"][k])
        writer.write(cs, st + _LOG_DELAY_NS, data)


def write_simulated_bag(
    simulate: Callable[..., SyntheticRecord],
    path: str | Path,
    *,
    snr_db: float | None = 30.0,
    seed: int = 0,
    storage: Storage = "mcap",
    style: Style = "stamped",
    **keywords: Any,
) -> SyntheticBag:
    """Simulate a test, add noise, write the bag (:func:`write_bag`).

    Parameters
    ----------
    simulate : callable
        :func:`~clm_core.synthetic.records.simulate_impact`,
        :func:`~clm_core.synthetic.records.simulate_receptance` or
        :func:`~clm_core.synthetic.records.simulate_passby`.
    path : path
        New bag directory (must not exist).
    snr_db : float or None
        Noise level [dB] (:func:`~clm_core.synthetic.records.add_noise`); None: noise-free.
    seed : int
        Noise seed.
    storage, style
        As in :func:`write_bag` (pass-by records are written in the clm_msgs types whatever the style).
    **keywords
        Keywords of ``simulate`` (e.g. ``soil``, ``n_areas``, ``fs``, ``duration``, ``hit_times``).

    Returns
    -------
    SyntheticBag
    """
    rec = simulate(**keywords)
    if snr_db is not None:
        rec = add_noise(rec, snr_db, seed)
    return write_bag(rec, path, storage=storage, style=style)
