"""Bags with clm_msgs types written by the suite's writer (clm_core.io.bags), read back with rosbags' AnyReader.

The reader is given no type store: it must use the message definitions
embedded in the bag (mcap schema records / the sqlite3 ``message_definitions``
table), and check their RIHS01 hashes. Needs rosbags only (no rclpy); when
rclpy and clm_msgs are available the raw bytes are also decoded by rclpy.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from msgcheck import same_arrays, same_wheel_loads
from rosbags.highlevel import AnyReader

from clm_core.io.bags import BagWriter
from clm_core.io.messages import typestore

pytestmark = pytest.mark.ros

HAVE_RCLPY = importlib.util.find_spec("rclpy") is not None and importlib.util.find_spec("clm_msgs") is not None

WHEELS_TOPIC = "/clm/wheel_loads"
SLEEPERS_TOPIC = "/clm/sleeper_response"
N = 25
N_SLEEPERS = 7
T0_NS = 1_700_000_000_000_000_000


def _messages(ts: Any, k: int) -> tuple[Any, Any]:
    T = ts.types
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=k // 1000, nanosec=(k % 1000) * 1_000_000),
        frame_id="line_A",
    )
    wheels = T["clm_msgs/msg/WheelLoads"](
        header=header,
        wheels=[
            T["clm_msgs/msg/WheelLoad"](
                id=i,
                position=0.5 * k + 2.5 * i,
                force=9.81e4 + k,
                speed=math.nan if i == 0 else 25.0,
            )
            for i in range(k % 4)  # includes empty wheel lists
        ],
    )
    idx = np.arange(N_SLEEPERS, dtype=np.int64) + k
    sleepers = T["clm_msgs/msg/SleeperResponse"](
        header=header,
        sleeper_index=idx,
        position=0.6 * idx,
        soil_force=1e3 * np.sin(idx + 0.1 * k),
        rail_deflection=1e-4 * np.cos(idx),
        sleeper_displacement=1e-4 * np.cos(idx + 0.5),
        area_displacement=1e-5 * idx,
    )
    return wheels, sleepers


def _write_bag(path: Path, storage: str) -> tuple[Any, list[tuple[Any, Any]]]:
    ts = typestore()
    written = []
    with BagWriter(path, storage, typestore=ts) as writer:
        c_wheels = writer.add_topic(WHEELS_TOPIC, "clm_msgs/msg/WheelLoads")
        c_sleepers = writer.add_topic(SLEEPERS_TOPIC, "clm_msgs/msg/SleeperResponse")
        for k in range(N):
            wheels, sleepers = _messages(ts, k)
            t = T0_NS + k * 1_000_000
            writer.write(c_wheels, t, ts.serialize_cdr(wheels, "clm_msgs/msg/WheelLoads"))
            writer.write(c_sleepers, t, ts.serialize_cdr(sleepers, "clm_msgs/msg/SleeperResponse"))
            written.append((wheels, sleepers))
    return ts, written


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_roundtrip_with_embedded_definitions(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / "bag"
    ts, written = _write_bag(bag, storage)
    suffix = ".mcap" if storage == "mcap" else ".db3"
    assert list(bag.glob(f"*{suffix}")), f"no {suffix} file in {list(bag.iterdir())}"

    got: dict[str, list[Any]] = {WHEELS_TOPIC: [], SLEEPERS_TOPIC: []}
    raw: dict[str, list[bytes]] = {WHEELS_TOPIC: [], SLEEPERS_TOPIC: []}
    with AnyReader([bag]) as reader:  # no default_typestore: definitions from the bag
        by_topic = {c.topic: c for c in reader.connections}
        assert set(by_topic) == {WHEELS_TOPIC, SLEEPERS_TOPIC}
        assert by_topic[WHEELS_TOPIC].msgtype == "clm_msgs/msg/WheelLoads"
        assert by_topic[SLEEPERS_TOPIC].msgtype == "clm_msgs/msg/SleeperResponse"
        for conn in reader.connections:
            assert conn.msgcount == N
            # The embedded definition gives the same type hash as our store.
            assert conn.digest == ts.hash_rihs01(conn.msgtype)
            assert reader.typestore.hash_rihs01(conn.msgtype) == conn.digest
        assert "clm_msgs/msg/WheelLoad" in reader.typestore.types
        for conn, timestamp, data in reader.messages():
            got[conn.topic].append(reader.deserialize(data, conn.msgtype))
            raw[conn.topic].append(bytes(data))
            assert (timestamp - T0_NS) % 1_000_000 == 0

    assert len(got[WHEELS_TOPIC]) == len(got[SLEEPERS_TOPIC]) == N
    for (wheels, sleepers), g_wheels, g_sleepers in zip(written, got[WHEELS_TOPIC], got[SLEEPERS_TOPIC], strict=True):
        same_wheel_loads(g_wheels, wheels)
        same_arrays(g_sleepers, sleepers)

    if HAVE_RCLPY:  # the bag's bytes are what rclpy would have put on the wire
        from clm_msgs.msg import SleeperResponse, WheelLoads
        from rclpy.serialization import deserialize_message

        for data, wheels in zip(raw[WHEELS_TOPIC], (w for w, _ in written), strict=True):
            same_wheel_loads(deserialize_message(data, WheelLoads), wheels)
        for data, sleepers in zip(raw[SLEEPERS_TOPIC], (s for _, s in written), strict=True):
            same_arrays(deserialize_message(data, SleeperResponse), sleepers)
