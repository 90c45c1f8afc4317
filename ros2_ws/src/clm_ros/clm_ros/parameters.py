"""ROS parameters generated from the run-settings schema (:mod:`clm_core.settings`).

:func:`declare_settings` declares node parameters from
:class:`clm_core.settings.Setting` objects: the default, a
``ParameterDescriptor`` whose description gives the unit, range and default,
``FloatingPointRange``/``IntegerRange`` from the setting's bounds, and
``read_only`` for structural settings. The nodes' own operational parameters
(frame id, timeouts) are settings of the same kind, declared below
(:data:`NODE_SETTINGS`), so every parameter of every node is described one way.
QoS is not among them: the nodes expose it through rclpy's standard QoS
overrides (``qos_overrides./topic.publisher.reliability``, ...).

Integers for real-valued parameters are accepted: ``-p track.kb:=60000000``
on the command line and ``ros2 param set /clm_track_node track.kb 60000000``
at run time (both give an INTEGER, which rclpy refuses for a DOUBLE
parameter) are converted to DOUBLE before rclpy checks the type. Likewise a
number or a list of numbers for a list-valued setting (a comma-separated
string, e.g. ``monitored_sleepers``): ``-p monitored_sleepers:=[120,150]`` and
``-p monitored_sleepers:=120`` become ``"120,150"`` and ``"120"``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.node import Node
from rclpy.parameter import Parameter

from clm_core.errors import ClmError
from clm_core.settings import MODEL_PARAMETERS, Setting, setting

# --------------------------------------------------------------------------- the nodes' own settings

#: Settings of the ROS nodes that are not run settings (transport, timing of the node itself).
NODE_SETTINGS: dict[str, Setting[Any]] = {
    s.name: s
    for s in (
        Setting("publish_every", int, 1, "-", "publish the response of every N-th accepted message (1: all)",
                minimum=1, maximum=100000),
        Setting("frame_id", str, "track", "-", "frame id of the output headers"),
        Setting("diagnostics_period", float, 1.0, "s", "period of /diagnostics", minimum=0.01, maximum=3600.0,
                read_only=True),
        Setting("autostart", bool, True, "-", "configure and activate at start", read_only=True),
        Setting("publish_clock", bool, False, "-", "publish /clock and stamp with simulation time from 0",
                read_only=True),
        Setting("wait_for_subscribers", int, 1, "-", "subscribers of wheel_loads to wait for before starting",
                minimum=0, maximum=100, read_only=True),
        Setting("discovery_timeout", float, 30.0, "s", "how long to wait for them", minimum=0.0, maximum=3600.0,
                read_only=True),
        Setting("ack_timeout", float, 10.0, "s", "after the run, wait this long for the track's answers",
                minimum=0.0, maximum=3600.0, read_only=True),
        Setting("push_timeout", float, 10.0, "s", "how long a push waits for the target node's parameter "
                "service and its answer", minimum=0.1, maximum=600.0),
        # --- the calibration node's (were calibration_node.py DEFAULT_METHOD, MAX_QUEUED and calibration_goal.py
        # ALLOWED_ROOTS; the methods are clm_core.calibration.options.METHODS, not imported here to keep the
        # calibration package out of every node's start: tests/ros/test_calibration_node.py checks they agree)
        Setting("default_method", str, "impact", "-", "method used when a goal leaves 'method' empty",
                choices=("impact", "receptance", "passby")),
        Setting("max_queued", int, 4, "-", "goals that may wait while one runs (0: reject while busy)", minimum=0,
                maximum=1000),
        Setting("allowed_roots", str, ".", "-", "directories (comma-separated) under which a goal's bag, "
                "parameter file and channel map may lie ('.': the node's working directory)", read_only=True),
    )
}


def lookup(name: str | Setting[Any]) -> Setting[Any]:
    """A setting by name: the nodes' own (:data:`NODE_SETTINGS`), then the run settings and model parameters."""
    if isinstance(name, Setting):
        return name
    return NODE_SETTINGS[name] if name in NODE_SETTINGS else setting(name)


# --------------------------------------------------------------------------- descriptors


def descriptor(s: Setting[Any], read_only: bool | None = None) -> ParameterDescriptor:
    """The ``ParameterDescriptor`` of a setting.

    Parameters
    ----------
    s : Setting
    read_only : bool, optional
        Override of ``s.read_only`` (a node that builds everything at start
        declares every parameter read-only).
    """
    text = s.help()
    if s.default is None:
        text += f" (unset: {s.ros_unset!r})"
    d = ParameterDescriptor(description=text, read_only=s.read_only if read_only is None else bool(read_only))
    if s.choices:
        d.additional_constraints = "one of " + ", ".join(s.choices)
    elif s.rule is not None and s.rule.__doc__:
        d.additional_constraints = s.rule.__doc__.strip().splitlines()[0]
    lo, hi = s.minimum, s.maximum
    if s.kind is float and (lo is not None or hi is not None):
        unset = s.ros_unset
        if not (isinstance(unset, float) and math.isnan(unset)):  # a NaN stand-in cannot pass a range check
            d.floating_point_range = [FloatingPointRange(
                from_value=-math.inf if lo is None else float(lo), to_value=math.inf if hi is None else float(hi),
                step=0.0)]
    if s.kind is int and (lo is not None or hi is not None):
        ilo = -(2**63) if lo is None else int(lo)
        ihi = 2**63 - 1 if hi is None else int(hi)
        if isinstance(s.ros_unset, int) and not isinstance(s.ros_unset, bool):
            ilo, ihi = min(ilo, s.ros_unset), max(ihi, s.ros_unset)
        d.integer_range = [IntegerRange(from_value=ilo, to_value=ihi, step=1)]
    return d


