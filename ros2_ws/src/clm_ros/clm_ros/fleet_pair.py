"""One train's vehicle node and track node in one process, on one executor (``clm fleet --pair-process``).

``python -m clm_ros.fleet_pair --ros-args -r __ns:=/train_0 -p name:=value ...``
builds the track-soil node (:class:`clm_ros.track_node.TrackNode`) and the
vehicle simulator node (:class:`clm_ros.vehicle_node.VehicleNode`) in this
process, both in the namespace given, and serves them with one
``EventsExecutor``: the vehicle's timetable (its ``service()``, as
:func:`clm_ros.node_main.run_node` does it) between two turns of the
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

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions

from clm_core.errors import ClmError
from clm_ros.lifetime import StopSignals, publish_synchronously
from clm_ros.node_main import exit_process, freeze_heap
from clm_ros.track_node import TrackNode
from clm_ros.vehicle_node import VehicleNode

#: Longest wait between two looks at the stop request [s].
POLL = 0.1


def main(args: list[str] | None = None) -> int:
    """Run the pair until SIGINT, SIGTERM or the vehicle's ``exit_code``; return the exit code."""
    stop = StopSignals()
    stop.install(interrupt=True)  # during start-up a signal interrupts at once
    track: Any = None
    vehicle: Any = None
    executor: Any = None
    code = 0
    try:
        publish_synchronously()
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        track = TrackNode(stop=stop)
        if track.model is None and track.get_parameter("autostart").value:
            return 2
        vehicle = VehicleNode()
        freeze_heap()
        executor = EventsExecutor()
        executor.add_node(track)
        executor.add_node(vehicle)
        stop.install(interrupt=False)
        while not stop.requested() and rclpy.ok():
            executor.spin_once(timeout_sec=min(max(vehicle.service(), 0.0), POLL))
            if vehicle.exit_code is not None:
                code = int(vehicle.exit_code)
                break
    except KeyboardInterrupt:
        pass
    except ClmError as exc:
        print(f"fleet_pair: error: {exc}", file=sys.stderr)
        code = 2
    finally:
        stop.install(interrupt=False)
        if vehicle is not None:
            vehicle.stop()
            vehicle.destroy_node()
        if track is not None:
            track.destroy_node()
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    exit_process(main())
