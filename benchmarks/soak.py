"""Soak: the track node for a long run of valid traffic, hostile frames, lifecycle transitions, parameter updates.

The track node (``clm_ros.track_node``, Mevergnies CLM, 61 sleepers) runs as a
process of its own; this process feeds it for ``--duration`` s of wall time:

- valid wheel loads at ``--rate`` Hz (4 wheels at 83.33 m/s; stamps continuous
  in 1/rate steps: pauses for transitions do not open stamp gaps);
- ``--hostile`` (1 %) hostile frames between them, drawn from: random bytes,
  truncated CDR, a header ``nanosec`` >= 1e9, NaN force, force 1.7e308 N,
  position 1e19 m, negative force, duplicate ids, unknown ids, a thousand
  wheels, a stamp 1e6 s ahead, a stamp going back;
- every 20-60 s a random lifecycle cycle (deactivate/activate, or
  deactivate/cleanup/configure/activate) and every 10-30 s a parameter update
  (a valid ``track.kb``, or an unstable ``soil.dc`` that must be refused).
  Traffic pauses around a transition until every answer owed has arrived.

Printed (never asserted): valid frames sent = answered (each exactly once),
hostile frames answered (must be 0), the node's counters, the transitions
and updates, the lag of the answers, split in two: the node's (the
``source_timestamp`` of each ``/wheel_rail_response``, the moment the node
published it, minus the moment this process published the wheel load) and
the delivery's (the middleware's reception time of the answer here, rmw
``received_timestamp``, minus its ``source_timestamp``: a reliable sample
lost on the way is repaired after the writer's next heartbeat), each with
median, p99, p99.9, max and the worst minute's p99 (the reception times are
not this process's lateness in taking the answers); and the worst ``lag_p99_s`` the
node itself reported in a diagnostics period), and the node's resident
memory (RSS) and open file descriptors from the first minute to the end with
the least-squares slope of RSS over that span (target: RSS flat within 5 %).

``--trace-python N`` runs the node under :mod:`tracemalloc` (N frames per
traceback; slows the node's allocations): it writes a snapshot every
``--trace-every`` s on ``SIGUSR2`` from this process (traffic pauses, as
around a transition, until the snapshot is written), and the report adds
the Python heap the node holds at each snapshot next to its RSS (a leak of
Python objects grows both; a native one, or the allocator's fragmentation,
only the RSS) and the allocation sites that grew most from the first
snapshot after the first minute to the last.

Usage::

    python benchmarks/soak.py [--duration 600] [--rate 1000] [--hostile 0.01] [--seed 1] [--hog N]
                              [--trace-python 12 [--trace-every 60]] [--timeline]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import random
import signal
import struct
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from node_lag import Listener, header_stamp, hogs, track_node
from online_path import stream

from clm_core.io.messages import encode_wheel_loads
from clm_core.io.timebase import NS

#: The node under tracemalloc: a snapshot into $CLM_SOAK_TRACE_DIR at each SIGUSR2 (run by the main thread at its
#: next bytecode; the executor wakes at every message).
TRACED_NODE = """
import os, runpy, signal, tracemalloc
tracemalloc.start(int(os.environ["CLM_SOAK_TRACE_FRAMES"]))
_n = [0]
def _snap(*_):
    d = os.environ["CLM_SOAK_TRACE_DIR"]
    tracemalloc.take_snapshot().dump(os.path.join(d, f"snap{_n[0]:04d}.part"))
    os.replace(os.path.join(d, f"snap{_n[0]:04d}.part"), os.path.join(d, f"snap{_n[0]:04d}.pickle"))
    _n[0] += 1
