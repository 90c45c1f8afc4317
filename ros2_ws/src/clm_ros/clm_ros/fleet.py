"""A fleet of trains online: N vehicle + track node pairs on one ROS graph, each pair in its own namespace.

``clm fleet --trains N --duration S --out DIR`` (issue 15.1) is the demo
(:mod:`clm_ros.launcher`) times N, with the same node processes, parameters
and recorder:

1. takes the ROS domain ``domain_id`` (held exclusively among the clm runs of
   this machine unless ``hold_domain`` is off, ``--join-domain``: then it
   joins the graph of that domain, e.g. another fleet's; discovery on
   loopback unless ``discovery_range`` says otherwise, docs/fleet.md);
2. runs N trains through the run harness (:mod:`clm_ros.harness`, the demo's):
   N track-soil nodes (``clm_ros.track_node``) and N vehicle simulator nodes
   (``clm_ros.vehicle_node``), the pair ``i`` in the namespace ``/train_i``
   (``i`` from ``first_index``, so that another host can add further pairs to
   the same graph), each one train of ``duration`` s with the irregularity
   seed ``seed + i``. Every vehicle waits for its own track node (its
   namespace, its endpoints matched: :mod:`clm_ros.readiness`) and the
   recorder; once every train is ready they start together (or ``stagger`` s
   apart);
3. records ``/train_i/wheel_loads``, ``/train_i/sleeper_response``,
   ``/train_i/wheel_rail_response`` of every pair and ``/diagnostics`` to one
   bag (``DIR/fleet_bag``, :class:`clm_ros.bag_tools.BagRecorder`, polled:
   log time = reception time by this process's middleware);
4. when every vehicle's latched status says its train is done (or its train
   failed: a node that died, even kill -9, ends only its own train) and every
   wheel-load message is
   answered, stops all nodes (SIGINT, each must exit 0), then checks each
   pair: in = out (each wheel-load message answered once, in order: the
   responses' stamps are the wheel loads' stamps) and, with ``verify``, its
   answers equal, bit for bit, the offline replay of its recorded wheel loads
   (:func:`clm_ros.replay.replay_bag` through
   :class:`clm_core.online.OnlineTrackModel`, the track node's code path).

``DIR/summary.json``: per train (``trains.train_i``) the messages in and out,
``feedback_used``/``feedback_total``, the lag median/p99/max from the first
message (``lag_*``, the data path's: the vehicle's reception of each
``wheel_rail_response`` minus the due time of its wheel-load message, as the
vehicle measures it, also ``vehicle_lag_*``), the recorder's lag behind the
data (``recorder_lag_*``: its reception of ``sleeper_response`` minus the
stamp; a recorder that falls behind under load loses nothing, issue 21: the
trains' writers keep the whole train for it, :meth:`TrainSpec.history`, and
the run waits for the bag to be complete), the offline check, each node's
CPU per message, its ``status`` (``ok``, ``failed``, ``timeout``, ``wrong``)
and ``reason``; ``overall``: the worst of each figure, whether every pair is
correct, how many trains ran at once (``max_running_at_once``,
``started_together``, ``start_spread_s``). The summary is written and the bag
kept whatever happened; then a train that is not ``ok`` makes the run an
error. Without the recorder (``record=False``, the capacity benchmark) the
counts and lags are the vehicles' own.

Users with a full ROS install get the same graph from
``ros2 launch clm_ros fleet.launch.py trains:=N``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from clm_core.io.files import write_json
from clm_ros.errors import ClmRosError
from clm_ros.harness import Train, TrainSpec, number, run_trains
from clm_ros.parameters import lookup
from clm_ros.processes import hold_domain_id, ros_env
from clm_ros.run_settings import RunSettings

#: Namespace of pair ``i``: ``/train_i``.
NAMESPACE = "train_{}"
#: The data topics of each pair (relative to its namespace) and their types.
PAIR_TOPICS = {
    "wheel_loads": "clm_msgs/msg/WheelLoads",
    "sleeper_response": "clm_msgs/msg/SleeperResponse",
    "wheel_rail_response": "clm_msgs/msg/WheelRailResponse",
}
#: What the fleet records of each pair by default: its wheel loads (the input of the offline check) and the answers
#: that close its loop. Not the 61-sleeper ``sleeper_response`` (~3 KB, a third of the messages) unless asked
#: (``record_sleepers``): every recorded topic costs the pair a send per message to one more reader and the
#: recorder a take and a write (docs/fleet.md: capacity).
RECORDED = ("wheel_loads", "wheel_rail_response")
#: Bag of pair ``name`` when each pair process records its own topics (``pair_process``), in the output directory.
PAIR_BAG = "{}_bag"
#: DDS discovery ranges (``ROS_AUTOMATIC_DISCOVERY_RANGE``): LOCALHOST keeps the graph on this machine.
DISCOVERY_RANGES = ("LOCALHOST", "SUBNET", "SYSTEM_DEFAULT")


def namespaces(trains: int, first_index: int = 0) -> list[str]:
    """The namespaces of the pairs ``first_index`` ... ``first_index + trains - 1`` (``/train_i``)."""
    return [f"/{NAMESPACE.format(i)}" for i in range(first_index, first_index + trains)]


def check_fleet(trains: int, first_index: int) -> None:
    """Refuse a fleet that cannot run (ClmRosError naming the value and the rule)."""
    for name, v in (("trains", trains), ("first_index", first_index)):
        try:
            lookup(f"fleet_{name}").check(v, name)
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
    stagger: float = 0.0,
    record_sleepers: bool = False,
) -> dict[str, Any]:
    """Run ``trains`` vehicle + track node pairs; return the summary (also ``out_dir/summary.json``).

    ``run``: what each pair runs (default: the run settings of
    :mod:`clm_core.settings`; pair ``i`` with the irregularity seed
    ``seed + i``), in the ROS domain ``run.domain_id``, held exclusively among
    the clm runs of this machine unless ``hold_domain`` is False (then the
    fleet joins whatever graph runs in that domain, e.g. another fleet's with
    another ``first_index``: the lock is a choice). ``record``: record the
    pairs' topics to ``out_dir/fleet_bag`` (needed by ``verify``, the
    offline check). ``discovery_range``/``static_peers``: DDS discovery of
    the node processes (docs/fleet.md: pairs on several hosts).
    ``pair_process``: each pair's two nodes in one process on one executor
    (:mod:`clm_ros.fleet_pair`) instead of two processes. The trains start
    together once all are ready; ``stagger`` [s]: train ``i`` starts
    ``i * stagger`` after the first (a schedule). The bag holds each pair's
    :data:`RECORDED` topics, and its ``sleeper_response`` with
    ``record_sleepers``.

    Raises
    ------
    ClmRosError
        A bad argument, the domain in use; or, after the summary is written and
        the bag kept, a train that failed (a node died, was not ready, did not
        exit cleanly), ran out of ``timeout`` or answered wrongly (counts,
        order, offline replay).
    """
    run = RunSettings() if run is None else run
    check_fleet(trains, first_index)
    if verify and not record:
        raise ClmRosError("verify needs the recorded wheel loads: pass record (drop --no-record) or --no-verify")
    if not 0.0 <= stagger <= 3600.0:
        raise ClmRosError(f"stagger = {stagger:g}: must be 0 to 3600 s")
    bag = Path(out_dir) / "fleet_bag"
    if bag.exists() and not overwrite:
        raise ClmRosError(f"{bag}: exists; choose another output directory or pass overwrite (--overwrite)")
    env = fleet_env(run.domain_id, discovery_range, static_peers)  # checks the range before anything starts
    kw: dict[str, Any] = dict(trains=trains, first_index=first_index, record=record, verify=verify, timeout=timeout,
                              progress=progress, pair_process=pair_process, stagger=stagger,
                              record_sleepers=record_sleepers)
    if not hold_domain:
        return _run_fleet(run.domain_id, env, Path(out_dir), run, **kw)
    with hold_domain_id(run.domain_id) as dom:
        return _run_fleet(dom, env, Path(out_dir), run, **kw)


def _run_fleet(dom: int, env: dict[str, str], out: Path, run: RunSettings, *, trains: int, first_index: int,
               record: bool, verify: bool, timeout: float, progress: bool, pair_process: bool,
               stagger: float, record_sleepers: bool) -> dict[str, Any]:
    from clm_core.progress import Progress

    track_params = run.track_parameters()
    recorded = (*RECORDED, "sleeper_response") if record_sleepers else RECORDED
    own = record and pair_process  # each pair process records its own topics (clm_ros.fleet_pair)
    specs = [TrainSpec(ns.strip("/"), ns, track_params,
                       run.vehicle_parameters(seed_offset=first_index + i, wait_for_subscribers=2 if record else 1),
                       pair_process=pair_process, start_offset=i * stagger, messages=run.messages,
                       own_bag=out / PAIR_BAG.format(ns.strip("/")) if own else None,
                       own_topics=recorded if own else ())
             for i, ns in enumerate(namespaces(trains, first_index))]
    for s in specs:
        if s.own_bag is not None and s.own_bag.exists():
            shutil.rmtree(s.own_bag)
    topics = {} if own else {f"{s.ns}/{t}": PAIR_TOPICS[t] for s in specs for t in recorded}
    bar = Progress(run.messages * trains if progress else None, "clm fleet", unit="msg")
    try:
        r = run_trains(out, specs, domain_id=dom, env=env,
                       topics={**topics, "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"} if record else None,
                       bag_name="fleet_bag", storage=run.storage, timeout=timeout, progress=bar.update_to)
    finally:
        bar.close()
    bag = out / "fleet_bag"
    counts = dict(r.message_counts)
    for s in specs:
        counts.update(_bag_counts(s.own_bag) if s.own_bag is not None else {})
    n_all = sum(counts.get(f"{s.ns}/wheel_loads", 0) for s in specs)
    summary: dict[str, Any] = {
        "recorder_cpu_us_per_message": 1e6 * r.recorder_cpu_s / n_all if record and n_all and not own else None,
        "message_counts": counts,
    }
    per_train: dict[str, Any] = {}
    for t in r.trains:
        f = _train_figures(t, r.exit_codes)
        data_bag = t.spec.own_bag or bag
        try:
            if record:
                f.update(_bag_figures(data_bag, t.spec.ns))
            if verify:
                f.update(_offline_check(data_bag, t.spec.ns, run))
        except Exception as exc:  # a train that recorded nothing (it never started): say so, keep going
            f["check_error"] = str(exc)
        f["correct"] = bool(t.state == "done" and f["in_equals_out"] and f.get("offline_equal", True)
                            and "check_error" not in f)
        if t.state == "done" and not f["correct"]:
            v = f["vehicle_node"]
            f["status"], f["reason"] = "wrong", (
                f"in = out: {f['in_equals_out']} (recorded {f['messages_in']} in, {f['messages_out']} out; the vehicle "
                f"published {v.get('published')}, {v.get('answered')} answered); equal to the offline replay: "
                f"{f.get('offline_equal', 'not checked')} (max difference {f.get('offline_max_abs_diff')})")
        per_train[t.spec.name] = f
    summary.update({
        "status": "ok" if all(t["correct"] for t in per_train.values()) and r.ok else "failed",
        "trains": per_train,
        "overall": {**_overall(per_train), **r.concurrency},
        "exit_codes": r.exit_codes,
        "loadavg": list(os.getloadavg()),
        "n_trains": trains, "first_index": first_index, **run.summary(),
        "seeds": [run.seed + first_index + i for i in range(trains)],
        "bag": str(bag) if record else None, "ros_domain_id": dom,
        "train_bags": {s.name: str(s.own_bag) for s in specs if s.own_bag is not None},
        "recorded_in": "pair processes" if own else "supervisor" if record else None,
        "supervisor_transport": r.supervisor_transport,
        "discovery_range": env["ROS_AUTOMATIC_DISCOVERY_RANGE"], "pair_process": pair_process, "stagger_s": stagger,
        "recorded_topics": list(recorded) if record else [],
    })
    write_json(out / "summary.json", summary)
    bad = [f"{k}: {t['status']}: {t['reason']}" for k, t in per_train.items() if not t["correct"]]
    if bad:
        raise ClmRosError(f"{'; '.join(bad)}; the summary is {out}/summary.json" + (f", the bag {bag}" if record
                                                                                      else ""))
    return summary


def _bag_counts(bag: Path) -> dict[str, int]:
    """Messages per topic of a bag (its metadata); empty when there is no readable bag (a pair that died)."""
    from clm_core.io.bags import BagReader

    try:
        with BagReader(bag) as reader:
            return {t: info.message_count for t, info in reader.topics.items()}
    except Exception:
        return {}


def _train_figures(t: Train, codes: dict[str, int]) -> dict[str, Any]:
    """Train ``t``'s status and reason, what its vehicle reported at the end of its train, its exit codes."""
    v = {k.removeprefix("train."): number(x) for k, x in t.final.items() if k.startswith("train.")}
    published, answered = int(v.get("published", 0)), int(v.get("answered", 0))
    ns = t.spec.ns
    return {
        "namespace": ns, "status": "ok" if t.state == "done" else t.state, "reason": t.reason,
        "messages_in": published, "messages_out": answered,
        "in_equals_out": published == answered > 0,
        "feedback_used": int(v.get("feedback_used", 0)), "feedback_total": int(v.get("feedback_total", 0)),
        "vehicle_lag_median_s": v.get("lag_median_s"), "vehicle_lag_p99_s": v.get("lag_p99_s"),
        "vehicle_lag_max_s": v.get("lag_max_s"),
        "lag_median_s": v.get("lag_median_s"), "lag_p99_s": v.get("lag_p99_s"), "lag_max_s": v.get("lag_max_s"),
        "vehicle_node": v,
        "cpu_us_per_message": t.cpu_us,
        "exit_codes": {k.rsplit("/", 1)[1]: c for k, c in codes.items() if k.startswith(ns + "/")},
    }


