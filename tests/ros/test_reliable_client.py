"""Clients that survive a lost response (clm_ros.reliable_client) against real servers over DDS.

A response is lost here the way the middleware loses it (issue 21: "failed to
send response (timeout): client will not receive response"): the request
reaches the server and is served, and its answer never reaches the caller
(the test drops the client's pending request, so a late answer is ignored,
as rclpy ignores an answer to a request it no longer waits for).

- an action goal whose response is lost: accepted all the same, found through
  the goal status topic, run exactly once (the server counts its executions),
  its result delivered; the same with its result response and a cancel lost;
- a goal refused by the server stays refused;
- a lifecycle transition whose answer is lost: confirmed by the node's state,
  taken once (the track node's own log says how often it activated);
- a parameter query whose first answer is lost: sent again, answered.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from typing import Any

import pytest

pytest.importorskip("clm_msgs.action", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from action_msgs.msg import GoalStatus
from clientnode import ClientNode
from clm_msgs.action import Calibrate
from clm_ros.reliable_client import GoalTracker, answered, transition_confirmed
from rclpy.action import ActionClient
from rclpy.task import Future

from tests.clitools import wait_or_stacks

NAME = "/clm_test/calibrate"
#: What the track node logs once per configure.
CONFIGURED = "]: configured: "
#: A real action server (rclpy ActionServer) that runs each goal for 0.3 s (1.5 s with ``slow`` in the bag path),
#: refuses goals whose bag path says ``refuse``, and prints each execution.
SERVER = """
import faulthandler, signal, sys, time, rclpy
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.executors import MultiThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from clm_msgs.action import Calibrate
from clm_ros.node_main import StopSignals, exit_process

# the test's SIGINT ends the loop below as it ends a clm node (clm_ros.node_main): rclpy.spin's own SIGINT handling
# followed by the interpreter's exit hung in 2 of 10 stress runs (30 s, no output)
faulthandler.register(signal.SIGUSR1, all_threads=True)  # the test asks for the stacks of a server that hangs
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
stop = StopSignals()
stop.install(interrupt=False)
node = rclpy.create_node("clm_test_action_server")
runs = []

def execute(goal):
    runs.append(goal.request.bag_path)
    print(f"executing {len(runs)} {goal.request.bag_path}", flush=True)
    end = time.monotonic() + (1.5 if "slow" in goal.request.bag_path else 0.3)
    while time.monotonic() < end:
        if goal.is_cancel_requested:
            goal.canceled()
            return Calibrate.Result(success=False, message="canceled")
        time.sleep(0.01)
    goal.succeed()
    return Calibrate.Result(success=True, message=f"run {len(runs)}")

ActionServer(node, Calibrate, sys.argv[1], execute,
             goal_callback=lambda g: GoalResponse.REJECT if "refuse" in g.bag_path else GoalResponse.ACCEPT,
             cancel_callback=lambda _g: CancelResponse.ACCEPT)
executor = MultiThreadedExecutor()
executor.add_node(node)
print("ready", flush=True)
while not stop.event.is_set():
    executor.spin_once(timeout_sec=0.05)
faulthandler.dump_traceback_later(20)  # a teardown that hangs shows its stacks before the test's 30-s kill
executor.shutdown(timeout_sec=5)
node.destroy_node()
rclpy.try_shutdown()
exit_process(0)
"""


def lose_first(obj: Any, method: str, drop: Callable[[Future], None]) -> list[int]:
    """Make the first call of ``obj.method`` lose its response: the request goes out, ``drop`` makes the client
    forget it (its answer, when it comes, is ignored), the caller gets a future that never completes. Returns a
    list that counts the calls."""
    real = getattr(obj, method)
    calls: list[int] = []

    def wrapped(*args: Any, **kwargs: Any) -> Future:
        fut = real(*args, **kwargs)
        calls.append(1)
        if len(calls) == 1:
            drop(fut)
            return Future()
        return fut

    setattr(obj, method, wrapped)
    return calls


class Client(ClientNode):
    def __init__(self, domain_id: int, procs: list[Any]) -> None:
        super().__init__(domain_id, procs, "clm_test_reliable_client", timeout=60.0, spin_period=0.01)
        self.action = ActionClient(self.node, Calibrate, NAME)
        self.goals = GoalTracker(self.node, self.action, self.until)

    def until(self, done: Callable[[], bool], seconds: float) -> None:
        end = time.monotonic() + seconds
        self.wait_for(lambda: done() or time.monotonic() > end, "an answer", seconds + 5.0)


@pytest.fixture
def server(ros_python: Any) -> Any:
    proc = ros_python.spawn(SERVER, [NAME], name="action_server")
    assert proc.stdout.readline().strip() == "ready", ros_python.wait(proc, 5)
    return proc


def _runs(proc: Any) -> list[str]:
    """Stop the server (SIGINT) and return its executions; one that does not exit within 30 s fails the test with
    every thread's stack (SIGUSR1: faulthandler) and its output."""
    proc.send_signal(signal.SIGINT)
    out, _ = wait_or_stacks(proc, 30, "the action server after SIGINT")
    return [line for line in out.splitlines() if line.startswith("executing")]


