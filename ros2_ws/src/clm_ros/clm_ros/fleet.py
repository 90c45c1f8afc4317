"""A fleet of trains online: N vehicle + track node pairs on one ROS graph, each pair in its own namespace.

``clm fleet --trains N --duration S --out DIR`` (issue 15.1) is the demo
(:mod:`clm_ros.launcher`) times N, with the same node processes, parameters
and recorder:

1. takes the ROS domain ``domain_id`` (held exclusively among the clm runs of
   this machine; discovery on loopback unless ``discovery_range`` says
   otherwise, docs/fleet.md);
2. starts N track-soil nodes (``clm_ros.track_node``), the pair ``i`` in the
   namespace ``/train_i`` (``i`` from ``first_index``, so that another host
   can add further pairs to the same graph), then, once this process records
   their answers, N vehicle simulator nodes (``clm_ros.vehicle_node``) in the
   same namespaces, each one train of ``duration`` s with the irregularity seed
   ``seed + i``. Every vehicle waits for its own track node (and the
   recorder), so each pair starts with its first message;
3. records ``/train_i/wheel_loads``, ``/train_i/sleeper_response``,
   ``/train_i/wheel_rail_response`` of every pair and ``/diagnostics`` to one
   bag (``DIR/fleet_bag``, :class:`clm_ros.bag_tools.BagRecorder`, polled:
   log time = reception time by this process's middleware);
4. when every vehicle reports its train done and every wheel-load message is
   answered, stops all nodes (SIGINT, each must exit 0), then checks each
   pair: in = out (each wheel-load message answered once, in order: the
   responses' stamps are the wheel loads' stamps) and, with ``verify``, its
   answers equal, bit for bit, the offline replay of its recorded wheel loads
   (:func:`clm_ros.replay.replay_bag` through
   :class:`clm_core.online.OnlineTrackModel`, the track node's code path).

``DIR/summary.json``: per train (``trains.train_i``) the messages in and out,
``feedback_used``/``feedback_total``, the lag median/p99/max from the first
message (recorder: reception of ``sleeper_response`` minus the stamp of its
wheel-load message, as the demo; ``vehicle_lag_*``: the vehicle's own
reception of ``wheel_rail_response`` minus the due time), the offline check,
each node's CPU per message; ``overall``: the worst of each figure and
whether every pair is correct. Without the recorder (``record=False``, the
capacity benchmark) the counts and lags are the vehicles' own.

Users with a full ROS install get the same graph from
``ros2 launch clm_ros fleet.launch.py trains:=N``.
"""

from __future__ import annotations

import gc
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from clm_core import settings
from clm_core.io.files import write_json
from clm_ros.errors import ClmRosError
from clm_ros.launcher import POLL, _number, _stop
from clm_ros.processes import hold_domain_id, proc_cpu_s, ros_args, ros_env
from clm_ros.run_settings import RunSettings

#: Namespace of pair ``i``: ``/train_i``.
NAMESPACE = "train_{}"
#: The data topics of each pair (relative to its namespace) and their types.
PAIR_TOPICS = {
    "wheel_loads": "clm_msgs/msg/WheelLoads",
    "sleeper_response": "clm_msgs/msg/SleeperResponse",
    "wheel_rail_response": "clm_msgs/msg/WheelRailResponse",
}
#: DDS discovery ranges (``ROS_AUTOMATIC_DISCOVERY_RANGE``): LOCALHOST keeps the graph on this machine.
DISCOVERY_RANGES = ("LOCALHOST", "SUBNET", "SYSTEM_DEFAULT")


def namespaces(trains: int, first_index: int = 0) -> list[str]:
    """The namespaces of the pairs ``first_index`` ... ``first_index + trains - 1`` (``/train_i``)."""
    return [f"/{NAMESPACE.format(i)}" for i in range(first_index, first_index + trains)]


def check_fleet(trains: int, first_index: int) -> None:
    """Refuse a fleet that cannot run (ClmRosError naming the value and the rule)."""
    for name, v in (("trains", trains), ("first_index", first_index)):
        try:
            settings.setting(f"fleet_{name}").check(v, name)
        except Exception as exc:
            raise ClmRosError(str(exc)) from None


