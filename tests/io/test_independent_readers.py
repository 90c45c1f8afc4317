"""Bags read by independent readers (issue 13, item 2): Foxglove's ``mcap`` + ``mcap-ros2-support``, and sqlite3.

Every shipped bag and freshly written bags (mcap and sqlite3) are decoded
without rosbags: the mcap library (chunk CRCs validated) and its ROS 2
decoder, built from the definitions embedded in the bag; for sqlite3,
Python's sqlite3 module and the same decoder built from the
``message_definitions`` table. Checked: counts equal the metadata's, fields
equal what was written (or what rosbags reads), the embedded definitions
carry the ``.msg`` comments (units, sign convention), the channels carry the
RIHS01 type hash and the offered QoS profiles, and the metadata says
version 9 / jazzy. rosbags reads the same bags back for the comparison.
"""

from __future__ import annotations

import math
import sqlite3
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

mcap_reader = pytest.importorskip("mcap.reader", reason="mcap is a dev dependency (pip install -e .[dev])")
mcap_decoder = pytest.importorskip("mcap_ros2.decoder", reason="mcap-ros2-support is a dev dependency")
mcap_dynamic = pytest.importorskip("mcap_ros2._dynamic", reason="mcap-ros2-support is a dev dependency")

from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from clm_core.io import _definitions  # noqa: E402
from clm_core.io import messages as msgs  # noqa: E402
from clm_core.io.bags import BagReader, BagWriter  # noqa: E402
from clm_core.io.timebase import NS, stamp_ns  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
SHIPPED = sorted(p.parent for p in (REPO / "bags").rglob("metadata.yaml"))


def _metadata(bag: Path) -> dict[str, Any]:
    info: dict[str, Any] = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return info


def _commented(name: str) -> bool:
    """Whether the writer's definition of ``name`` carries comments: always for clm_msgs, for another type only
    when its ``.msg`` is installed (the ROS venv); else it is rosbags' text, the same fields without comments."""
    pkg, *_, short = name.split("/")
    return pkg == "clm_msgs" or any((p / "share" / pkg / "msg" / f"{short}.msg").is_file()
                                    for p in _definitions._prefixes())


def _hash_of_schema(name: str, text: str) -> str:
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(text, name))
    return store.hash_rihs01(name)


def _mcap_check(bag: Path, fresh: bool = False) -> dict[str, list[Any]]:
    """Decode every message with mcap + mcap-ros2-support; check counts, hashes, QoS, comments.

    The shipped bags carry the comments of every definition; a ``fresh`` bag those :func:`_commented` says.
    """
    meta = _metadata(bag)
    assert meta["version"] == 9 and meta["ros_distro"] == "jazzy" and meta["storage_identifier"] == "mcap"
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    decoded: dict[str, list[Any]] = {t: [] for t in topics}
    with open(bag / meta["relative_file_paths"][0], "rb") as f:
        reader = mcap_reader.make_reader(f, decoder_factories=[mcap_decoder.DecoderFactory()], validate_crcs=True)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None
        for ch in summary.channels.values():
            tm = topics[ch.topic]["topic_metadata"]
            schema = summary.schemas[ch.schema_id]
            assert schema.name == tm["type"] and schema.encoding == "ros2msg"
            text = schema.data.decode()
            commented = _commented(schema.name) if fresh else True
            assert ("\n#" in "\n" + text) == commented, f"{schema.name}: comments of the definition"
            if schema.name.startswith("clm_msgs/"):
                assert "positive downwards" in text.lower() and "[m]" in text
            assert ch.metadata["topic_type_hash"] == tm["type_description_hash"] == _hash_of_schema(schema.name, text)
            assert yaml.safe_load(ch.metadata["offered_qos_profiles"]) == (tm["offered_qos_profiles"] or [])
            assert ch.message_encoding == "cdr"
        for _schema, channel, message, msg in reader.iter_decoded_messages(log_time_order=True):
            decoded[channel.topic].append((message.log_time, msg))
        stats = summary.statistics
        assert stats is not None and stats.message_count == meta["message_count"]
        rosbag2 = [m for m in reader.iter_metadata() if m.name == "rosbag2"]
        assert yaml.safe_load(rosbag2[0].metadata["serialized_metadata"])["ros_distro"] == "jazzy"
    counts = {t: len(v) for t, v in decoded.items()}
    assert counts == {t: info["message_count"] for t, info in topics.items()}
    return decoded


