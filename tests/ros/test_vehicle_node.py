"""The vehicle node in its own process over real DDS (loopback, own domain), with real signals.

- it waits for the track node (active and subscribed) before its clock starts, then runs its train closed loop;
- SIGINT and SIGTERM mid-train: exit 0 within 2 s (issue 12.4), no traceback;
- the track node killed (SIGKILL) mid-train: the vehicle goes on, says so, and uses the answers of a new
  track node when one comes;
- a namespaced pair (``-r __ns:=/train1``) works, and ignores a track node of another namespace;
- lifecycle: configure, activate, deactivate mid-train, activate again, cleanup, shutdown; an invalid set is
  refused at configure;
- a schedule of trains, one after another.

Wall time is asserted only for the 2-s exit the issue requires; every other wait is on a condition.
"""

from __future__ import annotations

import signal
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clientnode import ClientNode
from clm_msgs.msg import SleeperResponse, WheelLoads
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.experimental import EventsExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from clm_core.io.timebase import NS

START = 120.0  # a node process importing numba, building its model, discovering, on a loaded machine [s]
QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
VEHICLE = "clm_vehicle_node"


def stamp(raw: bytes) -> int:
    """Header stamp [ns] of serialized bytes (little- or big-endian CDR)."""
    sec, nsec = struct.unpack_from("<iI" if raw[1] == 1 else ">iI", raw, 4)
    return int(sec) * NS + int(nsec)


class Watcher(ClientNode):
    """An in-process client in the test's domain: wheel loads, answers and the vehicle's /diagnostics."""

    def __init__(self, domain_id: int, procs: list[subprocess.Popen[str]], ns: str = "") -> None:
        # EventsExecutor: ~3k callbacks/s, keeps up with loads and answers
        super().__init__(domain_id, procs, "clm_test_vehicle_watcher", executor=EventsExecutor, timeout=START)
        self.ns = ns
        self.loads: list[int] = []
        self.answers: list[int] = []
        self.diag: list[tuple[int, str, dict[str, str]]] = []  # (level, message, values) of the vehicle
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 50)

    def listen(self, answers: bool = False) -> None:
        """Subscribe to the wheel loads (a matched reader of the vehicle) and with ``answers`` to the answers."""
        self.node.create_subscription(WheelLoads, f"{self.ns}/wheel_loads", lambda r: self.loads.append(stamp(r)),
                                      QOS, raw=True)
        if answers:
            self.node.create_subscription(SleeperResponse, f"{self.ns}/sleeper_response",
                                          lambda r: self.answers.append(stamp(r)), QOS, raw=True)

    def _on_diag(self, msg: Any) -> None:
        for st in msg.status:
            if "vehicle simulator" in st.name and st.name.startswith(f"{self.ns}/{VEHICLE}"):
                level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
                self.diag.append((level, st.message, {kv.key: kv.value for kv in st.values}))

    def last(self) -> dict[str, str]:
        return self.diag[-1][2] if self.diag else {}

    def progress_note(self) -> str:
        return (f"({len(self.loads)} loads, {len(self.answers)} answers seen); vehicle diagnostics "
                f"{self.diag[-1:]}")