def fleet_env(domain_id: int, discovery_range: str = "LOCALHOST", static_peers: str = "") -> dict[str, str]:
    """Environment of the fleet's node processes: :func:`clm_ros.processes.ros_env`, with the discovery of a
    fleet that spans hosts when asked (``discovery_range`` SUBNET, or ``static_peers`` ``host1;host2``)."""
    if discovery_range not in DISCOVERY_RANGES:
        raise ClmRosError(f"discovery_range = {discovery_range!r}: one of {', '.join(DISCOVERY_RANGES)}")
    env = ros_env(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = discovery_range
    if static_peers:
        env["ROS_STATIC_PEERS"] = static_peers
    return env


@dataclass
class _Pair:
    """One train: its namespace, processes and what the launcher saw of them."""

    ns: str
    procs: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    vehicle: dict[str, str] = field(default_factory=dict)
    final: dict[str, str] = field(default_factory=dict)
    cpu0: dict[str, float | None] = field(default_factory=dict)
    cpu_us: dict[str, float | None] = field(default_factory=dict)
    n0: int = 0


class _Watch:
    """The vehicles' /diagnostics of every pair (their status names carry the nodes' namespaces)."""

    def __init__(self, pairs: list[_Pair]) -> None:
        self.pairs = {p.ns: p for p in pairs}

    def on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            ns = status.name.split(":", 1)[0].rsplit("/", 1)[0]
            pair = self.pairs.get(ns)
            if pair is None:
                continue
            if "vehicle simulator" in status.name:
                pair.vehicle = {kv.key: kv.value for kv in status.values}
                if pair.vehicle.get("final_train"):
                    pair.final = pair.vehicle


def run_fleet(
    out_dir: str | Path = "results/fleet",
    run: RunSettings | None = None,
    *,
    trains: int = 2,
    first_index: int = 0,
    hold_domain: bool = True,
    record: bool = True,
    verify: bool = True,
    discovery_range: str = "LOCALHOST",
    static_peers: str = "",
    timeout: float = 300.0,
    overwrite: bool = False,
    progress: bool = True,
    pair_process: bool = False,
) -> dict[str, Any]:
    """Run ``trains`` vehicle + track node pairs; return the summary (also ``out_dir/summary.json``).

    ``run``: what each pair runs (default: the run settings of
    :mod:`clm_core.settings`; pair ``i`` with the irregularity seed
    ``seed + i``), in the ROS domain ``run.domain_id``. ``record``: record the
    pairs' topics to ``out_dir/fleet_bag`` (needed by ``verify``, the
    offline check). ``discovery_range``/``static_peers``: DDS discovery of
    the node processes (docs/fleet.md: pairs on several hosts).
    ``pair_process``: each pair's two nodes in one process on one executor
    (:mod:`clm_ros.fleet_pair`) instead of two processes.

    Raises
    ------
    ClmRosError
        A bad argument, the domain in use, a node failed or exited early or did
        not exit cleanly, the run did not finish within ``timeout`` s, or a
        pair's answers are wrong (counts, order, offline replay): the summary
        is written first.
    """
    run = RunSettings() if run is None else run
    check_fleet(trains, first_index)
    if verify and not record:
        raise ClmRosError("verify needs the recorded wheel loads: pass record (drop --no-record) or --no-verify")
    bag = Path(out_dir) / "fleet_bag"
    if bag.exists() and not overwrite:
        raise ClmRosError(f"{bag}: exists; choose another output directory or pass overwrite (--overwrite)")
    env = fleet_env(run.domain_id, discovery_range, static_peers)  # checks the range before anything starts
    kw: dict[str, Any] = dict(trains=trains, first_index=first_index, record=record, verify=verify, timeout=timeout,
                              progress=progress, pair_process=pair_process)
    if not hold_domain:
        return _run_fleet(run.domain_id, env, Path(out_dir), run, **kw)
    with hold_domain_id(run.domain_id) as dom:
        return _run_fleet(dom, env, Path(out_dir), run, **kw)


def _run_fleet(dom: int, env: dict[str, str], out: Path, run: RunSettings, *, trains: int, first_index: int,
               record: bool, verify: bool, timeout: float, progress: bool, pair_process: bool) -> dict[str, Any]:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor

    from clm_core.progress import Progress
    from clm_ros.bag_tools import BagRecorder

    bag = out / "fleet_bag"
    if bag.exists():
        shutil.rmtree(bag)
    out.mkdir(parents=True, exist_ok=True)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
    if "ROS_STATIC_PEERS" in env:
        os.environ["ROS_STATIC_PEERS"] = env["ROS_STATIC_PEERS"]
    pairs = [_Pair(ns) for ns in namespaces(trains, first_index)]
    track_params = run.track_parameters()
    logs: dict[str, Any] = {}
    ctx = Context()
    rclpy.init(context=ctx, domain_id=dom)
    watch = _Watch(pairs)
    bar = Progress(run.messages * trains if progress else None, "clm fleet", unit="msg")
    nodes: list[Any] = []
    rec: BagRecorder | None = None
    summary: dict[str, Any] = {}
    rec_cpu0 = 0.0

    def start(pair: _Pair, kind: str, params: Mapping[str, Any]) -> None:
        name = f"{pair.ns.strip('/')}_{kind}"
        logs[name] = open(out / f"{name}.log", "w")
        module = "fleet_pair" if kind == "pair" else kind
        pair.procs[kind] = subprocess.Popen(
            [sys.executable, "-m", f"clm_ros.{module}", *ros_args(params), "-r", f"__ns:={pair.ns}"],
            env=env, stdout=logs[name], stderr=subprocess.STDOUT,
        )

    def check() -> None:
        for pair in pairs:
            for kind, p in pair.procs.items():
                if p.poll() is not None:
                    raise ClmRosError(f"{pair.ns} {kind.replace('_', ' ')} exited early with code {p.returncode}; "
                                      f"see {out}/{pair.ns.strip('/')}_{kind}.log")

    def vehicle_params(i: int) -> dict[str, Any]:
        return run.vehicle_parameters(seed_offset=first_index + i, wait_for_subscribers=2 if record else 1)

    try:
        for i, pair in enumerate(pairs):
            if pair_process:  # the vehicle waits for the recorder (wait_for_subscribers) before its train starts
                start(pair, "pair", {**track_params, **vehicle_params(i)})
            else:
                start(pair, "track_node", track_params)
        watcher = rclpy.create_node("clm_fleet_watch", context=ctx)
        nodes.append(watcher)
        ex = EventsExecutor(context=ctx)
        ex.add_node(watcher)
        watcher.create_subscription(DiagnosticArray, "/diagnostics", watch.on_diagnostics, 50)
        if record:
            recorder = rclpy.create_node("clm_fleet_recorder", context=ctx)
            nodes.append(recorder)
            topics = {f"{p.ns}/{t}": m for p in pairs for t, m in PAIR_TOPICS.items()}
            rec = BagRecorder(recorder, bag, {**topics, "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"},
                              storage=run.storage, polled=True)

        def spin_for(seconds: float) -> None:
            end = time.monotonic() + seconds
            while (left := end - time.monotonic()) > 0:
                ex.spin_once(timeout_sec=min(left, POLL))
                if rec is not None:
                    rec.poll()

        t_up = time.monotonic()
        answers = [f"{p.ns}/{t}" for p in pairs for t in ("sleeper_response", "wheel_rail_response")]
        while rec is not None and not rec.matched(answers):
            spin_for(0.02)
            check()
            if time.monotonic() - t_up > timeout:
                raise ClmRosError(f"the track nodes' answers not discovered after {timeout:g} s; see {out}/*.log")
        gc.collect()
        gc.freeze()
        for i, pair in enumerate(pairs):
            if not pair_process:
                start(pair, "vehicle_node", vehicle_params(i))
        t0 = time.monotonic()
        rec_cpu0 = time.process_time()
        while not all(p.final for p in pairs):
            spin_for(0.05)
            for p in pairs:
                n = _published(p, rec)
                if n and not p.cpu0:  # this train started: CPU from here on
                    p.cpu0 = {k: proc_cpu_s(q.pid) for k, q in p.procs.items()}
                    p.n0 = n
            bar.update_to(sum(_published(p, rec) for p in pairs))
            check()
            if time.monotonic() - t0 > timeout:
                late = [p.ns for p in pairs if not p.final]
                raise ClmRosError(f"trains {', '.join(late)} not done after {timeout:g} s; see {out}/*.log")
        bar.close()
        if rec is not None:  # every wheel-load message answered (or counted rejected) in the bag
            t1 = time.monotonic()
            while time.monotonic() - t1 < 60 and any(
                    rec.counts[f"{p.ns}/sleeper_response"] < rec.counts[f"{p.ns}/wheel_loads"] for p in pairs):
                spin_for(0.05)
        rec_cpu = time.process_time() - rec_cpu0
        for p in pairs:
            n = _published(p, rec) - p.n0
            cpu1 = {k: proc_cpu_s(q.pid) for k, q in p.procs.items()}
            p.cpu_us = {k: _per(p.cpu0.get(k), cpu1[k], n) for k in cpu1}
        n_all = sum(_published(p, rec) for p in pairs)
        summary["recorder_cpu_us_per_message"] = 1e6 * rec_cpu / n_all if record and n_all else None
        summary["message_counts"] = rec.close() if rec is not None else {}
    finally:
        bar.close()
        if rec is not None and not rec.closed:
            rec.abort()
        for n in nodes:
            n.destroy_node()
        procs = {f"{p.ns}/{k}": q for k in ("vehicle_node", "track_node", "pair") for p in pairs
                 for k2, q in p.procs.items() if k2 == k}
        codes = _stop(procs)
        for f in logs.values():
            f.close()
        rclpy.try_shutdown(context=ctx)
    per_train: dict[str, Any] = {}
    for p in pairs:
        t = _train_figures(p, codes)
        if record:
            t.update(_bag_figures(bag, p.ns))
        if verify:
            t.update(_offline_check(bag, p.ns, run))
        t["correct"] = bool(t["in_equals_out"] and t.get("offline_equal", True))
        per_train[p.ns.strip("/")] = t
    summary.update({
        "trains": per_train,
        "overall": _overall(per_train),
        "exit_codes": codes,
        "loadavg": list(os.getloadavg()),
        "n_trains": trains, "first_index": first_index, **run.summary(),
        "seeds": [run.seed + first_index + i for i in range(trains)],
        "bag": str(bag) if record else None, "ros_domain_id": dom,
        "discovery_range": env["ROS_AUTOMATIC_DISCOVERY_RANGE"], "pair_process": pair_process,
    })
    write_json(out / "summary.json", summary)
    bad = {k: c for k, c in codes.items() if c != 0}
    if bad:
        raise ClmRosError(f"node(s) did not exit cleanly on SIGINT: {bad}; see the logs in {out}/")
    wrong = [k for k, t in per_train.items() if not t["correct"]]
    if wrong:
        raise ClmRosError(f"wrong answers of {', '.join(wrong)} (in != out or not equal to offline replay); see "
                          f"{out}/summary.json")
    return summary


def _decode(topic: str, data: bytes) -> Any:
    """The numpy CDR decoding (clm_core.io.messages) of a message of a pair's data topic ``topic``."""
    from clm_core.io import messages

    return getattr(messages, f"decode_{topic}")(data)


def _published(p: _Pair, rec: Any) -> int:
    """Wheel-load messages of pair ``p`` so far: recorded, or as its vehicle last reported."""
    if rec is not None:
        return int(rec.counts[f"{p.ns}/wheel_loads"])
    return int(p.vehicle.get("train.published", 0))


def _per(a: float | None, b: float | None, n: int) -> float | None:
    return None if a is None or b is None or n <= 0 else round(1e6 * (b - a) / n, 1)


def _train_figures(p: _Pair, codes: dict[str, int]) -> dict[str, Any]:
    """What the vehicle of pair ``p`` reported at the end of its train, and its processes' exit codes."""
    v = {k.removeprefix("train."): _number(x) for k, x in p.final.items() if k.startswith("train.")}
    published, answered = int(v.get("published", 0)), int(v.get("answered", 0))
    return {
        "namespace": p.ns,
        "messages_in": published, "messages_out": answered,
        "in_equals_out": published == answered > 0,
        "feedback_used": int(v.get("feedback_used", 0)), "feedback_total": int(v.get("feedback_total", 0)),
        "vehicle_lag_median_s": v.get("lag_median_s"), "vehicle_lag_p99_s": v.get("lag_p99_s"),
        "vehicle_lag_max_s": v.get("lag_max_s"),
        "lag_median_s": v.get("lag_median_s"), "lag_p99_s": v.get("lag_p99_s"), "lag_max_s": v.get("lag_max_s"),
        "vehicle_node": v,
        "cpu_us_per_message": p.cpu_us,
        "exit_codes": {k.rsplit("/", 1)[1]: c for k, c in codes.items() if k.startswith(p.ns + "/")},
    }


def _bag_figures(bag: Path, ns: str) -> dict[str, Any]:
    """In = out of pair ``ns`` as recorded (once each, in order) and its lags from the recorder's log times."""
    from clm_core.io.bags import BagReader

    stamps: dict[str, list[int]] = {t: [] for t in PAIR_TOPICS}
    recv: list[int] = []
    with BagReader(bag) as reader:
        for bm in reader.messages([f"{ns}/{t}" for t in PAIR_TOPICS]):
            topic = bm.topic.rsplit("/", 1)[1]
            st = _decode(topic, bm.data).stamp_ns
            stamps[topic].append(st)
            if topic == "sleeper_response":
                recv.append(bm.log_ns - st)
    n_in, n_out, n_w = (len(stamps[t]) for t in PAIR_TOPICS)
    ok = n_in > 0 and stamps["wheel_loads"] == stamps["sleeper_response"] == stamps["wheel_rail_response"]
    lags = np.asarray(recv, float) / 1e9 if recv else np.full(1, np.nan)
    return {
        "messages_in": n_in, "messages_out": n_out, "wheel_rail_responses": n_w,
        "in_equals_out": bool(ok),
        "lag_median_s": float(np.median(lags)), "lag_p99_s": float(np.percentile(lags, 99)),
        "lag_max_s": float(np.max(lags)),
    }


def _offline_check(bag: Path, ns: str, run: RunSettings) -> dict[str, Any]:
    """Replay pair ``ns``'s recorded wheel loads offline; compare its recorded answers with the replay's."""
    from clm_core.io.bags import BagReader
    from clm_core.online import OnlineTrackModel
    from clm_core.params import SoilModel, load_model
    from clm_ros.replay import replay_bag

    m = OnlineTrackModel(load_model(run.track, run.soil, cast(SoilModel, run.model)), dt=run.dt,
                         n_sleepers=run.n_sleepers)
    with tempfile.TemporaryDirectory(prefix="clm_fleet_") as tmp:
        stats = replay_bag(bag, Path(tmp) / "offline", m, topic=f"{ns}/wheel_loads", out_prefix=ns)

        def answers(path: Path) -> dict[tuple[str, int], Any]:
            got: dict[tuple[str, int], Any] = {}
            with BagReader(path) as reader:
                topics = [f"{ns}/sleeper_response", f"{ns}/wheel_rail_response"]
                for bm in reader.messages(topics):
                    m = _decode(bm.topic.rsplit("/", 1)[1], bm.data)
                    got[(bm.topic, m.stamp_ns)] = m
            return got

        live, offline = answers(bag), answers(Path(tmp) / "offline")
    diff = 0.0
    fields_equal = live.keys() == offline.keys()
    for key, a in live.items():
        b = offline.get(key)
        if b is None:
            continue
        for x, y in zip(a, b):  # the fields of the decoded message (a NamedTuple)
            if isinstance(x, np.ndarray):
                if x.shape != y.shape:
                    fields_equal = False
                elif x.size:
                    d = np.abs(x.astype(float) - y.astype(float))
                    diff = max(diff, float(np.nanmax(d)) if np.isfinite(d).any() else 0.0)
                    fields_equal &= bool(np.array_equal(x, y, equal_nan=x.dtype.kind == "f"))
    return {"offline_accepted": stats.accepted, "offline_compared": len(live),
            "offline_equal": bool(fields_equal and len(live) > 0), "offline_max_abs_diff": diff}


def _overall(per_train: dict[str, Any]) -> dict[str, Any]:
    """The worst of each figure over the trains, and whether every pair is correct."""
    def worst(key: str) -> float | None:
        vals = [float(t[key]) for t in per_train.values() if t.get(key) is not None]
        return max(vals) if vals else None

    used = [t["feedback_used"] / t["feedback_total"] for t in per_train.values() if t["feedback_total"]]
    return {
        "trains": len(per_train),
        "all_correct": all(t["correct"] for t in per_train.values()),
        "all_in_equals_out": all(t["in_equals_out"] for t in per_train.values()),
        "all_offline_equal": all(t.get("offline_equal", True) for t in per_train.values()),
        "messages_in": sum(t["messages_in"] for t in per_train.values()),
        "messages_out": sum(t["messages_out"] for t in per_train.values()),
        "worst_lag_median_s": worst("lag_median_s"), "worst_lag_p99_s": worst("lag_p99_s"),
        "worst_lag_max_s": worst("lag_max_s"), "worst_vehicle_lag_p99_s": worst("vehicle_lag_p99_s"),
        "lowest_feedback_fraction": min(used) if used else None,
    }
