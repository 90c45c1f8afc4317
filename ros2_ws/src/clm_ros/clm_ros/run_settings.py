"""The run settings of an online run (``clm demo``, ``clm fleet``): one typed object, from the one schema.

:class:`RunSettings` holds what a vehicle + track node pair runs: the train,
its speed and length of run, the track and soil, the numerics, the rail
profile, the loop, the bag storage, the ROS domain and the nodes' real-time priority. Every field is the run
setting of :mod:`clm_core.settings` or :mod:`clm_ros.parameters` of the same name (type, unit, range and
default), checked at construction. ``clm demo`` and ``clm fleet`` offer these
options (:data:`NAMES`) and build the object from the parsed arguments
(:meth:`RunSettings.from_args`); :func:`clm_ros.launcher.run_demo` and
:func:`clm_ros.fleet.run_fleet` take it, and turn it into the nodes'
parameters (:meth:`RunSettings.track_parameters`,
:meth:`RunSettings.vehicle_parameters`) and the settings part of their
``summary.json`` (:meth:`RunSettings.summary`) here, in one place.

Light: nothing here imports the ROS layer or numpy (``clm --help`` reads :data:`NAMES`).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, fields
from typing import Any

from clm_core import settings
from clm_core.errors import ParameterError
from clm_ros import parameters

#: Period of the nodes' /diagnostics in an online run [s] (the launcher watches the vehicle's).
DIAGNOSTICS_PERIOD = 0.5


def _default(s: settings.Setting[Any]) -> Any:
    """The default of a run setting that has one (not automatic)."""
    if s.default is None:
        raise ParameterError(f"setting {s.name} has no default (automatic: {s.none_means})")
    return s.default


@dataclass(frozen=True)
class RunSettings:
    """What a vehicle + track node pair runs: the train, the track and soil, the numerics, the bag, the domain.

    Each field is the setting of the same name (:func:`clm_ros.parameters.lookup`)
    (its description, type, unit, range and default: ``clm demo --help``
    shows them), checked at construction: a value outside its setting's range
    raises :class:`ParameterError` naming the field, the value and the rule.
    A fleet's pair ``i`` runs with the irregularity seed ``seed + i``.
    """

    vehicle: str = _default(settings.VEHICLE)
    speed: float = _default(settings.SPEED)
    duration: float = _default(settings.DURATION)
    track: str = _default(settings.TRACK)
    soil: str = _default(settings.SOIL)
    model: str = _default(settings.MODEL)
    rate: float = _default(parameters.RATE)
    dt: float = _default(settings.DT)
    n_sleepers: int = _default(settings.N_SLEEPERS)
    irregularity: str = _default(settings.IRREGULARITY)
    seed: int = _default(settings.SEED)
    closed_loop: bool = _default(parameters.CLOSED_LOOP)
    storage: str = _default(settings.STORAGE)
    domain_id: int = _default(parameters.DOMAIN_ID)
    realtime_priority: int = _default(parameters.REALTIME_PRIORITY)

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, parameters.lookup(f.name).check(getattr(self, f.name), f.name))

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> RunSettings:
        """The settings of parsed ``clm demo`` / ``clm fleet`` arguments (their options :data:`NAMES`)."""
        return cls(**{name: getattr(args, name) for name in NAMES})

    @property
    def messages(self) -> int:
        """Wheel-load messages of one train: ``round(duration * rate) + 1``."""
        return round(self.duration * self.rate) + 1

    def track_parameters(self) -> dict[str, Any]:
        """The ROS parameters of the track node."""
        return {"track": self.track, "soil": self.soil, "model": self.model, "dt": self.dt,
                "n_sleepers": self.n_sleepers, "diagnostics_period": DIAGNOSTICS_PERIOD,
                "realtime_priority": self.realtime_priority}

    def vehicle_parameters(self, seed_offset: int = 0, wait_for_subscribers: int = 2) -> dict[str, Any]:
        """The ROS parameters of a vehicle node: one train, then idle until stopped (the launcher stops it).

        ``seed_offset`` is added to the irregularity seed (a fleet's pair
        ``i``); the vehicle waits for ``wait_for_subscribers`` readers of its
        wheel loads (the track node, and the recorder when there is one).
        """
        return {
            "vehicle": self.vehicle, "speed": self.speed, "duration": self.duration, "rate": self.rate,
            "irregularity": self.irregularity, "seed": self.seed + seed_offset,
            "closed_loop": self.closed_loop, "track": self.track, "soil": self.soil, "model": self.model,
            "trains": 1, "exit_when_done": False, "wait_for_subscribers": wait_for_subscribers,
            "diagnostics_period": DIAGNOSTICS_PERIOD, "realtime_priority": self.realtime_priority,
        }

    def summary(self) -> dict[str, Any]:
        """The settings as ``summary.json`` states them (keys with units; the seed of the first train)."""
        return {
            "vehicle": self.vehicle, "speed_m_per_s": self.speed, "duration_s": self.duration, "track": self.track,
            "soil": self.soil, "model": self.model, "rate_hz": self.rate, "dt_s": self.dt,
            "n_sleepers": self.n_sleepers, "irregularity": self.irregularity, "seed": self.seed,
            "closed_loop": self.closed_loop, "realtime_priority": self.realtime_priority,
        }


#: The run settings' names, in order: the options of ``clm demo`` and ``clm fleet`` (with the schema's defaults).
NAMES: tuple[str, ...] = tuple(f.name for f in fields(RunSettings))
#: Their settings (:func:`clm_ros.parameters.lookup`: the core's run settings and the nodes' own), in order.
RUN_SETTINGS: tuple[settings.Setting[Any], ...] = tuple(parameters.lookup(name) for name in NAMES)
