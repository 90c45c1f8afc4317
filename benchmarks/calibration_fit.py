#!/usr/bin/env python3
"""Benchmark: impact-test calibration of a 41-area record (issue 6 target: under 30 s).

    .venv/bin/python benchmarks/calibration_fit.py [BAG] [--repeat N]

BAG defaults to the shipped bags/calibration/impact_mevergnies (regenerated
into a temporary directory if missing). Prints the wall time of each stage
(bag reading with rosbags and checks, transfer functions, CLM fit: Eq. 16/18
first estimate + least-squares refinement with intervals, the Lysmer and
Winkler comparison fits) and of the whole ``calibrate`` call, best of N.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from clm_core.calibration import calibrate, read_bag
from clm_core.calibration.channels import find_channel_map, load_channel_map
from clm_core.calibration.impact import fit_impact
from clm_core.calibration.spectra import WindowSpec, transfer_functions
from clm_core.synthetic import simulate_impact, write_simulated_bag

SHIPPED = Path(__file__).resolve().parents[1] / "bags" / "calibration" / "impact_mevergnies"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", nargs="?", default=str(SHIPPED))
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    bag = Path(args.bag)
    tmp = None
    if not bag.exists():
        tmp = tempfile.TemporaryDirectory()
        bag = Path(tmp.name) / "impact_mevergnies"
        write_simulated_bag(simulate_impact, bag, snr_db=30.0, seed=1)
    cmap = load_channel_map(find_channel_map(bag))  # type: ignore[arg-type]
    stages: dict[str, list[float]] = {k: [] for k in ("read", "tf", "clm", "compare", "calibrate")}
    for _ in range(args.repeat):
        t = time.perf_counter()
        rec = read_bag(bag, cmap).recording
        stages["read"].append(time.perf_counter() - t)
        t = time.perf_counter()
        data, _ = transfer_functions(rec, 2.0, 150.0)
        first, _ = transfer_functions(rec, 2.0, 150.0, WindowSpec(exp_end=1.0))
        stages["tf"].append(time.perf_counter() - t)
        t = time.perf_counter()
        fit = fit_impact(data, "clm", first_data=first)
        stages["clm"].append(time.perf_counter() - t)
        t = time.perf_counter()
        fit_impact(data, "lysmer", first_data=first)
        fit_impact(data, "winkler", first_data=first)
        stages["compare"].append(time.perf_counter() - t)
        t = time.perf_counter()
        res = calibrate(bag, "impact")
        stages["calibrate"].append(time.perf_counter() - t)
    n_ch = rec.responses.shape[1]
    print(f"impact calibration, {n_ch} areas, {rec.duration:.2f} s at {rec.fs:g} Hz, {data.frequency.size} lines "
          f"in 2-150 Hz ({platform.processor() or platform.machine()}, best of {args.repeat})")
    labels = {
        "read": "read bag (rosbags, checks, common grid)",
        "tf": "transfer functions (H1, windows, noise model)",
        "clm": "CLM fit (Eq. 16/18 first estimate + refinement)",
        "compare": "Lysmer + Winkler comparison fits",
        "calibrate": "calibrate() end to end",
    }
    for k, v in stages.items():
        print(f"  {labels[k]:50s} {min(v):7.3f} s")
    print(f"  refinement: {fit.stats.nfev} evaluations, rms residual {fit.stats.rms:.3f}")
    print(f"IMPACT_FIT_SECONDS {min(stages['calibrate']):.3f} (target < 30 s)")
    vals = np.array([p.value for p in res.parameters])
    print("  fitted: " + ", ".join(f"{p.name} = {v:.4g}" for p, v in zip(res.parameters, vals)))
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
