"""``clm simulate --bag`` writes a bag that ``clm replay`` reads back and reproduces.

Two independent uses of the engine: the CLI's constant moving load, and the
online path replaying the bag's wheel loads (linearly interpolated between
the 0.5 ms outputs, exact for a constant speed). They agree within 1e-4 of the
peak soil force (the windows are placed differently).
"""

from __future__ import annotations

import numpy as np
import pytest

from clm_core.cli import main as clm
from clm_core.io.bags import BagReader
from clm_core.io.timebase import NS, stamp_ns


def _soil_forces(bag, topic="/sleeper_response"):  # type: ignore[no-untyped-def]
    with BagReader(bag) as reader:
        out = {}
        for bm in reader.messages([topic]):
            m = reader.deserialize(bm.data, bm.msgtype)
            t = stamp_ns(m.header)
            out[t] = dict(zip(np.asarray(m.sleeper_index).tolist(), np.asarray(m.soil_force).tolist()))
        return out


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_simulate_bag_replays(tmp_path, storage) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "sim"
    assert clm(["simulate", "--load", "100e3", "--speed", "30", "--duration", "0.4", "--dt", "1e-4",
                "--bag", "--storage", storage, "--out", str(out)]) == 0
    assert clm(["replay", str(out / "bag"), "--storage", storage, "--out", str(tmp_path / "replayed")]) == 0
    a = _soil_forces(out / "bag")
    b = _soil_forces(tmp_path / "replayed")
    assert len(a) == len(b) == 801
    peak = max(max(v.values()) for v in a.values())
    assert 30e3 < peak < 40e3
    worst = 0.0
    for t, fa in list(a.items())[200:]:
        fb = b[t]
        common = [g for g in fa if g in fb and abs(g * 0.6 - 30 * t / NS) < 6.0]  # within 10 bays of the load
        worst = max(worst, max(abs(fa[g] - fb[g]) for g in common))
    assert worst < 1e-4 * peak, worst
    print(f"worst difference {worst:.3g} N of peak {peak:.4g} N")
