"""An in-process ROS client that drives a track node running in another process.

Publishes wheel loads (typed messages or serialized bytes) with flow control
(at most ``max_in_flight`` messages ahead of the answers) or as one burst,
collects the answers through raw subscriptions decoded with the numpy CDR
codec (cheap enough to keep up with a node working off a backlog), the
``/diagnostics`` and optional extra topics, drives the node's lifecycle and
parameters through its services, and waits on discovery (never on fixed
sleeps).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import rclpy
from clientnode import RESEND_QUERY, answer
from clm_msgs.msg import SleeperResponse, WheelLoads, WheelRailResponse
from clm_ros.reliable_client import transition_confirmed
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from clm_core.io.messages import decode_sleeper_response, decode_wheel_rail_response

QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000, reliability=ReliabilityPolicy.BEST_EFFORT)
NODE = "/clm_track_node"

TRANSITIONS = {
    "configure": Transition.TRANSITION_CONFIGURE, "cleanup": Transition.TRANSITION_CLEANUP,
    "activate": Transition.TRANSITION_ACTIVATE, "deactivate": Transition.TRANSITION_DEACTIVATE,
    "unconfigured_shutdown": Transition.TRANSITION_UNCONFIGURED_SHUTDOWN,
    "inactive_shutdown": Transition.TRANSITION_INACTIVE_SHUTDOWN,
    "active_shutdown": Transition.TRANSITION_ACTIVE_SHUTDOWN,
}


class Driver:
    """Talk to a track node over DDS in ``domain_id`` (loopback only).

    Parameters
    ----------
    domain_id : int
    ns : str
        Namespace of the node's topics.
    wheel_qos : QoSProfile or None
        QoS of the wheel-load publisher (default reliable keep-all); None: no
        publisher (another process feeds the node).
    """

    def __init__(self, domain_id: int, ns: str = "", wheel_qos: QoSProfile | None = QOS) -> None:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = rclpy.create_node("clm_test_driver", context=self.ctx)
        self.exec = SingleThreadedExecutor(context=self.ctx)
        self.exec.add_node(self.node)
        self.ns = ns
        # readers this wheel-load writer has matched since it exists (the middleware's matched events); a
        # deactivation sets the floor a new subscription of the node must pass (wait_discovery)
        self.readers_matched_total = 0
        self._readers_floor = 0
        self.pub = None if wheel_qos is None else self.wheel_load_publisher(wheel_qos)
        self.sleepers: list[Any] = []
        self.wheels: list[Any] = []
        self.diagnostics: list[Any] = []
        self.received_at: list[float] = []
        self.node.create_subscription(SleeperResponse, f"{ns}/sleeper_response", self._on_sleepers, QOS, raw=True)
        self.node.create_subscription(WheelRailResponse, f"{ns}/wheel_rail_response",
                                      lambda b: self.wheels.append(decode_wheel_rail_response(b)), QOS, raw=True)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 100)
        self._clients: dict[str, Any] = {}

    def wheel_load_publisher(self, qos: QoSProfile) -> Any:
        """A wheel-load writer with ``qos`` whose matched readers :meth:`wait_discovery` follows (assign it to
        ``pub``)."""
        return self.node.create_publisher(WheelLoads, f"{self.ns}/wheel_loads", qos,
                                          event_callbacks=PublisherEventCallbacks(matched=self._on_matched))

    def _on_matched(self, info: Any) -> None:
        self.readers_matched_total = int(info.total_count)

    def _on_sleepers(self, raw: bytes) -> None:
        self.sleepers.append(decode_sleeper_response(raw))
        self.received_at.append(time.monotonic())

    def _on_diagnostics(self, msg: Any) -> None:
        if any(st.name.startswith(f"{self.ns}{NODE}: ") for st in msg.status):
            self.diagnostics.append((time.monotonic(), msg))

    def subscribe(self, msg_type: Any, topic: str, qos: QoSProfile | int = QOS, raw: bool = False) -> list[Any]:
        """Collect ``topic`` into the returned list."""
        out: list[Any] = []
        self.node.create_subscription(msg_type, topic, out.append, qos, raw=raw)
        return out

    def spin(self, seconds: float = 0.01) -> None:
        self.exec.spin_once(timeout_sec=seconds)

    def wait_for(self, cond: Callable[[], Any], timeout: float, what: str) -> None:
        t0 = time.monotonic()
        while not cond():
            if time.monotonic() - t0 > timeout:
                raise TimeoutError(f"{what} not within {timeout} s")
            self.spin(0.02)

    def wait_discovery(self, timeout: float = 30.0) -> None:
        """Until the node subscribes to wheel_loads (it is active) and its answers reach this driver; with a
        publisher here, also until the node's subscription has matched it (its ``/diagnostics`` say so):
        discovery is two-sided, and what a writer publishes before the reader has matched it may be lost to
        a volatile reader (seen twice on a starved core, before this wait: 0 answers to a 2000-message burst).
        After a deactivation (:meth:`transition`) this writer must have matched a reader it had not matched
        before it: the node's new subscription, not the old one whose leaving has not reached this process yet
        (the writer's reader count alone cannot tell them apart)."""
        topic = f"{self.ns}/wheel_loads"
        self.wait_for(
            lambda: ((self.pub.get_subscription_count() if self.pub else self.node.count_subscribers(topic)) >= 1
                     and self.node.count_publishers(f"{self.ns}/sleeper_response") >= 1
                     and self.node.count_publishers(f"{self.ns}/wheel_rail_response") >= 1),
            timeout, "discovery of the track node")
        if self.pub is not None:
            self.wait_for(lambda: self.readers_matched_total > self._readers_floor, timeout,
                          f"this driver's wheel-load writer matching the node's subscription (matched "
                          f"{self.readers_matched_total} reader(s) in all, {self._readers_floor} before the "
                          f"deactivation; a writer made by wheel_load_publisher?)")
            t_end = time.monotonic() + timeout
            while int(self.latest_diagnostics(timeout).get("wheel_load_publishers_matched", "0")) < 1:
                if time.monotonic() > t_end:
                    raise TimeoutError(f"the track node matching this driver's wheel-load publisher not within "
                                       f"{timeout} s")

    def send(self, msgs: Iterable[Any], expected_answers: int, max_in_flight: int = 50, timeout: float = 60.0) -> None:
        """Publish ``msgs`` keeping at most ``max_in_flight`` unanswered; wait for ``expected_answers`` answers."""
        sent = 0
        base = len(self.sleepers)
        base_w = len(self.wheels)
        t0 = time.monotonic()
        for m in msgs:
            while sent - (len(self.sleepers) - base) >= max_in_flight and time.monotonic() - t0 < timeout:
                self.spin(0.005)
            self.pub.publish(m)
            sent += 1
            self.spin(0)
        self.wait_answers(base + expected_answers, base_w + expected_answers, timeout)

    def burst(self, msgs: Iterable[Any], expected_answers: int, timeout: float = 120.0,
              stopped_pid: int | None = None) -> None:
        """Publish every message at once (a backlog at the node); wait for ``expected_answers`` answers.

        ``stopped_pid``: the node's process, stopped (SIGSTOP) while the messages are published and continued
        (SIGCONT) after, so the backlog is there however slowly this process publishes (on a loaded machine a
        node under SCHED_FIFO otherwise keeps up with it message by message: one message per batch)."""
        base, base_w = len(self.sleepers), len(self.wheels)
        if stopped_pid is not None:
            os.kill(stopped_pid, signal.SIGSTOP)
        try:
            for m in msgs:
                self.pub.publish(m)
        finally:
            if stopped_pid is not None:
                os.kill(stopped_pid, signal.SIGCONT)
        self.wait_answers(base + expected_answers, base_w + expected_answers, timeout)

    def wait_answers(self, n_sleepers: int, n_wheels: int, timeout: float) -> None:
        self.wait_for(lambda: len(self.sleepers) >= n_sleepers and len(self.wheels) >= n_wheels, timeout,
                      f"{n_sleepers} answers (have {len(self.sleepers)}, {len(self.wheels)})")

    def drain(self, rounds: int = 5000) -> None:
        """Run the callbacks of what is already received (one per ``spin_once``), until a few rounds bring
        nothing new to the answers and diagnostics."""
        quiet = 0
        for _ in range(rounds):
            before = len(self.sleepers) + len(self.wheels) + len(self.diagnostics)
            self.exec.spin_once(timeout_sec=0)
            quiet = quiet + 1 if len(self.sleepers) + len(self.wheels) + len(self.diagnostics) == before else 0
            if quiet >= 3:
                return

    def latest_diagnostics(self, timeout: float = 10.0) -> dict[str, str]:
        """The next ``/diagnostics`` of the node published from now on (older ones still queued are taken
        first), as ``{key: value}`` plus ``_level`` and ``_message``."""
        self.drain()
        n = len(self.diagnostics)
        self.wait_for(lambda: len(self.diagnostics) > n, timeout, "a /diagnostics message")
        return status_dict(self.diagnostics[-1][1])

    # ------------------------------------------------------------------ services

    def call(self, srv_type: Any, name: str, request: Any, timeout: float = 60.0,
             resend_after: float | None = None) -> Any:
        """Call the node's service ``name`` (e.g. ``change_state``) and return the response (``resend_after``:
        see :func:`clientnode.answer`)."""
        cli = self._clients.get(name)
        if cli is None:
            cli = self._clients[name] = self.node.create_client(srv_type, f"{NODE}/{name}")
        self.wait_for(cli.service_is_ready, timeout, f"service {name}")

        def until(done: Callable[[], bool], seconds: float) -> None:
            end = time.monotonic() + seconds
            while not done() and time.monotonic() < end:
                self.spin(0.02)

        return answer(cli, request, until, timeout, resend_after)

    def transition(self, name: str, timeout: float = 60.0) -> bool:
        """Trigger lifecycle transition ``name`` (configure, activate, ..., active_shutdown)."""
        req = ChangeState.Request(transition=Transition(id=TRANSITIONS[name]))
        cli = self._clients.get("change_state")
        if cli is None:
            cli = self._clients["change_state"] = self.node.create_client(ChangeState, f"{NODE}/change_state")
        self.wait_for(cli.service_is_ready, timeout, "service change_state")

        def until(done: Callable[[], bool], seconds: float) -> None:
            end = time.monotonic() + seconds
            while not done() and time.monotonic() < end:
                self.spin(0.02)

        # a lost answer: the node's state says whether the transition happened (clm_ros.reliable_client)
        done = transition_confirmed(lambda: cli.call_async(req), self.state, name, until, timeout)
        if done and (name == "deactivate" or name.endswith("shutdown")):
            self._readers_floor = self.readers_matched_total  # the node's subscription is gone
        return done

    def state(self) -> str:
        """The node's lifecycle state label."""
        return str(self.call(GetState, "get_state", GetState.Request(), resend_after=RESEND_QUERY)
                   .current_state.label)

    def set_double(self, name: str, value: float) -> Any:
        """Set one DOUBLE parameter; the ``SetParametersResult``."""
        req = SetParameters.Request(parameters=[Parameter(name=name, value=ParameterValue(
            type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
        return self.call(SetParameters, "set_parameters", req, resend_after=RESEND_QUERY).results[0]  # idempotent

    def close(self) -> None:
        self.exec.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def status_dict(msg: Any) -> dict[str, str]:
    """The node's status of a DiagnosticArray as ``{key: value}`` plus ``_level`` and ``_message``."""
    st = msg.status[0]
    level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
    return {kv.key: kv.value for kv in st.values} | {"_level": str(level), "_message": st.message}


NODE_SCRIPT = "import sys\nfrom clm_ros.track_node import main\nsys.exit(main(sys.argv))\n"


class NodeRun:
    """A track-node process and the driver talking to it; ``err`` (its log) once it has exited."""

    def __init__(self, proc: subprocess.Popen[str], drv: Driver) -> None:
        self.proc = proc
        self.drv = drv
        self.err = ""


@contextlib.contextmanager
def track_node(ros_python: Any, domain_id: int, *params: str, discover: bool = True, script: str = NODE_SCRIPT,
               **driver_options: Any) -> Iterator[NodeRun]:
    """Start the track node (``-p`` ``params``, diagnostics every 0.1 s; ``script`` runs it) and a
    :class:`Driver`; at the end close the driver, SIGTERM the node and check it exits 0 (its log in
    ``NodeRun.err``)."""
    args = ["--ros-args", "-p", "diagnostics_period:=0.1"]
    for p in params:
        args += ["-p", p]
    proc = ros_python.spawn(script, args, name="track_node")
    run = NodeRun(proc, Driver(domain_id, **driver_options))
    try:
        if discover:
            run.drv.wait_discovery()
        yield run
    except BaseException:
        run.drv.close()
        proc.terminate()
        _, err = ros_python.wait(proc, 20)
        print(f"--- track node log (exit {proc.returncode})\n{err}")  # shown by pytest with the failure
        raise
    run.drv.close()
    proc.terminate()
    _, run.err = ros_python.wait(proc, 20)
    assert proc.returncode == 0, f"track node exit {proc.returncode} after SIGTERM:\n{run.err}"
