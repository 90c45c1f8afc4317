"""The calibration node under bursts, hostile goals and a sim clock that never starts (issue 26, items 1, 4, 9).

Over real DDS (the node in its own process, the client in the test's):

- a burst of 50 goals and 50 service calls sent at once: every one answered
  (ABORTED with its reason here: the bag does not exist, so the fits are
  quick); with ``max_queued`` full behind a long fit, a burst is accepted up
  to the queue and the rest refused (goals rejected, calls answered ``busy``),
  every refusal counted in ``/diagnostics``; a burst of 100 cancels is
  answered whole;
- hostile goals: ``options_yaml`` nested 600 deep (goal and service) aborts
  with the reason; a parameter file or channel map outside ``allowed_roots``
  is refused without a byte of it in the answer; a FIFO as the bag, or inside
  a bag directory, is refused without being opened, and the node serves on;
- ``use_sim_time`` without ``/clock``: periodic ``/diagnostics`` go on, and a
  queued goal's cancel is answered while a fit runs.
"""

from __future__ import annotations

import os
import shutil
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("clm_msgs.action", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from action_msgs.msg import GoalStatus
from action_msgs.srv import CancelGoal
from clm_msgs.action import Calibrate as CalibrateAction
from clm_msgs.srv import Calibrate
from clm_ros.calibration_node import REQUEST_DEPTH, request_qos
from clm_ros.reliable_client import GoalTracker, answered
from rclpy.action import ActionClient
from rclpy.action.client import ClientGoalHandle
from test_calibration_node import (
    FIT_TIMEOUT,
    IMPACT_BAG,
    LONG_FIT,
    NAME,
    RECEPTANCE_BAG,
    Client,
    _check_aborted,
    _start_calibration_node,
)
from unique_identifier_msgs.msg import UUID

BURST = 50


@pytest.fixture
def client_factory(ros_python, ros_domain_id, monkeypatch) -> Iterator[Callable[[], Client]]:  # type: ignore[no-untyped-def]
    """Connected clients (created on demand, closed at teardown), as in test_calibration_node.py."""
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")  # before the in-process init
    clients: list[Client] = []

    def make() -> Client:
        clients.append(Client(ros_domain_id, ros_python.procs))
        return clients[-1]

    try:
        yield make
    finally:
        for c in clients:
            c.close()


def _burst_client(c: Client) -> ActionClient:
    """An action client whose queues hold a whole burst (:func:`clm_ros.calibration_node.request_qos`)."""
    q = request_qos()
    cli = ActionClient(c.node, CalibrateAction, NAME, goal_service_qos_profile=q, result_service_qos_profile=q,
                       cancel_service_qos_profile=q, feedback_sub_qos_profile=q)
    c.wait_for(cli.server_is_ready, "burst action client")
    return cli


def _warm_up(c: Client, cli: ActionClient, srv: Any, missing: Path) -> None:
    """Before a burst: one harmless request of each kind (a goal and a service call on a bag that does not exist,
    a cancel of an unknown goal), sent again until answered, so that the node's answer writers have matched this
    client's readers. Discovery is two-sided: ``server_is_ready()`` says nothing of the server's side, and an answer
    the node sends before its writer has matched is dropped (docs/ros-nodes.md, "Service and action races"); on a
    loaded machine (the full suite) a burst sent at once met it: its answers never came (the burst test was
    quarantined for that). Counted: 2 accepted, 2 failed."""
    goal = GoalTracker(c.node, cli, c._until)
    h = goal.send(CalibrateAction.Goal(bag_path=f"{missing}_warm"), 60.0)
    assert h.accepted and "does not exist" in goal.result(h, 60.0).result.message
    r = answered(srv, Calibrate.Request(bag_path=f"{missing}_warm", method="impact", request_id=uuid.uuid4().hex),
                 c._until, 60.0)
    assert "does not exist" in r.message
    unknown = ClientGoalHandle(cli, UUID(uuid=list(uuid.uuid4().bytes)), None)
    deadline = time.monotonic() + 60.0
    while True:
        fut = unknown.cancel_goal_async()  # a cancel of a goal the node does not know: changes nothing
        c._until(fut.done, 2.0)
        if fut.done():
            return
        assert time.monotonic() < deadline, "no answer to a cancel within 60 s"
        cli._remove_pending_cancel_request(fut)


def _values(st: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in st.values}


def test_burst_of_goals_and_service_calls_all_answered(ros_python, client_factory, tmp_path) -> None:  # type: ignore[no-untyped-def]
    assert REQUEST_DEPTH >= 2 * BURST
    _start_calibration_node(ros_python, "-p", "max_queued:=200")
    c = client_factory()
    c.ready()
    cli = _burst_client(c)
    srv = c.node.create_client(Calibrate, NAME, qos_profile=request_qos())
    c.wait_for(srv.service_is_ready, "burst service client")
    missing = tmp_path / "no_such_bag"
    _warm_up(c, cli, srv, missing)
    goal_futs = [cli.send_goal_async(CalibrateAction.Goal(bag_path=f"{missing}_{k}")) for k in range(BURST)]
    call_futs = [srv.call_async(Calibrate.Request(bag_path=f"{missing}_s{k}", method="impact")) for k in range(BURST)]
    c.wait_for(lambda: all(f.done() for f in goal_futs), "every goal response", 60.0)
    handles = [f.result() for f in goal_futs]
    print(f"goals accepted {sum(h.accepted for h in handles)} of {BURST}")
    assert all(h.accepted for h in handles)
    results = [h.get_result_async() for h in handles]
    c.wait_for(lambda: all(f.done() for f in results + call_futs), "every result and service answer", 120.0)
    n_goals = sum(r.result().status == GoalStatus.STATUS_ABORTED and "does not exist" in r.result().result.message
                  for r in results)
    n_calls = sum((not f.result().success) and "does not exist" in f.result().message for f in call_futs)
    print(f"answered: goals {n_goals}/{BURST}, service calls {n_calls}/{BURST}")
    assert (n_goals, n_calls) == (BURST, BURST)
    _, v = c.last_diag(lambda v: v.get("goals_failed") == str(2 * BURST + 2), "every goal and call counted")
    assert v["goals_accepted"] == str(2 * BURST + 2) and v["goals_rejected"] == "0" and v["state"] == "idle"


def test_burst_beyond_the_queue_is_refused_and_counted(ros_python, client_factory, tmp_path) -> None:  # type: ignore[no-untyped-def]
    _start_calibration_node(ros_python, "-p", "max_queued:=2")
    c = client_factory()
    c.ready()
    cli = _burst_client(c)
    srv = c.node.create_client(Calibrate, NAME, qos_profile=request_qos())
    c.wait_for(srv.service_is_ready, "burst service client")
    _warm_up(c, cli, srv, tmp_path / "no_such_bag")
    running = cli.send_goal_async(CalibrateAction.Goal(bag_path=str(RECEPTANCE_BAG), **LONG_FIT))
    c.wait_for(running.done, "the long goal's response")
    assert running.result().accepted
    c.last_diag(lambda v: v.get("state") == "running", "the long fit running")
    t0 = time.monotonic()
    # the goals first, then the calls (sent together, the node's order of the two would decide which are queued)
    goal_futs = [cli.send_goal_async(CalibrateAction.Goal(bag_path=str(IMPACT_BAG))) for _ in range(BURST)]
    c.wait_for(lambda: all(f.done() for f in goal_futs), "every goal response", 60.0)
    call_futs = [srv.call_async(Calibrate.Request(bag_path=str(IMPACT_BAG), method="impact")) for _ in range(BURST)]
    c.wait_for(lambda: all(f.done() for f in call_futs), "every service answer", 60.0)
    print(f"burst of {2 * BURST} answered in {time.monotonic() - t0:.2f} s behind the running fit")
    accepted = [f.result() for f in goal_futs if f.result().accepted]
    busy = [f.result() for f in call_futs if f.result().message.startswith("busy: a calibration is running")]
    print(f"burst behind a running fit (max_queued 2): {len(accepted)} goals accepted, "
          f"{BURST - len(accepted)} rejected; {len(busy)} of {BURST} service calls answered busy")
    assert len(accepted) == 2 and len(busy) == BURST and not any(f.result().success for f in call_futs)
    _, v = c.last_diag(lambda v: v.get("goals_rejected") == str(2 * BURST - 2), "every refusal counted")
    assert v["queued"] == "2" and v["goals_accepted"] == "5"  # the warm-up's 2, the long goal, 2 queued
    # a burst of cancels (every accepted goal, each asked 25 times), every one answered
    handles = [running.result(), *accepted]
    cancels = [cli._cancel_goal_async(h) for h in handles for _ in range(25)]
    c.wait_for(lambda: all(f.done() for f in cancels), "every cancel answer", 60.0)
    n_ok = sum(isinstance(f.result(), CancelGoal.Response) for f in cancels)
    print(f"cancels answered: {n_ok} of {len(cancels)}")
    assert n_ok == len(cancels)
    results = [h.get_result_async() for h in handles]
    c.wait_for(lambda: all(f.done() for f in results), "the canceled goals' results", FIT_TIMEOUT)
    assert [r.result().status for r in results] == [GoalStatus.STATUS_CANCELED] * 3
    c.last_diag(lambda v: v.get("goals_canceled") == "3" and v.get("state") == "idle", "three canceled")


def test_a_service_call_waiting_for_its_fit_holds_up_no_goal(ros_python, client_factory, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A call queued behind a running fit, then goals: the goals are answered (one queued, the rest refused) while
    the fit still runs. The call's handler awaits its fit; in the node's default mutually exclusive callback group
    it kept every goal, call and cancel waiting until that fit ended (a burst was admitted one per finished fit)."""
    _start_calibration_node(ros_python, "-p", "max_queued:=2")
    c = client_factory()
    c.ready()
    cli = _burst_client(c)
    srv = c.node.create_client(Calibrate, NAME, qos_profile=request_qos())
    c.wait_for(srv.service_is_ready, "service client")
    _warm_up(c, cli, srv, tmp_path / "no_such_bag")
    running = cli.send_goal_async(CalibrateAction.Goal(bag_path=str(RECEPTANCE_BAG), **LONG_FIT))
    c.wait_for(running.done, "the long goal's response")
    assert running.result().accepted
    long_result = running.result().get_result_async()
    c.last_diag(lambda v: v.get("state") == "running", "the long fit running")
    call = srv.call_async(Calibrate.Request(bag_path=str(IMPACT_BAG), method="impact"))
    c.last_diag(lambda v: v.get("queued") == "1", "the call queued")
    goals = [cli.send_goal_async(CalibrateAction.Goal(bag_path=str(IMPACT_BAG))) for _ in range(3)]
    c.wait_for(lambda: all(f.done() for f in goals) or long_result.done(), "the goals' responses", FIT_TIMEOUT)
    assert not long_result.done(), "the goals were answered only after the running fit had ended"
    assert [f.result().accepted for f in goals] == [True, False, False]
    _, v = c.last_diag(lambda v: v.get("goals_rejected") == "2", "two refusals counted")
    assert v["queued"] == "2"
    for h in (running.result(), goals[0].result()):
        cancel = cli._cancel_goal_async(h)
        c.wait_for(cancel.done, "a cancel answer")
    c.wait_for(call.done, "the queued call's answer", FIT_TIMEOUT)
    assert call.result().success, call.result().message


def _aborted_goal(c: Client, bag: str | Path, *fragments: str, **fields: Any) -> Any:
    status, res, _ = c.calibrate(bag, **fields)
    _check_aborted(status, res, *fragments)
    return res


def test_hostile_goals_abort_with_their_reason(ros_python, client_factory, tmp_path) -> None:  # type: ignore[no-untyped-def]
    _start_calibration_node(ros_python)
    c = client_factory()
    c.ready()
    deep = "a: " + "[" * 600 + "]" * 600
    _aborted_goal(c, IMPACT_BAG, "nested too deeply", options_yaml=deep)
    fut = c.call_service(IMPACT_BAG, "impact", deep)
    c.wait_for(fut.done, "service answer to deep options")
    assert not fut.result().success and "nested too deeply" in fut.result().message
    # reads outside allowed_roots: refused, and nothing of the file in the answer
    secret = Path("/etc/passwd")
    res = _aborted_goal(c, IMPACT_BAG, "outside the directories this node may read", params_file=str(secret))
    assert "root:" not in res.message and "root:" not in res.metrics_json
    res = _aborted_goal(c, IMPACT_BAG, "channel map (channels)", "outside", channels="/etc/hostname")
    assert Path("/etc/hostname").read_text().strip() not in res.message
    link = tmp_path / "link_to_etc"
    link.symlink_to("/etc")
    _aborted_goal(c, link / "passwd", "outside the directories")  # a symbolic link out of a root is followed
    # a FIFO as the bag, inside a bag directory, as the channel map: refused without being opened
    fifo = tmp_path / "blocking.mcap"
    os.mkfifo(fifo)
    _aborted_goal(c, fifo, "not a regular file")
    bag = tmp_path / "bag_with_fifo"
    shutil.copytree(IMPACT_BAG, bag)
    (bag / "channels.yaml").unlink()
    os.mkfifo(bag / "channels.yaml")
    _aborted_goal(c, bag, "'channels.yaml', which is not a regular file")
    _aborted_goal(c, IMPACT_BAG, "not a regular file", channels=str(fifo))
    # a FIFO goal canceled at once: answered (canceled or already aborted), and the node serves on
    g = c.send(fifo)
    c.cancel(g)
    r = c.result(g, timeout=30.0)
    assert r.status in (GoalStatus.STATUS_CANCELED, GoalStatus.STATUS_ABORTED), r.result.message
    status, res, _ = c.calibrate(IMPACT_BAG, compare=False)
    assert status == GoalStatus.STATUS_SUCCEEDED, res.message
    _, v = c.last_diag(lambda v: v.get("goals_succeeded") == "1", "the counts")
    assert int(v["goals_failed"]) + int(v["goals_canceled"]) == 9


def test_sim_time_without_clock(ros_python, client_factory) -> None:  # type: ignore[no-untyped-def]
    _start_calibration_node(ros_python, "-p", "use_sim_time:=true", "-p", "max_queued:=2")
    c = client_factory()
    c.ready()
    t0 = time.monotonic()
    c.wait_for(lambda: sum(t > t0 for t, _ in c.diagnostics) >= 3, "periodic diagnostics without /clock")
    a = c.send(RECEPTANCE_BAG, **LONG_FIT)
    b = c.send(IMPACT_BAG)
    assert a.handle.accepted and b.handle.accepted
    c.wait_for(lambda: "queued" in b.stages(), "B queued")
    c.cancel(b)
    rb = c.result(b, timeout=30.0)
    assert rb.status == GoalStatus.STATUS_CANCELED and rb.result.message == "canceled while queued (never started)"
    assert not a.result.done()  # B's cancel did not wait for A's fit
    t1 = time.monotonic()
    c.wait_for(lambda: any(t > t1 and _values(st).get("state") == "running" for t, st in c.diagnostics),
               "periodic diagnostics during the fit")
    c.cancel(a)
    assert c.result(a).status == GoalStatus.STATUS_CANCELED
