"""The calibration node: a service that fits model parameters to a recorded bag.

``clm_calibration_node`` offers ``~/calibrate`` (``clm_msgs/srv/Calibrate``,
``/clm_calibration_node/calibrate`` with the default name). A request names a
bag, a method (``impact``, ``receptance``, ``passby``; empty: the
``default_method`` parameter) and options (``options_yaml``, the mapping of
:class:`clm_core.calibration.CalibrationOptions`); the node calls
:func:`clm_core.calibration.calibrate`, the same code path as
``clm calibrate``, and answers with

- ``parameters_yaml``: the full parameter file (rail, track, fitted soil or
  track), which the track node (``-p params_file:=FILE``) and the CLI
  (``--params FILE``) load directly;
- ``metrics_json``: :meth:`CalibrationResult.summary` (band, norm, values with
  95 % intervals, residual statistics, identifiability warnings, record
  notes) plus a ``push`` section;
- ``success`` and a one-line ``message``. Every error (missing or corrupt
  bag, unknown method, bad options, a fit that cannot be done) gives
  ``success = false`` with the reason; the node keeps serving.

With ``push_to_node`` the fitted parameters go to a running track node
(``target_node``, e.g. ``/clm_track_node``) as ``<section>.<name>`` DOUBLE
parameters (``soil.mf``, ``soil.kf``, ... or ``track.kp``, ...; see
:func:`push_values`) through its ``set_parameters_atomically`` service: the
track node validates the whole set against its own configuration and either
takes all of it or none. A refusal keeps the track node's parameters; the
response then has ``success = false``, says that the fit itself succeeded
and quotes the track node's reason (the fitted parameters are still in
``parameters_yaml`` / ``metrics_json``).

Threading: the service runs in a reentrant callback group of a
:class:`~rclpy.executors.MultiThreadedExecutor`, so the fit occupies one
executor thread while the others keep answering (parameter services, the
push client's responses, a second request). One calibration runs at a time;
a request arriving meanwhile is answered at once with ``success = false``
and a message starting with ``busy``.

Parameters
----------
default_method : str
    Method used when a request leaves ``method`` empty (default ``impact``).
push_timeout : float
    How long a push waits for the target's parameter service to appear and
    answer [s] (default 10).

Run: ``python -m clm_ros.calibration_node`` or the console script
``calibration_node`` (``ros2 run clm_ros calibration_node`` in a full ROS
install); call with e.g. ``ros2 service call /clm_calibration_node/calibrate
clm_msgs/srv/Calibrate "{bag_path: bags/calibration/impact_mevergnies,
method: impact}"``.
"""

from __future__ import annotations

import math
import sys
import threading
import time
import traceback
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rclpy
from clm_msgs.srv import Calibrate
from rcl_interfaces.msg import (
    Parameter,
    ParameterType,
    ParameterValue,
    SetParametersResult,
)
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.client import Client
from rclpy.exceptions import InvalidParameterValueException, NameValidationException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.validate_full_topic_name import validate_full_topic_name

from clm_core.calibration import BagError, CalibrationError, CalibrationResult, calibrate
from clm_core.calibration.options import METHODS
from clm_core.errors import ClmError
from clm_core.io.history import dumps_json
from clm_core.params import PARAMETER_DOCS, SOIL_NAMES
from clm_core.settings import Setting
from clm_ros.parameters import NODE_SETTINGS, declare_settings

NODE_NAME = "clm_calibration_node"
#: Service name, relative to the node (``/clm_calibration_node/calibrate``).
SERVICE_NAME = "~/calibrate"
#: Default of the ``push_timeout`` parameter [s].
DEFAULT_PUSH_TIMEOUT: float = NODE_SETTINGS["push_timeout"].default
#: The ``default_method`` parameter.
DEFAULT_METHOD: Setting[str] = Setting("default_method", str, "impact", "-",
                                       "method used when a request leaves 'method' empty", choices=METHODS)


