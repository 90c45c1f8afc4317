"""Launch a fleet of trains: N vehicle simulator + track-soil node pairs, pair i in namespace /train_i (full ROS 2).

    ros2 launch clm_ros fleet.launch.py trains:=4
    ros2 launch clm_ros fleet.launch.py trains:=2 first_index:=2      # a second host: /train_2, /train_3
    ros2 launch clm_ros fleet.launch.py trains:=3 namespace:=line1    # /line1/train_0 ... /line1/train_2

The graph of ``clm fleet`` (clm_ros.fleet), which also records, checks each
pair against offline replay and writes summary.json: each pair is the demo's
(``demo.launch.py``: same parameter file, presets, remaps), in its own
namespace (with ``seed`` given, the vehicle ``i`` has the irregularity
seed ``seed + i``, as ``clm fleet``; else the parameter file's). Every
vehicle waits for the track node of its namespace, runs ``runs`` trains and
exits; the launch ends when every vehicle has exited. All pairs are in one ROS
domain (``ROS_DOMAIN_ID``); pairs on several hosts: docs/fleet.md.

Launch arguments
----------------
The common ones (``clm_ros.launch_common``; ``namespace`` is the prefix of
the pairs' namespaces) and:

trains : number of pairs (default 2).
first_index : index of the first pair (default 0).
vehicle, speed, duration : vehicle preset, speed [m/s], simulated time per
    train [s]; empty (the default): the parameter file's.
seed : irregularity seed of pair 0 (pair i: seed + i); empty (the default):
    the parameter file's, for every pair.
runs : trains run one after another by each vehicle (default 1).
"""

from typing import Any

from clm_ros import launch_common as common
from launch import LaunchDescription
from launch.actions import EmitEvent, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown


class _PairContext:
    """The launch context as pair ``i`` sees it: its namespace ``<namespace>/train_i``."""

    def __init__(self, context: Any, ns: str) -> None:
        self.launch_configurations = {**context.launch_configurations, "namespace": ns}


def nodes(context):  # type: ignore[no-untyped-def]
    trains, first = int(common.value(context, "trains")), int(common.value(context, "first_index"))
    if trains < 1 or first < 0:
        raise ValueError(f"trains = {trains}, first_index = {first}: need trains >= 1 and first_index >= 0")
    prefix = common.namespace(context)
    own = common.vehicle_settings(context)
    out, vehicles, done = [], [], []
    for i in range(first, first + trains):
        pair = _PairContext(context, f"{prefix}/train_{i}")
        out.append(common.node(pair, "track_node", "clm_track_node"))
        vehicles.append(common.node(pair, "vehicle_node", "clm_vehicle_node", {
            **own,
            **({"seed": int(common.value(context, "seed")) + i} if common.value(context, "seed") else {}),
            "trains": int(common.value(context, "runs")),
            "exit_when_done": True,
            "wait_for_subscribers": 1,
            "publish_clock": False,
            "use_sim_time": False,
        }))
    out += vehicles

    # the launch ends when the last vehicle has exited
    def exited(event, _context):  # type: ignore[no-untyped-def]
        done.append(event)
        if len(done) == len(vehicles):
            return [EmitEvent(event=Shutdown(reason="every vehicle's trains done"))]
        return []

    out += [RegisterEventHandler(OnProcessExit(target_action=v, on_exit=exited)) for v in vehicles]
    return out


def generate_launch_description() -> LaunchDescription:
    return common.launch_description(nodes, "ROS parameter file of every node", {
        "trains": ("2", "vehicle + track node pairs"),
        "first_index": ("0", "index of the first pair /train_i"),
        "seed": ("", "irregularity seed of pair 0 (pair i: + i); empty: the parameter file's"),
        "runs": ("1", "trains run by each vehicle"),
    }, vehicle=True)
