"""One run harness for ``clm demo`` and ``clm fleet``: start, readiness, start signal, end of run, recording, teardown.

The demo is a one-train fleet. :func:`run_trains` runs any number of trains
(a track node and a vehicle node each, or one :mod:`clm_ros.fleet_pair`
process), each in its namespace (the demo's in the root namespace), and
records their topics to one bag (a pair process given ``own_bag`` records its
own topics itself, :class:`clm_ros.fleet_pair.PairRecorder`; its latched
``recorder_status`` then stands for the recorder's match and counts); the
trains' data writers keep a whole train for a recorder that falls behind
(:meth:`TrainSpec.history`); :mod:`clm_ros.launcher` and
:mod:`clm_ros.fleet` are front ends that say what to run and turn the
:class:`RunResult` into their ``summary.json``.

Control-plane facts are state, never one message (issue 21):

- readiness: a train is ready when its vehicle's latched status
  (``vehicle_status``, :mod:`clm_ros.latched`) says it is ready (its own track
  node active, subscribed and matched: :mod:`clm_ros.readiness`) and the
  recorder has matched the track node's answers; the vehicles wait for a start
  time on their latched ``start_at`` (``start_signal``), given to every ready
  train at once, so the trains of a fleet start together, or ``start_offsets``
  after that common start (a user's schedule);
- end of a train: its vehicle's latched status carries the train's final
  figures (``final_train``): the middleware keeps and re-sends the latest
  state, so a dropped sample cannot hide it; its answers are then waited for
  in the recorded data itself;
- every wait is bounded (``ready_timeout``, ``timeout``) and ends with a
  reason. A train whose process dies (even kill -9) or whose vehicle reports
  an error ends ``failed`` with the reason; the other trains go on. The bag is
  always closed and kept (what was recorded up to the end), and the caller
  writes a summary with every train's ``status`` and ``reason``.

Train states: ``starting``, ``ready``, ``running``, ``done`` (its vehicle
finished the train), ``failed`` and ``timeout``.

The supervisor's own DDS participant (recorder, watcher) uses UDP only, never
Fast DDS shared memory (:func:`supervisor_participant_env`): a supervisor
starved by the scheduler, or stopped, must not lose the nodes for good, which
it did on shared memory when the nodes re-made its port under the same name
(docs/fleet.md). :attr:`RunResult.supervisor_transport` says what it used.
"""

from __future__ import annotations

import contextlib
import gc
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clm_core.environ import environment
from clm_ros.processes import proc_cpu_s, ros_args, stop_processes

#: How often the recorder takes the messages that have arrived [s] (their log times are their reception times).
POLL = 0.005
#: Time from the start signal to the common start of the trains [s]: the latched signal reaches every vehicle
#: before it, also when a reliable sample is repaired after a heartbeat on a loaded machine (with 0.3 s, a
#: train of three once started 0.29 s after the others at load 3.6).
START_LEAD = 1.0
#: How long before a train's start time its CPU window opens [ns] (its processes wait meanwhile: ~3 % of a core,
#: i.e. < 1 us per message of a 1-s train).
CPU_LEAD_NS = 20_000_000
#: Longest wait for the answers of a finished train to reach the bag [s].
ANSWERS_TIMEOUT = 60.0
#: Longest wait for the node processes to exit after SIGINT, all together [s] (then SIGTERM, then SIGKILL):
#: a loaded machine can take many seconds to tear a process down.
STOP_TIMEOUT = 45.0
#: Fast DDS transports of the supervisor's own participant with SUBNET discovery (env ``FASTDDS_BUILTIN_TRANSPORTS``).
SUPERVISOR_TRANSPORTS = "UDPv4"
#: Fast DDS profile of the supervisor's own participant with LOCALHOST discovery: UDP on the loopback interface only.
SUPERVISOR_PROFILE = Path(__file__).with_name("fastdds_supervisor.xml")
#: Environment variables that name a Fast DDS XML profile file (a user's own wins over :data:`SUPERVISOR_PROFILE`).
PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
#: Terminal train states.
ENDED = ("done", "failed", "timeout")
#: The data topics of a train (relative to its namespace): what its writers must keep for a recorder.
DATA_TOPICS = ("wheel_loads", "sleeper_response", "wheel_rail_response")
#: Messages a train's writers keep beyond its own messages while a recorder has not acknowledged them.
HISTORY_MARGIN = 1000
#: Most messages a train's writers keep for a recorder that falls behind (60 s at 1 kHz; ~3 KB per 61-sleeper
#: answer, held only while unacknowledged): a longer train is recorded completely only if its recorder is never
#: that far behind (the summary then says what is missing, the offline check fails).
MAX_HISTORY = 60000


