"""``clm demo``: the end-to-end ROS demo (vehicle node + track node over DDS, bag, plots).

Its options and their defaults are the run settings of :mod:`clm_core.settings` and :mod:`clm_ros.parameters`
(the same as the vehicle node's and ``clm simulate --vehicle``'s).
"""

from __future__ import annotations

import argparse
from typing import Any

from clm_core.commands import add_command, add_overwrite
from clm_ros.run_settings import RUN_SETTINGS


def register(sub: Any) -> None:
    """Add the ``demo`` sub-command."""
    p = add_command(sub, "demo", run, settings=RUN_SETTINGS)
    p.add_argument("--out", default="results/demo", help="output directory (default results/demo)")
    p.add_argument("--open-loop", dest="closed_loop", action="store_false", help=argparse.SUPPRESS)
    p.add_argument("--view", nargs="?", type=int, const=8765, default=None, metavar="PORT",
                   help="also serve the run live to Foxglove (clm view on PORT, default 8765)")
    add_overwrite(p)


def run(args: argparse.Namespace) -> int:
    """End-to-end demo: vehicle and track nodes over DDS, recorded and plotted.

    Starts the vehicle simulator node and the track-soil node as separate processes (loopback DDS), records the run
    to a bag and renders plots in --out.
    """
    from clm_core.commands import check_output, quantity
    from clm_ros.launcher import run_demo
    from clm_ros.run_settings import RunSettings

    check_output(args.out, args.overwrite)
    print(f"demo: ROS domain {args.domain_id}, discovery on loopback; watch it live from another terminal with "
          f"ROS_DOMAIN_ID={args.domain_id} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (topics /wheel_loads, "
          "/sleeper_response, /wheel_rail_response, /diagnostics)", flush=True)
    viewer = _start_view(args.domain_id, args.view) if args.view is not None else None
    try:
        s = run_demo(args.out, RunSettings.from_args(args), overwrite=args.overwrite)
    finally:
        if viewer is not None:
            from clm_ros.processes import stop_processes

            stop_processes([viewer])
    counts = s["message_counts"]
    used = 100.0 * s["feedback_used"] / s["feedback_total"] if s["feedback_total"] else 0.0
    print(f"demo: {counts.get('/wheel_loads', 0)} wheel-load messages, {counts.get('/sleeper_response', 0)} "
          f"responses; lag median {quantity(s['lag_median_s'], 's')}, p99 {quantity(s['lag_p99_s'], 's')}, max "
          f"{quantity(s['lag_max_s'], 's')}; {s['feedback_used']} of {s['feedback_total']} answers used as "
          f"feedback ({used:.1f} %)")
    sched = s["scheduling"]
    print(f"demo: node scheduling: track {sched['track_node']}, vehicle {sched['vehicle_node']}")
    print(f"demo: peak sleeper soil force {quantity(s['peak_sleeper_soil_force_N'], 'N')}, max rail deflection "
          f"{quantity(s['max_rail_deflection_m'], 'm')}, peak wheel load {quantity(s['peak_wheel_load_N'], 'N')}, "
          f"rms wheel load {quantity(s['rms_wheel_load_N'], 'N')}")
    print(f"demo: bag {s['bag']}, plots and summary.json in {args.out}/")
    return 0


def _start_view(domain_id: int, port: int) -> Any:
    """``clm view`` in the demo's domain on ``port``, as a process of its own (its output on this terminal)."""
    import subprocess
    import sys

    from clm_ros.processes import ros_env

    return subprocess.Popen([sys.executable, "-m", "clm_core.cli", "view", "--domain", str(domain_id), "--port",
                             str(port)], env=ros_env(domain_id), stdin=subprocess.DEVNULL)
