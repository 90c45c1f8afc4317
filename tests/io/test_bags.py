"""clm_core.io.bags: the one writer (rosbag2 Jazzy layout, atomic) and the one reader (what a bag is).

The metadata is compared with the text rosbag2 Jazzy writes (yaml-cpp's block
style, rosbag2's key order, version 9 QoS enums); the storage files are read
back with rosbags and, for sqlite3, with Python's sqlite3 module.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml

from clm_core.io import messages as msgs
from clm_core.io._rosbag2 import emit_yaml, qos_profile, qos_yaml
from clm_core.io.bags import BagReader, BagWriter, default_qos, storage_of
from clm_core.io.errors import BagError
from clm_core.io.timebase import NS

T0 = 1_700_000_000 * NS
STORAGES = ["mcap", "sqlite3"]


def write_wheel_bag(path: Path, storage: str = "mcap", n: int = 20, **kw: object) -> Path:
    with BagWriter(path, storage, **kw) as w:  # type: ignore[arg-type]
        c = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
        for k in range(n):
            t = T0 + k * 1_000_000
            w.write(c, t, msgs.encode_wheel_loads(t, "track", [0, 1], [0.1 * k, 0.1 * k - 2.5], [8e4, 8.1e4]))
    return path


QOS_TEXT = """- history: unknown
  depth: 0
  reliability: reliable
  durability: volatile
  deadline:
    sec: 9223372036
    nsec: 854775807
  lifespan:
    sec: 9223372036
    nsec: 854775807
  liveliness: automatic
  liveliness_lease_duration:
    sec: 9223372036
    nsec: 854775807
  avoid_ros_namespace_conventions: false"""


def _indent(text: str, n: int) -> str:
    return "\n".join(" " * n + line for line in text.splitlines())


def test_metadata_is_what_ros2_bag_record_of_jazzy_writes(tmp_path: Path) -> None:
    """rosbag2's key order, yaml-cpp's block style, no final newline (``fout << node``)."""
    bag = write_wheel_bag(tmp_path / "wheels", n=3)
    h = msgs.typestore().hash_rihs01(msgs.WHEEL_LOADS)
    want = f"""rosbag2_bagfile_information:
  version: 9
  storage_identifier: mcap
  duration:
    nanoseconds: 2000000
  starting_time:
    nanoseconds_since_epoch: {T0}
  message_count: 3
  topics_with_message_count:
    - topic_metadata:
        name: /wheel_loads
        type: clm_msgs/msg/WheelLoads
        serialization_format: cdr
        offered_qos_profiles:
{_indent(QOS_TEXT, 10)}
        type_description_hash: {h}
      message_count: 3
  compression_format: ""
  compression_mode: ""
  relative_file_paths:
    - wheels.mcap
  files:
    - path: wheels.mcap
      starting_time:
        nanoseconds_since_epoch: {T0}
      duration:
        nanoseconds: 2000000
      message_count: 3
  custom_data: ~
  ros_distro: jazzy"""
    assert (bag / "metadata.yaml").read_text() == want
    assert qos_yaml(default_qos()) == QOS_TEXT
    assert qos_yaml([]) == "[]"
    assert yaml.safe_load(want)["rosbag2_bagfile_information"]["topics_with_message_count"][0]["topic_metadata"][
        "offered_qos_profiles"
    ] == yaml.safe_load(QOS_TEXT)


def test_yaml_emitter_quotes_what_needs_quoting() -> None:
    data = {"a": "", "b": "true", "c": "1.5", "d": "x: y", "e": "ü/ok", "f": None, "g": [], "h": {}, "i": ["/t", 3]}
    text = emit_yaml(data)
    assert yaml.safe_load(text) == data
    assert 'a: ""' in text and "f: ~" in text and "g: []" in text and "h: {}" in text and "  - /t" in text


@pytest.mark.parametrize("storage", STORAGES)
def test_storage_files_carry_the_jazzy_metadata(tmp_path: Path, storage: str) -> None:
    qos = [qos_profile("best_effort"), qos_profile("reliable", "transient_local", "keep_last", 7)]
    with BagWriter(tmp_path / "b", storage) as w:
        c = w.add_topic("/sleepers", msgs.SLEEPER_RESPONSE, qos=qos)
        w.write(c, T0, msgs.encode_sleeper_response(T0, "x", [1, 2], *[np.ones(2)] * 5))
    with BagReader(tmp_path / "b") as r:
        assert r.topics["/sleepers"].qos == tuple(qos)
        assert r.storage == storage and r.has_metadata and not r.report.notes
    if storage == "sqlite3":
        con = sqlite3.connect(tmp_path / "b" / "b.db3")
        try:
            assert con.execute("SELECT ros_distro FROM schema").fetchone() == ("jazzy",)
            (meta,) = con.execute("SELECT metadata FROM metadata").fetchone()
            sql = "SELECT name, offered_qos_profiles, type_description_hash FROM topics"
            name, qtext, digest = con.execute(sql).fetchone()
            (text,) = con.execute("SELECT encoded_message_definition FROM message_definitions").fetchone()
        finally:
            con.close()
        assert yaml.safe_load(meta)["ros_distro"] == "jazzy"
        assert (name, qtext) == ("/sleepers", qos_yaml(qos))
        assert digest.startswith("RIHS01_") and "positive downwards" in text


def test_the_writer_never_leaves_a_partial_bag(tmp_path: Path) -> None:
    target = tmp_path / "out" / "bag"
    with pytest.raises(RuntimeError, match="stop"), BagWriter(target) as w:
        c = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
        w.write(c, T0, msgs.encode_wheel_loads(T0, "", [1], [1.0], [1.0]))
        assert w.directory.is_dir() and w.directory.name == "bag" and not target.exists()
        raise RuntimeError("stop")
    assert not target.exists()
    assert list((tmp_path / "out").iterdir()) == []  # no temporary directory left either
    write_wheel_bag(target)
    with pytest.raises(BagError, match="exists; choose a new path"):
        BagWriter(target)
    with pytest.raises(BagError, match="storage = 'rosbag1'"):
        BagWriter(tmp_path / "x", "rosbag1")
    with pytest.raises(BagError, match="unknown to the type store"), BagWriter(tmp_path / "y") as w:
        w.add_topic("/x", "nopkg/msg/Nothing")
    assert not (tmp_path / "y").exists()


@pytest.mark.parametrize("storage", STORAGES)
def test_what_a_bag_is(tmp_path: Path, storage: str) -> None:
    bag = write_wheel_bag(tmp_path / "bag", storage)
    suffix = ".mcap" if storage == "mcap" else ".db3"
    file = bag / f"bag{suffix}"
    for path, has_meta in ((bag, True), (file, False)):
        with BagReader(path) as r:
            assert r.has_metadata is has_meta and r.storage == storage
            assert [m.log_ns for m in r.messages()] == [T0 + k * 1_000_000 for k in range(20)]
            assert r.report.complete and r.report.expected == {"/wheel_loads": 20}
    assert storage_of(bag) == storage_of(file) == storage
    (bag / "metadata.yaml").unlink()  # a directory with one storage file and no metadata.yaml
    with BagReader(bag) as r:
        assert sum(1 for _ in r.messages()) == 20
        assert r.report.notes == [f"no metadata.yaml: counts checked against bag{suffix}'s own index"]
    (bag / f"other{suffix}").write_bytes(file.read_bytes())
    with pytest.raises(BagError, match=r"not a rosbag2 bag \(no metadata.yaml, and 2 .mcap/.db3 files\)"):
        BagReader(bag)
    with pytest.raises(BagError, match="not found: the path does not exist"):
        BagReader(tmp_path / "nothing")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(BagError, match="not a rosbag2 bag"):
        BagReader(tmp_path / "notes.txt")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(BagError, match=r"no metadata.yaml, and no .mcap/.db3 file"):
        BagReader(tmp_path / "empty_dir")


@pytest.mark.parametrize("storage", STORAGES)
def test_an_empty_bag_is_refused_clearly(tmp_path: Path, storage: str) -> None:
    with BagWriter(tmp_path / "none", storage):
        pass
    with pytest.raises(BagError, match=r"is empty: it holds no messages \(no topics\)"):
        BagReader(tmp_path / "none")
    with BagWriter(tmp_path / "quiet", storage) as w:
        w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
    with pytest.raises(BagError, match=r"is empty: it holds no messages \(/wheel_loads\)"):
        BagReader(tmp_path / "quiet")


def test_topics_of_the_wrong_type_are_named(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "b") as w:
        c = w.add_topic("/wheel_loads", "std_msgs/msg/String")
        w.write_msg(c, T0, w.typestore.types["std_msgs/msg/String"](data="hello"))
        w.add_topic("/silent", msgs.WHEEL_LOADS)
    with BagReader(tmp_path / "b") as r:
        with pytest.raises(BagError, match=r"topic /wheel_loads carries std_msgs/msg/String, expected clm_msgs/msg/"):
            r.find(msgs.WHEEL_LOADS, "/wheel_loads")
        with pytest.raises(BagError, match="topic /silent has no messages"):
            r.find(msgs.WHEEL_LOADS)
        with pytest.raises(BagError, match=r"no topic /x; topics in the bag: /silent \[clm_msgs/msg/WheelLoads\]"):
            r.require("/x", msgs.WHEEL_LOADS)
        with pytest.raises(BagError, match="no topic /x"):
            list(r.messages(["/x"]))


@pytest.mark.parametrize("storage", STORAGES)
def test_history_bag_round_trip(tmp_path: Path, storage: str) -> None:
    """clm_core.outputs.history_bag (``clm simulate --bag``) through the bottom layer's writer and codec."""
    from types import SimpleNamespace

    from clm_core.outputs.history_bag import write_history_bag

    rng = np.random.default_rng(3)
    n_t, n_w, n_s = 5, 3, 7
    pos = rng.random((n_t, n_w)) * 10
    pos[2, 1] = np.nan  # an absent wheel
    h = SimpleNamespace(
        t=np.arange(n_t) * 5e-4, wheel_position=pos, wheel_force=rng.random((n_t, n_w)) * 1e5,
        soil_force=rng.random((n_t, n_s)), rail_deflection=rng.random((n_t, n_s)),
        sleeper_displacement=rng.random((n_t, n_s)), area_displacement=rng.random((n_t, n_s)),
        first_sleeper=np.arange(n_t), spacing=0.6, wheel_deflection=rng.random((n_t, n_w)),
        wheel_velocity=rng.random((n_t, n_w)),
    )
    assert write_history_bag(h, tmp_path / "h", storage) == n_t
    with BagReader(tmp_path / "h") as r:
        got = {t: [msgs_of(r, m) for m in r.messages([t])] for t in r.topics}
    wl = got["/wheel_loads"][2]
    assert wl.stamp_ns == 1_000_000 and wl.ids.tolist() == [0, 2] and wl.positions.tolist() == pos[2, [0, 2]].tolist()
    s = got["/sleeper_response"][4]
    assert s.sleeper_index.tolist() == list(range(4, 11)) and np.allclose(s.position, 0.6 * np.arange(4, 11))
    assert s.soil_force.tolist() == h.soil_force[4].tolist()
    w = got["/wheel_rail_response"][2]
    assert w.wheel_id.tolist() == [0, 2] and w.rail_velocity.tolist() == h.wheel_velocity[2, [0, 2]].tolist()


def msgs_of(r: BagReader, m: object) -> object:
    decode = {msgs.WHEEL_LOADS: msgs.decode_wheel_loads, msgs.SLEEPER_RESPONSE: msgs.decode_sleeper_response,
              msgs.WHEEL_RAIL_RESPONSE: msgs.decode_wheel_rail_response}
    return decode[m.msgtype](m.data)  # type: ignore[attr-defined]
