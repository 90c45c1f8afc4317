"""Pushing fitted parameters to a running node, all or none (used by the calibration node).

:func:`push_values` says what a calibration sends (``{'soil.kf': value, ...}``);
:class:`ParameterPusher` sends it through the target's
``set_parameters_atomically`` service and returns a :class:`PushOutcome`
(accepted, or why not: the target's refusal reason, a target that is not
running, one that stops answering). The target validates the whole set
against its own configuration and takes all of it or none.

A dying target never blocks the caller longer than the push timeout and
never raises: the outcome says what happened and the caller keeps serving. A
target that comes back is reached again by the next push (the service
client is kept per target and matches the new process by discovery; an
unanswered request is sent again every :data:`RETRY_S` within the timeout).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.client import Client
from rclpy.exceptions import NameValidationException
from rclpy.node import Node
from rclpy.validate_full_topic_name import validate_full_topic_name

from clm_core.calibration import CalibrationError, CalibrationResult
from clm_core.params import PARAMETER_DOCS, SOIL_NAMES
from clm_ros.node_log import NodeLog

#: Poll interval while waiting for a target's service and answer [s]; a stop request is seen this fast.
POLL_S = 0.02
#: A request unanswered this long [s] is sent again (within the push timeout): a request sent to a target that
#: died, while discovery still lists it, is lost; the same request reaches a target that has come back since.
#: Setting the same values twice is harmless (the set is validated and taken as a whole each time).
RETRY_S = 1.0


def one_line(text: str) -> str:
    """``text`` with every run of white space (newlines included) as one blank."""
    return " ".join(text.split())


@dataclass(frozen=True)
class PushOutcome:
    """Result of pushing parameters to a node.

    Attributes
    ----------
    target : str
        Fully qualified target node name (``/clm_track_node``).
    service : str
        The parameter service called.
    accepted : bool
        True if the target took every parameter.
    reason : str
        Why not (the target's refusal reason, or a timeout / unreachable
        service); empty when accepted.
    values : mapping
        The parameters sent, ``{'soil.kf': value, ...}`` [SI].
    elapsed_s : float
        Wall time of the push [s].
    """

    target: str
    service: str
    accepted: bool
    reason: str
    values: Mapping[str, float] = field(default_factory=dict)
    elapsed_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready mapping (the ``push`` section of ``metrics_json``)."""
        return {
            "requested": True,
            "target": self.target,
            "service": self.service,
            "accepted": self.accepted,
            "reason": self.reason,
            "values": dict(self.values),
            "elapsed_s": self.elapsed_s,
        }


def push_values(result: CalibrationResult) -> dict[str, float]:
    """The parameters a calibration pushes to a track node, as ``{'<section>.<name>': value}``.

    Parameters
    ----------
    result : CalibrationResult
        A successful calibration (its parameter set is validated by clm_core).

    Returns
    -------
    dict
        ``impact``: the whole fitted soil, ``soil.mf soil.kf soil.df
        soil.kc soil.dc``, with the parameters the fitted model does not
        have set to 0 (a Lysmer fit gives a CLM soil without coupling; a
        Winkler fit has no soil mass, which a Lysmer/CLM track node
        refuses). ``receptance`` / ``passby``: the fitted parameters only
        (``track.kp``, ..., plus ``soil.*`` with a joint soil fit); the
        parameters held fixed come from the calibration's base set and are
        not imposed on the target. Values are taken from the validated
        parameter set, all finite.

    Raises
    ------
    CalibrationError
        A fitted name that is not a model parameter or a non-finite value
        (not expected from a successful calibration).
    """
    params = result.params
    if result.method == "impact":
        names = list(SOIL_NAMES)
    else:
        names = [p.name for p in result.parameters if p.fitted]
    out: dict[str, float] = {}
    for name in names:
        if name not in PARAMETER_DOCS:
            raise CalibrationError(f"fitted parameter {name!r} is not a model parameter; cannot push it")
        section = PARAMETER_DOCS[name][0]
        value = float(getattr(getattr(params, section), name))
        if not math.isfinite(value):
            raise CalibrationError(f"{section}.{name} = {value}: not finite; not pushed")
        out[f"{section}.{name}"] = value
    return out


def parameter_messages(values: Mapping[str, float]) -> list[Parameter]:
    """``rcl_interfaces/msg/Parameter`` DOUBLE messages for ``{name: value}``."""
    return [
        Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(v)))
        for name, v in values.items()
    ]