class CalibrationCancelled(BaseException):
    """Raised inside a running fit (from its progress callback) when the node shuts down.

    A ``BaseException`` so that no ``except Exception`` on the way swallows it.
    """


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


def _one_line(text: str) -> str:
    return " ".join(text.split())


def fit_message(result: CalibrationResult) -> str:
    """One-line description of a fit: method, model, band, norm, values, misfit, warnings."""
    vals = ", ".join(f"{p.name} = {p.value:.4g} {p.unit}".rstrip() for p in result.parameters)
    lo, hi = result.band
    text = (
        f"{result.method} fit ({result.model}, {lo:g}-{hi:g} Hz, {result.norm} norm): {vals}; "
        f"misfit {result.misfit:.3g}"
    )
    n = len(result.warnings)
    if n:
        text += f"; {n} warning(s), first: {_one_line(result.warnings[0])}"
    else:
        text += "; no warnings"
    return text


class CalibrationNode(Node):
    """Node offering ``~/calibrate`` (``clm_msgs/srv/Calibrate``); see the module docstring.

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ...).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        # parameters generated from settings (clm_ros.parameters); the method's choices are clm_core's METHODS
        declare_settings(self, (DEFAULT_METHOD, "push_timeout"))
        self._check_method(str(self.get_parameter("default_method").value))
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._busy = threading.Lock()
        self._running: tuple[str, str, float] | None = None  # (method, bag, start time)
        self._cancel = threading.Event()
        self._push_clients: dict[str, Client] = {}
        self._push_clients_lock = threading.Lock()
        self._service_group = ReentrantCallbackGroup()
        self._client_group = MutuallyExclusiveCallbackGroup()
        self.service = self.create_service(
            Calibrate, SERVICE_NAME, self.handle_calibrate, callback_group=self._service_group
        )
        self.get_logger().info(f"ready: {self.service.service_name} (methods {', '.join(METHODS)})")

    # ------------------------------------------------------------------ parameters

    @staticmethod
    def _check_method(method: str) -> None:
        if method not in METHODS:
            raise ValueError(f"default_method = {method!r}: must be one of {', '.join(METHODS)}")

    def _on_set_parameters(self, params: list[Any]) -> SetParametersResult:
        for p in params:
            if p.name == "default_method":
                try:
                    self._check_method(str(p.value))
                except ValueError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ service

    def handle_calibrate(self, request: Calibrate.Request, response: Calibrate.Response) -> Calibrate.Response:
        """Serve one ``Calibrate`` request (runs in an executor thread; never raises).

        Parameters
        ----------
        request : clm_msgs.srv.Calibrate.Request
        response : clm_msgs.srv.Calibrate.Response

        Returns
        -------
        clm_msgs.srv.Calibrate.Response
            Filled in; ``success = false`` with a one-line ``message`` on any error.
        """
        method = request.method.strip() or str(self.get_parameter("default_method").value)
        bag = request.bag_path.strip()
        if not self._busy.acquire(blocking=False):
            running = self._running
            what = (
                f"{running[0]} of {running[1]!r}, for {time.monotonic() - running[2]:.1f} s" if running else "starting"
            )
            return self._fail(
                response,
                f"busy: another calibration is running ({what}); one at a time, try again when it has finished",
                log=False,
            )
        try:
            self._running = (method, bag, time.monotonic())
            return self._calibrate_and_push(request, response, method, bag)
        except Exception as exc:  # a request must always get an answer
            self.get_logger().error(traceback.format_exc())
            return self._fail(response, f"internal error of the calibration node: {type(exc).__name__}: {exc}")
        finally:
            self._running = None
            self._busy.release()

    def _fail(self, response: Calibrate.Response, message: str, log: bool = True,
              extra: Mapping[str, Any] | None = None) -> Calibrate.Response:
        message = _one_line(message)
        if log:
            self.get_logger().warning(message)
        response.success = False
        response.message = message
        response.metrics_json = dumps_json({"error": message, **(extra or {})}, indent=None)
        return response

    def _calibrate_and_push(self, request: Calibrate.Request, response: Calibrate.Response,
                            method: str, bag: str) -> Calibrate.Response:
        ctx = {"method": method, "bag": bag}
        if not bag:
            return self._fail(response, "bag_path is empty: give the bag directory or .mcap/.db3 file", extra=ctx)
        if method not in METHODS:
            return self._fail(response, f"method = {method!r}: must be one of {', '.join(METHODS)}", extra=ctx)
        path = Path(bag).expanduser()
        if not path.exists():
            return self._fail(response, f"bag {bag!r} does not exist (as seen by the node, cwd {Path.cwd()})",
                              extra=ctx)
        self.get_logger().info(f"calibrating: {method} on {bag!r}")
        stage = [""]

        def progress(name: str, frac: float) -> None:
            if self._cancel.is_set():
                raise CalibrationCancelled("node shutting down")
            if name != stage[0]:
                stage[0] = name
                self.get_logger().info(f"  {name} ({100 * frac:.0f} %)")

        try:
            result = calibrate(path, method, request.options_yaml, progress=progress)
        except CalibrationCancelled:
            return self._fail(response, "calibration cancelled: the node is shutting down", log=False, extra=ctx)
        except BagError as exc:
            return self._fail(response, f"bag refused: {exc}", extra=ctx)
        except ClmError as exc:  # CalibrationError (options, channel map, band), ParameterError
            return self._fail(response, f"calibration failed: {exc}", extra=ctx)
        except Exception as exc:  # the node must survive anything a bag can trigger
            self.get_logger().error(traceback.format_exc())
            return self._fail(
                response,
                f"calibration failed with an unexpected {type(exc).__name__}: {exc} (traceback in the node's log)",
                extra=ctx,
            )

        response.parameters_yaml = result.parameters_yaml()
        metrics = result.summary()
        fit_text = fit_message(result)
        success = True
        message = fit_text
        if request.push_to_node:
            outcome = self._push_result(result, request.target_node)
            metrics["push"] = outcome.to_dict()
            if outcome.accepted:
                message = f"{fit_text}; pushed {len(outcome.values)} parameter(s) to {outcome.target}"
            else:
                success = False
                message = (
                    f"fit succeeded but the push to {outcome.target or repr(request.target_node)} failed: "
                    f"{outcome.reason} ({fit_text}; fitted parameters in parameters_yaml)"
                )
        else:
            metrics["push"] = {"requested": False}
        response.metrics_json = dumps_json(metrics, indent=1)
        response.success = success
        response.message = _one_line(message)
        log = self.get_logger().info if success else self.get_logger().warning
        log(response.message)
        return response

    # ------------------------------------------------------------------ push

    def _push_result(self, result: CalibrationResult, target_node: str) -> PushOutcome:
        try:
            values = push_values(result)
        except CalibrationError as exc:
            return PushOutcome(target=target_node, service="", accepted=False, reason=str(exc))
        try:
            return self.push_parameters(values, target_node)
        except Exception as exc:  # report it, keep the fit's answer
            self.get_logger().error(traceback.format_exc())
            return PushOutcome(target=target_node, service="", accepted=False, values=values,
                               reason=f"push failed with an unexpected {type(exc).__name__}: {exc}")

    def _client(self, service: str) -> Client:
        with self._push_clients_lock:
            cli = self._push_clients.get(service)
            if cli is None:
                cli = self.create_client(SetParametersAtomically, service, callback_group=self._client_group)
                self._push_clients[service] = cli
            return cli

    def push_parameters(self, values: Mapping[str, float], target_node: str,
                        timeout: float | None = None) -> PushOutcome:
        """Set DOUBLE parameters on a running node, all or none.

        Calls ``<target_node>/set_parameters_atomically`` (the target's
        parameter callback sees the whole set at once, so a set the track
        node finds invalid or unstable is refused as a whole and nothing
        changes). Must not be called from a callback of a single-threaded
        executor (it waits for the answer, which another executor thread
        delivers).

        Parameters
        ----------
        values : mapping
            ``{'soil.kf': 7.2e7, ...}`` [SI].
        target_node : str
            Target node name (``/clm_track_node``; a relative name is taken
            from the root namespace).
        timeout : float, optional
            Seconds to wait for the service and its answer; default the
            ``push_timeout`` parameter.

        Returns
        -------
        PushOutcome
            ``accepted`` and, if not, the target's reason (or why it could
            not be reached).
        """
        t0 = time.monotonic()
        budget = float(self.get_parameter("push_timeout").value) if timeout is None else float(timeout)
        try:
            target, service = target_service(target_node)
        except ValueError as exc:
            return PushOutcome(target=target_node, service="", accepted=False, reason=str(exc), values=dict(values))
        bad = [k for k, v in values.items() if not math.isfinite(float(v))]
        if not values or bad:
            reason = "nothing to push" if not values else f"non-finite value(s) for {', '.join(bad)}; nothing pushed"
            return PushOutcome(target=target, service=service, accepted=False, reason=reason, values=dict(values))

        def outcome(accepted: bool, reason: str) -> PushOutcome:
            return PushOutcome(target=target, service=service, accepted=accepted, reason=reason,
                               values=dict(values), elapsed_s=time.monotonic() - t0)

        cli = self._client(service)
        if not cli.wait_for_service(timeout_sec=budget):
            return outcome(False, f"no parameter service {service} within {budget:g} s (is {target} running?)")
        future = cli.call_async(SetParametersAtomically.Request(parameters=parameter_messages(values)))
        deadline = t0 + budget
        while not future.done():
            if self._cancel.is_set():
                future.cancel()
                return outcome(False, "node shutting down")
            if time.monotonic() > deadline:
                future.cancel()
                cli.remove_pending_request(future)
                return outcome(False, f"{service} did not answer within {budget:g} s")
            time.sleep(0.005)
        error = future.exception()
        if error is not None:
            return outcome(False, f"{service} call failed: {error}")
        res = future.result()
        if res is None:
            return outcome(False, f"{service} returned no result")
        if not res.result.successful:
            reason = _one_line(res.result.reason) or "refused without a reason"
            self.get_logger().warning(f"push to {target} refused: {reason}")
            return outcome(False, f"{target} refused the parameters: {reason}")
        self.get_logger().info(f"pushed {', '.join(f'{k} = {v:.6g}' for k, v in values.items())} to {target}")
        return outcome(True, "")

    # ------------------------------------------------------------------ shutdown

    def cancel(self) -> None:
        """Ask a running fit or push to stop (at its next progress report); used at shutdown."""
        self._cancel.set()

    def wait_idle(self, timeout: float) -> bool:
        """Wait until no calibration runs (at most ``timeout`` s); True if idle."""
        if self._busy.acquire(timeout=max(0.0, timeout)):
            self._busy.release()
            return True
        return False

    def destroy_node(self) -> None:
        """Cancel a running fit, then destroy the node."""
        self.cancel()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Console entry point ``calibration_node``: init, spin (multi-threaded), shut down.

    Parameters
    ----------
    args : list of str, optional
        Command line (``--ros-args`` ...); default ``sys.argv``.

    Returns
    -------
    int
        Exit code: 0, or 2 for an invalid parameter at start (e.g. ``default_method``).
    """
    rclpy.init(args=args)
    node: CalibrationNode | None = None
    executor: MultiThreadedExecutor | None = None
    try:
        try:
            node = CalibrationNode()
        except (ValueError, InvalidParameterValueException) as exc:  # bad default_method, value out of range
            print(f"{NODE_NAME}: {_one_line(str(exc))}", file=sys.stderr)
            return 2
        executor = MultiThreadedExecutor(num_threads=4)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.cancel()
            node.wait_idle(10.0)
        if executor is not None:
            executor.shutdown(timeout_sec=5.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