@pytest.mark.parametrize("bag", SHIPPED, ids=[str(p.relative_to(REPO / "bags")) for p in SHIPPED])
def test_shipped_bags_decode_with_mcap(bag: Path) -> None:
    decoded = _mcap_check(bag)
    with BagReader(bag) as r:  # rosbags reads the same values
        for topic in list(decoded)[:3]:
            for (log_ns, ind), m in zip(decoded[topic][:: max(1, len(decoded[topic]) // 50)],
                                        list(r.messages([topic]))[:: max(1, len(decoded[topic]) // 50)]):
                assert log_ns == m.log_ns
                ours = r.deserialize(m.data, m.msgtype)
                if hasattr(ours, "header"):
                    assert stamp_ns(ours.header) == ind.header.stamp.sec * NS + ind.header.stamp.nanosec
                for field in ("wrench", "vector", "soil_force", "wheels", "data"):
                    if hasattr(ours, field):
                        a, b = getattr(ours, field), getattr(ind, field)
                        if field == "wrench":
                            assert a.force.z == b.force.z
                        elif field == "vector":
                            assert a.z == b.z
                        elif field == "wheels":
                            assert [w.force for w in a] == [w.force for w in b]
                        else:
                            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def _fresh(path: Path, storage: str) -> dict[str, Any]:
    """A bag with clm_msgs and standard messages; return what was written."""
    rng = np.random.default_rng(5)
    written: dict[str, Any] = {"wheels": [], "sleepers": [], "wrench": []}
    with BagWriter(path, storage) as w:
        c_w = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
        c_s = w.add_topic("/sleeper_response", msgs.SLEEPER_RESPONSE)
        c_f = w.add_topic("/hammer/force", "geometry_msgs/msg/WrenchStamped")
        T = w.typestore.types
        for k in range(40):
            t = 1_700_000_000 * NS + k * 500_000
            n = k % 5
            ids, pos, force = np.arange(n, dtype=np.uint32), rng.normal(size=n), rng.normal(8e4, 1e3, n)
            w.write(c_w, t, msgs.encode_wheel_loads(t, "voie ü", ids, pos, force))
            written["wheels"].append((t, ids, pos, force))
            idx = np.arange(k, k + 61, dtype=np.int64)
            soil = rng.normal(size=61)
            w.write(c_s, t, msgs.encode_sleeper_response(t, "voie ü", idx, 0.6 * idx, soil, *[soil * 1e-6] * 3))
            written["sleepers"].append((t, idx, soil))
            v3 = T["geometry_msgs/msg/Vector3"]
            hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t // NS, nanosec=t % NS),
                                           frame_id="hammer")
            w.write_msg(c_f, t, T["geometry_msgs/msg/WrenchStamped"](
                header=hdr, wrench=T["geometry_msgs/msg/Wrench"](force=v3(x=0.0, y=0.0, z=float(k)),
                                                                 torque=v3(x=0.0, y=0.0, z=0.0))))
            written["wrench"].append((t, float(k)))
    return written


def _compare(decoded: dict[str, list[Any]], written: dict[str, Any]) -> None:
    for (log_ns, m), (t, ids, pos, force) in zip(decoded["/wheel_loads"], written["wheels"], strict=True):
        assert log_ns == t and m.header.stamp.sec * NS + m.header.stamp.nanosec == t
        assert m.header.frame_id == "voie ü"
        assert [w.id for w in m.wheels] == ids.tolist() and [w.position for w in m.wheels] == pos.tolist()
        assert [w.force for w in m.wheels] == force.tolist() and all(math.isnan(w.speed) for w in m.wheels)
    for (_, m), (_t, idx, soil) in zip(decoded["/sleeper_response"], written["sleepers"], strict=True):
        assert list(m.sleeper_index) == idx.tolist() and list(m.soil_force) == soil.tolist()
    assert [m.wrench.force.z for _, m in decoded["/hammer/force"]] == [z for _, z in written["wrench"]]


def test_fresh_mcap_bag_decodes_with_mcap(tmp_path: Path) -> None:
    written = _fresh(tmp_path / "bag", "mcap")
    _compare(_mcap_check(tmp_path / "bag", fresh=True), written)


def test_fresh_sqlite3_bag_decodes_without_rosbags(tmp_path: Path) -> None:
    written = _fresh(tmp_path / "bag", "sqlite3")
    meta = _metadata(tmp_path / "bag")
    assert meta["version"] == 9 and meta["ros_distro"] == "jazzy" and meta["storage_identifier"] == "sqlite3"
    con = sqlite3.connect(tmp_path / "bag" / meta["relative_file_paths"][0])
    try:
        defs = {name: (enc, text, h) for name, enc, text, h in con.execute(
            "SELECT topic_type, encoding, encoded_message_definition, type_description_hash FROM message_definitions")}
        topics = {tid: (name, typ, qos, h) for tid, name, typ, qos, h in con.execute(
            "SELECT id, name, type, offered_qos_profiles, type_description_hash FROM topics")}
        rows = con.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id").fetchall()
    finally:
        con.close()
    listed = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    decoders = {}
    for tid, (name, typ, qos, h) in topics.items():
        enc, text, dh = defs[typ]
        assert enc == "ros2msg" and ("\n#" in "\n" + text) == _commented(typ) and h == dh == _hash_of_schema(typ, text)
        assert h == listed[name]["topic_metadata"]["type_description_hash"]
        assert yaml.safe_load(qos) == listed[name]["topic_metadata"]["offered_qos_profiles"]
        decoders[tid] = (name, mcap_dynamic.generate_dynamic(typ, text)[typ])
    decoded: dict[str, list[Any]] = {name: [] for name, _ in decoders.values()}
    for tid, ts, data in rows:
        name, dec = decoders[tid]
        decoded[name].append((ts, dec(data)))
    assert Counter({t: len(v) for t, v in decoded.items()}) == Counter(
        {t: i["message_count"] for t, i in listed.items()})
    _compare(decoded, written)
    with BagReader(tmp_path / "bag") as r:  # and rosbags agrees
        assert sum(1 for _ in r.messages()) == len(rows) and r.report.complete
