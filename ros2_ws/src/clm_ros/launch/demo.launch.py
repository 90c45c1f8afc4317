"""Launch the CLM demo: vehicle simulator node + track-soil node (full ROS 2 install).

    ros2 launch clm_ros demo.launch.py
    ros2 launch clm_ros demo.launch.py record:=true bag:=demo_bag    # also ros2 bag record
    ros2 launch clm_ros demo.launch.py params_file:=/path/to/my_demo.yaml

The demo defaults (``config/demo.yaml``): the Thalys at 83.33 m/s (300 km/h)
over the Mevergnies track on its CLM soil, wheel loads at 1 kHz in closed
loop, track model at dt = 1e-4 s on a 61-sleeper window, 3 s simulated. The
vehicle node waits for the track node (and the recorder with
``record:=true``), runs, waits for the answers and exits; the launch then
shuts down (the track node with it). This is the graph ``clm demo`` starts
in the project's venv, where ``ros2 launch`` is not available (that command
also records with rosbags and plots).

Launch arguments
----------------
params_file : ROS parameter file for both nodes (default:
    share/clm_ros/config/demo.yaml).
namespace : namespace of both nodes and their topics (default none).
record : also run ``ros2 bag record`` of the demo topics (default false).
bag : output bag directory of the recorder (default clm_demo_bag).
log_level : debug, info, warn, error (default info).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, ExecuteProcess, RegisterEventHandler
from launch.conditions import IfCondition
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

#: What the demo records (the topics of ``clm demo``; the first three in the namespace).
TOPICS = ["wheel_loads", "sleeper_response", "wheel_rail_response"]


def generate_launch_description() -> LaunchDescription:
    default_params = PathJoinSubstitution([FindPackageShare("clm_ros"), "config", "demo.yaml"])
    params = LaunchConfiguration("params_file")
    ns = LaunchConfiguration("namespace")
    record = LaunchConfiguration("record")
    log = ["--log-level", LaunchConfiguration("log_level")]
    args = [
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="ROS parameter file of both nodes"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the nodes and topics"),
        DeclareLaunchArgument("record", default_value="false", description="also run ros2 bag record"),
        DeclareLaunchArgument("bag", default_value="clm_demo_bag", description="output bag of the recorder"),
        DeclareLaunchArgument("log_level", default_value="info", description="debug, info, warn or error"),
    ]
    track = Node(
        package="clm_ros",
        executable="track_node",
        name="clm_track_node",
        namespace=ns,
        parameters=[params],
        ros_arguments=log,
        output="screen",
        emulate_tty=True,
    )
    # with the recorder, the vehicle waits for two subscribers of wheel_loads so
    # that the bag holds the first message too
    n_subs = PythonExpression(["2 if '", record, "'.lower() in ('true', '1', 'yes') else 1"])
    vehicle = Node(
        package="clm_ros",
        executable="vehicle_node",
        name="clm_vehicle_node",
        namespace=ns,
        parameters=[params, {"wait_for_subscribers": ParameterValue(n_subs, value_type=int)}],
        ros_arguments=log,
        output="screen",
        emulate_tty=True,
    )
    # "/ns" or "" (the recorder runs outside the namespace: give it full topic names)
    prefix = PythonExpression(["'/' + '", ns, "'.strip('/') if '", ns, "'.strip('/') else ''"])
    recorder = ExecuteProcess(
        cmd=["ros2", "bag", "record", "--storage", "mcap", "--output", LaunchConfiguration("bag"),
             "--topics", *[[prefix, "/" + t] for t in TOPICS], "/diagnostics"],
        condition=IfCondition(record),
        output="screen",
    )
    # the vehicle node exits when its run is answered: end the demo then
    stop = RegisterEventHandler(OnProcessExit(target_action=vehicle, on_exit=[EmitEvent(event=Shutdown(
        reason="vehicle run finished"))]))
    return LaunchDescription([*args, recorder, track, vehicle, stop])
