#!/usr/bin/env python3
"""Benchmark: the numpy CDR codec of clm_core.io.messages, per message [us].

The track node's per-message edge in the next phase: decode one
``clm_msgs/WheelLoads`` of a 4-wheel frame, encode one ``SleeperResponse``
of a 61-sleeper window and one ``WheelRailResponse`` of 4 wheels. For
comparison (when rclpy and clm_msgs are importable), the current rclpy path:
``deserialize_message`` + ``frame_from_msg`` and ``rclpy_responses`` +
``serialize_message``. Prints the median and minimum of repeated timings and
the machine's load average (the machine is shared: read the minimum).

    .venv/bin/python benchmarks/cdr_codec.py [--repeat 15] [--number 2000]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import timeit
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CLM_ROS_SRC = REPO / "ros2_ws" / "src" / "clm_ros"
if str(CLM_ROS_SRC) not in sys.path:
    sys.path.insert(0, str(CLM_ROS_SRC))

from clm_core.io import messages as msgs  # noqa: E402
from clm_core.io.timebase import NS  # noqa: E402


def _time(fn: Any, repeat: int, number: int) -> tuple[float, float]:
    runs = [t / number * 1e6 for t in timeit.repeat(fn, number=number, repeat=repeat)]
    return statistics.median(runs), min(runs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--number", type=int, default=2000)
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    t_ns = 1_795_311_577 * NS + 12_847_207
    wl = msgs.encode_wheel_loads(t_ns, "track", np.arange(4, dtype=np.uint32), 30 + rng.random(4), 8e4 + rng.random(4),
                              np.full(4, 83.33))
    s_arrays = [np.arange(100, 161, dtype=np.int64), *(rng.random(61) for _ in range(5))]
    w_arrays = [np.arange(4, dtype=np.uint32), *(rng.random(4) for _ in range(3))]
    cases = {
        "decode WheelLoads (4 wheels)": lambda: msgs.decode_wheel_loads(wl),
        "encode SleeperResponse (61 sleepers)": lambda: msgs.encode_sleeper_response(t_ns, "track", *s_arrays),
        "encode WheelRailResponse (4 wheels)": lambda: msgs.encode_wheel_rail_response(t_ns, "track", *w_arrays),
    }
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; "
          f"{args.repeat} x {args.number} calls per case")
    total_med = total_min = 0.0
    for name, fn in cases.items():
        med, low = _time(fn, args.repeat, args.number)
        total_med += med
        total_min += low
        print(f"  {name:40s} median {med:6.2f} us   min {low:6.2f} us")
    print(f"  {'one frame in + both responses out':40s} median {total_med:6.2f} us   min {total_min:6.2f} us")
    try:
        from clm_msgs.msg import WheelLoads
        from clm_ros.conversions import rclpy_responses
        from rclpy.serialization import deserialize_message, serialize_message

        from clm_core.online import OnlineTrackModel, frame_from_msg
    except ImportError as exc:
        print(f"(rclpy comparison skipped: {exc})")
        return 0
    model = OnlineTrackModel.from_settings({"track": "mevergnies", "soil": "mevergnies", "model": "clm", "dt": 1e-4,
                                            "n_sleepers": 61})
    resp = model.process(frame_from_msg(deserialize_message(wl, WheelLoads)))
    rclpy_cases = {
        "rclpy: deserialize + frame_from_msg": lambda: frame_from_msg(deserialize_message(wl, WheelLoads)),
        "rclpy: rclpy_responses + serialize x2": lambda: [serialize_message(m) for m in rclpy_responses(resp, t_ns)],
        "codec: frame + both responses": lambda: (
            msgs.decode_wheel_loads(wl),
            msgs.encode_sleeper_response(t_ns, "track", *msgs.sleeper_fields(resp).values()),
            msgs.encode_wheel_rail_response(t_ns, "track", *msgs.wheel_fields(resp).values()),
        ),
    }
    for name, fn in rclpy_cases.items():
        med, low = _time(fn, args.repeat, max(1, args.number // 4))
        print(f"  {name:40s} median {med:6.2f} us   min {low:6.2f} us")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
