"""Launch the CLM demo: vehicle simulator node + track-soil node (full ROS 2 install).

    ros2 launch clm_ros demo.launch.py
    ros2 launch clm_ros demo.launch.py record:=true bag:=demo_bag          # also ros2 bag record
    ros2 launch clm_ros demo.launch.py namespace:=train1 use_sim_time:=true
    ros2 launch clm_ros demo.launch.py soil:=haren vehicle:=intercity speed:=44.4
    ros2 launch clm_ros demo.launch.py params_file:=/path/to/my_demo.yaml

The demo defaults (``config/demo.yaml``, the run settings of clm_core): the
Thalys at 83.33 m/s (300 km/h) on a german-low rail profile over the
Mevergnies track on its CLM soil, wheel loads at 1 kHz in closed loop, track
model at dt = 1e-4 s on a 61-sleeper window, 3 s simulated. The vehicle node
waits until the track node is active and subscribed (and the recorder with
``record:=true``), runs ``trains`` trains, waits for the answers and exits;
the launch then shuts down (the track node with it). ``clm demo`` starts the
same graph in the project's venv, where ``ros2 launch`` is not available
(it also records with rosbags, and plots).

Launch arguments
----------------
The common ones (``clm_ros.launch_common``): namespace, use_sim_time (the
vehicle then publishes ``/clock`` and stamps with simulation time),
params_file, track, soil, model, wheel_loads_topic, sleeper_response_topic,
wheel_rail_response_topic, log_level; and:

vehicle, speed, duration : vehicle preset, speed [m/s], simulated time per
    train [s]; empty (the default): the parameter file's.
trains : trains run one after another before the launch ends (default 1).
record : also run ``ros2 bag record`` of the demo topics (as ``clm demo``
    records them: the data topics, the window's markers, /diagnostics;
    default false).

The track node monitors sleepers 100, 200 and 300 (``monitored_sleepers``):
``config/foxglove_demo.json`` is a Foxglove layout of the demo (live with
foxglove_bridge, or on the recorded bag; docs/ros-nodes.md).
bag : output bag directory of the recorder (default clm_demo_bag).
"""

from clm_ros import launch_common as common
from launch import LaunchDescription
from launch.actions import EmitEvent, ExecuteProcess, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown


def nodes(context):  # type: ignore[no-untyped-def]
    record = common.flag(context, "record")
    sim = common.flag(context, "use_sim_time")
    track = common.node(context, "track_node", "clm_track_node",
                        {"monitored_sleepers": common.DEMO_MONITORED_SLEEPERS})
    own = common.vehicle_settings(context)
    vehicle = common.node(context, "vehicle_node", "clm_vehicle_node", {
        **own,
        "trains": int(common.value(context, "trains")),
        "exit_when_done": True,
        # with the recorder the vehicle waits for two readers of wheel_loads, so that the bag holds the first message
        "wait_for_subscribers": 2 if record else 1,
        # in a sim-time graph the vehicle is the clock: it publishes /clock and is not driven by it
        "publish_clock": sim,
        "use_sim_time": False,
    })
    out = [track, vehicle]
    if record:
        topics = [common.topic(context, t) for t in (*common.TOPICS, "track_markers")]
        out.append(ExecuteProcess(
            cmd=["ros2", "bag", "record", "--storage", "mcap", "--output", common.value(context, "bag"),
                 *(["--use-sim-time"] if sim else []), "--topics", *topics, "/diagnostics"],
            output="screen"))
    # the vehicle node exits when its trains are answered: end the demo then
    out.append(RegisterEventHandler(OnProcessExit(target_action=vehicle, on_exit=[EmitEvent(event=Shutdown(
        reason="vehicle trains done"))])))
    return out


def generate_launch_description() -> LaunchDescription:
    return common.launch_description(nodes, "ROS parameter file of both nodes", {
        "trains": ("1", "trains before the launch ends"),
        "record": ("false", "also run ros2 bag record"),
        "bag": ("clm_demo_bag", "output bag of the recorder"),
    }, vehicle=True)