def start(module: str, env: dict[str, str], cwd: Path, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", f"clm_ros.{module}", "--ros-args", *args], env=env, cwd=cwd,
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def vehicle_args(*extra: str, duration: float = 1.0) -> list[str]:
    return ["-p", f"duration:={duration}", "-p", "diagnostics_period:=0.2", "-p", "answer_timeout:=0.5", *extra]


def stop(p: subprocess.Popen[str], sig: int = signal.SIGINT, timeout: float = 20.0) -> tuple[int, str, float]:
    """Signal ``p``; (exit code, output, seconds from the signal to the exit)."""
    t0 = time.monotonic()
    p.send_signal(sig)
    try:
        out = p.communicate(timeout=timeout)[0]
    except subprocess.TimeoutExpired:
        p.kill()
        out = p.communicate()[0]
        pytest.fail(f"{p.args} still running {timeout} s after signal {sig}\n{out}")
    return p.returncode, out, time.monotonic() - t0


@pytest.fixture
def graph(ros_domain_id: int, ros_env: dict[str, str], tmp_path: Path) -> Iterator[Any]:
    procs: list[subprocess.Popen[str]] = []
    watchers: list[Watcher] = []

    def make(ns: str = "") -> Watcher:
        w = Watcher(ros_domain_id, procs, ns)
        watchers.append(w)
        return w

    def run(module: str, *args: str) -> subprocess.Popen[str]:
        p = start(module, ros_env, tmp_path, *args)
        procs.append(p)
        return p

    try:
        yield make, run
    finally:
        for w in watchers:
            w.close()
        for p in procs:
            if p.poll() is None:
                p.kill()
            try:
                p.communicate(timeout=10)
            except (ValueError, subprocess.TimeoutExpired):  # output already read
                pass


def test_waits_for_the_track_node_then_runs_closed_loop(graph) -> None:  # type: ignore[no-untyped-def]
    make, run = graph
    w = make()
    w.listen()  # a reader of wheel_loads that is not the track node; the vehicle waits for it too (2 readers)
    vehicle = run("vehicle_node", *vehicle_args("-p", "trains:=1", "-p", "exit_when_done:=true",
                                                "-p", "wait_for_subscribers:=2", duration=3.0))
    w.wait_for(lambda: any("waiting for clm_track_node" in m for _, m, _ in w.diag), "the vehicle waiting")
    assert not w.loads  # a listener is not the track node: nothing published yet
    t_track = time.time_ns()
    track = run("track_node")
    w.wait_for(lambda: vehicle.poll() is not None, "the vehicle's train and exit", allow_exit=True)
    out = vehicle.communicate()[0]
    assert vehicle.returncode == 0, out
    w.wait_for(lambda: len(w.loads) >= 3001, "every wheel load", allow_exit=True, timeout=60)
    assert len(w.loads) == 3001
    # the clock started once the track node was there, and the first message was answered like any other
    assert w.loads[0] > t_track
    assert all(b - a == 10**6 for a, b in zip(w.loads, w.loads[1:]))
    final = [v for _, _, v in w.diag if v.get("final_train") == "1"][-1]
    assert final["train.published"] == final["train.answered"] == "3001"
    used, late, after = (int(final[k]) for k in ("train.feedback_used", "train.too_late", "train.after_last_step"))
    # every answer used as feedback but those too late (a loaded machine) and those after the last step
    assert used > 0 and used + late + after == 3001, final
    assert "train 1: published 3001 wheel-load messages" in out and "3001 answered" in out
    stop(track)  # its own exit is the track node's tests' business


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_mid_train_exits_0_within_2_s(graph, sig: int) -> None:  # type: ignore[no-untyped-def]
    make, run = graph
    w = make()
    w.listen()
    vehicle = run("vehicle_node", *vehicle_args("-p", "track_node:=''", duration=60.0))
    w.wait_for(lambda: len(w.loads) > 300, "wheel loads flowing")
    code, out, seconds = stop(vehicle, sig)
    print(f"{signal.Signals(sig).name}: exit {code} after {seconds:.3f} s")
    assert code == 0 and "Traceback" not in out, out
    assert seconds < 2.0, f"exit after {seconds:.2f} s\n{out}"
    assert "train 1 (stopped): published" in out


def test_track_node_killed_and_back(graph) -> None:  # type: ignore[no-untyped-def]
    make, run = graph
    w = make()
    w.listen()
    vehicle = run("vehicle_node", *vehicle_args(duration=600.0))
    first = run("track_node")
    answered = lambda: int(w.last().get("train.answered", 0))  # noqa: E731
    w.wait_for(lambda: answered() > 300, "answers of the first track node")
    first.expected_exit = True  # type: ignore[attr-defined]
    first.kill()  # SIGKILL: no goodbye on the graph
    first.communicate()
    w.wait_for(lambda: w.diag[-1][0] == 1 and "no answer" in w.diag[-1][1], "the vehicle reporting the silence")
    n_loads, n_answered = len(w.loads), answered()
    w.wait_for(lambda: len(w.loads) > n_loads + 500, "wheel loads going on without a track node")
    assert vehicle.poll() is None
    second = run("track_node")
    w.wait_for(lambda: answered() > n_answered + 300 and "no answer" not in w.diag[-1][1],
               "answers of the second track node")
    code, out, seconds = stop(vehicle, signal.SIGTERM)
    print(f"SIGTERM with a track node back: exit {code} after {seconds:.3f} s")
    assert code == 0 and "Traceback" not in out, out
    assert seconds < 2.0, f"exit after {seconds:.2f} s\n{out}"
    assert "no answer from the track node" in out and "answers again" in out, out
    stop(second)


def test_namespaced_pair(graph) -> None:  # type: ignore[no-untyped-def]
    make, run = graph
    w = make("/train1")
    w.listen()
    root = make("")
    root.listen(answers=True)
    other = run("track_node")  # a track node outside the namespace: not the one the vehicle waits for
    vehicle = run("vehicle_node", "-r", "__ns:=/train1", *vehicle_args("-p", "trains:=1", "-p", "exit_when_done:=true",
                                                                       "-p", "wait_for_subscribers:=2", duration=0.5))
    w.wait_for(lambda: any("waiting for clm_track_node" in m for _, m, _ in w.diag), "the vehicle waiting")
    assert not w.loads
    track = run("track_node", "-r", "__ns:=/train1")
    w.wait_for(lambda: vehicle.poll() is not None, "the namespaced train and exit", allow_exit=True)
    assert vehicle.returncode == 0, vehicle.communicate()[0]
    final = [v for _, _, v in w.diag if v.get("final_train") == "1"][-1]
    assert final["train.answered"] == "501" and int(final["train.feedback_used"]) > 0  # the namespaced track node
    w.wait_for(lambda: len(w.loads) >= 501, "the namespaced wheel loads seen here", allow_exit=True, timeout=60)
    assert len(w.loads) == 501
    root.exec.spin_once(timeout_sec=0.1)
    assert not root.loads and not root.answers  # nothing on the topics outside the namespace
    stop(track)
    stop(other)


def test_lifecycle(graph) -> None:  # type: ignore[no-untyped-def]
    make, run = graph
    w = make()
    w.listen()
    node = f"/{VEHICLE}"
    vehicle = run("vehicle_node", *vehicle_args("-p", "autostart:=false", "-p", "track_node:=''", duration=60.0))
    assert w.state(node) == "unconfigured"
    assert w.transition(node, "configure") and w.state(node) == "inactive"
    assert not w.loads  # configured, not active: nothing published
    assert w.transition(node, "activate") and w.state(node) == "active"
    w.wait_for(lambda: len(w.loads) > 200, "wheel loads while active")
    assert w.transition(node, "deactivate") and w.state(node) == "inactive"
    n = len(w.loads)
    w.wait_for(lambda: w.last().get("state") == "inactive", "diagnostics of the inactive node")
    assert len(w.loads) <= n + 1  # the train stopped (one message may have been on its way)
    assert w.transition(node, "activate")
    w.wait_for(lambda: len(w.loads) > n + 200, "a new train after activating again")
    restarted = w.loads[n + 1:]
    assert all(b - a == 10**6 for a, b in zip(restarted, restarted[1:]))  # its own clock, 1 kHz
    assert w.transition(node, "deactivate")
    assert w.transition(node, "cleanup") and w.state(node) == "unconfigured"
    assert w.transition(node, "unconfigured_shutdown") and w.state(node) == "finalized"
    code, out, _ = stop(vehicle)
    assert code == 0 and "train 1 (stopped)" in out and "train 2 (stopped)" in out, out


def test_invalid_parameters_refused_at_configure(graph) -> None:  # type: ignore[no-untyped-def]
    make, run = graph
    bad = run("vehicle_node", "-p", "vehicle:=no_such_vehicle")
    bad.expected_exit = True  # type: ignore[attr-defined]
    out = bad.communicate(timeout=START)[0]
    assert bad.returncode == 2 and "configure refused" in out and "no_such_vehicle" in out, out
    w = make()
    node = f"/{VEHICLE}"
    idle = run("vehicle_node", "-p", "autostart:=false", "-p", "rate:=300.0")  # 1/(rate dt) not whole
    assert not w.transition(node, "configure") and w.state(node) == "unconfigured"
    code, out, _ = stop(idle)
    assert code == 0 and "must be a whole number" in out, out


def test_trains_one_after_another(graph) -> None:  # type: ignore[no-untyped-def]
    make, run = graph
    w = make()
    w.listen()
    vehicle = run("vehicle_node", *vehicle_args("-p", "track_node:=''", "-p", "trains:=2", "-p", "train_pause:=0.5",
                                                "-p", "exit_when_done:=true", "-p", "ack_timeout:=0.2", duration=0.3))
    w.wait_for(lambda: vehicle.poll() is not None, "two trains and the exit", allow_exit=True)
    out = vehicle.communicate()[0]
    assert vehicle.returncode == 0, out
    w.wait_for(lambda: len(w.loads) >= 602, "every wheel load", allow_exit=True, timeout=30)
    gaps = [b - a for a, b in zip(w.loads, w.loads[1:])]
    assert len(w.loads) == 602 and gaps.count(10**6) == 600
    assert max(gaps) >= 0.5 * NS  # the pause between the trains, on the stamps too
    assert w.last().get("trains_done") == "2" and "done: 2 train(s)" in w.diag[-1][1]


def test_waits_for_the_track_node_s_own_word_that_it_matched(graph, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    """A stand-in named ``clm_track_node`` in this process: on the graph, subscribed and answering, but its latched
    ``track_status`` (said as the track node says it: :func:`clm_ros.latched.follow`, once per change) says its
    subscription has matched no wheel-load publisher yet: no train starts, however long it waits (a clm track
    node's word is always awaited); once it says 1, the train starts (discovery is two-sided: the vehicle waits
    for the reader's side too).

    (Until 2026-12-04 the stand-in said it on /diagnostics, which the vehicle no longer reads: it then took the
    stand-in for a foreign track node and started after its 5-s fallback, which a loaded machine could reach
    within the test's 3-s window: stress run 10 of 10 at d3febfe.)"""
    from clm_msgs.msg import WheelRailResponse
    from clm_ros.latched import TRACK_STATUS, follow
    from clm_ros.vehicle_link import HANDSHAKE_TIMEOUT_NS

    make, run = graph
    w = make()
    stand_in = ClientNode(ros_domain_id, [], "clm_track_node", executor=EventsExecutor, timeout=START)
    try:
        got: list[int] = []
        stand_in.node.create_subscription(WheelLoads, "/wheel_loads", lambda r: got.append(stamp(r)), QOS, raw=True)
        stand_in.node.create_publisher(WheelRailResponse, "/wheel_rail_response", QOS)
        matched = ["0"]
        follow(stand_in.node, TRACK_STATUS, "track-soil model",
               lambda: (0, "active", {"state": "active", "wheel_load_publishers_matched": matched[0]}), period=0.1)
        vehicle = run("vehicle_node", *vehicle_args("-p", "trains:=1", "-p", "answer_timeout:=5.0", duration=0.5))
        w.wait_for(lambda: any("waiting for clm_track_node" in m for _, m, _ in w.diag), "the vehicle waiting")
        # graph and matching done long before; past the fallback for a track node without a word, too
        t_end = time.monotonic() + HANDSHAKE_TIMEOUT_NS / NS + 2.0
        while time.monotonic() < t_end:
            stand_in.exec.spin_once(timeout_sec=0.02)
            w.exec.spin_once(timeout_sec=0.0)
        assert not got and "waiting for clm_track_node" in w.diag[-1][1], w.diag[-1]
        matched[0] = "1"
        stand_in.wait_for(lambda: len(got) >= 501, "the train once the stand-in said it matched", timeout=60)
        assert all(b - a == 10**6 for a, b in zip(got, got[1:]))  # from its first message on, nothing lost
        assert vehicle.poll() is None
    finally:
        stand_in.close()


def _hold(w: Watcher, seconds: float) -> None:
    """Spin the watcher for ``seconds`` (a process stopped meanwhile; no condition to wait on)."""
    t_end = time.monotonic() + seconds
    w.wait_for(lambda: time.monotonic() >= t_end, f"{seconds:g} s passing")


def test_stopped_vehicle_does_not_blame_the_track_node(graph) -> None:  # type: ignore[no-untyped-def]
    """Issue 26.9: the vehicle's process stopped (SIGSTOP) for 3 answer timeouts, then continued. Nothing was
    outstanding while it stood still: it catches up, its answers flow, and it never reports the track node silent
    (before: 'no answer from the track node' at once on resuming, the silence measured from the last answer).

    The answer timeout is 1.5 s here, not the 0.5 s of the other tests: the catch-up is a burst of 4500 messages,
    and on the 2-core machine with three test files running (one compiling its kernels) the answers once stopped
    for more than 0.5 s in it (stress run 1 at bf90608): a true silence, not the one this test is about."""
    make, run = graph
    w = make()
    w.listen()
    vehicle = run("vehicle_node", *vehicle_args("-p", "answer_timeout:=1.5", duration=600.0))
    track = run("track_node")
    answered = lambda: int(w.last().get("train.answered", 0))  # noqa: E731
    w.wait_for(lambda: answered() > 500, "answers flowing")
    vehicle.send_signal(signal.SIGSTOP)
    try:
        _hold(w, 4.5)
    finally:
        vehicle.send_signal(signal.SIGCONT)
    n = answered()
    w.wait_for(lambda: answered() > n + 4500, "the train caught up and answered after the stop")
    code, out, _ = stop(vehicle, signal.SIGTERM)
    assert code == 0 and "Traceback" not in out, out
    blamed = [m for _, m, _ in w.diag if "no answer" in m]
    print(f"stopped 4.5 s: {answered()} answered, warnings {blamed[:1]}")
    assert not blamed and "no answer from the track node" not in out, (blamed[:3], out[-2000:])
    stop(track)


def test_silent_track_node_still_reported(graph) -> None:  # type: ignore[no-untyped-def]
    """A track node that is there but silent (SIGSTOP: on the graph, matched, no answer) while the vehicle runs is
    reported after answer_timeout (WARN, logged once); when it continues, its answers are used again."""
    make, run = graph
    w = make()
    w.listen()
    vehicle = run("vehicle_node", *vehicle_args(duration=600.0))
    track = run("track_node")
    answered = lambda: int(w.last().get("train.answered", 0))  # noqa: E731
    w.wait_for(lambda: answered() > 500, "answers flowing")
    track.send_signal(signal.SIGSTOP)
    try:
        w.wait_for(lambda: bool(w.diag) and w.diag[-1][0] == 1 and "no answer" in w.diag[-1][1],
                   "the vehicle reporting the silent track node")
    finally:
        track.send_signal(signal.SIGCONT)
    n = answered()
    w.wait_for(lambda: answered() > n + 300 and "no answer" not in w.diag[-1][1], "answers again, WARN cleared")
    code, out, _ = stop(vehicle, signal.SIGTERM)
    assert code == 0 and out.count("no answer from the track node") == 1 and "answers again" in out, out
    stop(track)
