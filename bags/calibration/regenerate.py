#!/usr/bin/env python3
"""Regenerate the shipped calibration bags of bags/calibration/ (deterministic: fixed seeds).

    .venv/bin/python bags/calibration/regenerate.py [--storage mcap|sqlite3] [--out DIR]

Writes ``impact_mevergnies/`` (soil impact test, 41 areas, Mevergnies CLM soil
of Table 1) and ``receptance_mevergnies/`` (hammer on the rail, Mevergnies
track of Table 2 on that soil), each a rosbag2 directory with its
``channels.yaml`` and ``truth.yaml``. See README.md here and docs/calibration.md.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from clm_core.synthetic import write_impact_bag, write_receptance_bag

HERE = Path(__file__).resolve().parent

#: What is shipped: name -> (writer, keyword arguments).
BAGS = {
    "impact_mevergnies": (
        write_impact_bag,
        dict(n_areas=41, quantity="velocity", fs=1000.0, duration=1.0, hit_times=(0.2,), pulse="half-sine",
             pulse_duration=0.003, amplitude=10e3, snr_db=30.0, seed=1),
    ),
    "receptance_mevergnies": (
        write_receptance_bag,
        dict(n_sleepers=41, rail_sleepers=(0, 1, 2, 3, 4), sleeper_sleepers=(0,), quantity="acceleration",
             fs=2000.0, duration=0.6, hit_times=(0.1,), pulse="half-sine", pulse_duration=0.0008, amplitude=20e3,
             snr_db=30.0, seed=1),
    ),
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--storage", default="mcap", choices=("mcap", "sqlite3"))
    ap.add_argument("--out", default=str(HERE), help="directory of the bags (default: this one)")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, (writer, kw) in BAGS.items():
        path = out / name
        if path.exists():
            shutil.rmtree(path)
        bag = writer(path, storage=args.storage, **kw)
        size = sum(f.stat().st_size for f in bag.path.iterdir())
        print(f"{bag.path}: {size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
