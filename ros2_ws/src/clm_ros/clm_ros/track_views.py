"""Live views of the track node for standard tools (PlotJuggler, Foxglove, RViz).

The answers of the track node describe a window that moves with the train:
entry i of ``sleeper_response`` is a different sleeper every few
milliseconds, so a plotting tool cannot follow one sleeper there. Two views
fix that:

- :class:`MonitoredSleepers`: fixed series, a ``clm_msgs/SleeperResponse``
  on ``monitored_sleepers`` whose entry i is always the same sleeper (global
  index, from the ``monitored_sleepers`` and ``monitored_positions``
  settings), its fields NaN while that sleeper is outside the window.
  PlotJuggler plots ``/monitored_sleepers/soil_force[0]`` as one sleeper's
  history.
- :func:`window_markers`: a ``visualization_msgs/MarkerArray`` of the window
  for RViz and Foxglove 3D: the sleepers as boxes coloured by their soil
  force (blue: none, red: the largest in the window) and lowered by their
  displacement, and the rail's deflected line; displacements are drawn
  :data:`EXAGGERATION` times larger (1 mm shows as 1 m). x is the position
  along the line, z points up.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from geometry_msgs.msg import Point, Vector3
from numpy.typing import NDArray
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from clm_core.errors import ParameterError
from clm_core.io.messages import encode_sleeper_response
from clm_core.settings import number_list
from clm_ros.parameters import MONITORED_POSITIONS, MONITORED_SLEEPERS

#: Drawing scale of displacements in the markers (1 mm -> 1 m).
EXAGGERATION = 1000.0
#: Sleeper box [m]: along the line, across, height.
SLEEPER_BOX = (0.25, 2.6, 0.2)


def monitored_indices(sleepers: str, positions: str, spacing: float) -> NDArray[np.int64]:
    """Global indices of the monitored sleepers, in the order given (duplicates removed).

    Parameters
    ----------
    sleepers : str
        ``monitored_sleepers``: comma-separated global indices.
    positions : str
        ``monitored_positions``: comma-separated positions [m]; each picks the
        nearest sleeper (sleeper i lies at i * spacing).
    spacing : float
        Sleeper spacing [m].

    Raises
    ------
    ParameterError
        A value that is not a whole number or not a finite position.
    """
    MONITORED_SLEEPERS.check(sleepers)
    MONITORED_POSITIONS.check(positions)
    idx = [int(v) for v in number_list(sleepers)] + [int(round(x / spacing)) for x in number_list(positions)]
    if len(idx) > 256:
        raise ParameterError(f"monitored_sleepers, monitored_positions: {len(idx)} sleepers; at most 256")
    return np.array(list(dict.fromkeys(idx)), dtype=np.int64)


class MonitoredSleepers:
    """Fixed per-sleeper series out of a moving window.

    Parameters
    ----------
    indices : (m,) int array
        Global indices of the monitored sleepers.
    spacing : float
        Sleeper spacing [m] (positions = index * spacing).
    """

    def __init__(self, indices: NDArray[np.int64], spacing: float) -> None:
        self.indices = np.ascontiguousarray(indices, dtype=np.int64)
        self.positions = self.indices.astype(np.float64) * spacing
        self._nan = np.full(self.indices.size, np.nan)

    def __bool__(self) -> bool:
        return bool(self.indices.size)

    def fields(self, sleeper_index: NDArray[np.int64], *arrays: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        """The monitored entries of window ``arrays`` (NaN for a sleeper outside the window).

        Parameters
        ----------
        sleeper_index : (N,) int array
            Global indices of the window (consecutive).
        *arrays : (N,) arrays
            Window fields (soil force, displacements, ...).
        """
        first = int(sleeper_index[0]) if sleeper_index.size else 0
        local = self.indices - first
        inside = (local >= 0) & (local < sleeper_index.size)
        pick = np.where(inside, local, 0)
        return [np.where(inside, a[pick], self._nan) if a.size else self._nan.copy() for a in arrays]

    def encode(self, stamp_ns: int, frame_id: str, sleepers: Any) -> bytes:
        """A serialized ``SleeperResponse`` of the monitored sleepers from the window fields of ``sleepers``
        (a :class:`clm_core.online.ResponseFrame`)."""
        f, r, s, a = self.fields(sleepers.sleeper_index, sleepers.soil_force, sleepers.rail_deflection,
                                 sleepers.sleeper_displacement, sleepers.area_displacement)
        return encode_sleeper_response(stamp_ns, frame_id, self.indices, self.positions, f, r, s, a)


def _colour(value: float) -> Any:
    """Blue (0) to red (1)."""
    v = min(max(value, 0.0), 1.0)
    return ColorRGBA(r=v, g=0.2 * (1.0 - abs(2.0 * v - 1.0)), b=1.0 - v, a=1.0)


def window_markers(sleepers: Any, header: Any) -> Any:
    """A ``visualization_msgs/MarkerArray`` of the window: sleepers coloured by soil force, the deflected rail.

    Parameters
    ----------
    sleepers : ResponseFrame
        ``sleeper_x`` [m], ``soil_force`` [N], ``rail_deflection`` and
        ``sleeper_displacement`` [m] (positive downwards) of the window.
    header : std_msgs/Header
        Stamp and frame of the markers.
    """
    x = np.asarray(sleepers.sleeper_x, dtype=float).tolist()
    force = np.asarray(sleepers.soil_force, dtype=float)
    scale = max(float(np.max(np.abs(force))) if force.size else 0.0, 1e3)
    zs = (-EXAGGERATION * np.asarray(sleepers.sleeper_displacement, dtype=float)).tolist()
    zr = (SLEEPER_BOX[2] - EXAGGERATION * np.asarray(sleepers.rail_deflection, dtype=float)).tolist()
    box = Marker(header=header, ns="sleepers (soil force: blue 0, red max; displacement x1000)", id=0,
                 type=Marker.CUBE_LIST, action=Marker.ADD, scale=Vector3(x=SLEEPER_BOX[0], y=SLEEPER_BOX[1],
                                                                          z=SLEEPER_BOX[2]))
    box.pose.orientation.w = 1.0
    box.points = [Point(x=a, y=0.0, z=b) for a, b in zip(x, zs)]
    box.colors = [_colour(v) for v in (force / scale).tolist()]
    rail = Marker(header=header, ns="rail (deflection x1000)", id=1, type=Marker.LINE_STRIP, action=Marker.ADD,
                  scale=Vector3(x=0.07, y=0.0, z=0.0))
    rail.pose.orientation.w = 1.0
    rail.color.r, rail.color.g, rail.color.b, rail.color.a = 0.8, 0.8, 0.8, 1.0
    rail.points = [Point(x=a, y=0.0, z=b) for a, b in zip(x, zr)]
    return MarkerArray(markers=[box, rail])
