"""The receiver node: free-field velocities at configured receivers, online, beside the track node.

Subscribes to the track node's ``sleeper_response`` (``clm_msgs/SleeperResponse``:
global sleeper indices, positions and ballast forces on the soil of the
simulated window, one message per answered frame) and publishes
``receiver_velocities`` (``clm_msgs/ReceiverVelocities``) every model step
(every M frames, 250 Hz at the track node's 1 kHz): the streaming two-step
computation :class:`clm_core.freefield.ReceiverStream`, which gives the
numbers of the offline :func:`clm_core.freefield.receiver_velocity` on the
same forces (tests/ros/test_receiver_node.py, over real DDS).

Parameters (the run-settings schema, :mod:`clm_core.settings`):
``receivers`` (distances [m] from the track axis, at ``receiver_x``),
``receivers_file`` (CSV of x, y rows), ``receiver_x`` [m] (NaN: 0),
``receiver_soil`` (empty: the profile of ``soil``), ``receiver_influence`` [m],
``soil``, ``track`` (spacing and contact area), ``rate`` [Hz] (the track
node's frame rate: frames are ``1 / rate`` apart).

Frames must come without gaps (the filters' state depends on every frame).
A gap (a lost message, a new train) is logged and counted, and the stream
restarts from the frame after it (forces held from there, as at a start).
"""

from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np
from rclpy.node import Node

from clm_core.errors import ClmError
from clm_ros.node_main import StopSignals, run_node
from clm_ros.qos import answers_qos

NODE_NAME = "receiver_node"

__all__ = ["ReceiverNode", "main"]


class ReceiverNode(Node):
    """Streaming free-field receivers; see the module docstring."""

    def __init__(self, signals: StopSignals | None = None, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        from clm_core.freefield import FreeFieldModel, ReceiverStream
        from clm_core.outputs.receivers import parse_receivers, receiver_soil
        from clm_core.params import model_from_settings
        from clm_core.settings import RECEIVER_INFLUENCE, SOIL, TRACK
        from clm_ros.parameters import RATE

        p = {
            "receivers": self.declare_parameter("receivers", "").value,
            "receivers_file": self.declare_parameter("receivers_file", "").value,
            "receiver_x": self.declare_parameter("receiver_x", math.nan).value,
            "receiver_soil": self.declare_parameter("receiver_soil", "").value,
            "receiver_influence": self.declare_parameter("receiver_influence", RECEIVER_INFLUENCE.default).value,
            "soil": self.declare_parameter("soil", SOIL.default).value,
            "track": self.declare_parameter("track", TRACK.default).value,
            "rate": self.declare_parameter("rate", RATE.default).value,
        }
        self.exit_code: int | None = None
        self.gaps = 0
        self._log: Any = self.get_logger()  # type: ignore[no-untyped-call]  # rclpy leaves it unannotated
        try:
            x0 = 0.0 if not math.isfinite(float(p["receiver_x"])) else float(p["receiver_x"])
            rec = parse_receivers(p["receivers"] or None, p["receivers_file"] or None, x0)
            soil = receiver_soil(p["receiver_soil"] or None, p["soil"])
            params = model_from_settings(p["track"], p["soil"], "clm", None, {})
            self.model = FreeFieldModel(soil, rec, params.track.spacing, 1.0 / float(p["rate"]),
                                        contact_length=params.track.contact_length,
                                        contact_width=params.track.contact_width,
                                        influence_length=float(p["receiver_influence"]))
        except ClmError as exc:
            self._log.error(f"receiver node: cannot start: {exc}")
            self.exit_code = 2
            return
        self._stream_type = ReceiverStream
        self.stream = ReceiverStream(self.model)
        from clm_msgs.msg import ReceiverVelocities, SleeperResponse

        self._msg_type = ReceiverVelocities
        self.pub = self.create_publisher(ReceiverVelocities, "receiver_velocities", answers_qos())
        self.sub = self.create_subscription(SleeperResponse, "sleeper_response", self._on_frame, answers_qos())
        self._log.info(
            f"receiver node: {rec.shape[0]} receivers, soil '{soil.name}', {self.model.n_zone} sleepers in the zone, "
            f"FIR {self.model.n_fir} taps at {1 / self.model.model_dt:g} Hz, latency {self.model.delay} steps, filters "
            f"{'read from the cache' if self.model.cached else 'built (now cached)'}")

    def _on_frame(self, msg: Any) -> None:
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        idx = np.asarray(msg.sleeper_index, dtype=np.int64)
        force = np.asarray(msg.soil_force, dtype=float)
        try:
            out = self.stream.push(t, idx, force)
        except ClmError as exc:
            self.gaps += 1
            self._log.warning(f"receiver node: frame refused ({exc}); stream restarted "
                                      f"({self.gaps} restart(s))")
            self.stream = self._stream_type(self.model)
            out = self.stream.push(t, idx, force) if np.all(np.isfinite(force)) else None
        if out is None:
            return
        t_out, v = out
        m = self._msg_type()
        ns = int(round(t_out * 1e9))
        m.header.stamp.sec, m.header.stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
        m.header.frame_id = msg.header.frame_id
        m.x = [float(a) for a in self.model.receivers[:, 0]]
        m.y = [float(a) for a in self.model.receivers[:, 1]]
        m.velocity = [float(a) for a in v]
        self.pub.publish(m)


def main(args: list[str] | None = None) -> int:
    """Console entry point ``receiver_node``: init, spin until SIGINT/SIGTERM, shut down cleanly (0; 2: bad setup)."""
    return run_node(ReceiverNode, args, NODE_NAME)


if __name__ == "__main__":
    sys.exit(main())
