"""The ROS nodes' settings table, and ROS parameters generated from settings (this one's and :mod:`clm_core.settings`).

Two tables of one :class:`clm_core.settings.Setting` kind, one per layer: the
core's (:data:`clm_core.settings.SETTINGS`: what the core runs) and the
nodes' own, here (:data:`NODE_SETTINGS`: transport, timing and real time of
the nodes, their diagnostics and live views, the vehicle node's schedule of
trains, ``clm demo``'s and ``clm fleet``'s options). :func:`lookup` finds a
setting in either; the ``clm`` options of the ROS commands are generated from
them like the core's (:func:`clm_core.commands._options.add_setting`).

:func:`declare_settings` declares node parameters from settings: the
default, a ``ParameterDescriptor`` whose description gives the unit, range
and default, ``FloatingPointRange``/``IntegerRange`` from the setting's
bounds, and ``read_only`` for structural settings. QoS is not among them: the
nodes expose it through rclpy's standard QoS overrides
(``qos_overrides./topic.publisher.reliability``, ...).

Integers for real-valued parameters are accepted: ``-p track.kb:=60000000``
on the command line and ``ros2 param set /clm_track_node track.kb 60000000``
at run time (both give an INTEGER, which rclpy refuses for a DOUBLE
parameter) are converted to DOUBLE before rclpy checks the type. Likewise a
number or a list of numbers for a list-valued setting (a comma-separated
string, e.g. ``monitored_sleepers``): ``-p monitored_sleepers:=[120,150]`` and
``-p monitored_sleepers:=120`` become ``"120,150"`` and ``"120"``.

Light at import: the table is read by ``clm --help`` (the ROS commands'
options), so rclpy is imported by the functions that declare parameters,
never by the module.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from clm_core.errors import ClmError
from clm_core.settings import MODEL_PARAMETERS, Setting, setting

if TYPE_CHECKING:
    from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
    from rclpy.node import Node
    from rclpy.parameter import Parameter


def _indices_rule(text: str) -> str:
    """Comma-separated whole numbers (empty: none), at most 256 of them."""
    items = [s.strip() for s in text.split(",") if s.strip()]
    try:
        [int(s) for s in items]
    except ValueError:
        return "expected comma-separated whole numbers (global sleeper indices), or nothing"
    return "" if len(items) <= 256 else "at most 256 sleepers"


def _optional_numbers_rule(text: str) -> str:
    """Comma-separated finite numbers, or nothing."""
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        return "expected comma-separated numbers"
    return "" if all(math.isfinite(v) for v in values) else "expected finite numbers"


# --------------------------------------------------------------------------- the table

# the wheel-load stream (vehicle node, clm demo)
RATE: Setting[float] = Setting("rate", float, 1000.0, "Hz", "wheel-load publication rate (1/(rate dt) must be a "
                               "whole number)", minimum=1.0, maximum=10000.0, read_only=True)
CLOSED_LOOP: Setting[bool] = Setting("closed_loop", bool, True, "-",
                                     "vehicle on the track node's rail deflection (false: on the quasi-static "
                                     "track compliance, no feedback)", read_only=True)

# the track node: real time, diagnostics, live views
LAG_BUDGET: Setting[float] = Setting(
    "lag_budget", float, 5e-3, "s", "answer lag (wheel-load stamp to published answer, on the stamps' clock) above "
    "which /diagnostics turns WARN", minimum=0.0, maximum=3600.0,
)
REALTIME_PRIORITY: Setting[int] = Setting(
    "realtime_priority", int, 10, "-", "SCHED_FIFO priority of the node process's threads once it is built "
    "(compilation and factorisation run before, at normal priority), so that other load on the machine does not "
    "delay an answer; 0: normal scheduling. Needs root, CAP_SYS_NICE or `ulimit -r`; refused, the node says so "
    "once (log, /diagnostics) and runs at normal priority", minimum=0, maximum=98, read_only=True,
)
MAX_FEEDBACK_DELAY: Setting[float] = Setting(
    "max_feedback_delay", float, 0.02, "s", "closed loop: an answer older than this is too late to be used as "
    "feedback (the vehicle ignores and counts it; the track node's /diagnostics turn ERROR)", minimum=0.0,
    maximum=10.0, read_only=True,
)
MONITORED_SLEEPERS: Setting[str] = Setting(
    "monitored_sleepers", str, "", "-", "global indices of sleepers whose fields are published as fixed series "
    "(topic monitored_sleepers; index i always the same sleeper, NaN while outside the window), comma-separated",
    rule=_indices_rule, read_only=True,
)
MONITORED_POSITIONS: Setting[str] = Setting(
    "monitored_positions", str, "", "m", "positions along the line whose nearest sleepers are monitored too "
    "(after monitored_sleepers), comma-separated", rule=_optional_numbers_rule, read_only=True,
)
ANSWER_LOOP: Setting[str] = Setting(
    "answer_loop", str, "executor", "-", "how the track node waits for wheel loads: executor = a thread waits on "
    "the arrival fd and hands each arrival to the executor, in order with the node's other events (/clock); "
    "waitset = the process's loop waits on the arrival fd itself and answers in its own thread, serving the "
    "executor one event per 2 ms in between: ~15 % less CPU per message (benchmarks/node_cpu.py), but /clock and "
    "other events fall behind under traffic (experimental)",
    choices=("executor", "waitset"), read_only=True,
)
MARKERS_PERIOD: Setting[float] = Setting(
    "markers_period", float, 0.1, "s", "period of the visualization_msgs/MarkerArray of the window (topic "
    "track_markers; wall clock); 0: none", minimum=0.0, maximum=3600.0, read_only=True,
)

# the vehicle node: its schedule of trains, the track node it waits for, the supervisor's start signal
TRAINS: Setting[int] = Setting(
    "trains", int, 0, "-", "trains the vehicle node runs after activation, one after another (0: until "
    "deactivated)", minimum=0, maximum=1_000_000, read_only=True,
)
HEADWAY: Setting[float] = Setting(
    "headway", float, 0.0, "s", "time between the starts of successive trains (0: each train starts train_pause "
    "after the previous one)", minimum=0.0, maximum=86400.0, read_only=True,
)
TRAIN_PAUSE: Setting[float] = Setting(
    "train_pause", float, 2.0, "s", "least pause between the end of a train and the start of the next (longer "
    "than the track node's max_gap, so that the track node starts each train from rest)", minimum=0.0,
    maximum=86400.0, read_only=True,
)
TRACK_NODE: Setting[str] = Setting(
    "track_node", str, "clm_track_node", "-", "name of the track node a train waits for: its wheel_loads "
    "subscription and wheel_rail_response publisher both matched (it is active and subscribed); empty: any "
    "subscriber", read_only=True,
)
ANSWER_TIMEOUT: Setting[float] = Setting(
    "answer_timeout", float, 1.0, "s", "a train without an answer of the track node for this long reports it "
    "silent (log, /diagnostics WARN) and runs on its predictor until answers return", minimum=0.01,
    maximum=3600.0, read_only=True,
)
EXIT_WHEN_DONE: Setting[bool] = Setting(
    "exit_when_done", bool, False, "-", "exit the vehicle node's process (code 0) after the last of `trains` "
    "trains (a launch file ends with it)", read_only=True,
)
#: The start signal: the first train of an activation waits for a start time on the latched topic ``start_at``
#: (std_msgs/Int64, system clock [ns]) in the node's namespace: a supervisor starts a fleet's trains together or
#: on its schedule (clm_ros.harness, clm_ros.readiness).
START_SIGNAL: Setting[bool] = Setting(
    "start_signal", bool, False, "-", "the first train of an activation also waits for a start time on the "
    "latched topic start_at (std_msgs/Int64, system clock ns; a supervisor's schedule)", read_only=True)

# clm demo, clm view: the ROS domain; clm fleet (issue 15.1): N vehicle + track node pairs on one ROS graph
DOMAIN_ID: Setting[int] = Setting(
    "domain_id", int, 42, "-", "ROS domain of clm demo's nodes (printed at start: watch the run live with "
    "ROS_DOMAIN_ID set to it)", minimum=0, maximum=232, flags=("--domain",),
)
FLEET_TRAINS: Setting[int] = Setting("fleet_trains", int, 2, "-", "vehicle + track node pairs started, each in "
                                     "its namespace /train_i", minimum=1, maximum=100, flags=("--trains",))
FLEET_FIRST_INDEX: Setting[int] = Setting("fleet_first_index", int, 0, "-", "index i of the first pair (/train_i): "
                                          "a second host starts further pairs", minimum=0, maximum=10000,
                                          flags=("--first-index",))

#: The ROS nodes' own settings by name (not run settings of the core: transport, timing, real time, views, the
#: schedule of trains, the ROS commands' options).
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
        RATE, CLOSED_LOOP,
        LAG_BUDGET, REALTIME_PRIORITY, MAX_FEEDBACK_DELAY, MONITORED_SLEEPERS, MONITORED_POSITIONS, MARKERS_PERIOD,
        ANSWER_LOOP,
        TRAINS, HEADWAY, TRAIN_PAUSE, TRACK_NODE, ANSWER_TIMEOUT, EXIT_WHEN_DONE, START_SIGNAL,
        DOMAIN_ID, FLEET_TRAINS, FLEET_FIRST_INDEX,
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

#: The track node's own settings (besides the model factory's, :data:`clm_core.online.model.FACTORY_SETTINGS`).
TRACK_NODE_SETTINGS: tuple[str, ...] = ("publish_every", "frame_id", "diagnostics_period", "autostart", "lag_budget",
                                        "max_feedback_delay", "monitored_sleepers", "monitored_positions",
                                        "markers_period", "realtime_priority", "answer_loop")


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
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

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


def _as_double(p: Parameter) -> Parameter:
    from rclpy.parameter import Parameter

    return Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))


def _as_text(p: Parameter) -> Parameter:
    """A number or a list of numbers as the comma-separated string of a list-valued setting."""
    from rclpy.parameter import Parameter

    values = p.value if p.type_ in (Parameter.Type.INTEGER_ARRAY, Parameter.Type.DOUBLE_ARRAY) else [p.value]
    return Parameter(p.name, Parameter.Type.STRING, ",".join(str(v) for v in values))


def _converted(p: Parameter, floats: set[str], texts: set[str]) -> Parameter:
    from rclpy.parameter import Parameter

    t = Parameter.Type
    if p.name in floats and p.type_ == t.INTEGER:
        return _as_double(p)
    if p.name in texts and p.type_ in (t.INTEGER, t.DOUBLE, t.INTEGER_ARRAY, t.DOUBLE_ARRAY):
        return _as_text(p)
    return p


def _pre_set(node: Node, params: list[Parameter]) -> list[Parameter]:
    """INTEGER values of real-valued parameters become DOUBLE, numbers of list-valued ones STRING
    (before rclpy's type check). A parameter the node does not have is refused here, by name: rclpy's own check
    names an empty list ("undeclared parameter(s): []", its generator is spent by ``any`` before it is listed)."""
    from rclpy.exceptions import ParameterNotDeclaredException

    unknown = [p.name for p in params if not node.has_parameter(p.name)]
    if unknown and not getattr(node, "_allow_undeclared_parameters", False):
        raise ParameterNotDeclaredException(unknown)
    floats: set[str] = getattr(node, _FLOATS_ATTR)
    texts: set[str] = getattr(node, _TEXTS_ATTR)
    return [_converted(p, floats, texts) for p in params]


def _validate(node: Node, params: list[Parameter]) -> SetParametersResult:
    """Refuse values outside the schema (choices, rules) with the setting's own message."""
    from rcl_interfaces.msg import SetParametersResult

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
