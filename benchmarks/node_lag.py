"""Benchmark: the track node over DDS, its lag and its CPU per message next to the kernel's (prints, never asserts).

The track node (``clm_ros.track_node``: Mevergnies track on its CLM soil,
dt = 1e-4 s) runs as a process of its own in a ROS domain of its own
(loopback discovery). Cases (``--case``, several with commas):

- ``track``: this process feeds the node with wheel loads at ``--rate`` Hz
  (4 wheels at 83.33 m/s, 85 kN +- 5 kN: :func:`online_path.stream`; stamps
  = the wall-clock time each message is due) for ``--duration`` s and listens
  to the answers. Lag = receive time here - stamp (the publisher's
  lateness, DDS both ways and the node). Cases of the issue: 61 sleepers at
  1 kHz (default), ``--sleepers 401``, ``--rate 2000``.
- ``backlog``: ``--backlog`` messages (default 5 000, i.e. 5 s of traffic at
  1 kHz) published at once to the running node; the time from the first
  publication to the last answer gives the clearance rate (simulated time /
  wall time; target >= 5).
- ``demo``: the vehicle node (``clm_ros.vehicle_node``, Thalys at 83.33 m/s,
  1 kHz, closed loop) feeds the node, as ``clm demo`` without the recorder;
  the CPU per message of both nodes.

Side by side in the same run and under the same load, this process times
the compiled kernel for the same steps (:func:`online_path.kernel_per_call`:
``run_steps`` for the steps of one message, 10 at 1 kHz, 5 at 2 kHz) and the
model alone (:func:`online_path.process_per_frame`), and prints the track
node's CPU per message (from ``/proc``, over the steady part of the run:
executor, DDS, decoding, model, encoding, publishing, diagnostics) as a
multiple of the kernel's (target <= 2x; well under 250 us for 61 sleepers).

``--hog N`` starts N busy-loop processes for the whole run (a loaded
machine). ``--runs K`` repeats every case and prints each run and the worst.
Figures only; the machine's load average is printed with them.

Usage::

    python benchmarks/node_lag.py [--case track,backlog,demo] [--duration 20] [--rate 1000] [--sleepers 61]
                                  [--backlog 5000] [--hog N] [--runs 3] [--json] [--keep-logs DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CLM_ROS_SRC = REPO / "ros2_ws" / "src" / "clm_ros"
for path in (CLM_ROS_SRC, REPO / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from clm_ros.processes import hold_domain_id, ros_args, ros_env, stop_processes  # noqa: E402
from online_path import KernelCall, stream  # noqa: E402
from online_path import side_by_side as tight_loops  # noqa: E402

from clm_core.io.messages import encode_wheel_loads  # noqa: E402
from clm_core.io.timebase import NS, lag_figures  # noqa: E402
from clm_core.params import load_model  # noqa: E402

TRACK = {"track": "mevergnies", "soil": "mevergnies", "model": "clm", "dt": 1e-4, "diagnostics_period": 1.0}
VEHICLE = {"vehicle": "thalys", "speed": 83.33, "rate": 1000.0, "dt": 1e-4, "irregularity": "german-low",
           "seed": 1, "closed_loop": True, "track": "mevergnies", "soil": "mevergnies", "model": "clm",
           "wait_for_subscribers": 1, "ack_timeout": 10.0}
CLK_TCK = os.sysconf("SC_CLK_TCK")


# ---------------------------------------------------------------------------------------------- environment


def proc_cpu_s(pid: int) -> float:
    """User + system CPU time of a process [s] (NaN once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def machine_cpu() -> tuple[float, float]:
    """(busy, total) jiffies of all CPUs."""
    v = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    return float(sum(v) - v[3] - v[4]), float(sum(v))


@contextlib.contextmanager
def hogs(n: int) -> Iterator[list[int]]:
    """``n`` busy-loop processes for the duration of the context (their pids)."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            p.kill()
            p.wait()


def header_stamp(raw: bytes) -> int:
    """``header.stamp`` [ns] of serialized CDR bytes (nothing else decoded)."""
    sec, nsec = struct.unpack_from("<iI" if raw[1] == 1 else ">iI", raw, 4)
    return sec * NS + nsec


class Listener:
    """This process on the bus: wheel-load publisher, raw answers (stamp, receive time), the node's diagnostics."""

    def __init__(self, domain_id: int) -> None:
        import rclpy
        from clm_msgs.msg import SleeperResponse, WheelLoads
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.experimental import EventsExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        self.rclpy = rclpy
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = rclpy.create_node("clm_node_lag", context=self.ctx)
        self.ex = EventsExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.node.create_publisher(WheelLoads, "/wheel_loads", qos)
        self.stamps: list[int] = []
        self.recv: list[int] = []
        self.diags: list[dict[str, str]] = []
        self.sub = self.node.create_subscription(SleeperResponse, "/sleeper_response", self._on_answer, qos, raw=True)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)

    def _on_answer(self, raw: bytes) -> None:
        self.recv.append(time.time_ns())
        self.stamps.append(header_stamp(raw))

    def _on_diag(self, msg: Any) -> None:
        for st in msg.status:
            if "track-soil" in st.name:
                self.diags.append({kv.key: kv.value for kv in st.values})

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.ex.spin_once(timeout_sec=left)

    def wait(self, cond: Any, timeout: float, what: str, proc: subprocess.Popen[bytes] | None = None) -> None:
        t0 = time.monotonic()
        while not cond():
            self.spin_for(0.02)
            if proc is not None and proc.poll() is not None:
                raise RuntimeError(f"{what}: the process exited with {proc.returncode}")
            if time.monotonic() - t0 > timeout:
                raise RuntimeError(f"{what} not within {timeout} s")

    def close(self) -> None:
        self.node.destroy_node()
        self.ex.shutdown()
        self.rclpy.try_shutdown(context=self.ctx)