@dataclass
class TrainSpec:
    """One train to run: its namespace ('' for the root), its nodes' parameters, how its nodes run.

    ``start_offset``: seconds after the common start at which this train starts (the user's schedule).
    """

    name: str
    ns: str
    track_params: Mapping[str, Any]
    vehicle_params: Mapping[str, Any]
    pair_process: bool = False
    start_offset: float = 0.0
    messages: int = 0
    #: With ``pair_process``: the bag its process records its own topics ``own_topics`` to (clm_ros.fleet_pair).
    own_bag: Path | None = None
    own_topics: tuple[str, ...] = ()

    def history(self) -> dict[str, int]:
        """The QoS override parameters that make its data writers keep a whole train for a recorder.

        A reliable keep-last writer drops a sample its history overwrites even when a reader has not acknowledged
        it: with the nodes' default depth of 5000, a recorder more than 5 s behind lost the first of a train's 5001
        wheel loads and its answers (issue 21: a 5-train fleet's offline replay then differed). With the depth at
        the train's messages (+ :data:`HISTORY_MARGIN`, at most :data:`MAX_HISTORY`) nothing of a train is
        overwritten before the recorder has it; a volatile writer frees what every reader has acknowledged, so
        the memory is held only while the recorder lags.
        """
        depth = min(self.messages + HISTORY_MARGIN, MAX_HISTORY)
        return {f"qos_overrides.{self.ns}/{t}.publisher.depth": depth for t in DATA_TOPICS}

    def topic(self, t: str) -> str:
        """Full name of this train's topic ``t``."""
        return f"{self.ns}/{t}"


@dataclass
class Train:
    """A train being run: its spec, processes, the latest latched status of its vehicle, its state and reason."""

    spec: TrainSpec
    procs: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    status: dict[str, str] = field(default_factory=dict)
    track: dict[str, str] = field(default_factory=dict)  # the latest latched status of its track node
    recorder: dict[str, str] = field(default_factory=dict)  # the latest latched status of its own recorder
    state: str = "starting"
    reason: str = ""
    published_live: int = 0  # wheel-load messages its vehicle last reported on /diagnostics (no recorder)
    start_ns: int = 0  # its start time given in the start signal (system clock) [ns]
    cpu0: dict[str, float | None] = field(default_factory=dict)  # its processes' CPU at the start of its window
    cpu_us: dict[str, float | None] = field(default_factory=dict)
    n0: int = 0  # wheel-load messages recorded when its CPU window started (0 unless the harness woke late)

    def end(self, state: str, reason: str = "") -> None:
        """Put the train in terminal ``state`` with ``reason`` (the first end wins)."""
        if self.state not in ENDED:
            self.state, self.reason = state, reason

    @property
    def final(self) -> dict[str, str]:
        """The vehicle's figures of its finished train (empty before)."""
        return self.status if "final_train" in self.status else {}


@dataclass
class RunResult:
    """What :func:`run_trains` saw: the trains, exit codes, counts, CPU, how many ran at once."""

    trains: list[Train]
    exit_codes: dict[str, int]
    message_counts: dict[str, int]
    recorder_cpu_s: float
    concurrency: dict[str, Any]
    bag: Path | None
    ros_domain_id: int
    #: What the supervisor's own participant used (:func:`supervisor_participant_env`): ``UDP on loopback``, ``UDP``
    #: (SUBNET discovery) or ``shared memory and UDP`` (a user's own Fast DDS profile, or a process that made another
    #: participant before).
    supervisor_transport: str = "unknown"

    @property
    def ok(self) -> bool:
        """Every train done and every node exited 0."""
        return all(t.state == "done" for t in self.trains) and not any(self.exit_codes.values())

    def reasons(self) -> str:
        """One line: the trains that did not end well and why."""
        return "; ".join(f"{t.spec.name}: {t.state}: {t.reason}" for t in self.trains if t.state != "done")


