"""The typed vehicle-run builder: a :class:`VehicleRunSpec` in, a coupled simulation out.

One path from settings to a coupled vehicle–track run for every caller:
``clm simulate --vehicle`` (:mod:`clm_core.commands.simulate`), the ROS
vehicle node and scripts. The spec's defaults are those of the run-settings
schema (:mod:`clm_core.settings`): the Thalys power car at 83.33 m/s
(300 km/h) on a ``german-low`` rail profile (a high-speed line), seed 1,
for 3 s with dt = 1e-4 s.

    spec = VehicleRunSpec(vehicle="thalys", speed=60.0, irregularity="fra5")
    run = build_vehicle_run(spec, load_model("mevergnies", "mevergnies", "clm"))
    result = run.simulation.run(run.duration)

:func:`clm_core.outputs.vehicle_run.run_vehicle` runs it and writes the outputs (history, figures,
summary) one layer up.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal, cast

from clm_core import settings
from clm_core.errors import ParameterError
from clm_core.params import ModelParams
from clm_core.peaks import wheel_load_statistics
from clm_core.vehicle import irregularity as ir
from clm_core.vehicle.coupled import CoupledResult, CoupledSimulation
from clm_core.vehicle.multibody import Train, build_train
from clm_core.vehicle.presets import load_vehicle


def _d(s: settings.Setting[Any]) -> Any:
    return s.default


@dataclass(frozen=True)
class VehicleRunSpec:
    """What a coupled vehicle–track run is: the train, its speed, the rail, the numerics.

    Every field is a run setting of :mod:`clm_core.settings` (same name,
    unit, range and default) except ``defects``. Checked at construction:
    a value outside its setting's range raises :class:`ParameterError`
    naming the field, the value and the rule.

    Attributes
    ----------
    vehicle : str
        Vehicle preset or vehicle YAML file.
    cars : int
        First ``cars`` cars of the preset's composition (ignored with ``train``).
    train : tuple of str
        Composition by vehicle-type names, front to rear (``+``: articulated,
        ``~``: reversed); empty: ``cars``.
    speed : float
        Train speed [m/s] (>= 0, towards +x).
    duration : float
        Simulated time [s].
    dt : float
        Time step [s].
    start : float
        Position of the first wheel at t = 0 [m].
    irregularity : str
        ``fra1``..``fra6``, ``german-low``, ``german-high``, ``none`` or a CSV profile file.
    seed : int
        Random seed of the profile.
    wavelength_band : str
        ``"LMIN,LMAX"`` of the random profile [m].
    defects : tuple of str
        Isolated defects, :func:`clm_core.vehicle.irregularity.parse_defect` syntax.
    lead_in : float
        Distance over which the profile is ramped in [m].
    hertz : float or None
        Hertz constant [N/m^1.5] of every wheel; None: from the wheel radius.
    track_engine : {'stream', 'fixed'}
        Streaming window or fixed reference track.
    n_sleepers : int or None
        Window size; None: the smallest that holds the train (>= 61).
    elements_per_bay : int
        Rail elements per sleeper bay.
    lead_sleepers : int or None
        Sleepers kept ahead of the first wheel; None: a third of the window.
    output_dt : float
        Interval of the recorded snapshots [s], rounded to whole steps.
    """

    vehicle: str = _d(settings.VEHICLE)
    cars: int = _d(settings.CARS)
    train: tuple[str, ...] = ()
    speed: float = _d(settings.SPEED)
    duration: float = _d(settings.DURATION)
    dt: float = _d(settings.DT)
    start: float = _d(settings.START)
    irregularity: str = _d(settings.IRREGULARITY)
    seed: int = _d(settings.SEED)
    wavelength_band: str = _d(settings.WAVELENGTH_BAND)
    defects: tuple[str, ...] = field(default=())
    lead_in: float = _d(settings.LEAD_IN)
    hertz: float | None = _d(settings.HERTZ)
    track_engine: str = _d(settings.TRACK_ENGINE)
    n_sleepers: int | None = None
    elements_per_bay: int = _d(settings.ELEMENTS_PER_BAY)
    lead_sleepers: int | None = _d(settings.LEAD_SLEEPERS)
    output_dt: float = _d(settings.OUTPUT_DT)

    def __post_init__(self) -> None:
        for f in fields(self):
            value: Any = getattr(self, f.name)
            if f.name in ("train", "defects"):
                if isinstance(value, str) or not isinstance(value, (tuple, list)):
                    raise ParameterError(f"{f.name} = {value!r}: must be a sequence of strings (a tuple or list)")
                value = tuple(str(v) for v in value)
            elif f.name == "n_sleepers":
                value = None if value is None else settings.N_SLEEPERS.check(value, "n_sleepers")
            else:
                value = settings.setting(f.name).check(value)
            object.__setattr__(self, f.name, value)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> VehicleRunSpec:
        """A spec from ``{field: value}`` (unknown names refused; None keeps the default)."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ParameterError(f"vehicle run: unknown setting(s) {unknown}; known: {', '.join(sorted(names))}")
        return cls(**{k: v for k, v in values.items() if v is not None})

    @property
    def band(self) -> tuple[float, float]:
        """The wavelength band (LMIN, LMAX) [m]."""
        return settings.wavelength_band(self.wavelength_band)