def target_service(target_node: str) -> tuple[str, str]:
    """Fully qualified node name and its ``set_parameters_atomically`` service.

    Parameters
    ----------
    target_node : str
        Node name, absolute (``/clm_track_node``, ``/ns/clm_track_node``) or
        relative to the root namespace (``clm_track_node``).

    Returns
    -------
    (str, str)
        ``('/clm_track_node', '/clm_track_node/set_parameters_atomically')``.

    Raises
    ------
    ValueError
        Empty or invalid name.
    """
    name = target_node.strip().rstrip("/")
    if not name:
        raise ValueError("target_node is empty: name the node to update, e.g. /clm_track_node")
    if not name.startswith("/"):
        name = "/" + name
    service = f"{name}/set_parameters_atomically"
    try:
        validate_full_topic_name(service, is_service=True)
    except NameValidationException as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"target_node = {target_node!r} is not a valid node name ({first})") from None
    return name, service


class ParameterPusher:
    """Sets DOUBLE parameters on running nodes through ``set_parameters_atomically``.

    Parameters
    ----------
    node : rclpy.node.Node
        The node whose service clients make the calls; its executor must be
        spinning in another thread (the answers arrive through it).
    stop : threading.Event
        Set when the node shuts down: a push waiting for a service or an
        answer gives up within :data:`POLL_S`.
    log : NodeLog, optional
        Where pushes are logged (default: a :class:`clm_ros.node_log.NodeLog` of ``node``).
    """

    def __init__(self, node: Node, stop: threading.Event, log: NodeLog | None = None) -> None:
        self._node = node
        self._log = log if log is not None else NodeLog(node)
        self._stop = stop
        self._clients: dict[str, Client] = {}
        self._lock = threading.Lock()
        self._group = MutuallyExclusiveCallbackGroup()

    def _client(self, service: str) -> Client:
        with self._lock:
            cli = self._clients.get(service)
            if cli is None:
                cli = self._node.create_client(SetParametersAtomically, service, callback_group=self._group)
                self._clients[service] = cli
            return cli

    def _wait_for_service(self, cli: Client, deadline: float) -> bool:
        while not cli.service_is_ready():
            if self._stop.is_set() or time.monotonic() > deadline:
                return False
            time.sleep(POLL_S)
        return True

    def push(self, values: Mapping[str, float], target_node: str, timeout: float) -> PushOutcome:
        """Set ``values`` on ``target_node``, all or none; never raises.

        Must not be called from a callback of a single-threaded executor (it
        waits for the answer, which another executor thread delivers).

        Parameters
        ----------
        values : mapping
            ``{'soil.kf': 7.2e7, ...}`` [SI].
        target_node : str
            Target node name (``/clm_track_node``; a relative name is taken
            from the root namespace).
        timeout : float
            Seconds to wait for the service and its answer, together.

        Returns
        -------
        PushOutcome
            ``accepted`` and, if not, the target's reason or why it could not
            be reached (not running, stopped answering, node shutting down).
        """
        t0 = time.monotonic()
        try:
            target, service = target_service(target_node)
        except ValueError as exc:
            return PushOutcome(target=target_node, service="", accepted=False, reason=str(exc), values=dict(values))
        bad = [k for k, v in values.items() if not math.isfinite(float(v))]
        if not values or bad:
            reason = "nothing to push" if not values else f"non-finite value(s) for {', '.join(bad)}; nothing pushed"
            return PushOutcome(target=target, service=service, accepted=False, reason=reason, values=dict(values))

        def outcome(accepted: bool, reason: str) -> PushOutcome:
            if not accepted:
                self._log.warning(f"push to {target} failed: {reason}")
            return PushOutcome(target=target, service=service, accepted=accepted, reason=reason,
                               values=dict(values), elapsed_s=time.monotonic() - t0)

        deadline = t0 + timeout
        cli = self._client(service)
        if not self._wait_for_service(cli, deadline):
            if self._stop.is_set():
                return outcome(False, "node shutting down")
            return outcome(False, f"no parameter service {service} within {timeout:g} s (is {target} running?)")
        request = SetParametersAtomically.Request(parameters=parameter_messages(values))
        future = cli.call_async(request)
        sent, attempts = time.monotonic(), 1
        while not future.done():
            now = time.monotonic()
            if self._stop.is_set() or now > deadline:
                cli.remove_pending_request(future)
                future.cancel()
                if self._stop.is_set():
                    return outcome(False, "node shutting down")
                return outcome(False, f"{service} did not answer within {timeout:g} s ({attempts} request(s); "
                               f"{target} stopped or is busy)")
            if now - sent > RETRY_S and cli.service_is_ready():
                cli.remove_pending_request(future)
                future.cancel()
                future = cli.call_async(request)
                sent, attempts = now, attempts + 1
            time.sleep(POLL_S)
        error = future.exception()
        if error is not None:
            return outcome(False, f"{service} call failed: {error}")
        res = future.result()
        if res is None:
            return outcome(False, f"{service} returned no result")
        if not res.result.successful:
            reason = one_line(res.result.reason) or "no reason given"
            return outcome(False, f"{target} refused the parameters: {reason}")
        self._log.info(f"pushed {', '.join(f'{k} = {v:.6g}' for k, v in values.items())} to {target}")
        return outcome(True, "")