def test_goal_with_lost_response_is_confirmed_and_run_once(server: Any, ros_domain_id: int) -> None:
    c = Client(ros_domain_id, [server])
    try:
        c.wait_for(c.action.server_is_ready, "action server")
        sends = lose_first(c.action, "send_goal_async", c.action._remove_pending_goal_request)
        handle = c.goals.send(Calibrate.Goal(bag_path="lost-goal-response"), timeout=60)
        assert handle.accepted
        # its acceptance was read from the status topic: the tracker knows its status from then on (rclpy's
        # handle, made after that status message, hears only later ones)
        assert c.goals.status_of(handle) in (GoalStatus.STATUS_ACCEPTED, GoalStatus.STATUS_EXECUTING,
                                             GoalStatus.STATUS_SUCCEEDED)
        results = lose_first(c.action, "_get_result_async", c.goals.forget_result_request)
        r = c.goals.result(handle, timeout=60)
        assert r.status == GoalStatus.STATUS_SUCCEEDED and r.result.success and r.result.message == "run 1"
        assert len(results) >= 2  # the lost result request was asked again
        refused = c.goals.send(Calibrate.Goal(bag_path="refuse"), timeout=60)
        assert not refused.accepted
        assert len(sends) >= 2
        # a cancel whose answer is lost: sent again, the goal canceled once
        slow = c.goals.send(Calibrate.Goal(bag_path="slow"), timeout=60)
        assert slow.accepted
        c.wait_for(lambda: c.goals.status_of(slow) == GoalStatus.STATUS_EXECUTING, "the slow goal executing")
        lose_first(c.action, "_cancel_goal_async", c.action._remove_pending_cancel_request)
        resp = c.goals.cancel(slow, timeout=60)
        assert [bytes(g.goal_id.uuid) for g in resp.goals_canceling] == [bytes(slow.goal_id.uuid)]
        assert c.goals.result(slow, timeout=60).status == GoalStatus.STATUS_CANCELED
    finally:
        c.close()
    runs = _runs(server)
    # the goal whose response was lost ran once (never twice), the refused one never, the slow one once
    assert runs == ["executing 1 lost-goal-response", "executing 2 slow"], runs


def test_transition_and_query_with_lost_answers(ros_python: Any, ros_domain_id: int) -> None:
    from driver import track_node
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from rcl_interfaces.srv import GetParameters

    with track_node(ros_python, ros_domain_id, "autostart:=false", discover=False) as run:
        drv = run.drv
        drv.wait_for(lambda: drv.state() == "unconfigured", 90, "the track node")
        cli = drv.node.create_client(ChangeState, "/clm_track_node/change_state")
        drv.wait_for(cli.service_is_ready, 60, "change_state")
        calls = lose_first(cli, "call_async", cli.remove_pending_request)

        def until(done: Callable[[], bool], seconds: float) -> None:
            end = time.monotonic() + seconds
            while not done() and time.monotonic() < end:
                drv.spin(0.02)

        req = ChangeState.Request(transition=Transition(id=Transition.TRANSITION_CONFIGURE))
        assert transition_confirmed(lambda: cli.call_async(req), drv.state, "configure", until, 120)
        assert drv.state() == "inactive" and len(calls) == 1  # confirmed through the state: sent once
        q = drv.node.create_client(GetParameters, "/clm_track_node/get_parameters")
        drv.wait_for(q.service_is_ready, 60, "get_parameters")
        queries = lose_first(q, "call_async", q.remove_pending_request)
        got = answered(q, GetParameters.Request(names=["dt"]), until, 60, resend_after=1.0)
        assert got.values[0].double_value > 0 and len(queries) >= 2
    # configured once: the lost answer was confirmed through the state, not by a second configure
    assert run.err.count(CONFIGURED) == 1, run.err
