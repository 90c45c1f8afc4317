#!/usr/bin/env python3
"""Regenerate the rigorous reference impact bag of bags/halfspace/ (deterministic: fixed seed).

    .venv/bin/python bags/halfspace/regenerate.py [--storage mcap|sqlite3] [--out DIR]

Writes ``impact_mevergnies_rigorous/``: the response of 41 contact areas
(0.6 m apart) on the Mevergnies half-space (paper Table 1 soil) to the Eq. (1)
pulse, from the rigorous half-space model (clm_core.halfspace), as a soil
impact test bag in the calibration-bag format, with ``channels.yaml`` and
``reference.yaml``. The same bag comes out of
``clm soil-calibrate --profile mevergnies --out DIR --impact-bag`` (in
``DIR/reference_impact_bag``). See README.md here.
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from clm_core.synthetic.reference import write_reference_impact_bag

HERE = Path(__file__).resolve().parent

#: What is shipped: name -> keyword arguments of write_reference_impact_bag.
BAGS = {
    "impact_mevergnies_rigorous": dict(
        profile="mevergnies",
        n_areas=41,
        spacing=0.6,
        sweep_max=150.0,
        df=1.0,
        fmin=0.0,
        fmax=80.0,
        norm="ls",
        quantity="velocity",
        fs=1000.0,
        amplitude=10e3,
        t0=0.2,
        td=0.001,
        shaping="gaussian",
        snr_db=30.0,
        seed=1,
    ),
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--storage", default="mcap", choices=("mcap", "sqlite3"))
    ap.add_argument("--out", default=str(HERE), help="directory of the bags (default: this one)")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, kw in BAGS.items():
        path = out / name
        keep = (path / "README.md").read_text(encoding="utf-8") if (path / "README.md").is_file() else None
        if path.exists():
            shutil.rmtree(path)
        t = time.perf_counter()
        bag = write_reference_impact_bag(path, storage=args.storage, **kw)  # type: ignore[arg-type]
        if keep is not None:  # the hand-written README of the shipped bag survives regeneration
            (path / "README.md").write_text(keep, encoding="utf-8")
        size = sum(f.stat().st_size for f in bag.path.iterdir())
        print(f"{bag.path}: {size / 1e6:.2f} MB ({time.perf_counter() - t:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
