"""Benchmark: how many 1-kHz trains one machine carries in real time (``clm fleet``; prints, never asserts).

For N = 1, 2, 3, ... this runs a fleet (:func:`clm_ros.fleet.run_fleet`: N
vehicle + track node pairs, each pair two processes in its namespace
``/train_i``, one ROS domain of its own on loopback) of ``--duration`` s
trains (Thalys at 83.33 m/s, wheel loads at ``--rate`` Hz, closed loop),
``--runs`` times, and prints per N and run:

- per train: the answer lag median / p99 / max (the vehicle's reception of
  each ``wheel_rail_response`` minus the due time of its wheel-load message,
  from the first message: publisher lateness, DDS both ways and the track
  node), the feedback fraction (answers used to close the loop), the late
  publishes (> 2 periods) and the CPU per message of its track and vehicle
  node (from /proc over the train);
- the worst train, the CPU used (cores: the nodes' CPU per message x rate x N)
  and the load average.

A train is carried when its lag p99 < 20 ms (a train that falls out of real
time has lags that grow without bound); the benchmark stops after the first N
where a train is not (or at ``--max-trains``; ``--no-stop``: every N) and
prints the largest N whose every train was carried in every run. Target (issue 15): >= 4 on a quiet 2-core machine.

By default nothing is recorded (``--no-record`` of ``clm fleet``: the
recorder is not needed for these figures and costs CPU); ``--record`` adds it
(one more process's work: every pair's three topics) and prints its CPU.

Usage::

    python benchmarks/fleet_capacity.py [--max-trains 8] [--duration 5] [--runs 2] [--rate 1000] [--record]
                                        [--pair-process]
                                        [--no-stop] [--json] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
CLM_ROS_SRC = REPO / "ros2_ws" / "src" / "clm_ros"
if str(CLM_ROS_SRC) not in sys.path:
    sys.path.insert(0, str(CLM_ROS_SRC))

#: A train is carried while its answer lag p99 stays under this [s] (every message answered).
LAG_P99_LIMIT = 0.020


def one_fleet(n: int, duration: float, rate: float, record: bool, out: Path, pair_process: bool = False
              ) -> dict[str, Any]:
    """Run a fleet of ``n`` trains in a free ROS domain; its summary."""
    from clm_ros.fleet import run_fleet
    from clm_ros.processes import hold_domain_id
    from clm_ros.run_settings import RunSettings

    with hold_domain_id() as dom:
        return run_fleet(out, RunSettings(duration=duration, rate=rate, domain_id=dom), trains=n, hold_domain=False,
                         record=record, verify=False, timeout=120 + 20 * duration * n, overwrite=True,
                         progress=False, pair_process=pair_process)


def figures(s: dict[str, Any], rate: float) -> dict[str, Any]:
    """Per-train and worst figures of one fleet run (lags from the vehicles' own counts)."""
    trains = {}
    cores = 0.0
    for name, t in s["trains"].items():
        v = t["vehicle_node"]
        cpu = t["cpu_us_per_message"]
        late = v["late_publishes"] / max(v["published"], 1)
        trains[name] = {
            "lag_median_ms": 1e3 * t["vehicle_lag_median_s"], "lag_p99_ms": 1e3 * t["vehicle_lag_p99_s"],
            "lag_max_ms": 1e3 * t["vehicle_lag_max_s"],
            "feedback": t["feedback_used"] / max(t["feedback_total"], 1), "late": late,
            "in_equals_out": t["in_equals_out"],
            "track_us": cpu.get("track_node"), "vehicle_us": cpu.get("vehicle_node"), "pair_us": cpu.get("pair"),
            "carried": t["vehicle_lag_p99_s"] < LAG_P99_LIMIT and t["in_equals_out"],
        }
        cores += sum(x for x in cpu.values() if x is not None) * rate / 1e6
    rec = s.get("recorder_cpu_us_per_message")
    if rec:
        cores += rec * rate * len(trains) / 1e6
    worst = {k: max(t[k] for t in trains.values()) for k in ("lag_median_ms", "lag_p99_ms", "lag_max_ms", "late")}
    worst["feedback"] = min(t["feedback"] for t in trains.values())
    return {"trains": trains, "worst": worst, "cores": cores, "recorder_us": rec,
            "carried": all(t["carried"] for t in trains.values()), "loadavg": s["loadavg"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--max-trains", type=int, default=8)
    ap.add_argument("--min-trains", type=int, default=1)
    ap.add_argument("--duration", type=float, default=5.0, help="simulated (= wall) time per train [s]")
    ap.add_argument("--rate", type=float, default=1000.0, help="wheel-load rate [Hz]")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--record", action="store_true", help="also record the fleet (the recorder's CPU)")
    ap.add_argument("--pair-process", action="store_true", help="each pair in one process (clm_ros.fleet_pair)")
    ap.add_argument("--no-stop", action="store_true", help="run every N up to --max-trains (figures of a loaded "
                    "machine)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON at the end")
    ap.add_argument("--keep", type=Path, default=None, help="keep the fleets' outputs (logs, summaries) here")
    args = ap.parse_args(argv)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    print(f"fleet capacity: {os.cpu_count()} cores, trains of {args.duration:g} s at {args.rate:g} Hz, "
          f"runs {args.runs}, recorder {'on' if args.record else 'off'}, "
          f"{'one process' if args.pair_process else 'two processes'} per train; load average at start "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    results: dict[int, list[dict[str, Any]]] = {}
    best = 0
    with tempfile.TemporaryDirectory(prefix="clm_fleet_bench_") as tmp:
        root = args.keep or Path(tmp)
        for n in range(args.min_trains, args.max_trains + 1):
            runs = []
            for r in range(args.runs):
                f = figures(one_fleet(n, args.duration, args.rate, args.record, root / f"n{n}_r{r}",
                                      args.pair_process), args.rate)
                runs.append(f)
                w = f["worst"]
                print(f"N={n} run {r + 1}: worst lag median {w['lag_median_ms']:.2f} ms, p99 {w['lag_p99_ms']:.2f} "
                      f"ms, max {w['lag_max_ms']:.2f} ms; lowest feedback {100 * w['feedback']:.1f} %; late "
                      f"{100 * w['late']:.2f} %; CPU {f['cores']:.2f} cores"
                      + (f" (recorder {f['recorder_us']:.0f} us/msg)" if f["recorder_us"] else "")
                      + f"; load {' '.join(f'{x:.2f}' for x in f['loadavg'])}; "
                      f"{'carried' if f['carried'] else 'NOT carried'}", flush=True)
                for name, t in f["trains"].items():
                    print(f"    {name}: lag median {t['lag_median_ms']:.2f} ms, p99 {t['lag_p99_ms']:.2f} ms, max "
                          f"{t['lag_max_ms']:.2f} ms; feedback {100 * t['feedback']:.1f} %; late "
                          f"{100 * t['late']:.2f} %; CPU/msg " + (f"pair process {t['pair_us']} us" if t["pair_us"] else
                                                    f"track {t['track_us']} us, vehicle {t['vehicle_us']} us"),
                          flush=True)
            results[n] = runs
            if all(f["carried"] for f in runs) and (best == n - 1 or n == args.min_trains):
                best = n
            elif not args.no_stop:
                break
    print(f"largest fleet carried (every train lag p99 < {1e3 * LAG_P99_LIMIT:g} ms in every run): {best} "
          f"train(s); load average at end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if args.json:
        print(json.dumps({"largest_carried": best, "results": results}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
