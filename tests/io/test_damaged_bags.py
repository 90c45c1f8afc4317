"""Damaged bags (issue 12, item 7): every tool cross-checks counts, refuses damage unless --allow-partial,
never leaves a partial output, and names an empty bag or a topic of the wrong type.

Real damaged files: 4 kB zeroed in the middle of an mcap (with chunk CRCs, as
our writer makes them, and without, as rosbags or older tools do), a
truncated file, a deleted metadata.yaml, rows deleted from an sqlite3 bag,
metadata that lists more messages than the file holds, an empty bag.
``clm calibrate`` is run as the user runs it; ``clm replay`` on damaged bags is in
tests/ros/test_replay_damaged.py, ``clm play`` over DDS in tests/ros/test_bag_tools.py.
"""

from __future__ import annotations

import shutil
import sqlite3
import subprocess
from pathlib import Path

import numpy as np
import pytest

from clm_core.io import messages as msgs
from clm_core.io.bags import BagReader, BagWriter
from clm_core.io.errors import BagError
from clm_core.io.timebase import NS
from tests.clitools import run_clm

T0 = 1_700_000_000 * NS
N = 3000  # ~10 chunks of 1 MB with the sleeper responses


def _wheels(k: int) -> bytes:
    t = T0 + k * 1_000_000
    return msgs.encode_wheel_loads(t, "track", [0, 1], [30.0 + 0.03 * k, 27.5 + 0.03 * k], [8e4, 8.1e4])


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A healthy mcap bag: N wheel-load frames and N 61-sleeper responses (about 10 chunks)."""
    path = tmp_path_factory.mktemp("bags") / "good"
    with BagWriter(path) as w:
        c_w = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
        c_s = w.add_topic("/sleeper_response", msgs.SLEEPER_RESPONSE)
        for k in range(N):
            t = T0 + k * 1_000_000
            w.write(c_w, t, _wheels(k))
            w.write(c_s, t, msgs.encode_sleeper_response(t, "track", np.arange(61), *[np.full(61, k * 1.0)] * 5))
    return path


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _zero_middle(bag: Path, size: int = 4096) -> None:
    f = next(bag.glob("*.mcap"))
    data = bytearray(f.read_bytes())
    mid = len(data) // 2
    data[mid : mid + size] = bytes(size)
    f.write_bytes(bytes(data))


def test_zeroed_chunk_is_found_and_named(good: Path, tmp_path: Path) -> None:
    bag = _copy(good, tmp_path / "zeroed")
    _zero_middle(bag)
    with BagReader(bag) as r, pytest.raises(BagError) as exc:
        for _ in r.messages():
            pass
    text = str(exc.value)
    assert "is damaged: chunk" in text and "Chunk checksum mismatch" in text and "--allow-partial" in text
    assert "on /wheel_loads" in text and "log time" in text and "bytes" in text
    with BagReader(bag, allow_partial=True) as r:
        read = [m.topic for m in r.messages()]
        rep = r.report
    assert not rep.complete and len(rep.damaged) == 1
    lost = {t: n - rep.read[t] for t, n in rep.expected.items()}
    assert 0 < lost["/wheel_loads"] < N and read.count("/wheel_loads") == N - lost["/wheel_loads"]
    assert f"/wheel_loads: read {N - lost['/wheel_loads']} of {N}" in rep.summary()


def test_zeroed_bytes_without_chunk_crc_are_found_by_the_counts(tmp_path: Path) -> None:
    """An mcap written by another tool (rosbags' own writer: no chunk CRC, no compression): the index counts."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = msgs.typestore()
    bag = tmp_path / "plain"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/wheel_loads", msgs.WHEEL_LOADS, typestore=ts)
        for k in range(20000):
            w.write(c, T0 + k * 1_000_000, _wheels(k))
    _zero_middle(bag)
    with pytest.raises(BagError, match=r"is damaged: .*chunk \d+ of \d+"):
        with BagReader(bag) as r:
            for _ in r.messages():
                pass
    with BagReader(bag, allow_partial=True) as r:
        n = sum(1 for _ in r.messages())
        assert 0 < n < 20000 and r.report.damaged and not r.report.complete


def test_truncated_file_is_refused(good: Path, tmp_path: Path) -> None:
    bag = _copy(good, tmp_path / "trunc")
    f = next(bag.glob("*.mcap"))
    f.write_bytes(f.read_bytes()[: f.stat().st_size * 3 // 5])
    for allow in (False, True):
        with pytest.raises(BagError, match=r"cannot be opened: .*truncated, corrupt .*mcap recover"):
            BagReader(bag, allow_partial=allow)


def test_deleted_metadata_uses_the_file_index(good: Path, tmp_path: Path) -> None:
    bag = _copy(good, tmp_path / "nometa")
    (bag / "metadata.yaml").unlink()
    with BagReader(bag) as r:
        assert sum(1 for _ in r.messages(["/wheel_loads"])) == N and r.report.complete
        assert "no metadata.yaml" in r.report.notes[0]
    _zero_middle(bag)  # still found without metadata.yaml: the chunk's CRC and the file's index
    with pytest.raises(BagError, match="is damaged: chunk"), BagReader(bag) as r:
        for _ in r.messages():
            pass


def test_metadata_listing_more_messages_than_the_file(good: Path, tmp_path: Path) -> None:
    bag = _copy(good, tmp_path / "more")
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace(f"message_count: {N}\n", f"message_count: {N + 5}\n", 1))
    with pytest.raises(BagError, match=rf"metadata.yaml lists {N + 5} messages, the mcap file's index {N}"):
        BagReader(bag)
    with BagReader(bag, allow_partial=True) as r:
        n = sum(1 for _ in r.messages(["/wheel_loads"]))
        assert n == N and not r.report.complete


def test_sqlite3_rows_missing(tmp_path: Path) -> None:
    bag = tmp_path / "db"
    with BagWriter(bag, "sqlite3") as w:
        c = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
        for k in range(50):
            w.write(c, T0 + k * 1_000_000, _wheels(k))
    con = sqlite3.connect(bag / "db.db3")
    con.execute("DELETE FROM messages WHERE id % 10 = 3")
    con.commit()
    con.close()
    with pytest.raises(BagError, match="metadata.yaml lists 50 messages, the sqlite3 file's index 45"):
        BagReader(bag)
    with BagReader(bag, allow_partial=True) as r:
        assert sum(1 for _ in r.messages()) == 45 and not r.report.complete


# ----------------------------------------------------------------------------------------- the commands


def _clm(*args: str) -> subprocess.CompletedProcess[str]:
    return run_clm(args)


def _leftovers(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if "partial" in p.name)


@pytest.fixture(scope="module")
def impact_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from clm_core.params import load_soil
    from clm_core.synthetic import add_noise, simulate_impact, write_bag

    rec = add_noise(simulate_impact(load_soil("mevergnies"), n_areas=5, duration=2.0, hit_times=(0.2,)), 30.0, 3)
    return write_bag(rec, tmp_path_factory.mktemp("cal") / "impact", compress=False).path


def test_calibrate_refuses_a_damaged_bag(impact_bag: Path, tmp_path: Path) -> None:
    bag = _copy(impact_bag, tmp_path / "zeroed")
    _zero_middle(bag)
    out = tmp_path / "out"
    p = _clm("calibrate", str(bag), "--method", "impact", "--out", str(out), "--no-plots")
    assert p.returncode == 2 and "is damaged: chunk" in p.stderr and "--allow-partial" in p.stderr, p.stderr
    assert not out.exists()
    # with --allow-partial the reading goes on; the record checks then name what the lost chunk took away
    # (the synthetic writer writes channel after channel: a chunk holds whole channels, or a stretch of one)
    with BagReader(bag, allow_partial=True) as r:
        for _ in r.messages():
            pass
        emptied = [t for t in r.report.expected if r.report.read.get(t, 0) == 0]
    p = _clm("calibrate", str(bag), "--method", "impact", "--out", str(out), "--no-plots", "--allow-partial")
    assert "is damaged" not in p.stderr
    if emptied:
        assert p.returncode == 2 and f"topic {sorted(emptied)[0]} has no messages" in p.stderr, p.stderr
    else:
        assert p.returncode == 0 or "gap" in p.stderr, p.stderr


def test_calibrate_empty_bag(impact_bag: Path, tmp_path: Path) -> None:
    with BagWriter(tmp_path / "empty") as w:
        w.add_topic("/hammer/force", "geometry_msgs/msg/WrenchStamped")
    shutil.copy(impact_bag / "channels.yaml", tmp_path / "empty" / "channels.yaml")
    p = _clm("calibrate", str(tmp_path / "empty"), "--method", "impact", "--out", str(tmp_path / "o"))
    assert p.returncode == 2 and "is empty: it holds no messages" in p.stderr, p.stderr


def test_calibration_names_a_loads_topic_of_the_wrong_type(tmp_path: Path) -> None:
    from clm_core.calibration import read_bag
    from clm_core.calibration.channels import parse_channel_map

    with BagWriter(tmp_path / "b") as w:
        T = w.typestore.types
        c = w.add_topic("/clm/wheel_loads", "std_msgs/msg/String")
        w.write_msg(c, T0, T["std_msgs/msg/String"](data="x"))
        c = w.add_topic("/clm/sleeper_response", msgs.SLEEPER_RESPONSE)
        w.write(c, T0, msgs.encode_sleeper_response(T0, "", [0], [0.0], [1.0], [1e-3], [1e-3], [1e-4]))
    cmap = parse_channel_map({"loads": {"topic": "/clm/wheel_loads"}, "channels": [
        {"topic": "/clm/sleeper_response", "sleeper": 0, "location": "rail", "quantity": "displacement",
         "units": "m", "field": "rail_deflection"}]})
    with pytest.raises(BagError, match="loads topic /clm/wheel_loads carries std_msgs/msg/String, expected clm_msgs"):
        read_bag(tmp_path / "b", cmap, need_force=False, need_loads=True)
