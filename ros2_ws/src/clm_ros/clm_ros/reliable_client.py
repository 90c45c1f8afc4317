"""Service and action clients that survive a lost response: nothing hangs, nothing is done twice.

The race (docs/ros-nodes.md, "Service and action races"): a server that
takes a request before its response writer has matched the new client's
response reader drops the response (Fast DDS: "failed to send response
(timeout): client will not receive response"). Discovery is two-sided, so
the client's ``service_is_ready()`` / ``server_is_ready()`` cannot rule it
out; a loaded machine makes it likely. A client that waits for that response
hangs; a client that simply sends again may do the work twice. The remedies:

- **queries** (``get_state``, ``get_parameters``, ``describe_parameters``, a
  set of the same values, a result request): sent again every
  ``resend_after`` s while unanswered (:func:`answered`): asking twice
  changes nothing;
- **lifecycle transitions** (:func:`transition_confirmed`): a transition sent
  twice would be a second transition; when no answer comes, the node's state
  (a query) says whether it happened: at the transition's goal state it did;
  in another primary state it was not taken, or taken and refused with no
  effect, so it is sent again (a refused one is refused again); a
  transition in progress is waited for;
- **action goals** (:class:`GoalTracker`): a goal is sent with its own goal
  id and its acceptance is read from the action's status topic (latched:
  transient local, so it cannot be missed) as well as from the response; it
  is sent again, *with the same goal id*, only while neither says it was
  accepted. The server refuses a goal id it already tracks (rclpy's
  ``ActionServer`` checks ``goal_exists``), so a goal that was accepted after
  all is never run twice; a refusal of the resent copy is taken as a refusal
  only when the status still does not list the goal. The result is asked
  for once the status says the goal is terminal, and asked again while
  unanswered (a query); a cancel is sent again while unanswered and the goal
  is not canceling (asking twice to cancel one goal cancels it once).

Every wait is bounded: :class:`TimeoutError` with what was waited for.
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Callable
from typing import Any

#: Seconds after which an unanswered request is sent again (or its effect checked).
RESEND_S = 2.0
#: Terminal goal states (action_msgs/GoalStatus: SUCCEEDED, CANCELED, ABORTED).
TERMINAL = (4, 5, 6)
#: Goal states that mean a cancel was taken (CANCELING, CANCELED).
CANCELING = (3, 5)

#: ``until(done, seconds)``: spin the client's executor until ``done()`` or ``seconds`` have passed.
Until = Callable[[Callable[[], bool], float], None]


def answered(cli: Any, request: Any, until: Until, timeout: float, resend_after: float | None = RESEND_S) -> Any:
    """The response of service client ``cli`` to ``request``, sent again every ``resend_after`` s while unanswered
    (None: once). Only for requests that change nothing when taken twice (queries).

    Raises
    ------
    TimeoutError
        No answer within ``timeout`` s.
    """
    deadline = time.monotonic() + timeout
    fut = cli.call_async(request)
    while True:
        left = deadline - time.monotonic()
        until(fut.done, left if resend_after is None else min(resend_after, left))
        if fut.done():
            return fut.result()
        if time.monotonic() >= deadline:
            cli.remove_pending_request(fut)
            raise TimeoutError(f"no answer of {cli.srv_name} within {timeout:g} s")
        cli.remove_pending_request(fut)
        fut = cli.call_async(request)


#: The state a lifecycle transition leads to, by transition label (lifecycle_msgs/Transition).
TRANSITION_GOALS = {"configure": "inactive", "activate": "active", "deactivate": "inactive",
                    "cleanup": "unconfigured", "unconfigured_shutdown": "finalized",
                    "inactive_shutdown": "finalized", "active_shutdown": "finalized"}
#: The primary lifecycle states (any other label is a transition in progress).
PRIMARY_STATES = ("unconfigured", "inactive", "active", "finalized")


def transition_confirmed(change: Callable[[], Any], state: Callable[[], str], name: str, until: Until,
                         timeout: float, resend_after: float = RESEND_S) -> bool:
    """Trigger lifecycle transition ``name``; whether it succeeded, confirmed by the node's state when the answer
    is lost.

    Parameters
    ----------
    change : callable
        Sends the ``change_state`` request; returns its future.
    state : callable
        The node's current state label (a query, itself resent while unanswered).
    name : str
        Transition label (``configure``, ``activate``, ...; :data:`TRANSITION_GOALS`).
    until : callable
        Spins the client's executor (see :data:`Until`).
    """
    goal = TRANSITION_GOALS[name]
    deadline = time.monotonic() + timeout
    fut = change()
    while True:
        until(fut.done, max(min(resend_after, deadline - time.monotonic()), 0.0))
        if fut.done():
            return bool(fut.result().success)
        if time.monotonic() >= deadline:
            raise TimeoutError(f"lifecycle transition {name}: no answer within {timeout:g} s")
        now = state()
        if now == goal:  # it happened; its answer was lost
            return True
        if now in PRIMARY_STATES:  # not taken, or taken and refused (no effect): sending it again is harmless
            fut = change()
        # else a transition in progress (configuring, activating, ...): its answer or its end is waited for


class GoalTracker:
    """Send goals of one action so that a lost response neither hangs the client nor duplicates a goal.

    Parameters
    ----------
    node : rclpy.node.Node
        The client's node (its executor is spun by ``until``).
    action_client : rclpy.action.ActionClient
        The client of the action.
    until : callable
        Spins the executor until a condition holds or a time has passed (:data:`Until`).
    """

    def __init__(self, node: Any, action_client: Any, until: Until) -> None:
        from action_msgs.msg import GoalStatusArray
        from rclpy.qos import qos_profile_action_status_default

        self.action = action_client
        self.until = until
        #: goal id (bytes) -> (status, acceptance stamp) as the status topic last said
        self.status: dict[bytes, tuple[int, Any]] = {}
        self.resent = 0  # goals, results and cancels sent again (a figure for tests and logs)
        name = action_client._action_name
        node.create_subscription(GoalStatusArray, f"{name}/_action/status", self._on_status,
                                 qos_profile_action_status_default)

    def _on_status(self, msg: Any) -> None:
        for st in msg.status_list:
            self.status[bytes(st.goal_info.goal_id.uuid)] = (int(st.status), st.goal_info.stamp)

    def status_of(self, handle: Any) -> int:
        """The goal's status as the status topic last said it (``GoalStatus.STATUS_*``; 0, unknown, before any).

        Read this, not ``handle.status``: rclpy updates a handle only from status messages that arrive after
        the goal's response, and the status topic need not wait for it; a goal queued behind a long one then
        keeps ``STATUS_UNKNOWN`` until its status changes again (a stress run of the ROS tests at 5188455: 20 s).
        """
        return self.status.get(bytes(handle.goal_id.uuid), (0, None))[0]

    def send(self, goal: Any, timeout: float, feedback_callback: Callable[[Any], None] | None = None,
             resend_after: float = RESEND_S) -> Any:
        """Send ``goal``; its ``ClientGoalHandle`` (``accepted`` False: refused) once its acceptance is known.

        Raises
        ------
        TimeoutError
            Neither a response nor the status said within ``timeout`` s whether the goal was accepted.
        """
        import uuid

        from unique_identifier_msgs.msg import UUID

        gid = UUID(uuid=list(uuid.uuid4().bytes))
        key = bytes(gid.uuid)
        deadline = time.monotonic() + timeout
        fut = self.action.send_goal_async(goal, feedback_callback=feedback_callback, goal_uuid=gid)
        sent = 1
        while True:
            step_end = time.monotonic() + resend_after
            def known(f: Any = fut) -> bool:
                return bool(f.done() or key in self.status)

            self.until(known, max(min(step_end, deadline) - time.monotonic(), 0.0))
            if fut.done():
                handle = fut.result()
                if handle.accepted:
                    return handle
                if sent == 1:
                    return handle  # the only request, refused: a refusal
                # a resent copy refused: the first may have been accepted (its id is tracked): the status says
                self.until(lambda: key in self.status, min(resend_after, max(deadline - time.monotonic(), 0.0)))
                if key not in self.status:
                    return handle
            if key in self.status:  # accepted (its response lost or not there yet): a handle of our own
                self._forget(fut)
                return self._handle(gid, self.status[key][1])
            if time.monotonic() >= deadline:
                self._forget(fut)
                raise TimeoutError(f"goal of {self.action._action_name}: neither accepted nor refused within "
                                   f"{timeout:g} s ({sent} request(s))")
            self._forget(fut)  # provably not accepted so far (not in the status): the same goal id again
            fut = self.action.send_goal_async(goal, feedback_callback=feedback_callback, goal_uuid=gid)
            sent += 1
            self.resent += 1

    def _forget(self, fut: Any) -> None:
        """Drop a pending goal request (a late response to it is then ignored by rclpy)."""
        self.action._remove_pending_goal_request(fut)

    def forget_result_request(self, fut: Any) -> None:
        """Drop a pending result request (a late response is then ignored; the goal's feedback still comes)."""
        seq = self.action._remove_pending_request(fut, self.action._pending_result_requests)
        self.action._result_sequence_number_to_goal_id.pop(seq, None)

    def _handle(self, gid: Any, stamp: Any) -> Any:
        """A ``ClientGoalHandle`` of an accepted goal whose response was lost, known to the client (its status,
        its result and cancel requests work as with any other handle)."""
        from rclpy.action.client import ClientGoalHandle

        response = self.action._action_type.Impl.SendGoalService.Response(accepted=True, stamp=stamp)
        handle = ClientGoalHandle(self.action, gid, response)
        self.action._goal_handles[bytes(gid.uuid)] = weakref.ref(handle)
        return handle

    def result(self, handle: Any, timeout: float, resend_after: float = RESEND_S) -> Any:
        """The goal's ``GetResult`` response (``status``, ``result``); asked again while unanswered.

        Raises
        ------
        TimeoutError
            No result within ``timeout`` s.
        """
        key = bytes(handle.goal_id.uuid)
        deadline = time.monotonic() + timeout
        fut = handle.get_result_async()
        while True:
            # a request taken before the server matched this client is answered into the void: ask again once the
            # status says the goal is over, and then every resend_after s
            def over(f: Any = fut) -> bool:
                return bool(f.done() or self.status.get(key, (0, None))[0] in TERMINAL)

            self.until(over, max(deadline - time.monotonic(), 0.0))
            if not fut.done():
                self.until(fut.done, max(min(resend_after, deadline - time.monotonic()), 0.0))
            if fut.done():
                return fut.result()
            if time.monotonic() >= deadline:
                raise TimeoutError(f"goal of {self.action._action_name}: no result within {timeout:g} s (status "
                                   f"{self.status.get(key, ('unknown',))[0]})")
            self.forget_result_request(fut)
            fut = handle.get_result_async()
            self.resent += 1

    def cancel(self, handle: Any, timeout: float, resend_after: float = RESEND_S) -> Any:
        """Cancel the goal; the ``CancelGoal`` response, asked again while unanswered (a response to a repeated
        cancel of a goal already canceling may list no goal: then the status confirms it).

        Returns the first response that lists the goal, else the last one.
        """
        key = bytes(handle.goal_id.uuid)
        deadline = time.monotonic() + timeout
        fut = handle.cancel_goal_async()
        sent = 1
        while True:
            self.until(fut.done, max(min(resend_after, deadline - time.monotonic()), 0.0))
            if fut.done():
                response = fut.result()
                if sent > 1 and not response.goals_canceling and self.status.get(key, (0, None))[0] in CANCELING:
                    # the first request was taken (the goal is canceling or canceled) and its answer lost: the
                    # answer it had, stated from the status
                    from action_msgs.msg import GoalInfo

                    response.return_code = 0
                    response.goals_canceling = [GoalInfo(goal_id=handle.goal_id, stamp=self.status[key][1])]
                return response
            if time.monotonic() >= deadline:
                raise TimeoutError(f"goal of {self.action._action_name}: no cancel response within {timeout:g} s")
            self.action._remove_pending_cancel_request(fut)
            fut = handle.cancel_goal_async()
            sent += 1
            self.resent += 1
