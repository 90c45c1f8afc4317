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

With ``-p record_bag:=PATH`` (``clm fleet --pair-process`` records this way)
the process also records the pair's own topics (``record_topics``, comma
separated, relative to the namespace) to the rosbag2 bag PATH
(:class:`PairRecorder`): raw subscriptions of a third node in the same
participant, so Fast DDS hands each message over within the process (no
transport, no send to another process's reader: the pair's writers and a
supervisor's recorder cost ~0.5 core at 5 trains x 1 kHz, issue 21), taken
between two turns of the executor and written as they come, at most
:data:`RECORD_POLL` s after they arrived. Its latched ``recorder_status``
says when its readers have matched the pair's writers and how many messages
of each topic it holds; the bag is closed (and appears at PATH) when the
process stops.

Exit codes: 0 after SIGINT/SIGTERM or the vehicle's last train with
``exit_when_done``; 2 when a node cannot be configured at start.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import rclpy
from rclpy.node import Node

from clm_ros.latched import RECORDER_STATUS, LatchedStatus
from clm_ros.node_main import StopSignals, run_node
from clm_ros.track_node import TrackNode
from clm_ros.vehicle_node import VehicleNode

#: Longest time a message waits in the pair recorder's reader before it is written [s].
RECORD_POLL = 0.02
#: How often the pair recorder's latched status is brought up to date [s].
STATUS_PERIOD = 0.25


class PairRecorder(Node):
    """Records the pair's own topics in its process (``record_bag``, ``record_topics``, ``storage``).

    The node itself has no subscription (the executor must not take the messages): they belong to a helper node
    no executor spins, taken by :meth:`serve_due` (:class:`clm_ros.bag_tools.BagRecorder`, polled). Without
    ``record_bag`` it records nothing and says so.
    """

    def __init__(self) -> None:
        super().__init__("clm_pair_recorder")
        from clm_ros.bag_tools import BagRecorder
        from clm_ros.fleet import PAIR_TOPICS

        path = str(self.declare_parameter("record_bag", "").value)
        wanted = [t.strip() for t in str(self.declare_parameter("record_topics", "wheel_loads").value).split(",")]
        storage = str(self.declare_parameter("storage", "mcap").value)
        unknown = [t for t in wanted if t not in PAIR_TOPICS]
        if unknown:
            raise ValueError(f"record_topics: {', '.join(unknown)} not among the pair's topics "
                             f"{', '.join(PAIR_TOPICS)}")
        self.rec: BagRecorder | None = None
        self._sub_node: Node | None = None
        self._status = LatchedStatus(self, RECORDER_STATUS, "pair recorder")
        self._next_status = 0.0
        if path:
            ns = self.get_namespace().rstrip("/")
            self._sub_node = rclpy.create_node("clm_pair_recorder_readers", namespace=self.get_namespace(),
                                               context=self.context)
            self.rec = BagRecorder(self._sub_node, path, {f"{ns}/{t}": PAIR_TOPICS[t] for t in wanted}, storage,
                                   polled=True)
        self._publish_status()

    def _publish_status(self) -> None:
        if self.rec is None:
            self._status.update(0, "not recording", {})
            return
        matched = self.rec.matched(list(self.rec.topics))
        self._status.update(0, "recording" if matched else "waiting for the pair's writers",
                            {"matched": matched, **{t.rsplit("/", 1)[1]: n for t, n in self.rec.counts.items()}})

    def serve_due(self) -> float:
        """Write what has arrived; bring the latched status up to date now and then; the next poll's wait [s]."""
        if self.rec is not None and not self.rec.closed:
            self.rec.poll()
            now = time.monotonic()
            if now >= self._next_status:
                self._next_status = now + STATUS_PERIOD
                self._publish_status()
        return RECORD_POLL

    def stop(self) -> None:
        """The process is ending: write what is left, close the bag (it appears at its path), say the counts."""
        if self.rec is not None and not self.rec.closed:
            self.rec.close()
            self._status.update(0, "closed", {"matched": True, **{t.rsplit("/", 1)[1]: n
                                                                  for t, n in self.rec.counts.items()}})

    def destroy_node(self) -> None:
        """Close the bag if still open, destroy the readers' node, then this node."""
        self.stop()
        if self._sub_node is not None:
            self._sub_node.destroy_node()
            self._sub_node = None
        super().destroy_node()  # type: ignore[no-untyped-call]


def _make(stop: StopSignals) -> tuple[Any, ...]:
    """The pair: the track node, then the vehicle node and its recorder (not built when the track model cannot be
    configured: the track node's ``exit_code`` 2 ends the process)."""
    track = TrackNode(stop=stop)
    if track.exit_code is not None:
        return (track,)
    return track, VehicleNode(), PairRecorder()


def main(args: list[str] | None = None) -> int:
    """Run the pair until SIGINT, SIGTERM or the vehicle's ``exit_code``; return the exit code
    (:func:`clm_ros.node_main.run_node`: one executor for both nodes, the vehicle's timetable between two turns)."""
    return run_node(_make, args, "fleet_pair", exit_now=args is None)


if __name__ == "__main__":
    sys.exit(main())
