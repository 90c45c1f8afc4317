"""What a calibration is asked and what it answers, in the calibration node's messages.

One request type for both ways of asking (the ``clm_msgs/action/Calibrate``
goal with typed options, the ``clm_msgs/srv/Calibrate`` request with options
as YAML): :class:`CalibrationRequest`. One outcome type,
:class:`CalibrationOutcome`, written into either answer
(:func:`action_result`, :func:`service_response`). No physics here: the
options go to :func:`clm_core.calibration.calibrate` as they are, which
validates them.

Which files a request may make the node read (:func:`check_paths`): the bag,
the base parameter file (``params``) and the channel map (``channels``) must
lie under one of the directories of the node's ``allowed_roots`` parameter
(after resolving symbolic links and ``..``), and be regular files (a bag
directory: holding only regular files and directories), so a goal can neither
read any file of the machine nor block the node on a FIFO or a device.
Refusals name the path and the rule, never the file's contents.
"""

from __future__ import annotations

import math
import os
import stat
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from clm_core.calibration import CalibrationError, CalibrationOptions, CalibrationResult, SoilFit
from clm_core.io.files import dumps_json
from clm_ros.calibration_push import PushOutcome, one_line

#: Terminal states of a calibration (the action's SUCCEEDED, ABORTED, CANCELED).
SUCCEEDED, ABORTED, CANCELED = "succeeded", "aborted", "canceled"

def parse_roots(text: str) -> tuple[Path, ...]:
    """The directories of ``allowed_roots`` (comma-separated), resolved (``.``: the working directory).

    Raises
    ------
    ValueError
        No directory given, or one that is not an existing directory.
    """
    roots: list[Path] = []
    for item in (t.strip() for t in text.split(",")):
        if not item:
            continue
        root = Path(item).expanduser().resolve()
        if not root.is_dir():
            raise ValueError(f"allowed_roots: {item!r} is not an existing directory")
        roots.append(root)
    if not roots:
        raise ValueError("allowed_roots is empty: give the directories (comma-separated) the node may read from")
    return tuple(roots)


def _regular(path: Path, what: str) -> str:
    """'' when ``path`` is a regular file (not following a last symbolic link out), else why not."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        return f"{what} {str(path)!r} cannot be read ({exc.strerror})"
    if not stat.S_ISREG(mode):
        return f"{what} {str(path)!r} is not a regular file (a FIFO, device or socket is never read)"
    return ""


def _allowed(raw: str, roots: Sequence[Path], what: str, directory_ok: bool) -> str:
    """'' when the file or bag ``raw`` lies under one of ``roots`` and is safe to read, else why not."""
    path = Path(raw).expanduser().resolve()
    if not any(path == r or path.is_relative_to(r) for r in roots):
        return (f"{what} {raw!r} is outside the directories this node may read (allowed_roots: "
                f"{', '.join(map(str, roots))})")
    if not path.exists():
        return f"{what} {raw!r} does not exist (as seen by the node, cwd {Path.cwd()})"
    if directory_ok and path.is_dir():
        try:
            entries = list(path.iterdir())
        except OSError as exc:
            return f"{what} {raw!r} cannot be listed ({exc.strerror})"
        for entry in entries:
            if not entry.is_dir() and not stat.S_ISREG(entry.stat().st_mode if entry.exists() else 0):
                return f"{what} {raw!r} holds {entry.name!r}, which is not a regular file (never read)"
        return ""
    return _regular(path, what)


def check_paths(request: CalibrationRequest, roots: Sequence[Path]) -> str:
    """Why the request may not be run ('' if it may): its bag, parameter file or channel map lies outside
    ``roots`` (the ``allowed_roots`` parameter) or is not a regular file (a bag directory: holds something else
    than regular files and directories). The message names the path and the rule, never the file's contents."""
    why = _allowed(request.bag, roots, "bag", directory_ok=True)
    if why:
        return why
    opts = request.options
    for key, what in (("params", "parameter file (params)"), ("channels", "channel map (channels)")):
        value = getattr(opts, key, None) if isinstance(opts, CalibrationOptions) else None
        if value:
            why = _allowed(str(value), roots, what, directory_ok=False)
            if why:
                return why
    return ""


