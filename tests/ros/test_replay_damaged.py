"""``clm replay`` on damaged bags (issue 12, item 7): refused unless --allow-partial, never a partial output.

The damaged bags are those of tests/io/test_damaged_bags.py (4 kB zeroed in the
middle of an mcap, an empty bag, a topic of the wrong type, a message that
cannot be decoded); ``clm replay`` lives in clm_ros, hence here.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

from clm_core.io import messages as msgs
from clm_core.io.bags import BagReader, BagWriter
from tests.clitools import run_clm
from tests.io.test_damaged_bags import T0, N, _copy, _leftovers, _wheels, _zero_middle
from tests.io.test_damaged_bags import good as good  # the healthy mcap bag (module fixture)


def _clm(*args: str) -> subprocess.CompletedProcess[str]:
    return run_clm(args)


def test_replay_refuses_a_damaged_bag_and_leaves_nothing(good: Path, tmp_path: Path) -> None:
    bag = _copy(good, tmp_path / "zeroed")
    _zero_middle(bag)
    out = tmp_path / "out"
    p = _clm("replay", str(bag), "--out", str(out), "--sleepers", "21")
    assert p.returncode == 2, p.stderr
    assert "is damaged: chunk" in p.stderr and "--allow-partial" in p.stderr
    assert not out.exists() and _leftovers(tmp_path) == []
    p = _clm("replay", str(bag), "--out", str(out), "--sleepers", "21", "--allow-partial")
    assert p.returncode == 0, p.stderr
    m = re.search(r"replay: (\d+) wheel-load messages read, (\d+) accepted.*partial input: (\d+) of the (\d+) listed",
                  p.stdout)
    assert m, p.stdout
    read, accepted, read_again, listed = map(int, m.groups())
    assert listed == N and 0 < read == read_again < N
    assert "warning: partial input: chunk" in p.stderr
    with BagReader(out) as r:  # the output is complete for what was read, and says so in its metadata
        assert r.topics["/wheel_loads"].message_count == read
        assert r.topics["/sleeper_response"].message_count == accepted
        assert sum(1 for _ in r.messages()) == read + 2 * accepted


def test_replay_empty_bag_and_wrong_type(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "empty") as w:
        w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
    p = _clm("replay", str(tmp_path / "empty"), "--out", str(tmp_path / "o1"))
    assert p.returncode == 2 and "is empty: it holds no messages (/wheel_loads)" in p.stderr, p.stderr
    with BagWriter(tmp_path / "strings") as w:
        c = w.add_topic("/wheel_loads", "std_msgs/msg/String")
        w.write_msg(c, T0, w.typestore.types["std_msgs/msg/String"](data="not a wheel"))
    p = _clm("replay", str(tmp_path / "strings"), "--topic", "/wheel_loads", "--out", str(tmp_path / "o2"))
    assert p.returncode == 2, p.stderr
    assert "topic /wheel_loads carries std_msgs/msg/String, expected clm_msgs/msg/WheelLoads" in p.stderr
    p = _clm("replay", str(tmp_path / "strings"), "--out", str(tmp_path / "o3"))
    assert p.returncode == 2 and "no clm_msgs/msg/WheelLoads topic; has ['/wheel_loads (std_msgs/msg/String)']" in (
        p.stderr
    ), p.stderr
    assert not any((tmp_path / o).exists() for o in ("o1", "o2", "o3")) and _leftovers(tmp_path) == []


def test_replay_failing_midway_leaves_nothing(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "bad") as w:
        c = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
        for k in range(30):
            w.write(c, T0 + k * 1_000_000, _wheels(k) if k != 20 else b"\x00\x01\x00\x00garbage")
    p = _clm("replay", str(tmp_path / "bad"), "--out", str(tmp_path / "out"), "--sleepers", "21")
    assert p.returncode == 2 and "message 21 on /wheel_loads cannot be decoded" in p.stderr, p.stderr
    assert not (tmp_path / "out").exists() and _leftovers(tmp_path) == []
