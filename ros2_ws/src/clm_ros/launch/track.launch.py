"""Launch the CLM track-soil node alone (full ROS 2 install; see docs/ros-setup.md).

    ros2 launch clm_ros track.launch.py
    ros2 launch clm_ros track.launch.py params_file:=/path/to/my_track.yaml namespace:=line1
    ros2 launch clm_ros track.launch.py soil:=haren wheel_loads_topic:=/simulator/wheel_loads
    ros2 launch clm_ros track.launch.py autostart:=false   # then: ros2 lifecycle set /clm_track_node configure

For an external vehicle simulator: publish ``clm_msgs/WheelLoads`` on
``wheel_loads`` once the node's subscription is there (it subscribes when
active, after its model is built and compiled), read ``sleeper_response`` and
``wheel_rail_response``. Without a ROS install (the project's venv) the same
is ``python -m clm_ros.track_node --ros-args --params-file config/demo.yaml``.

Launch arguments
----------------
The common ones (``clm_ros.launch_common``): namespace, use_sim_time,
params_file (its ``/**`` and ``/**/clm_track_node`` sections apply), track,
soil, model, wheel_loads_topic, sleeper_response_topic,
wheel_rail_response_topic, log_level; and:

node_name : node name (default clm_track_node; a parameter file section must
    match it).
autostart : configure and activate at start (default true; false for a
    lifecycle manager). Overrides the file.
"""

from clm_ros import launch_common as common
from launch import LaunchDescription


def nodes(context):  # type: ignore[no-untyped-def]
    return [common.node(context, "track_node", common.value(context, "node_name"),
                        {"autostart": common.flag(context, "autostart")})]


def generate_launch_description() -> LaunchDescription:
    return common.launch_description(nodes, "ROS parameter file of the track node", {
        "node_name": ("clm_track_node", "node name"),
        "autostart": ("true", "configure and activate at start (false: lifecycle manager)"),
    })