@dataclass(frozen=True)
class VehicleRun:
    """A built run: the simulation, how long to run it, and its settings for the summary.

    Attributes
    ----------
    spec : VehicleRunSpec
    simulation : CoupledSimulation
        Ready to :meth:`~CoupledSimulation.run`.
    train : Train
    duration : float
        Simulated time [s] (``spec.duration``).
    settings : dict
        JSON-ready description (vehicle, cars, wheel offsets, static loads,
        speed, profile and its rms, window, model).
    """

    spec: VehicleRunSpec
    simulation: CoupledSimulation
    train: Train
    duration: float
    settings: dict[str, Any]


def build_vehicle_run(spec: VehicleRunSpec, params: ModelParams) -> VehicleRun:
    """Build the coupled simulation ``spec`` describes on the track and soil ``params``.

    Parameters
    ----------
    spec : VehicleRunSpec
    params : ModelParams
        Track and soil; per-sleeper ``stiffness:`` defects are added to it.

    Returns
    -------
    VehicleRun

    Raises
    ------
    ParameterError, PresetError
        Unknown vehicle, inconsistent defects, a profile that is neither a
        spectrum, ``none`` nor a CSV file, a window too small for the train.
    """
    vf = load_vehicle(spec.vehicle)
    cars = vf.compose([s for s in spec.train if s.strip()]) if spec.train else vf.cars(spec.cars)
    train = build_train(cars)

    rail_defects: list[ir.DippedJoint | ir.JointStep] = []
    flats: list[ir.WheelFlat] = []
    for text in spec.defects:
        d = ir.parse_defect(text)
        if isinstance(d, dict):
            vals = {k: v for k, v in d.items() if k not in ("from", "to")}
            params = ir.local_stiffness_change(params, d["from"], d["to"], values=vals)
        elif isinstance(d, ir.WheelFlat):
            if d.wheel >= train.n_wheels:
                raise ParameterError(f"defect {text!r}: wheel {d.wheel}; the train has {train.n_wheels} wheels")
            flats.append(d)
        else:
            rail_defects.append(d)

    # rail profile over the whole path of the wheels
    x_lo = spec.start - float(train.wheel_offset[-1]) - 1.0
    x_hi = spec.start + spec.speed * spec.duration + 1.0
    kind = spec.irregularity.strip()
    profile: ir.Profile | None
    random = kind.lower() in ir.SPECTRA
    if kind.lower() == "none":
        profile = None
    elif random:
        profile = ir.random_profile(kind.lower(), x_lo, x_hi - x_lo, seed=spec.seed, band=spec.band)
    else:
        p = Path(kind)
        if not p.exists() and p.suffix.lower() != ".csv":
            raise ParameterError(
                f"irregularity = {kind!r}: not a spectrum ({', '.join(ir.SPECTRA)}), 'none', or an existing CSV file"
            )
        profile = ir.load_profile_csv(p)
    irr = ir.Irregularity(profile=profile, defects=tuple(rail_defects), flats=tuple(flats),
                       lead_in=spec.lead_in if profile is not None else 0.0)

    every = max(1, int(round(spec.output_dt / spec.dt)))
    sim = CoupledSimulation(
        train, params, spec.speed, spec.dt, irregularity=irr, x_start=spec.start,
        engine=cast(Literal["stream", "fixed"], spec.track_engine), n_sleepers=spec.n_sleepers,
        elements_per_bay=spec.elements_per_bay,
        lead_sleepers=spec.lead_sleepers, hertz=spec.hertz, snapshot_every=every, duration_hint=spec.duration,
    )
    description: dict[str, Any] = {
        "vehicle": spec.vehicle,
        "cars": [c.vehicle.name + ("~" if c.reversed else "") + ("+" if c.shares_front_bogie else "") for c in cars],
        "n_wheels": train.n_wheels,
        "wheel_offsets_m": train.wheel_offset.tolist(),
        "static_wheel_loads_N": train.static_wheel_loads().tolist(),
        "weight_per_rail_N": train.weight_per_rail,
        "note": "one rail line: wheel loads are per wheel, half the axle load",
        "speed_m_per_s": spec.speed,
        "duration_s": spec.duration,
        "dt_s": spec.dt,
        "start_m": spec.start,
        "irregularity": kind,
        "irregularity_rms_m": profile.rms() if profile is not None else 0.0,
        "seed": spec.seed if random else None,
        "wavelength_band_m": list(spec.band) if random else None,
        "lead_in_m": irr.lead_in,
        "defects": list(spec.defects),
        "hertz_constant_N_per_m1.5": sim.hertz.tolist(),
        "track_engine": sim.engine,
        "window_sleepers": sim.n_sleepers,
        "elements_per_bay": sim.elements_per_bay,
        "model": params.name or "parameter file",
        "soil_model": params.soil.model,
        "n_overrides": len(params.overrides),
    }
    return VehicleRun(spec=spec, simulation=sim, train=train, duration=spec.duration, settings=description)


