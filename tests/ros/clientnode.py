"""An in-process rclpy node of the test, in a context of its own, that talks to node processes and watches them.

:class:`ClientNode` is the base of the tests' clients (calibration, vehicle,
packaging): its own ``Context`` in the test's domain, one executor spun by
:meth:`ClientNode.wait_for`, which fails early, with the process's output,
when a watched node process has exited.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable, Iterable
from typing import Any

import pytest
import rclpy
from clm_ros.reliable_client import RESEND_S, Until, answered, transition_confirmed
from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor

from tests.clitools import ask_for_stacks

#: Seconds after which a query (get_state, parameters) is sent again when no answer has come (the race and its
#: remedies: clm_ros.reliable_client, docs/ros-nodes.md "Service and action races"). Only for requests that change
#: nothing: a transition sent twice would be a second transition (clm_ros.reliable_client.transition_confirmed).
RESEND_QUERY = RESEND_S

#: ``lifecycle_msgs/Transition`` ids by label (the labels of clm_ros.reliable_client.TRANSITION_GOALS).
TRANSITION_IDS = {"configure": 1, "cleanup": 2, "activate": 3, "deactivate": 4, "unconfigured_shutdown": 5,
                  "inactive_shutdown": 6, "active_shutdown": 7}


def answer(cli: Any, request: Any, until: Callable[[Callable[[], bool], float], None], timeout: float,
           resend_after: float | None = None) -> Any:
    """The response of ``cli`` to ``request``; sent again every ``resend_after`` s while unanswered (None: once)
    (:func:`clm_ros.reliable_client.answered`; :class:`TimeoutError` after ``timeout`` s in all)."""
    return answered(cli, request, until, timeout, resend_after)


class ClientNode:
    """rclpy node ``name`` in ``domain_id`` (loopback), spun in the test's thread.

    Parameters
    ----------
    domain_id : int
    procs : list of subprocess.Popen
        Node processes watched while waiting (the caller may append to the
        list later). A process may exit without failing the wait when its
        return code is in ``ok_exits`` or it has ``expected_exit = True``.
    name : str
        Node name.
    executor : callable
        Executor class (default ``SingleThreadedExecutor``).
    ok_exits : iterable of int
        Return codes that are not a failure while waiting.
    timeout : float
        Default timeout of :meth:`wait_for` and :meth:`call` [s].
    spin_period : float
        ``spin_once`` timeout of :meth:`wait_for` [s].
    """

    def __init__(self, domain_id: int, procs: list[Any], name: str,
                 executor: Callable[..., Executor] = SingleThreadedExecutor, ok_exits: Iterable[int] = (),
                 timeout: float = 60.0, spin_period: float = 0.02) -> None:
        self.procs = procs
        self.ok_exits = frozenset(ok_exits)
        self.timeout = timeout
        self.spin_period = spin_period
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = rclpy.create_node(name, context=self.ctx)
        self.exec = executor(context=self.ctx)
        self.exec.add_node(self.node)

    def progress_note(self) -> str:
        """What the client has seen so far, added to a timeout's message (override)."""
        return ""

    def _check_procs(self, what: str) -> None:
        for p in self.procs:
            if p.poll() is not None and p.returncode not in self.ok_exits and not getattr(p, "expected_exit", False):
                out, err = p.communicate()
                pytest.fail(f"{p.args} exited with {p.returncode} while waiting for {what}\n{out}\n{err or ''}")

    def _outputs(self) -> str:
        """The output of the watched processes. Those still running are asked for every thread's stack first
        (``kill -USR1``, :mod:`clm_core.stacks`: a clm node prints them to stderr and goes on), then killed: the
        wait failed, and a silent node's stacks say where it is."""
        text = []
        ask_for_stacks(self.procs)
        for p in self.procs:
            if p.poll() is None:
                p.kill()
            try:
                out, err = p.communicate(timeout=10)
            except (ValueError, subprocess.TimeoutExpired):  # already read, or stuck
                continue
            text.append(f"\n--- {p.args} (exit {p.returncode}):\n{out}\n{err or ''}")
        return "".join(text)

    def wait_for(self, cond: Callable[[], Any], what: str, timeout: float | None = None,
                 allow_exit: bool = False) -> None:
        """Spin until ``cond()``; fail after ``timeout`` s (default :attr:`timeout`) or, unless ``allow_exit``,
        when a watched process exits."""
        timeout = self.timeout if timeout is None else timeout
        t0 = time.monotonic()
        while not cond():
            if not allow_exit:
                self._check_procs(what)
            if time.monotonic() - t0 > timeout:
                pytest.fail(f"{what}: not within {timeout} s {self.progress_note()}".rstrip() + self._outputs())
            self.exec.spin_once(timeout_sec=self.spin_period)

    def _exchange(self, srv_type: Any, name: str, timeout: float | None,
                  talk: Callable[[Any, Until, float], Any]) -> Any:
        """``talk(client, until, timeout)`` on a client of service ``name`` once the service is there; its
        ``TimeoutError`` fails the test with the progress note and the watched processes' output."""
        cli = self.node.create_client(srv_type, name)
        timeout = self.timeout if timeout is None else timeout
        try:
            self.wait_for(cli.service_is_ready, f"service {name}", timeout)

            def until(done: Callable[[], bool], seconds: float) -> None:
                end = time.monotonic() + seconds
                self.wait_for(lambda: done() or time.monotonic() > end, f"answer of {name}", seconds + 1.0)

            try:
                return talk(cli, until, timeout)
            except TimeoutError as exc:
                pytest.fail(f"{exc} {self.progress_note()}".rstrip() + self._outputs())
        finally:
            self.node.destroy_client(cli)

    def call(self, srv_type: Any, name: str, request: Any, timeout: float | None = None,
             resend_after: float | None = None) -> Any:
        """Call service ``name`` once it is there; the response (``resend_after``: see :func:`answer`)."""
        return self._exchange(srv_type, name, timeout,
                              lambda cli, until, left: answer(cli, request, until, left, resend_after))

    def state(self, node: str) -> str:
        """Lifecycle state label of ``node`` (``get_state``, a query: sent again while unanswered)."""
        from lifecycle_msgs.srv import GetState

        return str(self.call(GetState, f"{node}/get_state", GetState.Request(), resend_after=RESEND_QUERY)
                   .current_state.label)

    def transition(self, node: str, name: str, timeout: float | None = None) -> bool:
        """Lifecycle transition ``name`` (``configure``, ``activate``, ...) of ``node``; whether it succeeded. A lost
        answer is settled by the node's state, never by sending the transition again blindly
        (:func:`clm_ros.reliable_client.transition_confirmed`)."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        req = ChangeState.Request(transition=Transition(id=TRANSITION_IDS[name]))
        return bool(self._exchange(ChangeState, f"{node}/change_state", timeout, lambda cli, until, left: (
            transition_confirmed(lambda: cli.call_async(req), lambda: self.state(node), name, until, left))))

    def close(self) -> None:
        """Shut the executor, the node and the context down."""
        self.exec.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
