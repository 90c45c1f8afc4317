"""Benchmark: offline replay speed (``clm replay``) as a real-time factor.

A wheel-load bag is generated first: ``--seconds`` (default 10) of
``clm_msgs/WheelLoads`` at ``--rate`` (default 1 kHz) of a 4-wheel vehicle
(two bogies, 2.5 m axle base, 12.5 m bogie centres) at 83.33 m/s, each wheel
85 kN plus a 5 % dynamic part, written with rosbags (mcap). It is then run
through :func:`clm_ros.replay.replay_bag` (the track node's code path: the
Mevergnies track on its CLM soil, 61-sleeper window, dt = 1e-4 s):

- **with output**: ``replay_bag`` as ``clm replay`` runs it, writing the inputs
  and both responses to an mcap bag;
- **without output**: the same call with the bag writer replaced by one that
  discards what it is given (responses still built and serialised: only the
  storage is left out);
- **model only**: read + deserialise + ``OnlineTrackModel.process``, no
  response messages (the floor of any replay).

RTF = simulated seconds / wall-clock seconds of the message loop (the
``ReplayStats`` figure; model construction and warm-up excluded), best of
``--repeat`` runs; the end-to-end wall time of each call (open, close) is
given too. Figures are printed, never asserted.

Usage::

    python benchmarks/replay_rtf.py [--seconds 10] [--rate 1000] [--repeat 3] [--json]
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
CLM_ROS_SRC = REPO / "ros2_ws" / "src" / "clm_ros"
if str(CLM_ROS_SRC) not in sys.path:
    sys.path.insert(0, str(CLM_ROS_SRC))

import clm_ros.replay as replay_mod  # noqa: E402

from clm_core.io.bags import BagReader, BagWriter  # noqa: E402
from clm_core.io.messages import WHEEL_LOADS, wheel_loads_msg  # noqa: E402
from clm_core.io.timebase import NS  # noqa: E402
from clm_core.online import OnlineTrackModel, Rejected, frame_from_msg  # noqa: E402
from clm_core.params import load_model  # noqa: E402

SPEED = 83.33
OFFSETS = np.array([0.0, 2.5, 12.5, 15.0])  # wheel positions behind the first one [m] (fits 61 sleepers)
STATIC = 85e3
T0_NS = 1_700_000_000 * NS


def write_wheel_bag(path: Path, seconds: float, rate: float, x0: float = 30.0) -> int:
    """A 4-wheel wheel-load bag (mcap) of ``seconds`` at ``rate``; returns the message count."""
    n = int(round(seconds * rate)) + 1
    period = int(round(NS / rate))
    rng = np.random.default_rng(1)
    phase = rng.uniform(0, 2 * np.pi, (3, OFFSETS.size))
    freq = np.array([3.0, 17.0, 41.0])  # body, bogie, wheelset-track [Hz]
    amp = np.array([0.03, 0.015, 0.005]) * STATIC
    with BagWriter(path, "mcap") as w:
        conn = w.add_topic("/wheel_loads", WHEEL_LOADS)
        for k in range(n):
            t = k / rate
            x = x0 + SPEED * t - OFFSETS
            F = STATIC + (amp[:, None] * np.sin(2 * np.pi * freq[:, None] * t + phase)).sum(axis=0)
            t_ns = T0_NS + k * period
            w.write_msg(conn, t_ns, wheel_loads_msg(w.typestore, t_ns, range(OFFSETS.size), x, F,
                                                    np.full(OFFSETS.size, SPEED)))
    return n


class NullWriter:
    """Drop-in for :class:`clm_core.io.bags.BagWriter` that stores nothing."""

    def __init__(self, *_a: Any, **_k: Any) -> None:
        self.bytes = 0

    def __enter__(self) -> NullWriter:
        return self

    def __exit__(self, *_a: Any) -> None:
        return None

    def add_topic(self, *_a: Any, **_k: Any) -> object:
        return object()

    def write(self, _conn: Any, _t: int, data: bytes) -> None:
        self.bytes += len(data)


def new_model(params: Any, dt: float, n_sleepers: int) -> OnlineTrackModel:
    return OnlineTrackModel.from_settings({"dt": dt, "n_sleepers": n_sleepers}, params=params)


def run_replay(in_bag: Path, out_dir: Path, params: Any, dt: float, n_sleepers: int, write: bool) -> dict[str, Any]:
    model = new_model(params, dt, n_sleepers)
    out = out_dir / f"out_{time.monotonic_ns()}"
    orig = replay_mod.BagWriter
    if not write:
        replay_mod.BagWriter = NullWriter  # type: ignore[misc,assignment]
    try:
        w0 = time.perf_counter()
        st = replay_mod.replay_bag(in_bag, out, model)
        wall = time.perf_counter() - w0
    finally:
        replay_mod.BagWriter = orig  # type: ignore[misc]
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file()) if out.exists() else 0
    return {"rtf": st.real_time_factor, "sim_time_s": st.sim_time_s, "loop_wall_s": st.wall_time_s,
            "call_wall_s": wall, "read": st.read, "written": st.written, "rejected": sum(st.rejected.values()),
            "output_bytes": size}


def run_model_only(in_bag: Path, params: Any, dt: float, n_sleepers: int) -> dict[str, Any]:
    model = new_model(params, dt, n_sleepers)
    reader = BagReader(in_bag)
    sim_t = 0.0
    n = 0
    try:
        w0 = time.perf_counter()
        for bm in reader.messages([reader.find(WHEEL_LOADS)]):
            msg = reader.deserialize(bm.data, bm.msgtype)
            before = model.stats.simulated_ns
            try:
                model.process(frame_from_msg(msg))
            except Rejected:
                continue
            sim_t += (model.stats.simulated_ns - before) / 1e9
            n += 1
        wall = time.perf_counter() - w0
    finally:
        reader.close()
    return {"rtf": sim_t / wall if wall > 0 else 0.0, "sim_time_s": sim_t, "loop_wall_s": wall, "read": n}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0, help="length of the generated bag [s] (default 10)")
    ap.add_argument("--rate", type=float, default=1000.0, help="wheel-load rate [Hz] (default 1000)")
    ap.add_argument("--dt", type=float, default=1e-4, help="track time step [s] (default 1e-4)")
    ap.add_argument("--sleepers", type=int, default=61, help="track window [sleepers] (default 61)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per case; the best is reported (default 3)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args()
    params = load_model("mevergnies", "mevergnies", "clm")
    res: dict[str, Any] = {"seconds": args.seconds, "rate_hz": args.rate, "dt_s": args.dt,
                           "n_sleepers": args.sleepers, "wheels": int(OFFSETS.size), "speed_m_per_s": SPEED,
                           "repeat": args.repeat, "python": platform.python_version(), "cores": os.cpu_count(),
                           "loadavg_before": os.getloadavg()}
    with tempfile.TemporaryDirectory(prefix="clm_replay_rtf_") as tmp:
        d = Path(tmp)
        w0 = time.perf_counter()
        res["messages"] = write_wheel_bag(d / "wheels", args.seconds, args.rate)
        res["bag_write_s"] = time.perf_counter() - w0
        res["input_bytes"] = sum(f.stat().st_size for f in (d / "wheels").rglob("*") if f.is_file())
        # warm-up: compiled kernels loaded, caches filled
        write_wheel_bag(d / "warm", 0.2, args.rate)
        run_replay(d / "warm", d, params, args.dt, args.sleepers, write=True)
        cases = {
            "with_output": lambda: run_replay(d / "wheels", d, params, args.dt, args.sleepers, write=True),
            "without_output": lambda: run_replay(d / "wheels", d, params, args.dt, args.sleepers, write=False),
            "model_only": lambda: run_model_only(d / "wheels", params, args.dt, args.sleepers),
        }
        for name, fn in cases.items():
            runs = [fn() for _ in range(args.repeat)]
            best = max(runs, key=lambda r: r["rtf"])
            best["rtf_all"] = [r["rtf"] for r in runs]
            res[name] = best
    res["loadavg_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(f"replay_rtf: {args.seconds:g} s wheel-load bag at {args.rate:g} Hz ({res['messages']} messages, "
          f"{res['wheels']} wheels at {SPEED} m/s, {res['input_bytes'] / 1e6:.2f} MB mcap), Mevergnies CLM, "
          f"{args.sleepers} sleepers, dt {args.dt:g} s; best of {args.repeat}")
    print(f"{'case':<16}{'RTF':>8}{'loop wall':>12}{'call wall':>12}{'us/msg':>9}  output")
    for name in ("with_output", "without_output", "model_only"):
        r = res[name]
        call = f"{r['call_wall_s']:10.2f} s" if "call_wall_s" in r else f"{'':>12}"
        out = f"{r['output_bytes'] / 1e6:.1f} MB mcap, {r['written']} responses" if name == "with_output" else (
            f"{r['written']} responses built, not stored" if name == "without_output" else "no response messages")
        print(f"{name:<16}{r['rtf']:8.2f}{r['loop_wall_s']:10.2f} s{call}{1e6 * r['loop_wall_s'] / r['read']:9.0f}  "
              f"{out}")
    print("(RTF = simulated / wall seconds of the message loop; all runs: "
          + "; ".join(f"{n} " + ", ".join(f"{x:.2f}" for x in res[n]["rtf_all"])
                      for n in ("with_output", "without_output", "model_only"))
          + f"; load average {res['loadavg_before'][0]:.2f} -> {res['loadavg_after'][0]:.2f} on {res['cores']} cores)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
