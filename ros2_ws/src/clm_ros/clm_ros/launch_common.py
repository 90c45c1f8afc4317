"""What the launch files of clm_ros share: their common arguments and how the nodes are made from them.

Used by ``launch/demo.launch.py``, ``launch/fleet.launch.py``,
``launch/track.launch.py`` and ``launch/replay.launch.py`` (``ros2 launch
clm_ros ...`` in a full ROS 2 install): each declares its description with
:func:`launch_description` (the common arguments, its own, its nodes).
``launch``/``launch_ros`` are imported inside the functions: this module
imports without them (they are not installable from PyPI; the
packaging test runs the launch files against stand-ins of their classes).

Common launch arguments
-----------------------
namespace
    Namespace of the nodes and their topics (``/diagnostics`` and ``/clock``
    stay global); default none. The same as ``-r __ns:=/train1`` on a node.
use_sim_time
    ``true``: the nodes run on ``/clock`` (the demo's vehicle node publishes
    it; a replay takes it from the bag); default ``false``.
params_file
    ROS parameter file of the nodes; default ``share/clm_ros/config/demo.yaml``.
track, soil, model
    Presets of the track, the soil and the foundation model
    (:mod:`clm_core.settings`); empty (the default): as the parameter file says.
wheel_loads_topic, sleeper_response_topic, wheel_rail_response_topic
    Remaps of the data topics (default: their own names, in the namespace).
log_level
    ``debug``, ``info``, ``warn`` or ``error``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

#: Presets given as launch arguments; empty: the parameter file's value.
PRESETS = ("track", "soil", "model")
#: The data topics, each with a ``<topic>_topic`` launch argument that remaps it.
TOPICS = ("wheel_loads", "sleeper_response", "wheel_rail_response")
#: The track node's live views (fixed per-sleeper series, the window as markers), recorded by the demo.
LIVE_VIEWS = {"monitored_sleepers": "clm_msgs/msg/SleeperResponse",
              "track_markers": "visualization_msgs/msg/MarkerArray"}
#: Sleepers the demo monitors (global indices; x = 60, 120, 180 m, all passed by the demo's train): the series
#: that config/foxglove_demo.json plots.
DEMO_MONITORED_SLEEPERS = "100,200,300"


def arguments(params_description: str = "ROS parameter file of the nodes") -> list[Any]:
    """``DeclareLaunchArgument`` of every common argument (see the module docstring)."""
    from launch.actions import DeclareLaunchArgument
    from launch.substitutions import PathJoinSubstitution
    from launch_ros.substitutions import FindPackageShare

    default_params = PathJoinSubstitution([FindPackageShare("clm_ros"), "config", "demo.yaml"])
    out = [
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the nodes and topics"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="run the nodes on /clock"),
        DeclareLaunchArgument("params_file", default_value=default_params, description=params_description),
        *[DeclareLaunchArgument(name, default_value="", description=f"{name} preset (empty: the parameter file's)")
          for name in PRESETS],
        *[DeclareLaunchArgument(f"{t}_topic", default_value=t, description=f"remap of the topic {t}")
          for t in TOPICS],
        DeclareLaunchArgument("log_level", default_value="info", description="debug, info, warn or error"),
    ]
    return out


#: Vehicle settings given as launch arguments of the demo and fleet launches (empty: the parameter file's) and
#: their types.
VEHICLE_SETTINGS: dict[str, type] = {"vehicle": str, "speed": float, "duration": float}


def vehicle_arguments() -> list[Any]:
    """``DeclareLaunchArgument`` of each of :data:`VEHICLE_SETTINGS`."""
    from launch.actions import DeclareLaunchArgument

    return [DeclareLaunchArgument(k, default_value="", description=f"vehicle {k} (empty: the parameter file's)")
            for k in VEHICLE_SETTINGS]


def vehicle_settings(context: Any) -> dict[str, Any]:
    """The :data:`VEHICLE_SETTINGS` given at launch, typed (those left empty are not in it)."""
    return {k: t(value(context, k)) for k, t in VEHICLE_SETTINGS.items() if value(context, k)}


def launch_description(
    nodes: Callable[[Any], list[Any]],
    params_description: str,
    own: Mapping[str, tuple[str, str]],
    *,
    vehicle: bool = False,
) -> Any:
    """The ``LaunchDescription`` of a clm_ros launch file.

    Parameters
    ----------
    nodes : callable
        Makes the launch's actions from its launch context (an ``OpaqueFunction``).
    params_description : str
        Description of the ``params_file`` argument (which nodes it configures).
    own : mapping
        The file's own arguments, ``{name: (default, description)}``, declared
        after the common ones (:func:`arguments`).
    vehicle : bool
        Also declare the vehicle's arguments (:func:`vehicle_arguments`).
    """
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction

    return LaunchDescription([
        *arguments(params_description),
        *(vehicle_arguments() if vehicle else []),
        *[DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in own.items()],
        OpaqueFunction(function=nodes),
    ])


def value(context: Any, name: str) -> str:
    """The value of launch argument ``name`` in ``context`` (an OpaqueFunction's launch context)."""
    return str(context.launch_configurations[name])


def flag(context: Any, name: str) -> bool:
    """A boolean launch argument (``true``, ``1``, ``yes``)."""
    return value(context, name).strip().lower() in ("true", "1", "yes")


def namespace(context: Any) -> str:
    """The namespace argument as ``/ns`` (or ``""``)."""
    ns = value(context, "namespace").strip("/")
    return f"/{ns}" if ns else ""


def topic(context: Any, name: str) -> str:
    """Full name of topic ``name`` after its remap (data topics) and in the namespace (for ``ros2 bag``)."""
    t = value(context, f"{name}_topic") if name in TOPICS else name
    return t if t.startswith("/") else f"{namespace(context)}/{t}"


def node(context: Any, executable: str, name: str, parameters: dict[str, Any] | None = None,
         **kwargs: Any) -> Any:
    """A ``launch_ros`` ``Node`` of clm_ros with the common arguments applied.

    Parameters, in this order (a later one wins): the parameter file, the
    presets given, ``use_sim_time``, then ``parameters``.
    """
    from launch_ros.actions import Node

    over: dict[str, Any] = {p: value(context, p) for p in PRESETS if value(context, p)}
    over["use_sim_time"] = flag(context, "use_sim_time")
    over.update(parameters or {})
    remaps = [(t, value(context, f"{t}_topic")) for t in TOPICS if value(context, f"{t}_topic") != t]
    return Node(
        package="clm_ros",
        executable=executable,
        name=name,
        namespace=namespace(context),
        parameters=[value(context, "params_file"), over],
        remappings=remaps,
        ros_arguments=["--log-level", value(context, "log_level")],
        output="screen",
        emulate_tty=True,
        **kwargs,
    )
