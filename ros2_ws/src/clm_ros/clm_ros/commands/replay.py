"""``clm replay IN_BAG --out OUT_BAG``: offline replay through the track node's code path."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from clm_core.commands._common import add_model_arguments, model_from_args


def register(sub: Any) -> None:
    """Add the ``replay`` sub-command."""
    p = sub.add_parser(
        "replay",
        help="run a wheel-load bag through the track model offline, write the responses as a bag",
        description="Reads clm_msgs/WheelLoads from IN_BAG (mcap or sqlite3), runs them through the same "
        "code as the track node (no middleware, faster than real time) and writes OUT_BAG with the inputs "
        "and the sleeper and wheel-rail responses.",
    )
    p.add_argument("in_bag", help="input rosbag2 bag (directory, .mcap or .db3)")
    p.add_argument("--out", required=True, help="output bag directory (must not exist)")
    p.add_argument("--topic", default=None, help="wheel-load topic (default: the only WheelLoads topic)")
    p.add_argument("--storage", default="mcap", choices=["mcap", "sqlite3"], help="output storage (default mcap)")
    add_model_arguments(p, sleepers_default=61)
    p.add_argument("--dt", type=float, default=1e-4, help="time step [s] (default 1e-4)")
    p.add_argument("--max-gap", type=float, default=1.0, help="stamp gap that re-synchronises [s] (default 1)")
    p.add_argument("--accept-new-wheels", action="store_true", help="accept wheel ids not in the first message")
    p.add_argument("--lead-sleepers", type=int, default=None, help="sleepers kept ahead of the foremost wheel")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Replay and print a JSON summary."""
    from clm_core.online import OnlineTrackModel
    from clm_ros.errors import ClmRosError
    from clm_ros.replay import replay_bag

    params = model_from_args(args)
    model = OnlineTrackModel(
        params,
        dt=args.dt,
        n_sleepers=args.sleepers,
        elements_per_bay=args.elements_per_bay,
        max_gap=args.max_gap,
        accept_new_wheels=args.accept_new_wheels,
        lead_sleepers=args.lead_sleepers,
    )
    bar: Any = None
    if sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(unit="msg", desc="replay")
    try:
        stats = replay_bag(
            args.in_bag,
            args.out,
            model,
            topic=args.topic,
            storage=args.storage,
            progress=(lambda n: bar.update(1)) if bar else None,
        )
    except ClmRosError as exc:
        print(f"clm replay: error: {exc}", file=sys.stderr)
        return 2
    finally:
        if bar is not None:
            bar.close()
    print(
        json.dumps(
            {
                "read": stats.read,
                "accepted": stats.accepted,
                "written": stats.written,
                "rejected": dict(stats.rejected),
                "sim_time_s": stats.sim_time_s,
                "wall_time_s": stats.wall_time_s,
                "real_time_factor": stats.real_time_factor,
            }
        )
    )
    return 0
