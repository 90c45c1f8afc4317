"""Benchmark: ``clm simulate`` end to end against its compute time, and the size of what it writes (issue 23).

Runs the command as a user does (a new process: imports, compiled-code
loading, computation, outputs, figures, report page) ``--repeats`` times and
prints, for each run and the worst:

- ``end_to_end_s``: wall time of the process, measured here;
- ``compute_s``: the computation inside it (``compute_wall_time_s`` of the
  summary for a vehicle run: build, time stepping, results, summary;
  ``stepping_wall_time_s`` for moving loads) and ``stepping_s`` (the time
  stepping alone, simulated time / ``real_time_factor``);
- the ratios end_to_end / compute and end_to_end / stepping (target of
  issue 23: end to end within 1.5 x the compute time);
- the CPU time of the process (user + system, ``getrusage``) and of the
  computation inside it (``compute_cpu_time_s``, vehicle runs), and their
  ratio: figures that do not depend on the other jobs of a shared machine;
  and the load average;
- the bytes written, per file.

Usage::

    python benchmarks/simulate_outputs.py [--repeats 3] [--duration 20] [--csv] [--out DIR] [-- extra clm args]

Figures are printed, never asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--vehicle", default="thalys")
    ap.add_argument("--csv", action="store_true", help="pass --csv (the CSV files too)")
    ap.add_argument("--out", default=None, help="output directory (default: a temporary one)")
    ap.add_argument("extra", nargs="*", help="more clm simulate arguments (after --)")
    a = ap.parse_args()
    base = Path(a.out or tempfile.mkdtemp(prefix="clm-simulate-bench-"))
    cmd = [sys.executable, "-m", "clm_core.cli", "simulate", "--vehicle", a.vehicle, "--duration", str(a.duration),
           *(["--csv"] if a.csv else []), *a.extra]
    print("command:", " ".join(cmd[2:]), "--out DIR --overwrite")
    rows = []
    for k in range(a.repeats):
        out = base / f"run{k}"
        load0 = os.getloadavg()[0]
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        tic = time.perf_counter()
        p = subprocess.run([*cmd, "--out", str(out), "--overwrite"], capture_output=True, text=True)
        wall = time.perf_counter() - tic
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if p.returncode != 0:
            print(p.stdout, p.stderr, file=sys.stderr)
            return 1
        s = json.loads((out / "summary.json").read_text())
        compute = s.get("compute_wall_time_s", s.get("stepping_wall_time_s"))
        stepping = s["simulated_time_s"] / s["real_time_factor"]
        sizes = {f.name: f.stat().st_size for f in sorted(out.iterdir()) if f.is_file()}
        cpu_compute = s.get("compute_cpu_time_s")
        cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        row = {"end_to_end_s": wall, "compute_s": compute, "stepping_s": stepping,
               "cpu_compute_s": cpu_compute, "cpu_ratio": cpu / cpu_compute if cpu_compute else None,
               "ratio_to_compute": wall / compute, "ratio_to_stepping": wall / stepping,
               "cpu_s": cpu,
               "command_wall_time_s": s.get("command_wall_time_s"), "loadavg": (load0, os.getloadavg()[0]),
               "bytes": sum(sizes.values()), "files": sizes}
        rows.append(row)
        print(f"run {k}: end to end {wall:.2f} s, compute {compute:.2f} s, stepping {stepping:.2f} s, ratio "
              f"{row['ratio_to_compute']:.2f} (to stepping {row['ratio_to_stepping']:.2f}), CPU {row['cpu_s']:.2f} s "
              f"(compute {cpu_compute or float('nan'):.2f} s: ratio {row['cpu_ratio'] or float('nan'):.2f}), "
              f"{row['bytes'] / 1e6:.1f} MB, load {load0:.1f}->{os.getloadavg()[0]:.1f}")
    worst = max(rows, key=lambda r: r["ratio_to_compute"])
    cpu_worst = max(rows, key=lambda r: r["cpu_ratio"] or 0.0)
    print(f"worst CPU ratio of {len(rows)}: process CPU {cpu_worst['cpu_s']:.2f} s = "
          f"{cpu_worst['cpu_ratio'] or 0:.2f} x the compute's CPU ({cpu_worst['cpu_compute_s'] or 0:.2f} s) "
          "(load-independent)")
    print(f"worst of {len(rows)}: end to end {worst['end_to_end_s']:.2f} s = {worst['ratio_to_compute']:.2f} x compute "
          f"({worst['compute_s']:.2f} s), {worst['ratio_to_stepping']:.2f} x stepping; slowest end to end "
          f"{max(r['end_to_end_s'] for r in rows):.2f} s; files: "
          + ", ".join(f"{n} {b / 1e6:.2f} MB" for n, b in worst["files"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