signal.signal(signal.SIGUSR2, _snap)
runpy.run_module("clm_ros.track_node", run_name="__main__", alter_sys=True)
"""

HOSTILE = ("random_bytes", "truncated", "nanosec", "nan_force", "huge_force", "far_position", "tensile",
           "duplicate_id", "unknown_id", "thousand_wheels", "future_stamp", "stamp_back")


def hostile(kind: str, rng: random.Random, t_ns: int, valid: bytes, pos: np.ndarray) -> bytes:
    """A frame of ``kind`` stamped near ``t_ns`` (between two valid frames) that the node must refuse."""
    f = np.full(4, 85e3)
    ids = [0, 1, 2, 3]
    if kind == "random_bytes":
        return bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 200)))
    if kind == "truncated":
        return valid[: rng.randrange(4, len(valid) - 8)]
    if kind == "nanosec":
        return valid[:8] + struct.pack("<I", 1_500_000_000) + valid[12:]
    if kind == "nan_force":
        f[rng.randrange(4)] = float("nan")
    elif kind == "huge_force":
        f[rng.randrange(4)] = 1.7e308
    elif kind == "far_position":
        pos = pos.copy()
        pos[rng.randrange(4)] = 1e19
    elif kind == "tensile":
        f[rng.randrange(4)] = -5e4
    elif kind == "duplicate_id":
        ids = [0, 0, 2, 3]
    elif kind == "unknown_id":
        ids = [0, 1, 2, 77]
    elif kind == "thousand_wheels":
        n = 1000
        return encode_wheel_loads(t_ns, "track", np.arange(n), np.linspace(0, 10, n), np.full(n, 1e3))
    elif kind == "future_stamp":
        t_ns += 10**6 * NS
    elif kind == "stamp_back":
        t_ns -= 50 * 10**6
    return encode_wheel_loads(t_ns, "track", ids, pos, f)


def rss_fds(pid: int) -> tuple[float, int]:
    """Resident memory [MB] and open file descriptors of a process."""
    status = Path(f"/proc/{pid}/status").read_text()
    rss = float(next(ln.split()[1] for ln in status.splitlines() if ln.startswith("VmRSS"))) / 1024
    return rss, len(os.listdir(f"/proc/{pid}/fd"))


class Control:
    """Lifecycle transitions and parameter updates of the node through its services; a lost answer neither hangs
    the soak nor repeats a transition (clm_ros.reliable_client, as every client of the suite)."""

    def __init__(self, lis: Listener) -> None:
        from lifecycle_msgs.srv import ChangeState, GetState
        from rcl_interfaces.srv import SetParameters

        self.lis = lis
        self.change = lis.node.create_client(ChangeState, "/clm_track_node/change_state")
        self.getstate = lis.node.create_client(GetState, "/clm_track_node/get_state")
        self.setp = lis.node.create_client(SetParameters, "/clm_track_node/set_parameters")

    def _until(self, done: Any, seconds: float) -> None:
        end = time.monotonic() + seconds
        while not done() and time.monotonic() < end:
            self.lis.spin_for(0.02)

    def _query(self, cli: Any, req: Any) -> Any:
        """The answer to a request that changes nothing when taken twice (sent again while unanswered)."""
        from clm_ros.reliable_client import RESEND_S, answered

        self.lis.wait(cli.service_is_ready, 30, "service")
        return answered(cli, req, self._until, 60, RESEND_S)

    def state(self) -> str:
        from lifecycle_msgs.srv import GetState

        return str(self._query(self.getstate, GetState.Request()).current_state.label)

    def transition(self, label: str) -> bool:
        from clm_ros.reliable_client import transition_confirmed
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        self.lis.wait(self.change.service_is_ready, 30, "service")
        req = ChangeState.Request(transition=Transition(label=label))
        return bool(transition_confirmed(lambda: self.change.call_async(req), self.state, label, self._until, 60))

    def set_double(self, name: str, value: float) -> bool:
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters

        req = SetParameters.Request(parameters=[Parameter(name=name, value=ParameterValue(
            type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
        return bool(self._query(self.setp, req).results[0].successful)  # the same value twice: one outcome


def soak(a: argparse.Namespace, log_dir: Path) -> dict[str, Any]:
    import rclpy
    from clm_msgs.msg import WheelRailResponse
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    rng = random.Random(a.seed)
    period = round(NS / a.rate)
    trace_dir = log_dir / "tracemalloc"
    traced: dict[str, Any] = {}
    if a.trace_python:
        trace_dir.mkdir(exist_ok=True)
        traced = {"python_args": ("-c", TRACED_NODE), "env_extra": {
            "CLM_SOAK_TRACE_DIR": str(trace_dir), "CLM_SOAK_TRACE_FRAMES": str(a.trace_python)}}
    snaps: list[tuple[float, float]] = []  # (time [s], RSS [MB]) of each snapshot asked for
    with track_node({"diagnostics_period": 0.5}, log_dir, "track_node_soak", **traced) as (proc, lis):
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        wheel_answers: list[int] = []
        wheel_times: list[tuple[int, int]] = []  # the answers' source_timestamp and received_timestamp [ns]
        # a node no executor spins: its answers are taken with the middleware's times (rmw_message_info_t)
        timing = rclpy.create_node("clm_soak_timing", context=lis.ctx)
        wsub = timing.create_subscription(WheelRailResponse, "/wheel_rail_response", lambda _b: None, qos, raw=True)

        def drain() -> None:
            while True:
                with wsub.handle:
                    taken = wsub.handle.take_message(wsub.msg_type, True)
                if taken is None:
                    return
                wheel_answers.append(header_stamp(taken[0]))
                wheel_times.append((int(taken[1]["source_timestamp"]), int(taken[1]["received_timestamp"])))
        ctl = Control(lis)
        chunk = stream(10_000, a.rate)  # positions repeat every 10 s of traffic, shifted forwards
        t_first = time.time_ns()
        valid: list[int] = []
        sent_at: dict[int, int] = {}  # stamp -> wall time of the publish [ns]
        hostile_sent: dict[str, int] = dict.fromkeys(HOSTILE, 0)
        hostile_stamps: set[int] = set()
        log: list[str] = []
        events: list[tuple[int, int, str]] = []  # (start, end [ns, system clock], what): transitions, updates
        mem: list[tuple[float, float, int]] = []
        updates = {"valid": 0, "valid_refused": 0, "unstable_refused": 0, "unstable_accepted": 0}
        t0 = time.monotonic()
        next_cycle = t0 + rng.uniform(20, 60)
        next_snap = t0 + (a.trace_every if a.trace_python else float("inf"))  # from the first frame, as the others
        next_update = t0 + rng.uniform(10, 30)
        next_mem = t0
        next_due = next_drain = time.monotonic()
        k = 0

        def settle() -> None:
            """Every answer owed has arrived (or none came for 5 s: the report shows what is missing)."""
            last, t_last = -1, time.monotonic()
            while len(lis.stamps) < len(valid) or len(wheel_answers) < len(valid):
                drain()
                got = len(lis.stamps) + len(wheel_answers)
                if got != last:
                    last, t_last = got, time.monotonic()
                elif time.monotonic() - t_last > 5.0:
                    return
                lis.spin_for(0.02)

        def ready() -> None:
            lis.wait(lambda: lis.pub.get_subscription_count() >= 1 and lis.sub.get_publisher_count() >= 1
                     and wsub.get_publisher_count() >= 1, 60, "the node active and matched")

        blocked = [0]  # publications the middleware refused (the node's reader too far behind), then repeated

        def send(raw: bytes) -> None:
            """Publish ``raw``; a refusal (a reliable keep-all writer full: the node's reader has not acknowledged
            its history, e.g. a node slowed by ``--trace-python`` on a loaded machine) is counted and the same
            frame published again once this process has spun for 10 ms (nothing is lost or reordered)."""
            for _ in range(6000):
                try:
                    lis.pub.publish(raw)
                    return
                except Exception as exc:  # rclpy's RCLError: "cannot publish data"
                    if "publish" not in str(exc):
                        raise
                    blocked[0] += 1
                    drain()
                    lis.spin_for(0.01)
            raise RuntimeError("the node's reader acknowledged nothing for 60 s: wheel loads refused throughout")

        def snapshot() -> None:
            """The node's heap snapshot (``--trace-python``), written before this returns."""
            snaps.append((time.monotonic() - t0, rss_fds(proc.pid)[0]))
            proc.send_signal(signal.SIGUSR2)
            lis.wait(lambda: len(list(trace_dir.glob("*.pickle"))) >= len(snaps), 600, "a heap snapshot")

        while (now := time.monotonic()) - t0 < a.duration:
            if now >= next_mem:
                mem.append((now - t0, *rss_fds(proc.pid)))
                next_mem = now + 10
            if now >= next_snap:  # traffic pauses while the node writes a snapshot (seconds: its main thread
                settle()  # stops; a reliable keep-all writer of wheel loads would fill and refuse to publish)
                snapshot()
                next_snap = time.monotonic() + a.trace_every
                next_due = time.monotonic()
            if now >= next_cycle:
                settle()
                full = rng.random() < 0.5
                labels = ["deactivate", "cleanup", "configure", "activate"] if full else ["deactivate", "activate"]
                for label in labels:
                    t_ev = time.time_ns()
                    ok = ctl.transition(label)
                    events.append((t_ev, time.time_ns(), label))
                    log.append(f"{now - t0:6.1f} s {label}: {'ok' if ok else 'REFUSED'}")
                    if label == "deactivate":  # this process sees the subscription go before it comes back
                        lis.wait(lambda: lis.pub.get_subscription_count() == 0, 30, "the subscription gone")
                    if label == "cleanup":
                        lis.wait(lambda: lis.sub.get_publisher_count() == 0, 30, "old answer publishers gone")
                ready()
                next_cycle = time.monotonic() + rng.uniform(20, 60)
                next_due = time.monotonic()
            if now >= next_update:
                t_ev = time.time_ns()
                if rng.random() < 0.7:
                    kb = rng.uniform(40e6, 80e6)
                    key = "valid" if ctl.set_double("track.kb", kb) else "valid_refused"
                else:
                    key = "unstable_accepted" if ctl.set_double("soil.dc", -4e5) else "unstable_refused"
                events.append((t_ev, time.time_ns(), f"update {key}"))
                updates[key] += 1
                next_update = time.monotonic() + rng.uniform(10, 30)
            if now >= next_drain:
                drain()
                next_drain = now + 0.01
            if now < next_due:
                lis.ex.spin_once(timeout_sec=next_due - now)
                continue
            next_due += 1.0 / a.rate
            f = chunk[k % len(chunk)]
            t_ns = t_first + k * period
            pos = f.positions + 83.33 * 10.0 * (k // len(chunk))
            raw = encode_wheel_loads(t_ns, "track", f.ids, pos, f.forces)
            if rng.random() < a.hostile:
                kind = rng.choice(HOSTILE)
                h = hostile(kind, rng, t_ns - period // 2, raw, pos)
                hostile_sent[kind] += 1
                with contextlib.suppress(struct.error, IndexError):
                    hostile_stamps.add(header_stamp(h))
                send(h)
            sent_at[t_ns] = time.time_ns()
            send(raw)
            valid.append(t_ns)
            k += 1
        settle()
        mem.append((time.monotonic() - t0, *rss_fds(proc.pid)))
        if a.trace_python:
            snapshot()
        n_diag = len(lis.diags)
        lis.wait(lambda: len(lis.diags) > n_diag + 1, 10, "final diagnostics")
        d = lis.diags[-1]
        answered = lis.stamps
        drain()
        lags = [(src - sent_at[st], recv - src, recv) for st, (src, recv) in zip(wheel_answers, wheel_times)
                if st in sent_at]
        timing.destroy_node()
        node_p99 = [float(x["lag_p99_s"]) for x in lis.diags
                    if x.get("lag_p99_s", "nan") not in ("nan",) and not x["lag_p99_s"].startswith("unavailable")]
        t_sig = time.monotonic()
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(30)
        exit_s = time.monotonic() - t_sig
    valid_set = set(valid)
    return {
        "valid_sent": len(valid), "answered": len(answered), "answered_wheel_rail": len(wheel_answers),
        "answered_valid_distinct": len(valid_set & set(answered)),
        "duplicates": len(answered) - len(set(answered)),
        "answered_hostile": len(hostile_stamps & set(answered) - valid_set),
        "in_order": answered == sorted(answered), "hostile_sent": hostile_sent, "node": d, "log": log,
        "updates": updates, "memory": mem, "lags": lags, "node_lag_p99_s": node_p99, "events": events, "exit_code": rc,
        "exit_s": exit_s, "loadavg": os.getloadavg()[0], "snapshots": snaps, "trace_dir": trace_dir,
        "publish_refused": blocked[0],
    }


def heap_growth(r: dict[str, Any], top: int = 12) -> None:
    """Print the node's traced Python heap next to its RSS at each snapshot, and the allocation sites that grew
    most from the first snapshot after the first minute to the last (``--trace-python``)."""
    import tracemalloc

    files = sorted(Path(r["trace_dir"]).glob("*.pickle"))
    snaps = [tracemalloc.Snapshot.load(str(f)) for f in files]
    if len(snaps) < 2:
        print(f"tracemalloc: {len(snaps)} snapshot(s), nothing to compare")
        return
    print("tracemalloc: the node's Python heap (traced) and RSS at each snapshot:")
    for (t, rss), s in zip(r["snapshots"], snaps):
        print(f"  {t:7.1f} s  heap {sum(x.size for x in s.statistics('filename')) / 2**20:8.2f} MB  RSS {rss:7.1f} MB")
    first = next((i for i, (t, _) in enumerate(r["snapshots"]) if t >= 60.0), 0)
    first = min(first, len(snaps) - 2)
    t0, t1 = r["snapshots"][first][0], r["snapshots"][len(snaps) - 1][0]
    diff = snaps[-1].compare_to(snaps[first], "traceback")
    print(f"tracemalloc: the {top} allocation sites that grew most from {t0:.0f} s to {t1:.0f} s:")
    for st in diff[:top]:
        print(f"  {st.size_diff / 1024:+9.1f} kB  {st.count_diff:+7d} blocks  (now {st.size / 1024:.1f} kB)")
        for line in st.traceback.format()[-2 * 6:]:
            print(f"      {line}")


def late_episodes(lags: np.ndarray, events: list[tuple[int, int, str]], late_ms: float = 100.0) -> None:
    """Print the episodes of answers the node published more than ``late_ms`` after their wheel load (answers
    closer than 1 s together are one episode), each with the last transition or update begun before it."""
    pub = lags[:, 2] - lags[:, 1]  # the node's publish time [ns]
    sent = pub - lags[:, 0]
    late = np.flatnonzero(lags[:, 0] > late_ms * 1e6)
    if not late.size:
        print(f"no answer published more than {late_ms:g} ms after its wheel load")
        return
    splits = np.flatnonzero(np.diff(sent[late]) > NS) + 1
    episodes = np.split(late, splits)
    print(f"{late.size} answers published more than {late_ms:g} ms after their wheel load, in {len(episodes)} "
          f"episode(s); the worst 8:")
    for ep in sorted(episodes, key=lambda e: -lags[e, 0].max())[:8]:
        t = int(sent[ep[0]])
        before = [e for e in events if e[0] <= t + NS]
        what = (f"{before[-1][2]} begun {(t - before[-1][0]) * 1e-9:+.2f} s before, took "
                f"{(before[-1][1] - before[-1][0]) * 1e-9:.2f} s" if before else "no event before")
        print(f"  at {(t - sent[0]) * 1e-9:7.1f} s: {ep.size} answers, worst {lags[ep, 0].max() * 1e-6:.0f} ms; "
              f"last transition/update: {what}")


def report(r: dict[str, Any], a: argparse.Namespace) -> None:
    d = r["node"]
    print(f"soak: {a.duration:g} s at {a.rate:g} Hz, {100 * a.hostile:g} % hostile frames, seed {a.seed}, "
          f"{a.hog} hog(s); load average {r['loadavg']:.2f}")
    ok = r["answered_valid_distinct"] == r["valid_sent"] == r["answered"] == r["answered_wheel_rail"]
    print(f"valid frames: sent {r['valid_sent']}, answered {r['answered']} (sleeper_response), "
          f"{r['answered_wheel_rail']} (wheel_rail_response), distinct {r['answered_valid_distinct']}, duplicates "
          f"{r['duplicates']}, in order {r['in_order']}: in = out {'YES' if ok else 'NO'}")
    print(f"hostile frames: sent {sum(r['hostile_sent'].values())} "
          f"({', '.join(f'{k} {v}' for k, v in r['hostile_sent'].items())}); answered {r['answered_hostile']}")
    rej = {k[len('rejected.'):]: v for k, v in d.items() if k.startswith("rejected.")}
    print(f"node counters: received {d['received']}, accepted {d['accepted']}, published {d['published']}, "
          f"rejected {d['rejected']} ({', '.join(f'{k} {v}' for k, v in rej.items())}), not accepted "
          f"{d['not_accepted']}, resyncs {d['resyncs']}, publish failed {d['publish_failed']}, largest batch "
          f"{d['largest_batch']}")
    if r["publish_refused"]:
        print(f"publications refused by the middleware and repeated (the node behind): {r['publish_refused']}")
    print(f"lifecycle: {len(r['log'])} transitions ({sum('REFUSED' in x for x in r['log'])} refused); parameter "
          f"updates: {r['updates']}")
    if r["lags"]:
        lags = np.array(r["lags"], dtype=np.int64)
        minute = (lags[:, 2] - lags[0, 2]) // (60 * NS)
        for col, what in ((0, "node (answer published - wheel load published)"),
                          (1, "delivery (answer received - published)")):
            x = lags[:, col] * 1e-6  # [ms]
            worst_minute = max(float(np.percentile(x[minute == m], 99)) for m in np.unique(minute))
            q = np.percentile(x, [50, 99, 99.9])
            print(f"lag, {what}, {x.size} answers: median {q[0]:.2f} ms, p99 {q[1]:.2f} ms, p99.9 {q[2]:.2f} ms, "
                  f"max {x.max():.1f} ms; worst minute's p99 {worst_minute:.2f} ms")
        late_episodes(lags, r["events"])
        print(f"the node's own lag_p99_s (answer published - stamp; the stamps run behind the wall clock after each "
              f"pause), worst period {1e3 * max(r['node_lag_p99_s'], default=float('nan')):.2f} ms of "
              f"{len(r['node_lag_p99_s'])}")
    mem = r["memory"]
    base = next((m for m in mem if m[0] >= 60.0), mem[min(1, len(mem) - 1)])
    last = mem[-1]
    peak = max(m[1] for m in mem)
    span = [m for m in mem if m[0] >= base[0]]
    slope = float(np.polyfit([m[0] for m in span], [m[1] for m in span], 1)[0]) * 60 if len(span) > 2 else float("nan")
    print(f"memory: RSS {base[1]:.1f} MB at {base[0]:.0f} s -> {last[1]:.1f} MB at {last[0]:.0f} s "
          f"({100 * (last[1] / base[1] - 1):+.1f} %; slope {slope:+.3f} MB/min over {len(span)} samples; peak "
          f"{peak:.1f} MB; at start {mem[0][1]:.1f} MB); file descriptors {base[2]} -> {last[2]} (start {mem[0][2]})")
    print(f"exit on SIGINT: code {r['exit_code']} after {r['exit_s']:.2f} s")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=600.0, help="wall seconds of traffic")
    ap.add_argument("--rate", type=float, default=1000.0, help="valid wheel-load rate [Hz]")
    ap.add_argument("--hostile", type=float, default=0.01, help="fraction of hostile frames (one per draw)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--hog", type=int, default=0, help="busy-loop processes for the whole run")
    ap.add_argument("--keep-logs", default=None, help="directory for the node log")
    ap.add_argument("--timeline", action="store_true", help="print the transitions and the memory samples")
    ap.add_argument("--trace-python", type=int, default=0, metavar="FRAMES",
                    help="run the node under tracemalloc with FRAMES frames per traceback (0: off)")
    ap.add_argument("--trace-every", type=float, default=60.0, help="seconds between two heap snapshots")
    a = ap.parse_args()
    with contextlib.ExitStack() as stack:
        log_dir = Path(a.keep_logs) if a.keep_logs else Path(stack.enter_context(
            tempfile.TemporaryDirectory(prefix="clm_soak_")))
        log_dir.mkdir(parents=True, exist_ok=True)
        stack.enter_context(hogs(a.hog))
        r = soak(a, log_dir)
        report(r, a)
        if a.trace_python:
            heap_growth(r)
    if a.timeline:
        print("\n".join(r["log"]))
        print("\n".join(f"{t:7.1f} s RSS {m:7.1f} MB fds {n}" for t, m, n in r["memory"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
