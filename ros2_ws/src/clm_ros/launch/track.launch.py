"""Launch the CLM track-soil node alone (full ROS 2 install; see docs/ros-setup.md).

    ros2 launch clm_ros track.launch.py
    ros2 launch clm_ros track.launch.py params_file:=/path/to/my_track.yaml namespace:=line1
    ros2 launch clm_ros track.launch.py autostart:=false   # then: ros2 lifecycle set /clm_track_node configure

Launch arguments
----------------
params_file : ROS parameter file (default: share/clm_ros/config/demo.yaml; its
    ``/**`` and ``/**/clm_track_node`` sections apply).
namespace : namespace of the node and its topics (default none).
node_name : node name (default clm_track_node; a parameter file section must
    match it).
autostart : configure and activate at start (default true; false for a
    lifecycle manager). Overrides the file.
log_level : debug, info, warn, error (default info).

The node subscribes to ``wheel_loads`` (clm_msgs/WheelLoads) and publishes
``sleeper_response``, ``wheel_rail_response`` and ``/diagnostics``. Without a
ROS install (the project's venv) the same is
``python -m clm_ros.track_node --ros-args --params-file config/demo.yaml``.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    default_params = PathJoinSubstitution([FindPackageShare("clm_ros"), "config", "demo.yaml"])
    args = [
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="ROS parameter file of the track node"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the node and its topics"),
        DeclareLaunchArgument("node_name", default_value="clm_track_node", description="node name"),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="configure and activate at start (false: lifecycle manager)"),
        DeclareLaunchArgument("log_level", default_value="info", description="debug, info, warn or error"),
    ]
    track = Node(
        package="clm_ros",
        executable="track_node",
        name=LaunchConfiguration("node_name"),
        namespace=LaunchConfiguration("namespace"),
        parameters=[
            LaunchConfiguration("params_file"),
            {"autostart": ParameterValue(LaunchConfiguration("autostart"), value_type=bool)},
        ],
        ros_arguments=["--log-level", LaunchConfiguration("log_level")],
        output="screen",
        emulate_tty=True,
    )
    return LaunchDescription([*args, track])
