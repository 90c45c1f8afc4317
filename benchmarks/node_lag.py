"""Benchmark: end-to-end lag of the track-soil node driven by the vehicle node at 1 kHz over DDS.

The demo's graph without the bag recorder: the track node
(``clm_ros.track_node``, Mevergnies track on its CLM soil, 61-sleeper window,
dt = 1e-4 s) and the vehicle simulator node (``clm_ros.vehicle_node``, Thalys
at 83.33 m/s, wheel loads at 1 kHz, closed loop) run as separate processes in
a ROS domain of their own (loopback discovery, as ``clm demo``) for
``--duration`` simulated seconds. This process only listens:

- ``/wheel_loads`` through a raw subscription (stamp only; off with
  ``--no-tap``; the vehicle then waits for 2 readers instead of 1): splits the
  lag into vehicle lateness + DDS, and track node + DDS back;
- ``/sleeper_response`` through a raw subscription (the CDR header stamp is
  read from the bytes, nothing else is deserialised) on an EventsExecutor:
  lag = receive time - wheel-load stamp (the vehicle stamps a message with
  the wall-clock time it is due to be published, so the lag includes its own
  lateness, DDS twice and the track node's callback);
- ``/diagnostics`` of the track node: its own lag (publish time - stamp,
  median and 99th percentile over its last 10 000 messages), real-time factor
  of the model, counts.

Reported: lag median / p99 / max (this subscriber, over the whole run and
after the first second; the track node's own figures), messages sent by the
vehicle, accepted / published by the track node, received here, answered to
the vehicle, dropped; CPU use of each process and of the machine (other
work on a shared machine shows there). Targets: median < 5 ms, p99 < 20 ms,
none dropped. Figures are printed, never asserted.

Where the time goes: ``--stages N`` (default 2000) times, in this process and
without middleware, each step of the per-message path on the same vehicle and
track (vehicle model step, message construction, (de)serialisation, the track
node's conversion, model step and response construction); compared with each
node's CPU time per message in the live run, the rest is the rclpy executor
and DDS. ``--cprofile`` runs the nodes under cProfile in the live run (slower:
only for the breakdown) and prints their top functions. ``--track-executor
events`` runs the unchanged ``TrackNode`` class under rclpy's EventsExecutor
(spun with ``spin_once``: its ``spin()`` delivered no callback to this node on
the Jazzy wheels) instead of the shipped SingleThreadedExecutor: an
experiment, to size that fix.

Usage::

    python benchmarks/node_lag.py [--duration 60] [--json] [--stages 2000] [--cprofile] [--no-tap]
                                  [--track-executor single|events] [--keep-logs DIR]

Measured (2-core shared machine, 60 s, shipped node): the track node needs
~1.0 ms of CPU per message (model ~0.3-0.5 ms, executor + two publishes the
rest), i.e. a whole core at 1 kHz, so it falls behind and the lag grows through
the run (median ~2 s, p99 ~4 s); nothing is dropped (keep-all reliable QoS).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import pstats
import re
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CLM_ROS_SRC = REPO / "ros2_ws" / "src" / "clm_ros"
if str(CLM_ROS_SRC) not in sys.path:
    sys.path.insert(0, str(CLM_ROS_SRC))

from clm_ros.processes import hold_domain_id, ros_args, ros_env, stop_processes  # noqa: E402

from clm_core.io.timebase import NS  # noqa: E402

TARGET_MEDIAN_S = 5e-3
TARGET_P99_S = 20e-3
TRACK = {"track": "mevergnies", "soil": "mevergnies", "model": "clm", "dt": 1e-4, "n_sleepers": 61,
         "diagnostics_period": 1.0}
VEHICLE = {"vehicle": "thalys", "speed": 83.33, "rate": 1000.0, "dt": 1e-4, "irregularity": "german-low",
           "seed": 1, "closed_loop": True, "track": "mevergnies", "soil": "mevergnies", "model": "clm",
           "wait_for_subscribers": 1, "ack_timeout": 10.0}
CLK_TCK = os.sysconf("SC_CLK_TCK")

#: ``--track-executor events``: the unchanged TrackNode spun by rclpy's EventsExecutor instead of the
#: SingleThreadedExecutor of ``clm_ros.track_node.main`` (an experiment for the report, not the shipped node)
TRACK_EVENTS = """
import sys
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from clm_ros.track_node import TrackNode
rclpy.init(args=sys.argv)
node = TrackNode()
ex = EventsExecutor()
ex.add_node(node)
try:
    while rclpy.ok():  # EventsExecutor.spin() delivered nothing here (Jazzy wheels); spin_once does
        ex.spin_once(timeout_sec=0.1)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