def _bag_figures(bag: Path, ns: str) -> dict[str, Any]:
    """In = out of pair ``ns`` as recorded (once each, in order) and the recorder's lag behind the data (its log
    time, the reception by its middleware, of each ``wheel_rail_response`` minus the stamp): the recorder's
    backlog, ``recorder_lag_*``, not the data path's lag (that is the vehicle's, ``lag_*``)."""
    from clm_core.io.timebase import lag_figures
    from clm_ros.bag_tools import read_topics

    got = read_topics(bag, [f"{ns}/{t}" for t in PAIR_TOPICS])
    recorded = [t for t in PAIR_TOPICS if f"{ns}/{t}" in got]
    stamps = {t: [m.stamp_ns for _, m in got[f"{ns}/{t}"]] for t in recorded}
    recv = [log - m.stamp_ns for log, m in got.get(f"{ns}/wheel_rail_response", [])]
    answers = [stamps[t] for t in recorded if t != "wheel_loads"]
    n_in = len(stamps.get("wheel_loads", []))
    ok = n_in > 0 and bool(answers) and all(a == stamps["wheel_loads"] for a in answers)
    return {
        "messages_in": n_in, "messages_out": len(stamps.get("wheel_rail_response", [])),
        "wheel_rail_responses": len(stamps.get("wheel_rail_response", [])),
        **({"sleeper_responses": len(stamps["sleeper_response"])} if "sleeper_response" in stamps else {}),
        "recorded_topics": recorded,
        "in_equals_out": bool(ok),
        **lag_figures(recv).named("recorder_lag"),
    }


