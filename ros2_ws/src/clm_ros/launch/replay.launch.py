"""Replay a bag of wheel loads through the CLM track-soil node over DDS (full ROS 2 install).

    ros2 launch clm_ros replay.launch.py bag:=/path/to/demo_bag
    ros2 launch clm_ros replay.launch.py bag:=demo_bag out:=answers_bag use_sim_time:=true rate:=0.5
    ros2 launch clm_ros replay.launch.py bag:=demo_bag namespace:=line1 soil:=haren

Starts the track node and ``ros2 bag play`` of the bag's ``/wheel_loads``
(remapped into the namespace / onto ``wheel_loads_topic``); with ``out`` also
``ros2 bag record`` of the answers. With ``use_sim_time:=true`` the player
publishes the bag's time on ``/clock`` (``--clock``) and the nodes run on it.
The launch ends 2 s after the player is done. ``clm replay`` computes the same
answers offline, without middleware (bit for bit: tests/ros/test_track_node.py).

Launch arguments
----------------
The common ones (``clm_ros.launch_common``): namespace, use_sim_time,
params_file, track, soil, model, wheel_loads_topic, sleeper_response_topic,
wheel_rail_response_topic, log_level; and:

bag : the bag to play (required).
rate : playback rate (default 1.0).
out : bag of the answers (``ros2 bag record``); empty (the default): none.
"""

from clm_ros import launch_common as common
from launch import LaunchDescription
from launch.actions import EmitEvent, ExecuteProcess, RegisterEventHandler, TimerAction
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown


def nodes(context):  # type: ignore[no-untyped-def]
    bag = common.value(context, "bag")
    if not bag:
        raise RuntimeError("replay.launch.py: give the bag to play: bag:=/path/to/bag")
    sim = common.flag(context, "use_sim_time")
    wheel_loads = common.topic(context, "wheel_loads")
    out = [common.node(context, "track_node", "clm_track_node")]
    play = ExecuteProcess(
        cmd=["ros2", "bag", "play", bag, "--rate", common.value(context, "rate"), "--topics", "/wheel_loads",
             *(["--clock"] if sim else []), *(["--remap", f"/wheel_loads:={wheel_loads}"]
                                              if wheel_loads != "/wheel_loads" else [])],
        output="screen")
    out.append(play)
    if common.value(context, "out"):
        out.append(ExecuteProcess(
            cmd=["ros2", "bag", "record", "--storage", "mcap", "--output", common.value(context, "out"),
                 *(["--use-sim-time"] if sim else []), "--topics", wheel_loads,
                 common.topic(context, "sleeper_response"), common.topic(context, "wheel_rail_response"),
                 "/diagnostics"],
            output="screen"))
    # the player exits at the end of the bag: the last answers, then the end
    out.append(RegisterEventHandler(OnProcessExit(target_action=play, on_exit=[TimerAction(
        period=2.0, actions=[EmitEvent(event=Shutdown(reason="bag played"))])])))
    return out


def generate_launch_description() -> LaunchDescription:
    return common.launch_description(nodes, "ROS parameter file of the track node", {
        "bag": ("", "the bag to play (required)"),
        "rate": ("1.0", "playback rate"),
        "out": ("", "bag of the answers (empty: none)"),
    })
