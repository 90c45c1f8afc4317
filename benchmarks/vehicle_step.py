#!/usr/bin/env python3
"""Benchmark: the vehicle node's model step per 1 kHz wheel-load message, CPU time [us].

The per-message work of the vehicle simulator node (``clm_ros.vehicle_node``)
without middleware, on the demo's run (Thalys power car at 83.33 m/s on a
``german-low`` profile, dt = 1e-4 s, 10 substeps per message, closed loop):

- ``model``: :meth:`clm_core.vehicle.streaming.StreamingVehicle.advance` (one
  compiled call: wheel positions, irregularity, 10 steps of the vehicle, the
  Hertz contact and the single-DOF track predictor) plus the positions of the
  message. Target (issue 10): <= 100 us.
- ``model, paced at 1 kHz``: the same with a 1-ms sleep between messages,
  as the node runs it (CPU time of the thread, ``time.thread_time``): the
  caches are cold at every message, which costs about 1.5 times the
  back-to-back figure.
- ``model, numpy irregularity``: the same with the rail profile evaluated by
  numpy in Python every message (the reference path of the tests; the
  irregularity evaluation before it was compiled).
- ``edge``: what the node adds per message around the model: encoding the
  ``WheelLoads`` bytes (:func:`clm_core.io.messages.encode_wheel_loads`),
  decoding the ``WheelRailResponse`` bytes of the answer and applying it as
  feedback (:meth:`~clm_core.vehicle.streaming.StreamingVehicle.set_track_response`).

Each figure is CPU time (``time.process_time``) over ``--messages`` messages,
repeated ``--runs`` times; the median and the worst run are printed with the
load average (the machine is shared).

    .venv/bin/python benchmarks/vehicle_step.py [--runs 5] [--messages 2000] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable

import numpy as np

from clm_core.io.messages import decode_wheel_rail_response, encode_wheel_loads, encode_wheel_rail_response
from clm_core.io.timebase import NS
from clm_core.params import load_model
from clm_core.vehicle.run import VehicleRunSpec, build_vehicle_run
from clm_core.vehicle.streaming import StreamingVehicle

SUBSTEPS = 10


def per_message(fn: Callable[[int], object], n: int, pace: float = 0.0) -> float:
    """CPU time per call of ``fn(k)`` for k in range(n) [us]; ``pace`` > 0: sleep that long between calls [s]."""
    if not pace:
        c0 = time.process_time()
        for k in range(n):
            fn(k)
        return 1e6 * (time.process_time() - c0) / n
    cpu = 0.0
    for k in range(n):
        c0 = time.thread_time()
        fn(k)
        cpu += time.thread_time() - c0
        time.sleep(pace)
    return 1e6 * cpu / n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--messages", type=int, default=2000)
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    a = ap.parse_args()
    params = load_model("mevergnies", "mevergnies", "clm")
    # long enough a profile for every run of every case
    duration = 1.0 + 4 * a.runs * a.messages / 1000.0
    sim = build_vehicle_run(VehicleRunSpec(duration=duration), params).simulation
    fast = StreamingVehicle(sim)
    ref = StreamingVehicle(sim, compiled_irregularity=False)
    ids = np.arange(fast.train.n_wheels)
    speeds = np.full(ids.size, sim.speed)

    def model(v: StreamingVehicle) -> Callable[[int], object]:
        def step(_k: int) -> object:
            v.advance(SUBSTEPS)
            return v.x

        return step

    # a track answer to the current step, as the track node sends it
    answer = encode_wheel_rail_response(0, "track", ids, fast.x, fast._history[fast.k] + 1e-6,
                                        np.zeros(ids.size))

    def edge(k: int) -> object:
        # the node's encode / decode / feedback around one model step (model step not counted here)
        encode_wheel_loads(k * NS // 1000, "track", ids, fast.x, fast.P, speeds)
        d = decode_wheel_rail_response(answer)
        fast.set_track_response(fast.k, d.rail_deflection[np.argsort(d.wheel_id)])
        fast._history[fast.k] = fast.w.copy()  # keep the prediction for the next call (the model is not stepped)
        return d

    cases = {"model": (model(fast), 0.0), "model, paced at 1 kHz": (model(fast), 1e-3),
             "model, numpy irregularity": (model(ref), 0.0), "edge": (edge, 0.0)}
    out: dict[str, dict[str, float]] = {}
    for name, (fn, pace) in cases.items():
        fn(0)
        runs = [per_message(fn, a.messages, pace) for _ in range(a.runs)]
        out[name] = {"median_us": statistics.median(runs), "worst_us": max(runs), "best_us": min(runs)}
    load = os.getloadavg()
    if a.json:
        print(json.dumps({"cpu_us_per_message": out, "loadavg": load, "messages": a.messages, "runs": a.runs}))
        return 0
    print(f"vehicle node per 1 kHz message (10 steps of 0.1 ms), CPU time over {a.messages} messages, {a.runs} runs; "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores")
    for name, f in out.items():
        print(f"  {name:28s} median {f['median_us']:6.1f} us   worst {f['worst_us']:6.1f} us   "
              f"best {f['best_us']:6.1f} us")
    print("  target (issue 10): model <= 100 us per message")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