@dataclass(frozen=True)
class CalibrationRequest:
    """One calibration to run.

    Attributes
    ----------
    bag : str
        Bag path as given (seen by the node).
    method : str
        ``impact``, ``receptance`` or ``passby`` (as given; checked when run).
    options : CalibrationOptions, mapping or str
        Options (a mapping or YAML text is validated by ``calibrate``).
    allow_partial : bool
        Fit what is left of a damaged bag.
    push : bool
        Push the fitted parameters to ``target`` after a successful fit.
    target : str
        Node to push to.
    error : str
        Set when the request itself is invalid (the options of a goal): the
        calibration fails with this message without reading the bag.
    """

    bag: str
    method: str
    options: CalibrationOptions | Mapping[str, Any] | str = ""
    allow_partial: bool = False
    push: bool = False
    target: str = ""
    error: str = ""

    def context(self) -> dict[str, Any]:
        """``{'method': ..., 'bag': ...}`` for error metrics."""
        return {"method": self.method, "bag": self.bag}


def _list(values: Any) -> list[Any]:
    return [v for v in values]


def goal_options(goal: Any) -> CalibrationOptions:
    """The :class:`CalibrationOptions` of a ``Calibrate`` action goal.

    Fields at their default (empty string, negative or NaN band limit, 0
    count, empty array, ``compare`` true) leave the option to the
    calibration's default or to ``options_yaml``; an option given both as a
    field and in ``options_yaml`` is refused.

    Parameters
    ----------
    goal : clm_msgs.action.Calibrate.Goal

    Returns
    -------
    CalibrationOptions

    Raises
    ------
    CalibrationError
        Invalid YAML, unknown keys, an option given twice, names and values
        of the starting values of different lengths, or any value the
        options refuse (the message names it).
    """
    typed: dict[str, Any] = {}
    for name in ("fmin", "fmax"):
        v = float(getattr(goal, name))
        if math.isfinite(v) and v >= 0:
            typed[name] = v
    for key, fld in (("norm", "norm"), ("model", "model"), ("first", "first_estimate"), ("interval", "interval"),
                     ("soil", "soil"), ("params", "params_file"), ("channels", "channels")):
        text = str(getattr(goal, fld)).strip()
        if text:
            typed[key] = text
    for name in ("n_areas", "n_sleepers", "max_nfev"):
        v = int(getattr(goal, name))
        if v != 0:
            typed[name] = v
    if not goal.compare:
        typed["compare"] = False
    fit = [str(x).strip() for x in goal.fit if str(x).strip()]
    if fit:
        typed["fit"] = fit
    names, values = _list(goal.initial_names), _list(goal.initial_values)
    if len(names) != len(values):
        raise CalibrationError(
            f"initial_names ({len(names)}) and initial_values ({len(values)}) must have the same length"
        )
    if names:
        typed["initial"] = {str(n): float(v) for n, v in zip(names, values)}
    CalibrationOptions.from_yaml(goal.options_yaml)  # YAML and its keys checked with the calibration's own messages
    extra = (yaml.safe_load(goal.options_yaml) or {}) if goal.options_yaml.strip() else {}
    twice = sorted(set(extra) & set(typed))
    if twice:
        raise CalibrationError(
            f"option(s) {twice} given both as goal field(s) and in options_yaml: give each option once"
        )
    return CalibrationOptions.from_mapping({**extra, **typed})


def request_from_goal(goal: Any, default_method: str) -> CalibrationRequest:
    """The request of a ``Calibrate`` action goal (never raises: invalid options set ``error``)."""
    method = goal.method.strip() or default_method
    bag = goal.bag_path.strip()
    options, error = _parsed(lambda: goal_options(goal))
    return CalibrationRequest(bag=bag, method=method, options=options, allow_partial=bool(goal.allow_partial),
                              push=bool(goal.push_to_node), target=goal.target_node, error=error)


def _parsed(parse: Any) -> tuple[CalibrationOptions | str, str]:
    """``(options, '')`` from ``parse()``, or ``('', why)``: any failure of the options is the request's error."""
    try:
        return parse(), ""
    except CalibrationError as exc:
        return "", f"calibration failed: {exc}"
    except RecursionError:
        return "", (f"calibration failed: options_yaml is nested too deeply (Python's recursion limit, "
                    f"{sys.getrecursionlimit()}, reached while reading it)")
    except Exception as exc:  # anything else a hostile text can trigger: the goal is refused with it
        return "", f"calibration failed: invalid options ({type(exc).__name__}: {exc})"