finally:
    node.destroy_node()
    rclpy.try_shutdown()
"""


# ---------------------------------------------------------------------------------------------- environment


def proc_cpu_s(pid: int) -> float | None:
    """User + system CPU time of a process [s] (None once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def machine_cpu() -> tuple[float, float]:
    """(busy, total) jiffies of all CPUs."""
    v = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = v[3] + v[4]
    return float(sum(v) - idle), float(sum(v))


def pct(x: np.ndarray, q: float) -> float:
    return float(np.percentile(x, q)) if x.size else float("nan")


# ---------------------------------------------------------------------------------------------- live run


def run_live(duration: float, log_dir: Path, cprofile: bool, timeout: float, tap: bool,
             track_executor: str = "single") -> dict[str, Any]:
    import rclpy
    from clm_msgs.msg import SleeperResponse, WheelLoads
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    n_expected = int(round(duration * VEHICLE["rate"])) + 1
    stamps = np.zeros(n_expected + 1000, dtype=np.int64)
    recv = np.zeros(n_expected + 1000, dtype=np.int64)
    count = [0]
    in_stamps = np.zeros(n_expected + 1000, dtype=np.int64)
    in_recv = np.zeros(n_expected + 1000, dtype=np.int64)
    in_count = [0]
    diags: list[tuple[float, dict[str, str]]] = []

    def on_raw(raw: bytes) -> None:
        t = time.time_ns()
        i = count[0]
        if i < stamps.size:
            endian = "<" if raw[1] == 1 else ">"
            sec, nsec = struct.unpack_from(endian + "iI", raw, 4)
            stamps[i] = sec * NS + nsec
            recv[i] = t
        count[0] = i + 1

    def on_input(raw: bytes) -> None:
        t = time.time_ns()
        i = in_count[0]
        if i < in_stamps.size:
            endian = "<" if raw[1] == 1 else ">"
            sec, nsec = struct.unpack_from(endian + "iI", raw, 4)
            in_stamps[i] = sec * NS + nsec
            in_recv[i] = t
        in_count[0] = i + 1

    def on_diag(msg: Any) -> None:
        for st in msg.status:
            if "track-soil" in st.name:
                diags.append((time.monotonic(), {kv.key: kv.value for kv in st.values}))

    with hold_domain_id() as dom:
        env = ros_env(dom, pythonpath=[str(CLM_ROS_SRC)])
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        prof = {name: log_dir / f"{name}.prof" for name in ("track_node", "vehicle_node")}

        def cmd(name: str, params: dict[str, Any]) -> list[str]:
            pre = [sys.executable]
            if cprofile:
                pre += ["-m", "cProfile", "-o", str(prof[name])]
            if name == "track_node" and track_executor == "events":
                script = log_dir / "track_node_events.py"
                script.write_text(TRACK_EVENTS)
                return [*pre, str(script), *ros_args(params)]
            return [*pre, "-m", f"clm_ros.{name}", *ros_args(params)]

        logs = {n: open(log_dir / f"{n}.log", "w") for n in ("track_node", "vehicle_node")}
        procs: dict[str, subprocess.Popen[bytes]] = {}
        ctx = Context()
        rclpy.init(context=ctx, domain_id=dom)
        result: dict[str, Any] = {"ros_domain_id": dom, "track_executor": track_executor}
        try:
            procs["track_node"] = subprocess.Popen(cmd("track_node", TRACK), env=env, stdout=logs["track_node"],
                                                   stderr=subprocess.STDOUT)
            node = rclpy.create_node("clm_node_lag_listener", context=ctx)
            ex = EventsExecutor(context=ctx)
            ex.add_node(node)
            qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
            sub = node.create_subscription(SleeperResponse, "/sleeper_response", on_raw, qos, raw=True)
            node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
            if tap:
                node.create_subscription(WheelLoads, "/wheel_loads", on_input, qos, raw=True)

            def spin_for(seconds: float) -> None:
                end = time.monotonic() + seconds
                while (left := end - time.monotonic()) > 0:
                    ex.spin_once(timeout_sec=left)

            t0 = time.monotonic()
            while sub.get_publisher_count() < 1 or not diags:  # track node up, configured and active
                spin_for(0.05)
                if procs["track_node"].poll() is not None:
                    raise RuntimeError(f"track node exited with {procs['track_node'].returncode}; see {log_dir}")
                if time.monotonic() - t0 > 120:
                    raise RuntimeError(f"track node not up within 120 s; see {log_dir}")
            vparams = {**VEHICLE, "duration": duration, "wait_for_subscribers": 2 if tap else 1}
            procs["vehicle_node"] = subprocess.Popen(cmd("vehicle_node", vparams), env=env,
                                                     stdout=logs["vehicle_node"], stderr=subprocess.STDOUT)
            pids = {n: p.pid for n, p in procs.items()}
            # CPU samples: (wall, track cpu, vehicle cpu, machine busy, machine total), from the first answer on
            samples: list[tuple[float, float | None, float | None, float, float]] = []
            t_start = time.monotonic()
            next_sample = 0.0
            while procs["vehicle_node"].poll() is None:
                spin_for(0.05)
                now = time.monotonic()
                if count[0] and now >= next_sample:
                    samples.append((now, proc_cpu_s(pids["track_node"]), proc_cpu_s(pids["vehicle_node"]),
                                    *machine_cpu()))
                    next_sample = now + 0.5
                if procs["track_node"].poll() is not None:
                    raise RuntimeError(f"track node exited early; see {log_dir}/track_node.log")
                if now - t_start > duration + timeout:
                    raise RuntimeError(f"vehicle node still running after {duration + timeout:g} s")
            t_vehicle_done = time.monotonic()
            t1 = time.monotonic()
            while count[0] < n_expected and time.monotonic() - t1 < 10:
                spin_for(0.05)
            # a diagnostics message issued after the last answer (the final counts)
            n_diag = len(diags)
            t2 = time.monotonic()
            while len(diags) < n_diag + 2 and time.monotonic() - t2 < 5:
                spin_for(0.05)
            samples.append((time.monotonic(), proc_cpu_s(pids["track_node"]), None, *machine_cpu()))
            own_cpu = time.process_time()
            node.destroy_node()
        finally:
            stop_processes(procs.values(), timeout=20)
            for f in logs.values():
                f.close()
            rclpy.try_shutdown(context=ctx)

    n = min(count[0], stamps.size)
    lag = (recv[:n] - stamps[:n]) / 1e9
    t_rel = (stamps[:n] - stamps[0]) / 1e9 if n else np.zeros(0)
    steady = lag[t_rel >= 1.0]
    # split of the lag: wheel loads seen here (vehicle lateness + DDS) and the rest (track node + DDS back)
    split: dict[str, float] = {}
    ni = min(in_count[0], in_stamps.size)
    if ni:
        arrive = dict(zip(in_stamps[:ni].tolist(), in_recv[:ni].tolist()))
        a_in = np.array([(arrive[s] - s) / 1e9 for s in stamps[:n].tolist() if s in arrive])
        a_tr = np.array([(r - arrive[s]) / 1e9 for s, r in zip(stamps[:n].tolist(), recv[:n].tolist()) if s in arrive])
        split = {"input_median_s": float(np.median(a_in)), "input_p99_s": pct(a_in, 99),
                 "input_max_s": float(a_in.max()), "track_median_s": float(np.median(a_tr)),
                 "track_p99_s": pct(a_tr, 99), "track_max_s": float(a_tr.max()), "inputs_seen_here": ni}
    vlog = (log_dir / "vehicle_node.log").read_text(errors="replace")
    m = re.search(r"published (\d+) wheel-load messages at [\d.]+ Hz \((\d+) late by > 2 periods\), (\d+) answered "
                  r"\((\d+) used as feedback, (\d+) too late\).*?vehicle model (\d+) us per message", vlog, re.S)
    vehicle = ({k: int(v) for k, v in zip(("sent", "late", "answered", "feedback_used", "feedback_stale",
                                           "model_us_per_message"), m.groups())} if m else {})
    final = diags[-1][1] if diags else {}
    # steady-state CPU: from the first answer to the vehicle's last sample
    cpu: dict[str, Any] = {"cores": os.cpu_count()}
    if len(samples) >= 2:
        s0 = samples[0]
        last_v = max((s for s in samples if s[2] is not None), key=lambda s: s[0])
        s_end = samples[-1]
        wall = last_v[0] - s0[0]
        if wall > 0:
            cpu["track_node_pct"] = 100 * ((last_v[1] or 0) - (s0[1] or 0)) / wall
            cpu["vehicle_node_pct"] = 100 * ((last_v[2] or 0) - (s0[2] or 0)) / wall
            cpu["machine_busy_pct"] = 100 * (last_v[3] - s0[3]) / max(last_v[4] - s0[4], 1.0)
            cpu["window_s"] = wall
        msgs = max(n, 1)
        cpu["track_node_cpu_us_per_message"] = 1e6 * ((s_end[1] or 0) - (s0[1] or 0)) / msgs
        cpu["vehicle_node_cpu_us_per_message"] = 1e6 * ((last_v[2] or 0) - (s0[2] or 0)) / msgs
    cpu["listener_cpu_s"] = own_cpu
    cpu["loadavg"] = os.getloadavg()
    sent = vehicle.get("sent", n_expected)
    accepted = int(final.get("accepted", -1))
    result.update({
        "duration_s": duration,
        "expected_messages": n_expected,
        "lag_median_s": float(np.median(lag)) if n else float("nan"),
        "lag_p99_s": pct(lag, 99),
        "lag_p999_s": pct(lag, 99.9),
        "lag_max_s": float(lag.max()) if n else float("nan"),
        "lag_steady_median_s": float(np.median(steady)) if steady.size else float("nan"),
        "lag_steady_p99_s": pct(steady, 99),
        "lag_over_5ms": int((lag > 5e-3).sum()),
        "lag_over_20ms": int((lag > 20e-3).sum()),
        "lag_p99_per_10s_s": [pct(lag[(t_rel >= a) & (t_rel < a + 10)], 99) for a in range(0, int(duration) + 1, 10)
                              if ((t_rel >= a) & (t_rel < a + 10)).any()],
        "lag_split": split,
        "track_node_diagnostics": final,
        "track_lag_p99_max_reported_s": max((float(d["lag_p99_s"]) for _, d in diags if "lag_p99_s" in d),
                                            default=float("nan")),
        "vehicle": vehicle,
        "counts": {
            "vehicle_sent": sent,
            "track_received": int(final.get("received", -1)),
            "track_accepted": accepted,
            "track_published": int(final.get("published", -1)),
            "track_rejected": int(final.get("rejected", -1)),
            "responses_received_here": n,
            "answered_to_vehicle": vehicle.get("answered", -1),
            "dropped": sent - n,
        },
        "cpu": cpu,
        "vehicle_run_wall_s": t_vehicle_done - t_start,
    })
    if cprofile:
        result["cprofile"] = {name: top_functions(path) for name, path in prof.items() if path.exists()}
    return result


def top_functions(path: Path, n: int = 15) -> list[dict[str, Any]]:
    st = pstats.Stats(str(path))
    rows = []
    for (file, line, func), (_cc, nc, tt, ct, _) in st.stats.items():  # type: ignore[attr-defined]
        rows.append({"function": f"{Path(file).name}:{line}({func})", "calls": nc, "tottime_s": tt, "cumtime_s": ct})
    rows.sort(key=lambda r: -r["tottime_s"])
    return rows[:n]


# ---------------------------------------------------------------------------------------------- stage timing


def stage_times(n: int) -> dict[str, float]:
    """Median cost [us] of each step of the per-message path, in one process, no middleware."""
    from clm_msgs.msg import WheelLoads
    from clm_ros.conversions import rclpy_responses, rclpy_wheel_loads
    from rclpy.serialization import deserialize_message, serialize_message

    from clm_core.io.messages import frame_from_msg
    from clm_core.online import OnlineTrackModel
    from clm_core.params import load_model
    from clm_core.vehicle.run import VehicleRunSpec, build_vehicle_run
    from clm_core.vehicle.streaming import StreamingVehicle

    params = load_model(TRACK["track"], TRACK["soil"], TRACK["model"])
    spec = VehicleRunSpec(vehicle=VEHICLE["vehicle"], cars=1, speed=VEHICLE["speed"],
                          duration=n / VEHICLE["rate"] + 1, dt=VEHICLE["dt"], start=VEHICLE.get("start", 0.0),
                          irregularity=VEHICLE["irregularity"], seed=VEHICLE["seed"])
    sim = build_vehicle_run(spec, params).simulation
    veh = StreamingVehicle(sim)
    substeps = int(round(1.0 / (VEHICLE["rate"] * sim.dt)))
    model = OnlineTrackModel(params, dt=TRACK["dt"], n_sleepers=TRACK["n_sleepers"])
    ids = np.arange(veh.train.n_wheels)
    keys = ["vehicle_model", "build_wheel_loads", "serialize_wheel_loads", "deserialize_wheel_loads",
            "track_frame_from_msg", "track_model_process", "track_build_responses", "serialize_responses",
            "vehicle_feedback"]
    t = {k: np.zeros(n) for k in keys}
    pc = time.perf_counter
    P = veh.P.copy()
    for k in range(n + 200):
        i = k - 200  # the first 200 messages warm up (JIT, caches)
        a = pc()
        if k:
            P = veh.advance(substeps)
        b = pc()
        msg = rclpy_wheel_loads(k * NS // 1000 + 5 * NS, ids, veh.positions(), P, np.full(ids.size, sim.speed))
        c = pc()
        raw = serialize_message(msg)
        d = pc()
        msg2 = deserialize_message(raw, WheelLoads)
        e = pc()
        frame = frame_from_msg(msg2)
        f = pc()
        resp = model.process(frame)
        g = pc()
        s, w = rclpy_responses(resp, k * NS // 1000 + 5 * NS)
        h = pc()
        serialize_message(s)
        serialize_message(w)
        j = pc()
        w_def = np.asarray(w.rail_deflection)
        veh.set_track_response(veh.k, w_def)
        m = pc()
        if i >= 0:
            for key, v in zip(keys, (b - a, c - b, d - c, e - d, f - e, g - f, h - g, j - h, m - j)):
                t[key][i] = v
    out = {k: float(np.median(v) * 1e6) for k, v in t.items()}
    out["track_callback_total"] = out["track_frame_from_msg"] + out["track_model_process"] + \
        out["track_build_responses"]
    out["n_wheels"] = float(ids.size)
    return out


# ---------------------------------------------------------------------------------------------- report


def ms(x: float) -> str:
    return f"{1e3 * x:8.3f} ms"


def print_report(r: dict[str, Any]) -> None:
    c = r["counts"]
    d = r["track_node_diagnostics"]
    ok = lambda b: "ok" if b else "MISSED"  # noqa: E731
    print(f"node_lag: {r['duration_s']:g} s at 1 kHz, Thalys 83.33 m/s over Mevergnies CLM, 61 sleepers, dt 1e-4 s, "
          f"{r['cpu'].get('cores')} cores (domain {r['ros_domain_id']}); track node executor: {r['track_executor']}")
    print()
    print("lag wheel-load stamp -> response           median        p99     p99.9       max")
    print(f"  listener (receive - stamp), all     {ms(r['lag_median_s'])} {ms(r['lag_p99_s'])} "
          f"{ms(r['lag_p999_s'])} {ms(r['lag_max_s'])}")
    print(f"  listener, after the first second    {ms(r['lag_steady_median_s'])} {ms(r['lag_steady_p99_s'])}")
    if d:
        print(f"  track node (publish - stamp)*       {ms(float(d['lag_median_s']))} {ms(float(d['lag_p99_s']))}"
              f"   (* its last 10 000 messages; max p99 reported during the run "
              f"{1e3 * r['track_lag_p99_max_reported_s']:.3f} ms)")
    sp = r.get("lag_split")
    if sp:
        print(f"  split: stamp -> wheel loads here   {ms(sp['input_median_s'])} {ms(sp['input_p99_s'])} "
              f"{'':>11} {ms(sp['input_max_s'])}   (vehicle lateness + DDS)")
        print(f"         wheel loads -> response     {ms(sp['track_median_s'])} {ms(sp['track_p99_s'])} "
              f"{'':>11} {ms(sp['track_max_s'])}   (DDS + track node queue and callback + DDS)")
    print(f"  messages over 5 ms: {r['lag_over_5ms']}, over 20 ms: {r['lag_over_20ms']}; p99 per 10 s: "
          + ", ".join(f"{1e3 * x:.2f}" for x in r["lag_p99_per_10s_s"]) + " ms")
    print()
    print("messages")
    print(f"  vehicle sent {c['vehicle_sent']}, track received {c['track_received']}, accepted "
          f"{c['track_accepted']}, published {c['track_published']}, rejected {c['track_rejected']}")
    print(f"  responses received here {c['responses_received_here']}, answered to the vehicle "
          f"{c['answered_to_vehicle']}, dropped {c['dropped']}")
    v = r["vehicle"]
    if v:
        print(f"  vehicle: {v['late']} published late by > 2 periods, feedback used {v['feedback_used']} "
              f"(stale {v['feedback_stale']}), vehicle model {v['model_us_per_message']} us per message")
    if d:
        print(f"  vehicle run took {r['vehicle_run_wall_s']:.2f} s wall for {r['duration_s']:g} s of messages "
              "(including its start-up and the wait for answers)")
        print(f"  track model real-time factor {d.get('real_time_factor')} (simulated / callback compute time)")
    cpu = r["cpu"]
    print()
    print("CPU (steady state)")
    if "track_node_pct" in cpu:
        print(f"  track node {cpu['track_node_pct']:.0f} % of a core ({cpu['track_node_cpu_us_per_message']:.0f} us "
              f"per message), vehicle node {cpu['vehicle_node_pct']:.0f} % "
              f"({cpu['vehicle_node_cpu_us_per_message']:.0f} us per message), machine busy "
              f"{cpu['machine_busy_pct']:.0f} % of {cpu['cores']} cores; load average {cpu['loadavg'][0]:.2f}")
    st = r.get("stages")
    if st:
        print()
        print(f"per-message path in one process, no middleware (median of {r['stages_n']}, {int(st['n_wheels'])} "
              "wheels)")
        for k, val in st.items():
            if k != "n_wheels":
                print(f"  {k:<28} {val:8.1f} us")
        if "track_node_cpu_us_per_message" in cpu:
            rest = cpu["track_node_cpu_us_per_message"] - st["track_callback_total"] - st["deserialize_wheel_loads"] \
                - st["serialize_responses"]
            print(f"  => track node CPU per message {cpu['track_node_cpu_us_per_message']:.0f} us, of which "
                  f"callback {st['track_callback_total']:.0f} us, (de)serialisation "
                  f"{st['deserialize_wheel_loads'] + st['serialize_responses']:.0f} us; rclpy executor + DDS "
                  f"~{rest:.0f} us")
    for name, rows in r.get("cprofile", {}).items():
        print()
        print(f"cProfile {name} (top by own time; profiled run, slower)")
        for row in rows:
            print(f"  {row['tottime_s']:8.2f} s own {row['cumtime_s']:8.2f} s cum {row['calls']:>9}  {row['function']}")
    print()
    print(f"targets: median < 5 ms {ok(r['lag_median_s'] < TARGET_MEDIAN_S)}, p99 < 20 ms "
          f"{ok(r['lag_p99_s'] < TARGET_P99_S)}, none dropped {ok(c['dropped'] == 0)}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0, help="simulated (= wall) seconds of the run (default 60)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    ap.add_argument("--stages", type=int, default=2000, help="messages of the per-stage timing (0: skip)")
    ap.add_argument("--cprofile", action="store_true", help="run the nodes under cProfile, print their top functions")
    ap.add_argument("--no-tap", action="store_true",
                    help="do not subscribe to /wheel_loads here (no split of the lag; the vehicle waits for 1 reader)")
    ap.add_argument("--track-executor", choices=("single", "events"), default="single",
                    help="single: the track node as shipped; events: the same node class spun by the EventsExecutor "
                    "(an experiment)")
    ap.add_argument("--keep-logs", default=None, help="directory for the node logs (default: a temporary one)")
    ap.add_argument("--timeout", type=float, default=120.0, help="extra wall time allowed past --duration [s]")
    args = ap.parse_args()
    with contextlib.ExitStack() as stack:
        if args.keep_logs:
            log_dir = Path(args.keep_logs)
            log_dir.mkdir(parents=True, exist_ok=True)
        else:
            log_dir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="clm_node_lag_")))
        r = run_live(args.duration, log_dir, args.cprofile, args.timeout, not args.no_tap, args.track_executor)
    if args.stages > 0:
        r["stages"] = stage_times(args.stages)
        r["stages_n"] = args.stages
    r["python"] = platform.python_version()
    r["targets"] = {"median_s": TARGET_MEDIAN_S, "p99_s": TARGET_P99_S, "dropped": 0}
    if args.json:
        print(json.dumps(r, indent=2, default=float))
    else:
        print_report(r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