@contextlib.contextmanager
def track_node(params: dict[str, Any], log_dir: Path, name: str,
               python_args: Sequence[str] = ("-m", "clm_ros.track_node"),
               env_extra: Mapping[str, str] | None = None) -> Iterator[tuple[subprocess.Popen[bytes], Listener]]:
    """The track node in a domain of its own and this process's listener, both ready (node active).

    ``python_args``: how the interpreter starts the node (default ``-m clm_ros.track_node``; soak.py's
    ``--trace-python`` starts it under ``tracemalloc``); ``env_extra``: added to the node's environment."""
    with hold_domain_id() as dom:
        env = {**ros_env(dom, pythonpath=[str(CLM_ROS_SRC)]), **(env_extra or {})}
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        with open(log_dir / f"{name}.log", "w") as log:
            proc = subprocess.Popen([sys.executable, *python_args, *ros_args({**TRACK, **params})],
                                    env=env, stdout=log, stderr=subprocess.STDOUT)
            lis = Listener(dom)
            try:
                # active and subscribed (the signal the vehicle node waits for), answers reaching us
                lis.wait(lambda: lis.pub.get_subscription_count() >= 1 and lis.sub.get_publisher_count() >= 1
                         and lis.diags, 180, "track node ready", proc)
                lis.env = env  # type: ignore[attr-defined]
                yield proc, lis
            finally:
                lis.close()
                stop_processes([proc], timeout=20)


def answer_lags(stamps: list[int], recv: list[int]) -> dict[str, float]:
    """Lag (receive time - stamp) over all answers and over the first second of traffic [s]."""
    st = np.asarray(stamps, dtype=np.int64)
    rv = np.asarray(recv, dtype=np.int64)
    lag = (rv - st) / 1e9
    first = (st - st[0] < NS) if st.size else np.zeros(0, dtype=bool)
    whole, start = lag_figures(st, received_ns=rv), lag_figures(st[first], received_ns=rv[first])
    return {"answers": float(whole.n), **whole.named(), "over_5ms": float((lag > 5e-3).sum()),
            "over_20ms": float((lag > 20e-3).sum()), "first_second_median_s": start.median_s,
            "first_second_max_s": start.max_s}


def side_by_side(sleepers: int, rate: float, frames: int = 1500) -> dict[str, float]:
    """CPU time per message [us] in this process for the same steps as the node's: the bare kernel
    (:class:`online_path.KernelCall`, ``run_steps``) and the model alone (``process``), in tight loops
    (:func:`online_path.side_by_side`) and at the node's cadence (one call each per message period, idle in
    between, as the node runs: the caches and the CPU go cold between two messages)."""
    from clm_core.online import OnlineTrackModel

    params = load_model("mevergnies", "mevergnies", "clm")
    steps = round(1.0 / (rate * TRACK["dt"]))
    todo = stream(frames, rate)
    kc, _, pc, _ = tight_loops(params, sleepers, steps, todo)
    kernel = KernelCall(params, sleepers, steps)
    model = OnlineTrackModel.from_settings({"dt": TRACK["dt"], "n_sleepers": sleepers}, params=params)
    model.process(todo[0])
    k_cpu = m_cpu = 0.0
    period = 1.0 / rate
    next_t = time.perf_counter()
    for f in todo[1:]:
        for i in (0, 1):  # the kernel, then the model, half a period apart
            next_t += period / 2
            time.sleep(max(next_t - time.perf_counter(), 0.0))
            c = time.thread_time()
            if i == 0:
                kernel(1)
                k_cpu += time.thread_time() - c
            else:
                model.process_batch([f])
                m_cpu += time.thread_time() - c
    n = len(todo) - 1
    return {"kernel_us": kc * 1e6, "model_us": pc * 1e6, "steps": float(steps),
            "kernel_cadence_us": 1e6 * k_cpu / n, "model_cadence_us": 1e6 * m_cpu / n}