def _offline_check(bag: Path, ns: str, run: RunSettings) -> dict[str, Any]:
    """Replay pair ``ns``'s recorded wheel loads offline; compare its recorded answers with the replay's."""
    from clm_core.online import OnlineTrackModel
    from clm_ros.bag_tools import read_topics
    from clm_ros.replay import replay_bag

    m = OnlineTrackModel.from_settings(run.track_parameters())  # what the pair's track node was given
    with tempfile.TemporaryDirectory(prefix="clm_fleet_") as tmp:
        stats = replay_bag(bag, Path(tmp) / "offline", m, topic=f"{ns}/wheel_loads", out_prefix=ns)

        topics = [f"{ns}/sleeper_response", f"{ns}/wheel_rail_response"]

        def answers(path: Path, only: Any = None) -> dict[tuple[str, int], Any]:
            return {(topic, msg.stamp_ns): msg for topic, msgs in read_topics(path, only or topics).items()
                    for _, msg in msgs}

        live = answers(bag)  # the answer topics recorded live
        offline = answers(Path(tmp) / "offline", sorted({topic for topic, _ in live}) or topics)
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
        "status": {k: t["status"] for k, t in per_train.items()},
        "all_in_equals_out": all(t["in_equals_out"] for t in per_train.values()),
        "all_offline_equal": all(t.get("offline_equal", True) for t in per_train.values()),
        "messages_in": sum(t["messages_in"] for t in per_train.values()),
        "messages_out": sum(t["messages_out"] for t in per_train.values()),
        "worst_lag_median_s": worst("lag_median_s"), "worst_lag_p99_s": worst("lag_p99_s"),
        "worst_lag_max_s": worst("lag_max_s"), "worst_vehicle_lag_p99_s": worst("vehicle_lag_p99_s"),
        "worst_recorder_lag_p99_s": worst("recorder_lag_p99_s"),
        "lowest_feedback_fraction": min(used) if used else None,
    }
