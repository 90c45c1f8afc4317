"""``clm fleet``: N vehicle + track node pairs on one ROS graph, each in its namespace, checked and summarised.

Its run options and their defaults are the run settings of :mod:`clm_core.settings` and :mod:`clm_ros.parameters`
(as ``clm demo``'s); ``--trains`` and ``--first-index`` are the fleet's
(docs/fleet.md: pairs on several hosts).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from clm_core.commands import add_command, add_overwrite
from clm_ros.parameters import FLEET_FIRST_INDEX, FLEET_TRAINS
from clm_ros.run_settings import RUN_SETTINGS


def register(sub: Any) -> None:
    """Add the ``fleet`` sub-command."""
    p = add_command(sub, "fleet", run, settings=(FLEET_TRAINS, FLEET_FIRST_INDEX, *RUN_SETTINGS))
    p.add_argument("--out", default="results/fleet", help="output directory (default results/fleet)")
    p.add_argument("--open-loop", dest="closed_loop", action="store_false", help=argparse.SUPPRESS)
    p.add_argument("--no-record", dest="record", action="store_false",
                   help="no bag (figures from the vehicles' own counts and lags; implies --no-verify)")
    p.add_argument("--record-sleepers", action="store_true",
                   help="also record each pair's sleeper_response (61 sleepers, ~3 KB at 1 kHz per train; default: "
                   "its wheel_loads and wheel_rail_response, what the offline check needs)")
    p.add_argument("--no-verify", dest="verify", action="store_false",
                   help="skip the offline replay check of each pair's answers")
    p.add_argument("--discovery-range", default="LOCALHOST", choices=("LOCALHOST", "SUBNET", "SYSTEM_DEFAULT"),
                   help="ROS_AUTOMATIC_DISCOVERY_RANGE of the nodes (default LOCALHOST; SUBNET for pairs on "
                   "several hosts, docs/fleet.md)")
    p.add_argument("--static-peers", default="", metavar="HOSTS",
                   help="ROS_STATIC_PEERS of the nodes, e.g. '192.168.1.10;192.168.1.11' (docs/fleet.md)")
    p.add_argument("--pair-process", action="store_true",
                   help="each train's vehicle and track node in one process on one executor (default: two "
                   "processes per train)")
    p.add_argument("--stagger", type=float, default=0.0, metavar="S",
                   help="train i starts i*S s after the first (default 0: all trains start together once ready)")
    p.add_argument("--join-domain", dest="hold_domain", action="store_false",
                   help="do not hold the ROS domain exclusively: join the graph of another clm fleet in that domain "
                   "(e.g. one with another --first-index, on this machine or another host)")
    p.add_argument("--timeout", type=float, default=600.0,
                   help="longest time of the trains after their start [s] (default 600)")
    add_overwrite(p)


def run(args: argparse.Namespace) -> int:
    """Many trains online: N vehicle + track node pairs over DDS, each in its namespace /train_i.

    Starts N vehicle simulator + track-soil node pairs as separate processes, pair i in the namespace /train_i, all
    in one ROS domain; records them to DIR/fleet_bag, checks every pair (each wheel-load message answered once, in
    order; answers equal to the offline replay of its recorded wheel loads) and writes per-train and overall figures
    to DIR/summary.json.
    """
    from clm_core.commands import check_output, quantity
    from clm_ros.errors import ClmRosError
    from clm_ros.fleet import check_fleet, namespaces, run_fleet
    from clm_ros.run_settings import RunSettings

    try:
        check_fleet(args.fleet_trains, args.fleet_first_index)
    except ClmRosError as exc:
        print(f"clm fleet: error: {exc}", file=sys.stderr)
        return 2
    check_output(args.out, args.overwrite)
    ns = namespaces(args.fleet_trains, args.fleet_first_index)
    print(f"fleet: {args.fleet_trains} train(s) {ns[0]} ... {ns[-1]} in ROS domain {args.domain_id}, discovery "
          f"{args.discovery_range}; watch them live with ROS_DOMAIN_ID={args.domain_id}", flush=True)
    record = args.record
    try:
        s = run_fleet(
            args.out, RunSettings.from_args(args), trains=args.fleet_trains, first_index=args.fleet_first_index,
            record=record, verify=args.verify and record, discovery_range=args.discovery_range,
            static_peers=args.static_peers, timeout=args.timeout, overwrite=args.overwrite,
            pair_process=args.pair_process, stagger=args.stagger, hold_domain=args.hold_domain,
            record_sleepers=args.record_sleepers,
        )
    except ClmRosError as exc:
        print(f"clm fleet: error: {exc}", file=sys.stderr)
        return 1
    for name, t in s["trains"].items():
        used = 100.0 * t["feedback_used"] / t["feedback_total"] if t["feedback_total"] else 0.0
        check = ("equal to offline replay" if t.get("offline_equal") else
                 "offline replay not checked" if "offline_equal" not in t else "NOT equal to offline replay")
        print(f"fleet: {name}: {t['messages_in']} in, {t['messages_out']} out; lag median "
              f"{quantity(t['lag_median_s'], 's')}, p99 {quantity(t['lag_p99_s'], 's')}, max "
              f"{quantity(t['lag_max_s'], 's')}"
              + (f" (recorder behind by p99 {quantity(t['recorder_lag_p99_s'], 's')})" if "recorder_lag_p99_s" in t
                 else "") + f"; feedback {t['feedback_used']}/{t['feedback_total']} "
              f"({used:.1f} %); {check}")
    o = s["overall"]
    print(f"fleet: worst lag p99 {quantity(o['worst_lag_p99_s'], 's')}, max {quantity(o['worst_lag_max_s'], 's')}; "
          f"all correct: {o['all_correct']}; {o['max_running_at_once']} train(s) ran at once; summary.json in "
          f"{args.out}/")
    return 0
