"""``clm demo``: the end-to-end ROS demo (vehicle node + track node over DDS, bag, plots)."""

from __future__ import annotations

import argparse
import json
from typing import Any


def register(sub: Any) -> None:
    """Add the ``demo`` sub-command."""
    p = sub.add_parser(
        "demo",
        help="end-to-end demo: vehicle and track nodes over DDS, recorded and plotted",
        description="Starts the vehicle simulator node and the track-soil node as separate "
        "processes (loopback DDS), records the run to a bag and renders plots in --out.",
    )
    p.add_argument("--out", default="results/demo", help="output directory (default results/demo)")
    p.add_argument("--vehicle", default="thalys")
    p.add_argument("--speed", type=float, default=83.33, help="[m/s] (default 83.33 = 300 km/h)")
    p.add_argument("--duration", type=float, default=3.0, help="simulated seconds (default 3)")
    p.add_argument("--track", default="mevergnies")
    p.add_argument("--soil", default="mevergnies")
    p.add_argument("--model", default="clm")
    p.add_argument("--rate", type=float, default=1000.0, help="wheel-load rate [Hz] (default 1000)")
    p.add_argument("--dt", type=float, default=1e-4, help="track time step [s]")
    p.add_argument("--sleepers", type=int, default=61, help="track window [sleepers]")
    p.add_argument(
        "--irregularity",
        default="german-low",
        help="rail irregularity: none, fra1..fra6, german-low, german-high or a CSV (default german-low, "
        "a high-speed line)",
    )
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--open-loop", action="store_true", help="vehicle on the quasi-static track (no feedback)")
    p.add_argument("--storage", default="mcap", choices=["mcap", "sqlite3"])
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the demo and print its summary."""
    from clm_ros.launcher import run_demo

    s = run_demo(
        args.out,
        vehicle=args.vehicle,
        speed=args.speed,
        duration=args.duration,
        track=args.track,
        soil=args.soil,
        model=args.model,
        rate_hz=args.rate,
        dt=args.dt,
        n_sleepers=args.sleepers,
        irregularity=args.irregularity,
        seed=args.seed,
        closed_loop=not args.open_loop,
        storage=args.storage,
    )
    keys = [
        "message_counts",
        "lag_median_s",
        "lag_p99_s",
        "peak_sleeper_soil_force_N",
        "max_rail_deflection_m",
        "peak_wheel_load_N",
        "rms_wheel_load_N",
        "bag",
    ]
    print(json.dumps({k: s[k] for k in keys}, indent=2))
    print(f"demo: bag and plots in {args.out}/")
    return 0