def run_trains(out: Path, specs: list[TrainSpec], *, domain_id: int, env: dict[str, str],
               topics: Mapping[str, str] | None, bag_name: str, storage: str, timeout: float,
               ready_timeout: float | None = None, log_name: Callable[[TrainSpec, str], str] | None = None,
               progress: Callable[[int], None] | None = None) -> RunResult:
    """Run ``specs``' trains to their end; record ``topics`` (None: no bag) to ``out/bag_name``.

    Parameters
    ----------
    out : Path
        Output directory (logs ``<log_name>.log``, the bag).
    specs : list of TrainSpec
    domain_id : int
        ROS domain of everything (the caller holds it, or joins a graph on purpose).
    env : dict
        Environment of the node processes (:func:`clm_ros.processes.ros_env`, discovery).
    topics : mapping or None
        Topic -> type name to record; None: no recording (figures from the vehicles' own counts).
    timeout : float
        Longest time from the common start to the end of every train [s]; the trains still running then end
        ``timeout``.
    ready_timeout : float, optional
        Longest time for every train to be ready [s] (default ``timeout``: a loaded machine can take minutes to
        start the processes); a train not ready then ends ``failed`` (the others run).
    log_name : callable
        ``(spec, kind) -> file stem`` of a node process's log (default ``<name>_<kind>``).
    progress : callable
        Called with the wheel-load messages so far (all trains).
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor
    from std_msgs.msg import Int64

    from clm_ros.bag_tools import BagRecorder
    from clm_ros.latched import LATCHED_QOS, RECORDER_STATUS, TRACK_STATUS, VEHICLE_STATUS, status_values
    from clm_ros.readiness import START_AT

    ready_timeout = timeout if ready_timeout is None else ready_timeout
    bag = out / bag_name if topics is not None else None
    if bag is not None and bag.exists():
        shutil.rmtree(bag)
    out.mkdir(parents=True, exist_ok=True)
    trains = [Train(s) for s in specs]
    logs: dict[str, Any] = {}
    name_of = log_name or (lambda s, kind: f"{s.name}_{kind}")
    ctx = Context()
    nodes: list[Any] = []
    rec: BagRecorder | None = None
    counts: dict[str, int] = {}
    rec_cpu = 0.0
    concurrency: dict[str, Any] = {}
    supervisor_transport = "not started"

    def start(t: Train, kind: str, params: Mapping[str, Any]) -> None:
        stem = name_of(t.spec, kind)
        logs[stem] = open(out / f"{stem}.log", "w")
        module = "fleet_pair" if kind == "pair" else kind
        ns = ["-r", f"__ns:={t.spec.ns}"] if t.spec.ns else []
        if (topics is not None or t.spec.own_bag) and t.spec.messages:  # its writers keep the train for a recorder
            params = {**params, **t.spec.history()}
        if t.spec.own_bag is not None:
            params = {**params, "record_bag": str(t.spec.own_bag), "record_topics": ",".join(t.spec.own_topics),
                      "storage": storage}
        t.procs[kind] = subprocess.Popen([sys.executable, "-m", f"clm_ros.{module}", *ros_args(params), *ns],
                                         env=env, stdout=logs[stem], stderr=subprocess.STDOUT)

    def vehicle_params(t: Train) -> dict[str, Any]:
        return {**t.spec.vehicle_params, "start_signal": True}

    def check_processes() -> None:
        for t in trains:
            for kind, p in t.procs.items():
                if p.poll() is not None and t.state not in ENDED:
                    when = "during its train" if t.state == "running" else "before its train started"
                    t.end("failed", f"{kind.replace('_', ' ')} exited with code {p.returncode} {when}; see "
                                    f"{out}/{name_of(t.spec, kind)}.log")

    try:
        # this process's participant (recorder, watcher) talks to the nodes over UDP only; the nodes keep theirs.
        # It is made before the nodes, so it has the lowest participant id of the host, which every node's initial
        # peers reach (rmw_fastrtps: ids 0 to 31 on one host).
        global _profile_loaded
        sup_env = supervisor_participant_env(env)
        with environment(sup_env):
            rclpy.init(context=ctx, domain_id=domain_id)
            watcher = rclpy.create_node("clm_run_watch", context=ctx)  # the participant is created here
        nodes.append(watcher)
        _profile_loaded = _profile_loaded or "FASTRTPS_DEFAULT_PROFILES_FILE" in sup_env
        supervisor_transport = _own_transport()
        for t in trains:  # every process at once; each vehicle waits for its own track node and the start signal
            if t.spec.pair_process:
                start(t, "pair", {**t.spec.track_params, **vehicle_params(t)})
            else:
                start(t, "track_node", t.spec.track_params)
                start(t, "vehicle_node", vehicle_params(t))
        ex = EventsExecutor(context=ctx)
        ex.add_node(watcher)
        starters = {}
        for t in trains:
            def on_status(msg: Any, t: Train = t) -> None:
                t.status = status_values(msg)

            def on_track(msg: Any, t: Train = t) -> None:
                t.track = status_values(msg)

            watcher.create_subscription(DiagnosticArray, t.spec.topic(VEHICLE_STATUS), on_status, LATCHED_QOS)
            watcher.create_subscription(DiagnosticArray, t.spec.topic(TRACK_STATUS), on_track, LATCHED_QOS)
            if t.spec.own_bag is not None:
                def on_recorder(msg: Any, t: Train = t) -> None:
                    t.recorder = status_values(msg)

                watcher.create_subscription(DiagnosticArray, t.spec.topic(RECORDER_STATUS), on_recorder,
                                            LATCHED_QOS)
            starters[t.spec.name] = watcher.create_publisher(Int64, t.spec.topic(START_AT), LATCHED_QOS)
        if topics is None:  # progress from the vehicles' periodic diagnostics (best effort: only a progress bar)
            by_ns = {t.spec.ns: t for t in trains}

            def on_diagnostics(msg: Any) -> None:
                for st in msg.status:
                    t = by_ns.get(st.name.split(":", 1)[0].rsplit("/", 1)[0])
                    if t is not None and "vehicle simulator" in st.name:
                        v = next((kv.value for kv in st.values if kv.key == "train.published"), "0")
                        t.published_live = int(v) if v.isdigit() else 0

            watcher.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
        else:
            recorder = rclpy.create_node("clm_run_recorder", context=ctx)
            nodes.append(recorder)
            rec = BagRecorder(recorder, out / bag_name, dict(topics), storage=storage, polled=True)

        def spin_for(seconds: float) -> None:
            end = time.monotonic() + seconds
            while (left := end - time.monotonic()) > 0:
                ex.spin_once(timeout_sec=min(left, POLL))
                if rec is not None:
                    rec.poll()

        def published(t: Train) -> int:
            if t.spec.own_bag is not None:
                return int(t.recorder.get("wheel_loads", 0) or 0)
            if rec is not None:
                return int(rec.counts.get(t.spec.topic("wheel_loads"), 0))
            return t.published_live or int(t.status.get("train.published", 0) or 0)

        # readiness: the vehicle says it is ready (its own track node matched, its writer matched the recorder's
        # reader), the recorder's readers have matched the vehicle's and the track node's writers, and the track
        # node says its answer writers have matched every known reader (discovery is two-sided: a writer sends
        # nothing to a reader it has not matched, a reader drops what comes from a writer it has not matched; the
        # first wheel load and its answers were missing from a bag of every train of a 5-train fleet)
        t_up = time.monotonic()
        while True:
            spin_for(0.02)
            check_processes()
            for t in trains:
                answers = [t.spec.topic(x) for x in DATA_TOPICS if rec is not None and t.spec.topic(x) in rec.topics]
                own = t.spec.own_bag is not None
                if t.state == "starting" and "waiting for the start signal" in t.status.get("state", "") and (
                        not answers or rec is None or rec.matched(answers)) and (
                        not own or t.recorder.get("matched") == "True") and (
                        not (answers or own) or _answers_matched(watcher, t)):
                    t.state = "ready"
            if all(t.state != "starting" for t in trains):
                break
            if time.monotonic() - t_up > ready_timeout:
                for t in trains:
                    if t.state == "starting":
                        said = t.status.get("state") or "no status from its vehicle"
                        t.end("failed", f"not ready after {ready_timeout:g} s (vehicle: {said}); see the logs in "
                                        f"{out}/")
                break
        # the start signal: every ready train at once (plus its offset), latched
        gc.collect()
        gc.freeze()  # no 0.1-s full collection of the start-up heap while recording (clm_ros.node_main)
        t_start = time.time_ns() + int(START_LEAD * 1e9)
        for t in trains:
            if t.state == "ready":
                t.start_ns = t_start + int(t.spec.start_offset * 1e9)
                starters[t.spec.name].publish(Int64(data=t.start_ns))
                t.state = "running"
        concurrency["started_together"] = sum(t.state == "running" for t in trains)
        t0 = time.monotonic()
        rec_cpu0 = time.process_time()
        while any(t.state not in ENDED for t in trains):
            # a train's CPU window opens just before its start time (CPU_LEAD_NS), not when its first messages reach
            # the recorder: a starved supervisor saw a demo's train first 654 of 1001 messages in
            due = [t.start_ns - CPU_LEAD_NS - time.time_ns() for t in trains if t.state == "running" and not t.cpu0]
            spin_for(min(0.05, max(0.0, min(due) / 1e9)) if due else 0.05)
            for t in trains:
                if t.state == "running" and not t.cpu0 and time.time_ns() >= t.start_ns - CPU_LEAD_NS:
                    t.cpu0 = {k: proc_cpu_s(q.pid) for k, q in t.procs.items()}
                    t.n0 = published(t)
                if t.state == "running" and t.final:
                    t.end("done")
                elif t.state == "running" and t.status.get("level") == "2":
                    t.end("failed", f"vehicle: {t.status.get('message', '')}")
            check_processes()
            if progress is not None:
                progress(sum(published(t) for t in trains))
            if time.monotonic() - t0 > timeout + START_LEAD + max((s.start_offset for s in specs), default=0.0):
                for t in trains:
                    said = t.status.get("state") or "no status from its vehicle"
                    t.end("timeout", f"not done {timeout:g} s after its start (vehicle: {said})")
        if rec is not None or any(t.spec.own_bag for t in trains):  # every finished train complete in its bag
            t1 = time.monotonic()
            while time.monotonic() - t1 < ANSWERS_TIMEOUT and not all(_recorded(rec, t) for t in trains
                                                                         if t.state == "done"):
                spin_for(0.05)
                check_processes()
        if rec is not None:
            if "/diagnostics" in rec.counts:  # the nodes' last counters in the bag: two more /diagnostics of each
                n_diag, t2 = rec.counts["/diagnostics"], time.monotonic()
                while rec.counts["/diagnostics"] < n_diag + 4 * len(trains) and time.monotonic() - t2 < 5:
                    spin_for(0.05)
        rec_cpu = time.process_time() - rec_cpu0
        for t in trains:
            n = published(t) - t.n0
            cpu1 = {k: proc_cpu_s(q.pid) for k, q in t.procs.items()}
            t.cpu_us = {k: _per(t.cpu0.get(k), cpu1[k], n) for k in cpu1}
    except KeyboardInterrupt:  # the user stopped the run: what ran is recorded and summarised all the same
        for t in trains:
            t.end("failed", "interrupted (SIGINT) before its train was done")
    finally:
        if rec is not None:
            counts = _close(rec)
        for n in nodes:
            n.destroy_node()
        procs = {_proc_key(t, k): q for k in ("vehicle_node", "track_node", "pair") for t in trains
                 for k2, q in t.procs.items() if k2 == k}
        stop_processes(procs.values(), timeout=STOP_TIMEOUT)
        for f in logs.values():
            f.close()
        rclpy.try_shutdown(context=ctx)
    codes = {k: int(p.returncode) for k, p in procs.items()}
    for t in trains:
        bad = {k: codes[_proc_key(t, k)] for k in t.procs if codes[_proc_key(t, k)] != 0}
        if bad and t.state == "done":
            t.state, t.reason = "failed", f"node(s) did not exit cleanly: {bad}; see the logs in {out}/"
    concurrency.update(_concurrency(trains))
    return RunResult(trains, codes, counts, rec_cpu, concurrency, bag, domain_id, supervisor_transport)


def supervisor_participant_env(env: Mapping[str, str], fresh: bool | None = None) -> dict[str, str]:
    """The environment for the supervisor's own participant, given the nodes' ``env``: UDP only, as far as the nodes'.

    With the nodes on ``LOCALHOST`` discovery, rmw_fastrtps (Jazzy) gives every participant Fast DDS shared memory
    besides UDP, whatever ``FASTDDS_BUILTIN_TRANSPORTS`` says: a supervisor stopped for 6.5 s had its port re-made
    under the same name by the nodes and got nothing more after it resumed (the bag stopped growing; the run waited
    out its timeout for the latched end of train; the track node's answers were late too in one such run, p99
    3.75 s). So the supervisor's participant takes the ``SUBNET`` range
    (rmw_fastrtps then leaves the transports to the profile), ``127.0.0.1`` as its only static peer, and
    :data:`SUPERVISOR_PROFILE`: UDP bound to the loopback interface, no multicast, so nothing leaves the host.

    Fast DDS reads its profile file once per process, at the first participant. So this applies only where no
    participant was made before in this process (``fresh``, default :func:`_fresh_for_profile`: ``clm demo`` and
    ``clm fleet`` are fresh processes), and not with a user's own profile file (:data:`PROFILE_VARS`); otherwise
    the participant keeps the nodes' ``LOCALHOST`` discovery (shared memory and UDP, never beyond the host), which
    :attr:`RunResult.supervisor_transport` then says. With ``SUBNET`` discovery (pairs on several hosts) the
    built-in transports are limited to UDPv4 (:data:`SUPERVISOR_TRANSPORTS`; a user's own setting kept).
    """
    out = {"ROS_AUTOMATIC_DISCOVERY_RANGE": env["ROS_AUTOMATIC_DISCOVERY_RANGE"]}
    peers = [p for p in env.get("ROS_STATIC_PEERS", "").split(";") if p]
    if out["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST":
        if not any(v in os.environ for v in PROFILE_VARS) and (_fresh_for_profile() if fresh is None else fresh):
            out.update({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
                        "FASTRTPS_DEFAULT_PROFILES_FILE": str(SUPERVISOR_PROFILE)})
            peers = ["127.0.0.1"]  # its own trains are on this host (others' supervisors record theirs)
    else:
        out["FASTDDS_BUILTIN_TRANSPORTS"] = os.environ.get("FASTDDS_BUILTIN_TRANSPORTS", SUPERVISOR_TRANSPORTS)
    if peers:
        out["ROS_STATIC_PEERS"] = ";".join(peers)
    return out


#: Whether this process made its first participant with :data:`SUPERVISOR_PROFILE` (then it is Fast DDS's default).
_profile_loaded = False


def _fresh_for_profile() -> bool:
    """Whether Fast DDS will read :data:`SUPERVISOR_PROFILE` for the next participant of this process: no
    participant was made before (no Fast DDS thread, ``dds.*``: a shared-memory participant leaves its watchdog
    ``dds.shm.wdog`` behind), or the first one was made with it."""
    if _profile_loaded:
        return True
    try:
        names = [t.read_text().strip() for t in Path("/proc/self/task").glob("*/comm")]
    except OSError:
        return False
    return bool(names) and not any(n.startswith("dds.") for n in names)


def _own_transport() -> str:
    """What this process's Fast DDS participants use, from ``/proc/self``: ``shared memory and UDP`` if one maps a
    shared-memory port, else ``UDP on loopback`` if every UDP socket of the process is bound to 127.x, else ``UDP``
    (``unknown`` without ``/proc``)."""
    try:
        if "/dev/shm/fastrtps_port" in Path("/proc/self/maps").read_text():
            return "shared memory and UDP"
        links = []
        for fd in os.listdir("/proc/self/fd"):
            with contextlib.suppress(OSError):  # the listing's own descriptor is gone by now
                links.append(os.readlink(f"/proc/self/fd/{fd}"))
        inodes = {x[8:-1] for x in links if x.startswith("socket:[")}
        rows = [r.split() for r in Path("/proc/self/net/udp").read_text().splitlines()[1:]]
    except OSError:
        return "unknown"
    mine = [r[1] for r in rows if len(r) > 9 and r[9] in inodes]  # local address: hex IPv4 (little endian):port
    return "UDP on loopback" if mine and all(a.split(":")[0].endswith("7F") for a in mine) else "UDP"


def _answers_matched(node: Any, t: Train) -> bool:
    """Whether train ``t``'s track node says (latched ``track_status``) that its answer writers have matched every
    reader of them known on the graph (this recorder's among them): the writers' side of the recorder's match."""
    for topic in ("sleeper_response", "wheel_rail_response"):
        said = t.track.get(f"{topic}_readers_matched", "")
        if not said.isdigit() or int(said) < len(node.get_subscriptions_info_by_topic(t.spec.topic(topic))):
            return False
    return True


def _recorded(rec: Any, t: Train) -> bool:
    """Whether the bag holds every wheel-load message train ``t``'s vehicle published (its final figures) and an
    answer to each (a recorder that falls behind under load catches up before the bag is closed)."""
    c = rec.counts if rec is not None and t.spec.own_bag is None else {
        t.spec.topic(k): int(v) for k, v in t.recorder.items() if k in DATA_TOPICS}
    n = int(t.final.get("train.published", 0) or 0)
    if t.spec.topic("wheel_loads") not in c and t.spec.own_bag is None:  # not recorded: nothing to wait for
        return True
    w = c.get(t.spec.topic("wheel_loads"), 0)
    return bool(w >= n and all(c[t.spec.topic(x)] >= w for x in DATA_TOPICS[1:] if t.spec.topic(x) in c))


def _proc_key(t: Train, kind: str) -> str:
    """Key of a process in the exit codes: ``kind`` (root namespace, the demo) or ``<ns>/kind``."""
    return f"{t.spec.ns}/{kind}" if t.spec.ns else kind


def _close(rec: Any) -> dict[str, int]:
    """Close the bag, keeping what was recorded; a bag that cannot be finished is dropped (its counts kept)."""
    try:
        return dict(rec.close())
    except Exception:  # a bag that cannot be finished (full disk, ...): what the counts say, no bag
        counts = dict(rec.counts)
        rec.abort()
        return counts


def _per(a: float | None, b: float | None, n: int) -> float | None:
    return None if a is None or b is None or n <= 0 else round(1e6 * (b - a) / n, 1)


def _concurrency(trains: list[Train]) -> dict[str, Any]:
    """How many trains ran at once: the largest overlap of their [start, end] (system clock, from each vehicle's
    latched status), and the spread of their starts [s]."""
    spans = []
    for t in trains:
        s, e = int(t.status.get("train.start_ns", 0) or 0), int(t.status.get("train.end_ns", 0) or 0)
        if s:
            spans.append((s, e or time.time_ns()))
    events = sorted([(s, 1) for s, _ in spans] + [(e, -1) for _, e in spans])
    running = most = 0
    for _, d in events:
        running += d
        most = max(most, running)
    starts = [s for s, _ in spans]
    return {"max_running_at_once": most, "start_spread_s": (max(starts) - min(starts)) / 1e9 if starts else None}


def number(text: str) -> float | int | str:
    """A status value as a number where it is one (int, then float), else the text."""
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text