# ---------------------------------------------------------------------------------------------- cases


def case_track(a: argparse.Namespace, log_dir: Path) -> dict[str, Any]:
    """This process feeds the node at a.rate for a.duration s."""
    n = int(a.duration * a.rate)
    period = round(NS / a.rate)
    params = {"n_sleepers": a.sleepers, **getattr(a, "node_params", {})}  # node_params: benchmarks/node_cpu.py
    with track_node(params, log_dir, "track_node") as (proc, lis):
        t0 = time.time_ns() + NS // 2
        frames = stream(n, a.rate, t0)
        raws = [encode_wheel_loads(f.stamp_ns, "track", f.ids, f.positions, f.forces) for f in frames]
        while time.time_ns() < t0:
            lis.spin_for(0.01)
        samples: list[tuple[float, ...]] = []

        def sample() -> None:
            samples.append((time.monotonic(), proc_cpu_s(proc.pid), *machine_cpu(), float(len(lis.stamps))))

        sent_at = np.zeros(n, dtype=np.int64)  # when each message actually went out [ns]
        k = 0
        while k < n:
            due = (t0 + k * period - time.time_ns()) / NS
            if due > 0:
                lis.ex.spin_once(timeout_sec=due)
                continue
            sent_at[k] = time.time_ns()
            lis.pub.publish(raws[k])
            k += 1
            if k == n // 10:  # the steady part: from 10 % of the run to the last answer
                sample()
        lis.wait(lambda: len(lis.stamps) >= n, 30, "every answer")
        sample()
        n_diag = len(lis.diags)
        lis.wait(lambda: len(lis.diags) > n_diag, 10, "final diagnostics")
        rtf = [float(d["real_time_factor"]) for d in lis.diags if d.get("real_time_factor", "nan") != "nan"]
        out = steady_cpu(samples, proc.pid)
        out.update(answer_lags(lis.stamps, lis.recv))
        # the same without this process's own lateness: from the moment each message was published
        index = {int(f.stamp_ns): i for i, f in enumerate(frames)}
        late = sent_at - np.array([f.stamp_ns for f in frames])
        from_pub = lag_figures([r - sent_at[index[st]] for st, r in zip(lis.stamps, lis.recv) if st in index])
        late_f = lag_figures(late)
        out.update({**from_pub.named("from_publish"), "publisher_late_p99_s": late_f.p99_s,
                    "publisher_late_max_s": late_f.max_s})
        dp = [float(d["data_path_cpu_us_per_message"]) for d in lis.diags
              if d.get("data_path_cpu_us_per_message", "nan") != "nan"]
        out.update({"sent": float(n), "rtf_min": min(rtf, default=float("nan")),
                    "data_path_us": float(np.median(dp)) if dp else float("nan"),
                    "rtf_median": float(np.median(rtf)) if rtf else float("nan"),
                    "diagnostics": lis.diags[-1]})
    out.update(side_by_side(a.sleepers, a.rate))
    return out


def steady_cpu(samples: list[tuple[float, ...]], pid: int) -> dict[str, Any]:
    """Track-node CPU per message and % of a core, machine busy, between the first and the last sample."""
    (w0, c0, b0, t0, n0), (w1, c1, b1, t1, n1) = samples[0], samples[-1]
    msgs = max(n1 - n0, 1.0)
    return {"track_cpu_us_per_message": 1e6 * (c1 - c0) / msgs, "track_cpu_pct": 100 * (c1 - c0) / (w1 - w0),
            "machine_busy_pct": 100 * (b1 - b0) / max(t1 - t0, 1.0), "loadavg": os.getloadavg()[0]}


