"""``clm record`` and ``clm play``: rosbag2 record and play over DDS (rosbags, no ``ros2 bag``)."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from typing import Any

from clm_core.commands import add_command, add_setting


def register(sub: Any) -> None:
    """Add the ``record`` and ``play`` sub-commands."""
    r = add_command(sub, "record", run_record)
    r.add_argument("topics", nargs="+", help="TOPIC or TOPIC:TYPE (type default: discovered on the graph)")
    r.add_argument("--out", required=True, help="output bag directory (must not exist; appears when recording stops)")
    add_setting(r, "storage")
    r.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    r.add_argument("--count", type=int, default=None, help="stop after this many messages on the first topic")
    r.add_argument("--discovery-timeout", type=float, default=20.0, help="wait for topic types [s]")
    p = add_command(sub, "play", run_play)
    p.add_argument("bag", help="rosbag2 bag (directory, .mcap or .db3)")
    p.add_argument("--topics", nargs="*", default=None, help="topics to play (default all)")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (1 real time; 0 as fast as answered)")
    p.add_argument("--ack-topic", default="/sleeper_response", help="answers for --rate 0 flow control")
    p.add_argument("--max-in-flight", type=int, default=20,
                   help="--rate 0: messages published ahead of their answers (default 20)")
    p.add_argument("--allow-partial", action="store_true",
                   help="play what is left of a damaged bag (missing messages, damaged chunks) instead of refusing it")


def _init() -> Any:
    import rclpy

    rclpy.init()
    return rclpy


def run_record(args: argparse.Namespace) -> int:
    """Record topics to a rosbag2 bag (mcap or sqlite3).

    Raw subscriptions (reliable, keep-all) written to a bag until Ctrl-C, --duration or --count.
    """
    rclpy = _init()
    from clm_ros.bag_tools import BagRecorder

    node = rclpy.create_node("clm_bag_recorder")
    stop = {"now": False}
    signal.signal(signal.SIGINT, lambda *_: stop.__setitem__("now", True))
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__("now", True))
    try:
        topics: dict[str, str] = {}
        t0 = time.monotonic()
        for spec in args.topics:
            topic, _, msgtype = spec.partition(":")
            while not msgtype:
                types = dict(node.get_topic_names_and_types())
                if topic in types:
                    msgtype = types[topic][0]
                elif time.monotonic() - t0 > args.discovery_timeout:
                    print(f"clm record: error: topic {topic} not seen on the graph after {args.discovery_timeout:g} s")
                    return 2
                else:
                    rclpy.spin_once(node, timeout_sec=0.05)
            topics[topic] = msgtype
        rec = BagRecorder(node, args.out, topics, args.storage)
        first = next(iter(topics))
        start = time.monotonic()
        try:
            while not stop["now"]:
                rclpy.spin_once(node, timeout_sec=0.05)
                if args.duration is not None and time.monotonic() - start >= args.duration:
                    break
                if args.count is not None and rec.counts[first] >= args.count:
                    break
            counts = rec.close()
        except Exception as exc:  # a full disk (OSError ENOSPC, sqlite's "disk is full"), an I/O error
            return _write_failed(rec, args.out, exc)
        print(json.dumps(counts))
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _write_failed(rec: Any, out: str, exc: Exception) -> int:
    """The bag could not be written (full disk, I/O error): drop the partial bag, say so in one line; exit code 1.

    A bag cut at a failed write is not readable (no index, no metadata; the mcap or sqlite file may end inside a
    record), so nothing is left rather than a file that looks like a bag: neither ``out`` nor the hidden
    ``.NAME.partial-*`` directory.
    """
    n = sum(rec.counts.values())
    rec.abort()
    why = " ".join(str(getattr(exc, "strerror", None) or exc).split())[:200]
    print(f"clm record: error: writing {out!r} failed after {n} message(s): {why} ({type(exc).__name__}); "
          "the partial bag was removed", file=sys.stderr)
    return 1


def run_play(args: argparse.Namespace) -> int:
    """Publish a bag's messages (real time, scaled, or flow-controlled).

    Publishes the messages of a rosbag2 bag (mcap or sqlite3) on their topics, with their recorded timing
    (--rate 1), scaled (--rate 2: twice as fast), or as fast as a node answers them (--rate 0: at most
    --max-in-flight messages without an answer on --ack-topic). Prints the counts sent.
    """
    rclpy = _init()
    from clm_ros.bag_tools import play_bag

    node = rclpy.create_node("clm_bag_player")
    try:
        sent = play_bag(node, args.bag, args.topics, args.rate, args.ack_topic, max_in_flight=args.max_in_flight,
                        allow_partial=getattr(args, "allow_partial", False))
        print(json.dumps(sent))
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