def request_from_service(request: Any, default_method: str) -> CalibrationRequest:
    """The request of a ``Calibrate`` service call (options as YAML text, validated here; never raises)."""
    options, error = _parsed(lambda: CalibrationOptions.from_yaml(request.options_yaml))
    return CalibrationRequest(bag=request.bag_path.strip(), method=request.method.strip() or default_method,
                              options=options, push=bool(request.push_to_node), target=request.target_node,
                              error=error)


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
        text += f"; {n} warning(s), first: {one_line(result.warnings[0])}"
    else:
        text += "; no warnings"
    return text


@dataclass(frozen=True)
class CalibrationOutcome:
    """How a calibration ended.

    Attributes
    ----------
    status : {'succeeded', 'aborted', 'canceled'}
        The goal's terminal state.
    message : str
        One line: the fit (and push), or what went wrong.
    result : CalibrationResult or None
        The fit, when it completed (also with a refused push, or a cancel
        that came after the fit).
    push : PushOutcome or None
        The push, when one was made.
    context : mapping
        Method and bag, for the error metrics.
    """

    status: str
    message: str
    result: CalibrationResult | None = None
    push: PushOutcome | None = None
    context: Mapping[str, Any] = field(default_factory=dict)

    @property
    def success(self) -> bool:
        """True if the fit completed and, if requested, the push was accepted."""
        return self.status == SUCCEEDED

    def metrics(self) -> dict[str, Any]:
        """The ``metrics_json`` object: the fit's summary and a ``push`` section, or ``error``."""
        if self.result is None:
            return {"error": self.message, "status": self.status, **self.context}
        out = self.result.summary()
        out["push"] = self.push.to_dict() if self.push is not None else {"requested": False}
        if not self.success:
            out["error"] = self.message
            out["status"] = self.status
        return out


def failed(status: str, message: str, request: CalibrationRequest | None = None) -> CalibrationOutcome:
    """An outcome without a fit (``status`` aborted or canceled)."""
    return CalibrationOutcome(status=status, message=one_line(message),
                              context=request.context() if request is not None else {})


def action_result(outcome: CalibrationOutcome, result_type: type) -> Any:
    """The ``Calibrate`` action result of an outcome.

    Parameters
    ----------
    outcome : CalibrationOutcome
    result_type : type
        ``clm_msgs.action.Calibrate.Result``.
    """
    msg = result_type(success=outcome.success, message=outcome.message)
    r = outcome.result
    if r is not None:
        msg.method, msg.model, msg.norm = r.method, r.model, r.norm
        msg.fmin, msg.fmax = (float(x) for x in r.band)
        ps = r.parameters
        msg.names = [p.name for p in ps]
        msg.units = [p.unit for p in ps]
        msg.values = [float(p.value) for p in ps]
        msg.std_error = [float(p.std) for p in ps]
        msg.ci95_low = [float(p.ci_low) for p in ps]
        msg.ci95_high = [float(p.ci_high) for p in ps]
        msg.identifiable = [bool(p.identifiable) for p in ps]
        msg.at_bound = [bool(p.at_bound) for p in ps]
        msg.misfit = float(r.misfit)
        msg.rms_residual = float(r.stats.rms)
        msg.n_areas = int(r.main_fit.n_areas) if isinstance(r.main_fit, SoilFit) else 0
        msg.fit_duration = float(r.elapsed_s)
        msg.warnings = [one_line(w) for w in r.warnings]
        msg.parameters_yaml = r.parameters_yaml()
    if outcome.push is not None:
        msg.push_requested = True
        msg.push_target = outcome.push.target
        msg.push_accepted = outcome.push.accepted
        msg.push_reason = outcome.push.reason
    msg.metrics_json = dumps_json(outcome.metrics(), indent=None)
    return msg


def service_response(outcome: CalibrationOutcome, response: Any) -> Any:
    """Fill a ``Calibrate`` service response from an outcome (``parameters_yaml`` only with a fit)."""
    response.success = outcome.success
    response.message = outcome.message
    response.parameters_yaml = outcome.result.parameters_yaml() if outcome.result is not None else ""
    response.metrics_json = dumps_json(outcome.metrics(), indent=1 if outcome.result is not None else None)
    return response
