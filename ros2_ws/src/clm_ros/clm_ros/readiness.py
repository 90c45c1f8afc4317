"""How a vehicle knows that its own track node is ready, and when its train starts (clm_ros.vehicle_node).

A vehicle waits for its OWN track node: the node named ``track_node`` in the
vehicle's namespace, its ``wheel_loads`` reader and ``wheel_rail_response``
writer on the graph (:func:`owned`), every reader of ``wheel_loads`` known on
the graph matched by the vehicle's writer (:func:`all_matched`: a count of
matched readers cannot tell whose they are), and the track node's own latched
word that its reader matched the vehicle's writer (``track_status``,
:mod:`clm_ros.latched`). Never "any N readers".

With ``start_signal`` the first train of an activation also waits for a
start time on the latched topic ``start_at`` (:data:`START_AT`): a supervisor
(:mod:`clm_ros.harness`) starts the trains of a fleet together, or on the
user's schedule, once every one is ready.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.qos import QoSCompatibility, qos_check_compatible

from clm_ros.parameters import START_SIGNAL  # the setting lives in the nodes' table (issue 22)

__all__ = ["START_AT", "START_SIGNAL", "all_matched", "owned"]
#: The latched start-time topic (relative: in the node's namespace).
START_AT = "start_at"


def owned(endpoint: Any, name: str, ns: str) -> bool:
    """Whether a graph endpoint (``TopicEndpointInfo``) belongs to node ``name`` in namespace ``ns``."""
    return bool(endpoint.node_name == name and endpoint.node_namespace == ns)


def all_matched(pub: Any, readers: Sequence[Any]) -> bool:
    """Whether ``pub`` has matched every reader of its topic known on the graph that can match it (compatible QoS).

    The count of matched readers alone cannot tell whose: with a recorder and a listener on another host, two
    readers match before the track node's has (issue 21: a vehicle that started then lost the track node's first
    334 messages). Every known reader matched includes the track node's.
    """
    compatible = [r for r in readers
                  if qos_check_compatible(pub.qos_profile, r.qos_profile)[0] != QoSCompatibility.ERROR]
    return int(pub.get_subscription_count()) >= len(compatible)