def simulate_vehicle(
    spec: VehicleRunSpec, params: ModelParams, progress: bool = False
) -> tuple[VehicleRun, CoupledResult, dict[str, Any]]:
    """Build and run the coupled simulation of ``spec``; write nothing.

    The one computing core of a vehicle run: ``clm simulate --vehicle``
    (:func:`clm_core.outputs.vehicle_run.run_vehicle`, which then writes the outputs) and every case of
    ``clm study`` (:mod:`clm_core.studies`) call it, so a study row and the
    ``summary.json`` of the same run alone hold the same numbers.

    Parameters
    ----------
    spec : VehicleRunSpec
    params : ModelParams
    progress : bool
        Show a progress bar (on a terminal).

    Returns
    -------
    (VehicleRun, CoupledResult, dict)
        The built run, its time histories and the summary
        (:meth:`CoupledResult.summary` with ``settings`` and
        ``sleeper_passing_frequency_Hz``; described in
        :func:`clm_core.outputs.vehicle_run.run_vehicle`).
    """
    run = build_vehicle_run(spec, params)
    sim = run.simulation
    res = sim.run(run.duration, progress=progress)
    summary = res.summary()
    summary.update({"settings": run.settings})
    summary["sleeper_passing_frequency_Hz"] = sim.speed / params.track.spacing if sim.speed > 0 else None
    summary.update(wheel_load_statistics(res.wheel_load, res.static_wheel_load, (res.t >= summary["stats_from_s"])
                                         & res.peak_window().instants(res.wheel_position.max(axis=1))))
    return run, res, summary