def case_backlog(a: argparse.Namespace, log_dir: Path) -> dict[str, Any]:
    """a.backlog messages at once to the running node: how fast it clears them."""
    n = a.backlog
    with track_node({"n_sleepers": a.sleepers, "diagnostics_period": 0.2}, log_dir, "track_node_backlog") as (
            proc, lis):
        frames = stream(n, a.rate, time.time_ns())
        raws = [encode_wheel_loads(f.stamp_ns, "track", f.ids, f.positions, f.forces) for f in frames]
        c0 = proc_cpu_s(proc.pid)
        w0 = time.monotonic()
        for r in raws:
            lis.pub.publish(r)
        w_pub = time.monotonic() - w0
        lis.wait(lambda: len(lis.stamps) >= n, 120, "the backlog answered")
        wall = (lis.recv[-1] - lis.recv[0]) / 1e9 + 0.0
        w_all = time.monotonic() - w0
        cpu = proc_cpu_s(proc.pid) - c0
        n_diag = len(lis.diags)
        lis.wait(lambda: len(lis.diags) > n_diag, 10, "final diagnostics")
        d = lis.diags[-1]
        simulated = n / a.rate
        during = [x for x in lis.diags if 0 < int(x.get("accepted", 0)) < n]
        return {"messages": float(n), "simulated_s": simulated, "publish_s": w_pub, "clear_s": w_all,
                "clearance": simulated / w_all, "first_to_last_answer_s": wall, "cpu_clearance": simulated / cpu,
                "track_cpu_us_per_message": 1e6 * cpu / n, "largest_batch": float(d["largest_batch"]),
                "batches": float(d["batches"]), "diagnostics_during": float(len(during)),
                "loadavg": os.getloadavg()[0]}


