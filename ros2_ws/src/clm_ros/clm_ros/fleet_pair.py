"""One train's vehicle node and track node in one process, on one executor (``clm fleet --pair-process``).

``python -m clm_ros.fleet_pair --ros-args -r __ns:=/train_0 -p name:=value ...``
builds the track-soil node (:class:`clm_ros.track_node.TrackNode`) and the
vehicle simulator node (:class:`clm_ros.vehicle_node.VehicleNode`) in this
process, both in the namespace given, and serves them with one
``EventsExecutor``: the vehicle's timetable (its ``serve_due()``, by
:func:`clm_ros.node_main.run_node`) between two turns of the
executor, which runs the track node's callbacks. The two nodes still talk
over DDS topics (Fast DDS delivers within the process), so the graph, the
topics and every answer are those of two separate processes; what is saved is
one process per train, one wake-up per message on the pair's side, and the
transport between processes. The ``-p`` parameters apply to both nodes (each
takes the ones it declares; the fleet gives shared ones, such as ``track``,
the same value).

Exit codes: 0 after SIGINT/SIGTERM or the vehicle's last train with
``exit_when_done``; 2 when a node cannot be configured at start.
"""

from __future__ import annotations

import sys
from typing import Any

from clm_ros.node_main import StopSignals, run_node
from clm_ros.track_node import TrackNode
from clm_ros.vehicle_node import VehicleNode


def _make(stop: StopSignals) -> tuple[Any, ...]:
    """The pair: the track node, then the vehicle node (not built when the track model cannot be configured:
    the track node's ``exit_code`` 2 ends the process)."""
    track = TrackNode(stop=stop)
    if track.exit_code is not None:
        return (track,)
    return track, VehicleNode()


def main(args: list[str] | None = None) -> int:
    """Run the pair until SIGINT, SIGTERM or the vehicle's ``exit_code``; return the exit code
    (:func:`clm_ros.node_main.run_node`: one executor for both nodes, the vehicle's timetable between two turns)."""
    return run_node(_make, args, "fleet_pair", exit_now=args is None)


if __name__ == "__main__":
    sys.exit(main())
