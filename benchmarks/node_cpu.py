"""Benchmark: the track node's CPU per message, executor against wait-set loop, next to the bare kernel (prints only).

The track node (``clm_ros.track_node``, Mevergnies CLM, dt = 1e-4 s, 61
sleepers) runs as a process of its own, fed by this process at ``--rate`` Hz
for ``--duration`` s (:func:`node_lag.case_track`: 4 wheels at 83.33 m/s,
stamps = the wall-clock time each message is due), in each way it can wait
for wheel loads (the node's ``answer_loop`` setting):

- ``executor``: a thread waits on the subscription's arrival eventfd and
  hands each arrival to rclpy's EventsExecutor as a task; the executor thread
  takes and answers;
- ``waitset``: the process's loop (:func:`clm_ros.node_main.run_node`) waits
  on the arrival eventfd itself (``select``) and takes and answers in its own
  thread, serving the executor (services, timers) in between.

The node's CPU per message is read from ``/proc`` over the steady part of
each run (everything: DDS threads, the loop, decoding, model, encoding,
publishing, diagnostics). In this same process and under the same load, the
compiled kernel is timed for the steps of one message
(:func:`node_lag.side_by_side`: ``run_steps`` at the node's cadence, and in
a tight loop); each figure is printed as a multiple of the kernel's. The
modes alternate run by run (``--runs`` of each), so that a change of the
machine's load falls on both. The load average is printed with every run:
the machine is shared.

Usage::

    nice -n 10 python benchmarks/node_cpu.py [--runs 3] [--duration 15] [--rate 1000] [--sleepers 61] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import node_lag

MODES = ("executor", "waitset")


def one_run(mode: str, a: argparse.Namespace, log_dir: Path) -> dict[str, Any]:
    """One run of the node in ``mode``: CPU per message, lags, the kernel's cost beside it."""
    ns = argparse.Namespace(duration=a.duration, rate=a.rate, sleepers=a.sleepers,
                            node_params={"answer_loop": mode, "realtime_priority": a.realtime_priority})
    r = node_lag.case_track(ns, log_dir)
    r.pop("diagnostics", None)
    return {"mode": mode, **r}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3, help="runs of each mode, alternating")
    ap.add_argument("--duration", type=float, default=15.0, help="seconds of traffic per run")
    ap.add_argument("--rate", type=float, default=1000.0, help="wheel-load rate [Hz]")
    ap.add_argument("--sleepers", type=int, default=61, help="window length of the track node")
    ap.add_argument("--realtime-priority", type=int, default=0,
                    help="the node's realtime_priority (default 0: normal scheduling, CPU figures only)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    a = ap.parse_args()
    print(f"node_cpu: {os.cpu_count()} cores, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} at "
          f"start; {a.sleepers} sleepers, {a.rate:g} Hz, {a.duration:g} s per run, {a.runs} run(s) per mode")
    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="clm_node_cpu_") as tmp:
        for i in range(a.runs):
            for mode in MODES:
                r = one_run(mode, a, Path(tmp))
                runs.append(r)
                node, kc, kt = r["track_cpu_us_per_message"], r["kernel_cadence_us"], r["kernel_us"]
                print(f"  run {i + 1} {mode:8s}: node {node:6.0f} us CPU/message = {node / kc:.2f} x kernel at the "
                      f"same cadence ({kc:.0f} us), {node / kt:.2f} x kernel in a tight loop ({kt:.0f} us); "
                      f"data path {r['data_path_us']:.0f} us; lag p99 {1e3 * r['lag_p99_s']:.2f} ms, max "
                      f"{1e3 * r['lag_max_s']:.2f} ms; {int(r['answers'])}/{int(r['sent'])} answered; load "
                      f"{r['loadavg']:.2f}, machine busy {r['machine_busy_pct']:.0f} %", flush=True)
    if a.json:
        print(json.dumps(runs, indent=2, default=float))
    print("summary (median over runs; worst = highest):")
    for mode in MODES:
        rs = [r for r in runs if r["mode"] == mode]
        node = [r["track_cpu_us_per_message"] for r in rs]
        ratio = [r["track_cpu_us_per_message"] / r["kernel_cadence_us"] for r in rs]
        tight = [r["track_cpu_us_per_message"] / r["kernel_us"] for r in rs]
        print(f"  {mode:8s}: {np.median(node):6.0f} us CPU/message (worst {max(node):.0f}); "
              f"{np.median(ratio):.2f} x kernel at cadence (worst {max(ratio):.2f}); "
              f"{np.median(tight):.2f} x kernel tight (worst {max(tight):.2f}); target <= 2.5 x kernel")
    med = {m: float(np.median([r["track_cpu_us_per_message"] for r in runs if r["mode"] == m])) for m in MODES}
    cheaper = min(med, key=med.__getitem__)
    print(f"  cheaper: {cheaper} ({med[cheaper]:.0f} us against {max(med.values()):.0f} us per message); load "
          f"average at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        sys.exit(main())