def case_demo(a: argparse.Namespace, log_dir: Path) -> dict[str, Any]:
    """The vehicle node at 1 kHz in closed loop with the track node, for a.duration s."""
    with track_node({"n_sleepers": a.sleepers}, log_dir, "track_node_demo") as (proc, lis):
        vlog = log_dir / "vehicle_node.log"
        with open(vlog, "w") as log:
            veh = subprocess.Popen([sys.executable, "-m", "clm_ros.vehicle_node",
                                    *ros_args({**VEHICLE, "duration": a.duration})],
                                   env=lis.env, stdout=log, stderr=subprocess.STDOUT)  # type: ignore[attr-defined]
            try:
                samples: list[tuple[float, ...]] = []
                while veh.poll() is None:
                    lis.spin_for(0.5)
                    if lis.stamps:
                        samples.append((time.monotonic(), proc_cpu_s(proc.pid), proc_cpu_s(veh.pid),
                                        *machine_cpu(), float(len(lis.stamps))))
            finally:
                stop_processes([veh], timeout=20)
        good = [s for s in samples if not np.isnan(s[2])]
        out: dict[str, Any] = answer_lags(lis.stamps, lis.recv)
        if len(good) >= 3:
            (_, c0, v0, b0, t0, n0), (_, c1, v1, b1, t1, n1) = good[len(good) // 10], good[-1]
            msgs = max(n1 - n0, 1.0)
            out.update({"track_cpu_us_per_message": 1e6 * (c1 - c0) / msgs,
                        "vehicle_cpu_us_per_message": 1e6 * (v1 - v0) / msgs,
                        "machine_busy_pct": 100 * (b1 - b0) / max(t1 - t0, 1.0)})
        m = re.search(r"(\d+) used as feedback", vlog.read_text(errors="replace"))
        out.update({"feedback_used": float(m.group(1)) if m else float("nan"), "loadavg": os.getloadavg()[0],
                    "diagnostics": lis.diags[-1] if lis.diags else {}})
    out.update(side_by_side(a.sleepers, VEHICLE["rate"]))
    return out


CASES = {"track": case_track, "backlog": case_backlog, "demo": case_demo}


# ---------------------------------------------------------------------------------------------- report


def report(case: str, runs: list[dict[str, Any]], a: argparse.Namespace) -> None:
    ms = lambda x: f"{1e3 * x:8.2f} ms"  # noqa: E731
    print(f"\n== {case}: {a.sleepers} sleepers, {a.rate:g} Hz wheel loads, {a.hog} hog(s), {len(runs)} run(s)")
    if case == "backlog":
        for i, r in enumerate(runs):
            print(f"  run {i + 1}: {int(r['messages'])} messages ({r['simulated_s']:.1f} s of traffic) cleared in "
                  f"{r['clear_s']:.2f} s wall: {r['clearance']:.1f}x real time (the node's CPU time alone: "
                  f"{r['cpu_clearance']:.1f}x); track node "
                  f"{r['track_cpu_us_per_message']:.0f} us CPU/message; batches {int(r['batches'])}, largest "
                  f"{int(r['largest_batch'])}; diagnostics during it {int(r['diagnostics_during'])}; load "
                  f"{r['loadavg']:.2f}")
        print(f"  worst: {min(r['clearance'] for r in runs):.1f}x real time, median "
              f"{np.median([r['clearance'] for r in runs]):.1f}x (target >= 5); by the node's CPU time: worst "
              f"{min(r['cpu_clearance'] for r in runs):.1f}x (a wall figure far below it: the node waited for the "
              "messages or for a core, not for its own work)")
        return
    for i, r in enumerate(runs):
        node = r.get("track_cpu_us_per_message", float("nan"))
        line = (f"  run {i + 1}: lag median {ms(r['lag_median_s'])} p99 {ms(r['lag_p99_s'])} max {ms(r['lag_max_s'])}"
                f" (>5 ms: {int(r['over_5ms'])}, >20 ms: {int(r['over_20ms'])}) of {int(r['answers'])} answers; "
                f"first second: median {ms(r['first_second_median_s'])}, max {ms(r['first_second_max_s'])}\n"
                + (f"         from the actual publication: median {ms(r['from_publish_median_s'])} p99 "
                   f"{ms(r['from_publish_p99_s'])} max {ms(r['from_publish_max_s'])} (this publisher late by up to "
                   f"{ms(r['publisher_late_max_s'])}, p99 {ms(r['publisher_late_p99_s'])})\n"
                   if "from_publish_median_s" in r else "") +
                f"         track node {node:6.0f} us CPU/message = {node / r['kernel_cadence_us']:.2f} x the compiled "
                f"kernel at the same cadence ({r['kernel_cadence_us']:.0f} us for {int(r['steps'])} steps; "
                f"model alone {r['model_cadence_us']:.0f} us)\n"
                f"         tight loops: kernel {r['kernel_us']:.0f} us (node = {node / r['kernel_us']:.2f} x), "
                f"model alone {r['model_us']:.0f} us; node's own data path {r.get('data_path_us', float('nan')):.0f} "
                "us (its diagnostics)")
        if "vehicle_cpu_us_per_message" in r:
            line += f"; vehicle node {r['vehicle_cpu_us_per_message']:.0f} us CPU/message"
        if "rtf_min" in r:
            line += f"; track RTF median {r['rtf_median']:.1f}, min {r['rtf_min']:.1f}"
        if "feedback_used" in r:
            line += f"; feedback used {int(r['feedback_used'])}"
        line += f"\n         machine busy {r.get('machine_busy_pct', float('nan')):.0f} %, load {r['loadavg']:.2f}"
        print(line)
    worst = max(runs, key=lambda r: r["lag_p99_s"])
    ratios = [r.get("track_cpu_us_per_message", float("nan")) / r["kernel_cadence_us"] for r in runs]
    print(f"  worst run: lag median {ms(worst['lag_median_s'])}, p99 {ms(worst['lag_p99_s'])}; track CPU/message "
          f"up to {max(r.get('track_cpu_us_per_message', float('nan')) for r in runs):.0f} us, up to "
          f"{max(ratios):.2f} x kernel at the same cadence (target <= 2)"
          + (f"; track RTF min {min(r['rtf_min'] for r in runs):.1f} (target >= 2)" if "rtf_min" in runs[0] else ""))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="track,backlog", help="track, backlog, demo (comma-separated)")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of traffic (track, demo)")
    ap.add_argument("--rate", type=float, default=1000.0, help="wheel-load rate [Hz] (track, backlog)")
    ap.add_argument("--sleepers", type=int, default=61, help="window length of the track node")
    ap.add_argument("--backlog", type=int, default=5000, help="messages of the backlog case")
    ap.add_argument("--hog", type=int, default=0, help="busy-loop processes started for the whole run")
    ap.add_argument("--runs", type=int, default=1, help="repetitions of every case")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    ap.add_argument("--keep-logs", default=None, help="directory for the node logs (default: a temporary one)")
    a = ap.parse_args()
    results: dict[str, list[dict[str, Any]]] = {}
    print(f"node_lag: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start; Mevergnies CLM, "
          f"dt 1e-4 s; CPU figures from /proc and getrusage")
    with contextlib.ExitStack() as stack:
        log_dir = Path(a.keep_logs) if a.keep_logs else Path(stack.enter_context(
            tempfile.TemporaryDirectory(prefix="clm_node_lag_")))
        log_dir.mkdir(parents=True, exist_ok=True)
        stack.enter_context(hogs(a.hog))
        for case in a.case.split(","):
            results[case] = [CASES[case](a, log_dir) for _ in range(a.runs)]
            if not a.json:
                report(case, results[case], a)
    if a.json:
        print(json.dumps(results, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
