"""``clm replay IN_BAG --out OUT_BAG``: offline replay through the track node's code path."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from clm_core.commands import (
    add_command,
    add_model_arguments,
    add_overwrite,
    add_setting,
    add_window_arguments,
    model_from_args,
    quantity,
)
from clm_core.settings import ONLINE_POLICY


def register(sub: Any) -> None:
    """Add the ``replay`` sub-command."""
    p = add_command(sub, "replay", run)
    p.add_argument("in_bag", help="input rosbag2 bag (directory, .mcap or .db3)")
    p.add_argument("--out", required=True, help="output bag directory (must not exist, or --overwrite)")
    p.add_argument("--topic", default=None, help="wheel-load topic (default: the only WheelLoads topic)")
    add_setting(p, "storage")
    add_model_arguments(p)
    add_window_arguments(p)
    for name in ("dt", "max_gap", "accept_new_wheels", "lead_sleepers", *ONLINE_POLICY):
        add_setting(p, name)
    p.add_argument("--max-rejected", type=int, default=0, metavar="N",
                   help="most wheel-load messages that may be refused by the input policy (counted per cause); one "
                   "more ends the replay with an error and no output bag; default 0")
    add_overwrite(p, "the output bag")
    p.add_argument("--allow-partial", action="store_true",
                   help="replay what is left of a damaged input bag (missing messages or damaged chunks) instead of "
                   "refusing it; the damage is reported")


def _message_count(path: str, topic: str | None) -> int | None:
    """Number of wheel-load messages in the bag (from its metadata), or None if it cannot be told."""
    from clm_core.io.bags import BagReader
    from clm_core.io.messages import WHEEL_LOADS

    try:
        with BagReader(path, allow_partial=True) as reader:
            return reader.topics[reader.find(WHEEL_LOADS, topic)].message_count or None
    except Exception:
        return None  # replay_bag reports the error


def run(args: argparse.Namespace) -> int:
    """Run a wheel-load bag through the track model offline, write the responses as a bag.

    Reads clm_msgs/WheelLoads from IN_BAG (mcap or sqlite3), runs them through the same code as the track node (no
    middleware, faster than real time) and writes OUT_BAG with the inputs and the sleeper and wheel-rail responses.
    """
    import shutil
    from pathlib import Path

    from clm_core.commands import remove_bag
    from clm_core.online import OnlineTrackModel
    from clm_core.progress import Progress
    from clm_ros.errors import ClmRosError
    from clm_ros.replay import replay_bag

    out = Path(args.out)
    if out.exists():
        if not args.overwrite:
            print(f"clm replay: error: --out {out}: exists; choose a new path or pass --overwrite", file=sys.stderr)
            return 2
        remove_bag(out, "--out")
    model = OnlineTrackModel.from_settings(vars(args), params=model_from_args(args))
    if args.max_rejected < 0:
        print(f"clm replay: error: --max-rejected = {args.max_rejected}: must be >= 0", file=sys.stderr)
        return 2
    try:
        with Progress(_message_count(args.in_bag, args.topic), "clm replay", unit="msg") as bar:
            stats = replay_bag(args.in_bag, out, model, topic=args.topic, storage=args.storage,
                               progress=bar.update_to, allow_partial=getattr(args, "allow_partial", False),
                               max_rejected=args.max_rejected)
    except BaseException as exc:
        shutil.rmtree(out, ignore_errors=True)  # no partial output bag
        if isinstance(exc, ClmRosError):
            print(f"clm replay: error: {exc}", file=sys.stderr)
            return 2
        raise
    rejected = ", ".join(f"{n} {k}" for k, n in sorted(stats.rejected.items())) or "none"
    print(f"replay: {stats.read} wheel-load messages read, {stats.accepted} accepted, rejected: {rejected}; "
          f"{quantity(stats.sim_time_s, 's')} simulated in {quantity(stats.wall_time_s, 's')} "
          f"(real-time factor {quantity(stats.real_time_factor, '', 3)}) -> {out}"
          + (f"; partial input: {stats.read} of the {stats.expected} listed" if stats.damage else ""))
    for line in stats.damage:
        print(f"clm replay: warning: partial input: {line}", file=sys.stderr)
    return 0
