"""``clm replay`` on the online path: hostile messages in a bag (issue 12.1, 12.2, 12.3 in replay).

Replay reads the bag in chunks through ``process_batch``; its answers are
those of the node (``process`` message by message) bit for bit. Refused
messages beyond ``--max-rejected`` (default 0) end it with exit code 2, one
clear line (no traceback) and no output bag.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from clm_core.io import messages as msgs
from clm_core.io.bags import BagReader, BagWriter
from clm_core.online import OnlineTrackModel
from clm_core.params import load_model
from tests.clitools import run_clm
from tests.online.tools import MS, WALL, answers, stream


def _clm(*args: str) -> subprocess.CompletedProcess[str]:
    return run_clm(args)


def _bag(path: Path, frames: list[tuple[int, list[int], list[float], list[float]]], junk: tuple[int, ...] = ()) -> Path:
    with BagWriter(path) as w:
        c = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
        for k, (t, ids, p, f) in enumerate(frames):
            data = b"\x00\x01\x00\x00garbage" if k in junk else msgs.encode_wheel_loads(t, "track", ids, p, f)
            w.write(c, WALL + k * MS, data)
    return path


def _hostile_stream(n: int = 600) -> list[tuple[int, list[int], list[float], list[float]]]:
    good = [(f.stamp_ns, f.ids.tolist(), f.positions.tolist(), f.forces.tolist()) for f in stream(n, t0=WALL)]
    t = good[300][0]
    bad = [
        (t + 1000, [0, 1], [1e19, 1e19 - 3], [85e3, 85e3]),  # OverflowError in the window shift, once
        (t + 2000, [0, 1], [39.0, 36.0], [1.7e308, 85e3]),  # NaN answers ever after, once
        (t + 3000, [0, 1], [39.0, 36.0], [1e12, 85e3]),  # kilometres of deflection, once
        (t + 3 * 10**17, [0, 1], [39.0, 36.0], [85e3, 85e3]),  # 9.5 years ahead: blinded the replay, once
    ]
    return good[:301] + bad + good[301:]


def _responses(path: Path) -> list[tuple[str, int, msgs.SleeperResponseData | msgs.WheelRailResponseData]]:
    out = []
    with BagReader(path) as r:
        for m in r.messages(["/sleeper_response", "/wheel_rail_response"]):
            d = (msgs.decode_sleeper_response(m.data) if m.topic == "/sleeper_response"
                 else msgs.decode_wheel_rail_response(m.data))
            out.append((m.topic, m.log_ns, d))
    return out


def test_refused_messages_end_the_replay_cleanly(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "hostile", _hostile_stream())
    p = _clm("replay", str(bag), "--out", str(tmp_path / "out"))
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    line = p.stderr.strip().splitlines()[-1]
    assert line.startswith("clm replay: error: 1 of the first 302 wheel-load messages refused, more than "
                           "--max-rejected 0 allows: 1 implausible_position (first: message 302: "), line
    assert not (tmp_path / "out").exists() and not [q for q in tmp_path.iterdir() if "partial" in q.name]


def test_allowed_refusals_replay_like_the_node(tmp_path: Path) -> None:
    """With --max-rejected the refused messages are counted; the answers are the node's, message by message."""
    frames = _hostile_stream()
    bag = _bag(tmp_path / "hostile", frames, junk=(100,))
    p = _clm("replay", str(bag), "--out", str(tmp_path / "out"), "--max-rejected", "5")
    assert p.returncode == 0, p.stderr
    assert ("replay: 604 wheel-load messages read, 599 accepted, rejected: 2 implausible_force, 1 "
            "implausible_position, 1 malformed, 1 stamp_jump;") in p.stdout, p.stdout
    node = OnlineTrackModel(load_model("mevergnies", "mevergnies", "clm"))
    from clm_core.online import WheelFrame

    ref = answers(node, [WheelFrame.of(t, i, x, f) for k, (t, i, x, f) in enumerate(frames) if k != 100])
    ref = [r for r in ref if not hasattr(r, "reason")]
    got = _responses(tmp_path / "out")
    sleepers = [d for topic, _, d in got if topic == "/sleeper_response"]
    wheels = [d for topic, _, d in got if topic == "/wheel_rail_response"]
    assert len(sleepers) == len(wheels) == len(ref) == 599
    for s, w, r in zip(sleepers, wheels, ref):
        assert s.stamp_ns == r.stamp_ns == w.stamp_ns  # type: ignore[union-attr]
        assert s.soil_force.tobytes() == r.soil_force.tobytes()  # type: ignore[union-attr]
        assert s.rail_deflection.tobytes() == r.rail_deflection.tobytes()  # type: ignore[union-attr]
        assert w.rail_deflection.tobytes() == r.wheel_deflection.tobytes()  # type: ignore[union-attr]
        assert np.all(np.isfinite(s.soil_force)) and np.max(np.abs(w.rail_deflection)) < 5e-3


def test_policy_bounds_are_options(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "b", [(f.stamp_ns, [0, 1], f.positions.tolist(), f.forces.tolist())
                                for f in stream(30, t0=WALL)])
    p = _clm("replay", str(bag), "--out", str(tmp_path / "o"), "--max-wheel-force", "5e4")
    assert p.returncode == 2 and "30 implausible_force" not in p.stderr and "1 implausible_force" in p.stderr
    p = _clm("replay", str(bag), "--out", str(tmp_path / "o"), "--resync-confirm", "1")
    assert p.returncode == 2 and p.stderr.strip() == "clm replay: error: --resync-confirm = 1: must be 2 to 1000"
    p = _clm("replay", "--help")
    assert "--max-response-displacement" in p.stdout and "--max-rejected" in p.stdout
