"""Benchmark: 1600-frequency receptance sweep of a 41-sleeper CLM track.

Prints the wall time of the banded direct sweep and, in the same run, of a
reference that solves each frequency with scipy's sparse LU (splu), and
their ratio. Usage: python benchmarks/receptance_sweep.py [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import scipy.sparse.linalg as spla

from clm_core.frequency import receptance
from clm_core.params import load_model
from clm_core.track import assemble


def best_of(fn, repeat: int = 5) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sleepers", type=int, default=41)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    s = assemble(load_model("mevergnies", "mevergnies", "clm"), a.sleepers)
    f = np.linspace(0.25, 400.0, 1600)
    t_band = best_of(lambda: receptance(s, f))

    def reference() -> None:
        F = np.zeros(s.n_dof)
        c = s.n_sleepers // 2
        F[s.rail_w[s.sleeper_node[c]]] = 1.0
        for fk in f:
            w = 2 * np.pi * fk
            spla.splu((s.K - w**2 * s.M + 1j * w * s.C).tocsc()).solve(F.astype(complex))

    t_ref = best_of(reference, 2)
    out = {
        "sleepers": a.sleepers,
        "n_dof": s.n_dof,
        "frequencies": f.size,
        "banded_s": t_band,
        "sparse_lu_reference_s": t_ref,
        "speedup": t_ref / t_band,
    }
    if a.json:
        print(json.dumps(out))
    else:
        print(f"receptance sweep, {a.sleepers} sleepers ({s.n_dof} DOFs), {f.size} frequencies:")
        print(f"  banded direct solve : {t_band * 1e3:8.1f} ms")
        print(f"  scipy splu reference: {t_ref * 1e3:8.1f} ms   (ratio {t_ref / t_band:.1f}x)")


if __name__ == "__main__":
    main()
