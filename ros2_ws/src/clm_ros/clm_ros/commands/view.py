"""``clm view``: watch the demo live in Foxglove without a ROS install (:mod:`clm_ros.view`)."""

from __future__ import annotations

import argparse
from typing import Any

from clm_core.commands import add_command, add_setting
from clm_ros.parameters import DOMAIN_ID

#: The default --rate [Hz] (clm_ros.view.DEFAULT_RATE; repeated here so that `clm --help` imports no rclpy).
DEFAULT_RATE = 100.0


def register(sub: Any) -> None:
    """Add the ``view`` sub-command."""
    p = add_command(sub, "view", run)
    add_setting(p, DOMAIN_ID)
    p.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765, Foxglove's; 0: any free)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address the server listens on (default 127.0.0.1: this machine only)")
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC[:TYPE]",
                   help="topics to offer (default the demo's six: /wheel_loads /sleeper_response "
                        "/wheel_rail_response /monitored_sleepers /track_markers /diagnostics); another topic "
                        "needs its type, e.g. /clock:rosgraph_msgs/msg/Clock")
    p.add_argument("--rate", type=float, default=DEFAULT_RATE,
                   help=f"relay at most this many messages per second of each topic [Hz] (default "
                        f"{DEFAULT_RATE:g}; 0: every message)")
    p.add_argument("--log-period", type=float, default=10.0,
                   help="seconds between two lines of counts while messages flow (default 10; 0: only at exit)")
    p.add_argument("--nice", type=int, default=10,
                   help="niceness added to the relay's process, 0 to 19 (default 10: the nodes get the CPU first)")
    p.add_argument("--stats", default=None, metavar="FILE", help="write the counts at exit to FILE (JSON)")


def run(args: argparse.Namespace) -> int:
    """Serve the demo's topics to Foxglove over a WebSocket (no ROS install needed).

    A Foxglove WebSocket server relaying the topics of a ROS domain as their own CDR bytes with ros2msg schemas.
    A topic is subscribed on DDS only while a client watches it, and thinned to --rate (the first message of every
    period). Counts (taken, relayed, thinned, dropped) are logged while messages flow and printed at exit
    (Ctrl-C). In Foxglove: Open connection, Foxglove WebSocket, ws://localhost:8765, then import the layout
    config/foxglove_demo.json of clm_ros.
    """
    from clm_ros.view import parse_topics, run_view

    run_view(parse_topics(args.topics), args.domain_id, args.rate, host=args.host, port=args.port,
             log_period=args.log_period, stats=args.stats, nice=args.nice)
    return 0