# --------------------------------------------------------------------------- declaration

_FLOATS_ATTR = "_clm_float_parameters"
_TEXTS_ATTR = "_clm_list_parameters"
_SETTINGS_ATTR = "_clm_settings"


_NUMBERS = (Parameter.Type.INTEGER, Parameter.Type.DOUBLE, Parameter.Type.INTEGER_ARRAY,
            Parameter.Type.DOUBLE_ARRAY)


def _as_double(p: Parameter) -> Parameter:
    return Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))


def _as_text(p: Parameter) -> Parameter:
    """A number or a list of numbers as the comma-separated string of a list-valued setting."""
    values = p.value if p.type_ in (Parameter.Type.INTEGER_ARRAY, Parameter.Type.DOUBLE_ARRAY) else [p.value]
    return Parameter(p.name, Parameter.Type.STRING, ",".join(str(v) for v in values))


def _converted(p: Parameter, floats: set[str], texts: set[str]) -> Parameter:
    if p.name in floats and p.type_ == Parameter.Type.INTEGER:
        return _as_double(p)
    if p.name in texts and p.type_ in _NUMBERS:
        return _as_text(p)
    return p


def _pre_set(node: Node, params: list[Parameter]) -> list[Parameter]:
    """INTEGER values of real-valued parameters become DOUBLE, numbers of list-valued ones STRING
    (before rclpy's type check). A parameter the node does not have is refused here, by name: rclpy's own check
    names an empty list ("undeclared parameter(s): []", its generator is spent by ``any`` before it is listed)."""
    unknown = [p.name for p in params if not node.has_parameter(p.name)]
    if unknown and not getattr(node, "_allow_undeclared_parameters", False):
        raise ParameterNotDeclaredException(unknown)
    floats: set[str] = getattr(node, _FLOATS_ATTR)
    texts: set[str] = getattr(node, _TEXTS_ATTR)
    return [_converted(p, floats, texts) for p in params]


def _validate(node: Node, params: list[Parameter]) -> SetParametersResult:
    """Refuse values outside the schema (choices, rules) with the setting's own message."""
    known: dict[str, Setting[Any]] = getattr(node, _SETTINGS_ATTR)
    for p in params:
        s = known.get(p.name)
        if s is None:
            continue
        try:
            s.from_ros(p.value)
        except ClmError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
    return SetParametersResult(successful=True)


def declare_settings(
    node: Node, names: Iterable[str | Setting[Any]], read_only: bool | None = None
) -> dict[str, Any]:
    """Declare one parameter per setting on ``node``; return ``{name: value}`` as the node starts with.

    Parameters
    ----------
    node : rclpy.node.Node
    names : iterable of str or Setting
        Run settings (:data:`clm_core.settings.SETTINGS`), model parameters
        (``track.kb``) or the nodes' own (:data:`NODE_SETTINGS`).
    read_only : bool, optional
        Declare every one read-only (True) or none (False); default: each
        setting's own ``read_only``.

    Notes
    -----
    Values given as integers for real-valued settings (``-p speed:=80``) are
    taken as DOUBLE, at declaration and on later changes. Later changes are
    also checked against the schema (choices, rules) and refused with its
    message; the values at start are checked by the node when it builds its
    model (the track node stays unconfigured on a bad value rather than dying).
    """
    if not hasattr(node, _FLOATS_ATTR):
        setattr(node, _FLOATS_ATTR, set())
        setattr(node, _TEXTS_ATTR, set())
        setattr(node, _SETTINGS_ATTR, {})
        node.add_pre_set_parameters_callback(lambda params: _pre_set(node, params))
    floats: set[str] = getattr(node, _FLOATS_ATTR)
    texts: set[str] = getattr(node, _TEXTS_ATTR)
    known: dict[str, Setting[Any]] = getattr(node, _SETTINGS_ATTR)
    # rclpy keeps the command-line overrides in this dict (no public accessor); an integer given for a
    # real-valued parameter would be refused by the type check of declare_parameter
    overrides: dict[str, Parameter] = getattr(node, "_parameter_overrides", {})
    values: dict[str, Any] = {}
    for item in names:
        s = lookup(item)
        if s.kind is float:
            floats.add(s.name)
        elif s.kind is str and s.rule is not None:  # list-valued settings are strings with a rule
            texts.add(s.name)
        o = overrides.get(s.name)
        if o is not None:
            overrides[s.name] = _converted(o, floats, texts)
        p = node.declare_parameter(s.name, s.to_ros(), descriptor(s, read_only))
        known[s.name] = s
        values[s.name] = p.value
    if not getattr(node, "_clm_validating", False):
        node.add_on_set_parameters_callback(lambda params: _validate(node, params))
        node._clm_validating = True  # type: ignore[attr-defined]
    return values


def declare_model_parameters(node: Node) -> None:
    """Every scalar model parameter as ``<section>.<name>`` (``track.kb``, ``soil.kf``), NaN = from the preset.

    Not read-only: a running track node takes a new set (validated as a whole) at run time.
    """
    declare_settings(node, MODEL_PARAMETERS.values(), read_only=False)
