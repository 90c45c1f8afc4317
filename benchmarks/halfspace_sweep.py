"""Speed benchmark: rigorous 41-area flexibility sweep, 0-150 Hz at 1 Hz steps.

Usage::

    .venv/bin/python benchmarks/halfspace_sweep.py [--profile mevergnies] [--areas 41]
        [--fmax 150] [--df 1] [--centre-only] [--nx 6 --ny 12] [--json]

Computes the full N x N flexibility of N rigid 2.5 m x 0.285 m areas at
0.6 m (unless ``--centre-only``) with the default mesh of
:func:`clm_core.halfspace.calibrate.auto_geometry` (6 x 12 cosine-graded
cells per area for Mevergnies, within ~2 % of the mesh-extrapolated sums,
see docs/halfspace.md) and prints the wall time.

OpenBLAS runs single-threaded unless OPENBLAS_NUM_THREADS is set: on a
shared 2-core machine its two-thread LU is several times slower under load.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import sys
import time
from dataclasses import replace

import numpy as np

from clm_core.halfspace.bem import RowModel
from clm_core.halfspace.calibrate import auto_geometry
from clm_core.profile import load_profile


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--profile", default="mevergnies")
    p.add_argument("--areas", type=int, default=41)
    p.add_argument("--fmax", type=float, default=150.0)
    p.add_argument("--df", type=float, default=1.0)
    p.add_argument("--nx", type=int, default=None)
    p.add_argument("--ny", type=int, default=None)
    p.add_argument("--centre-only", action="store_true", help="centre column only (what the calibration needs)")
    p.add_argument("--json", action="store_true", help="print one JSON line instead of text")
    args = p.parse_args(argv)
    prof = load_profile(args.profile)
    geo = auto_geometry(prof, args.fmax, n_areas=args.areas)
    if args.nx:
        geo = replace(geo, nx=args.nx)
    if args.ny:
        geo = replace(geo, ny=args.ny)
    freqs = np.arange(0.0, args.fmax + 0.5 * args.df, args.df)
    t0 = time.perf_counter()
    model = RowModel(prof, geo, f_max=float(freqs[-1]))
    t1 = time.perf_counter()
    res = model.sweep(freqs, full=not args.centre_only)
    t2 = time.perf_counter()
    S = res.total_sum()
    out = {
        "profile": prof.name,
        "areas": geo.n_areas,
        "mesh": [geo.nx, geo.ny],
        "frequencies": int(freqs.size),
        "full_matrix": not args.centre_only,
        "setup_s": round(t1 - t0, 3),
        "sweep_s": round(t2 - t1, 3),
        "total_s": round(t2 - t0, 3),
        "per_frequency_s": round((t2 - t1) / freqs.size, 4),
        "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "load_average": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "S_0Hz_MN_per_m": round(float(S[0].real) / 1e6, 3),
    }
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"{out['profile']}: {out['areas']} areas, mesh {geo.nx} x {geo.ny} per area, {out['frequencies']} "
            f"frequencies ({'full N x N' if out['full_matrix'] else 'centre column'}): {out['total_s']:.1f} s "
            f"(setup {out['setup_s']:.1f} s, {1e3 * out['per_frequency_s']:.0f} ms per frequency; "
            f"load average {out['load_average']})"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
