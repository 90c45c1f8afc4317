"""Run settings: one schema for the command line, the ROS nodes and the typed run builders.

Every setting of a run (time step, window, speed, irregularity, ...) is
declared here ONCE, with its type, unit, admissible range, default and
description. The ``clm`` options (:mod:`clm_core.commands._options`), the ROS
parameter descriptors (``clm_ros.parameters``) and the defaults of the typed
builders (:class:`clm_core.vehicle.run.VehicleRunSpec`) are generated from
this table, so a default has one value everywhere: ``clm simulate
--vehicle``, the vehicle node and ``clm demo`` run the same train at the same
speed on the same rail profile unless told otherwise.

This is the core's table: what the core runs. The ROS nodes' own settings
(their real time, diagnostics and views, the vehicle node's schedule of
trains, ``clm demo``'s and ``clm fleet``'s) are settings of the same
:class:`Setting` kind in the table of ``clm_ros.parameters``.

A setting whose default is ``None`` is *automatic*; ``none_means`` says what
that is (e.g. ``lead_sleepers``: a third of the window). ROS parameters cannot
be unset, so such a setting has a stand-in value there (``ros_unset``: -1,
NaN or the empty string).

Ranges are inclusive (as ROS ``FloatingPointRange``/``IntegerRange``); a value
outside is refused by :meth:`Setting.check` with a :class:`ParameterError`
naming the setting, the value and the rule. Rules that need more than the
value (a file that must exist, a window large enough for the train) are
checked where the run is built.

Nothing here imports numpy, the ROS layer or any heavy module: ``clm --help``
reads this table.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Generic, TypeVar, cast

from clm_core.errors import ParameterError
from clm_core.params import PARAMETER_DOCS, SOIL_MODELS

V = TypeVar("V", float, int, str, bool)

_KIND_NAMES = {float: "a real number", int: "an integer", str: "a string", bool: "true or false"}


@dataclass(frozen=True)
class Setting(Generic[V]):
    """One run setting: name, type, unit, range, default and description.

    Attributes
    ----------
    name : str
        Identifier: the ROS parameter name, the keyword of the typed builders
        and the key in ``summary.json`` files (snake_case).
    kind : type
        ``float``, ``int``, ``str`` or ``bool``.
    default : value or None
        The one default; None: automatic (see ``none_means``).
    unit : str
        SI unit (``m/s``, ``s``, ``Hz``); ``-`` for counts and names.
    description : str
        What it sets, in a few words (no unit, no default: added by :meth:`help`).
    minimum, maximum : float, optional
        Inclusive bounds of numeric settings (in ``unit``).
    choices : tuple of str
        Admissible values of a string setting (empty: any string).
    read_only : bool
        Structural: fixed once a model or run is built (a ROS node refuses
        changes at run time).
    none_means : str
        For an automatic setting (default None): what an unset value means.
    ros_unset : value, optional
        The ROS parameter value that stands for "unset" (-1, NaN, ``""``).
    flags : tuple of str
        Command-line option strings; default ``--name-with-dashes``. The first
        is the canonical one; others are accepted synonyms.
    rule : callable, optional
        Extra rule on a value: returns ``""`` when the value is admissible,
        else the rule it breaks (e.g. ``"two values LMIN,LMAX with 0 < LMIN < LMAX"``).
    """

    name: str
    kind: type[V]
    default: V | None
    unit: str
    description: str
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False
    none_means: str = ""
    ros_unset: V | None = None
    flags: tuple[str, ...] = ()
    rule: Callable[[V], str] | None = None

    def __post_init__(self) -> None:
        if self.default is None and not self.none_means:
            raise ValueError(f"setting {self.name}: an automatic default (None) needs none_means")
        if self.default is not None:
            self.check(self.default)

    # ------------------------------------------------------------------ names and text

    @property
    def option(self) -> str:
        """The canonical command-line option, e.g. ``--speed``."""
        return self.flags[0] if self.flags else "--" + self.name.replace("_", "-")

    @property
    def option_strings(self) -> tuple[str, ...]:
        """Every command-line option string (canonical first)."""
        return self.flags if self.flags else (self.option,)

    def range_text(self) -> str:
        """The admissible values in words: ``0 to 150 m/s``, ``>= 1``, ``one of mcap, sqlite3``."""
        u = "" if self.unit in ("", "-") else f" {self.unit}"
        if self.choices:
            return "one of " + ", ".join(self.choices)
        lo, hi = self.minimum, self.maximum
        fmt = (lambda x: str(int(x))) if self.kind is int else _num
        if lo is not None and hi is not None:
            return f"{fmt(lo)} to {fmt(hi)}{u}"
        if lo is not None:
            return f">= {fmt(lo)}{u}"
        if hi is not None:
            return f"<= {fmt(hi)}{u}"
        return ""

    def default_text(self) -> str:
        """The default as shown in help texts."""
        if self.default is None:
            return self.none_means
        if self.kind is bool:
            return "true" if self.default else "false"
        u = "" if self.unit in ("", "-") else f" {self.unit}"
        if self.kind is str:
            return f"{self.default}" if self.default != "" else "none"
        return f"{_num(float(self.default))}{u}"

    def help(self) -> str:
        """Description with unit, range and default: ``train speed [m/s]; 0 to 150 m/s; default 83.33 m/s``."""
        text = self.description + ("" if self.unit in ("", "-") else f" [{self.unit}]")
        rng = self.range_text()
        if rng:
            text += f"; {rng}"
        return f"{text}; default {self.default_text()}"

    # ------------------------------------------------------------------ values

    def check(self, value: Any, label: str | None = None) -> V | None:
        """Return ``value`` as this setting's type, or raise :class:`ParameterError`.

        Parameters
        ----------
        value : object
            Candidate value; None is admissible for an automatic setting.
            Integers are accepted for real-valued settings (``60000000`` for
            60e6); booleans are never numbers.
        label : str, optional
            Name used in the message (default ``name``; the CLI passes the option).

        Raises
        ------
        ParameterError
            ``"<label> = <value>: <rule>"``: wrong type, outside the range,
            not among the choices, or breaking ``rule``.
        """
        who = label or self.name
        if value is None:
            if self.default is None:
                return None
            raise ParameterError(f"{who}: a value is needed ({self.range_text() or _KIND_NAMES[self.kind]})")
        v = cast(V, self._convert(value, who))
        if isinstance(v, float) and not math.isfinite(v):
            raise ParameterError(f"{who} = {v}: must be finite")
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if (self.minimum is not None and v < self.minimum) or (self.maximum is not None and v > self.maximum):
                raise ParameterError(f"{who} = {_num(float(v))}: must be {self.range_text()}")
        if self.choices and v not in self.choices:
            raise ParameterError(f"{who} = {v!r}: must be {self.range_text()}")
        if self.rule is not None:
            broken = self.rule(v)
            if broken:
                raise ParameterError(f"{who} = {v!r}: {broken}")
        return v

    def parse(self, text: str, label: str | None = None) -> V | None:
        """Convert command-line ``text`` and :meth:`check` it."""
        who = label or self.option
        if self.kind is bool:
            low = text.strip().lower()
            if low not in ("true", "false", "1", "0", "yes", "no"):
                raise ParameterError(f"{who} = {text!r}: must be true or false")
            return self.check(low in ("true", "1", "yes"), who)
        if self.kind in (int, float):
            try:
                num: float | int = int(text) if self.kind is int else float(text)
            except ValueError:
                raise ParameterError(f"{who} = {text!r}: must be {_KIND_NAMES[self.kind]}") from None
            return self.check(num, who)
        return self.check(text, who)

    def from_ros(self, value: Any) -> V | None:
        """A ROS parameter value as this setting's value (``ros_unset`` -> None), checked."""
        unset = self.ros_unset
        if unset is not None and (value == unset or _both_nan(value, unset)):
            return None
        return self.check(value)

    def to_ros(self) -> V:
        """The default as a ROS parameter value (``ros_unset`` for an automatic setting)."""
        if self.default is not None:
            return self.default
        if self.ros_unset is None:
            raise ValueError(f"setting {self.name}: automatic, and no ROS stand-in value (ros_unset)")
        return self.ros_unset

    def _convert(self, value: Any, who: str) -> Any:
        k = self.kind
        if k is bool:
            if isinstance(value, bool):
                return value
        elif k is int:
            if isinstance(value, int) and not isinstance(value, bool):
                return value
            if isinstance(value, float) and value.is_integer():
                return int(value)
        elif k is float:
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                return float(value)
        elif isinstance(value, str):
            return value
        raise ParameterError(f"{who} = {value!r}: must be {_KIND_NAMES[k]}")


def _num(x: float) -> str:
    """A number in help and error texts: ``83.33``, ``0.0001``, ``2147483647``, ``1e+07``."""
    if float(x).is_integer() and abs(x) < 1e6:
        return str(int(x))
    return f"{x:.6g}"


def _both_nan(a: Any, b: Any) -> bool:
    return isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)


def _band_rule(text: str) -> str:
    """``wavelength_band``: two numbers LMIN,LMAX [m] with 0 < LMIN < LMAX."""
    try:
        lo, hi = (float(s) for s in text.split(","))
    except ValueError:
        return "expected two numbers LMIN,LMAX in m"
    if not (0 < lo < hi and math.isfinite(hi)):
        return "need 0 < LMIN < LMAX (finite, in m)"
    return ""


def _numbers_rule(text: str) -> str:
    """Comma-separated finite numbers."""
    try:
        vals = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        return "expected comma-separated numbers"
    if not vals or not all(math.isfinite(v) for v in vals):
        return "expected finite numbers"
    return ""


def number_list(text: str) -> list[float]:
    """The numbers of a comma-separated setting value (``"1, 2.5"`` -> ``[1.0, 2.5]``; empty -> ``[]``)."""
    return [float(s) for s in text.split(",") if s.strip()]


def wavelength_band(text: str) -> tuple[float, float]:
    """Parse a ``wavelength_band`` value ``"LMIN,LMAX"`` [m] (checked)."""
    WAVELENGTH_BAND.check(text)
    lo, hi = (float(s) for s in text.split(","))
    return lo, hi


# ----------------------------------------------------------------------------- the schema

# the model
TRACK: Setting[str] = Setting("track", str, "mevergnies", "-", "track preset or YAML file (rail + track)",
                              read_only=True)
SOIL: Setting[str] = Setting("soil", str, "mevergnies", "-", "soil preset or YAML file", read_only=True)
MODEL: Setting[str] = Setting("model", str, "clm", "-", "foundation model", choices=SOIL_MODELS, read_only=True)
PARAMS_FILE: Setting[str] = Setting(
    "params_file", str, None, "-", "full parameter file (rail, track, soil, overrides); replaces track/soil/model",
    none_means="none (the track, soil and model presets)", ros_unset="", flags=("--params",), read_only=True,
)

# the track engine (streaming window)
DT: Setting[float] = Setting("dt", float, 1.0e-4, "s", "integration time step (track and vehicle)",
                             minimum=1e-6, maximum=1e-2, read_only=True)
N_SLEEPERS: Setting[int] = Setting("n_sleepers", int, 61, "-", "sleepers in the simulated window",
                                   minimum=11, maximum=4001, flags=("--sleepers",), read_only=True)
ELEMENTS_PER_BAY: Setting[int] = Setting("elements_per_bay", int, 2, "-", "rail elements per sleeper bay",
                                         minimum=1, maximum=16, read_only=True)
LEAD_SLEEPERS: Setting[int] = Setting(
    "lead_sleepers", int, None, "-", "sleepers kept ahead of the foremost wheel", minimum=1, maximum=4000,
    none_means="a third of the window", ros_unset=-1, flags=("--lead-sleepers", "--lead"), read_only=True,
)
MAX_GAP: Setting[float] = Setting("max_gap", float, 1.0, "s",
                                  "a stamp gap above this is a jump (re-synchronises once confirmed, see "
                                  "resync_confirm)",
                                  minimum=1e-4, maximum=1e6)
ACCEPT_NEW_WHEELS: Setting[bool] = Setting("accept_new_wheels", bool, False, "-",
                                           "accept wheel ids not in the first message (wheels entering)")
INITIAL_STATE: Setting[str] = Setting(
    "initial_state", str, "static", "-", "initial state: static equilibrium under the initial loads, or at rest",
    choices=("static", "rest"), flags=("--initial",), read_only=True,
)

# the online input policy (clm_core.online: the track node and clm replay refuse what breaks it, counted per cause)
MAX_WHEEL_FORCE: Setting[float] = Setting(
    "max_wheel_force", float, 1.0e6, "N", "largest plausible wheel force (a frame with a larger one is refused)",
    minimum=1.0, maximum=1.0e9)
MAX_WHEEL_POSITION: Setting[float] = Setting(
    "max_wheel_position", float, 1.0e7, "m", "largest plausible distance of a wheel from the line's origin",
    minimum=1.0, maximum=1.0e9)
MAX_WHEEL_SPEED: Setting[float] = Setting(
    "max_wheel_speed", float, 250.0, "m/s", "largest plausible wheel speed (the speeds of a frame; NaN = unknown)",
    minimum=0.1, maximum=1.0e4)
MAX_RESPONSE_FORCE: Setting[float] = Setting(
    "max_response_force", float, 1.0e8, "N",
    "largest plausible soil force in a response (a frame whose response exceeds it is refused, the state restored)",
    minimum=1.0, maximum=1.0e12)
MAX_RESPONSE_DISPLACEMENT: Setting[float] = Setting(
    "max_response_displacement", float, 0.5, "m",
    "largest plausible rail, sleeper or soil displacement in a response (beyond: the frame is refused, the state "
    "restored)", minimum=1e-6, maximum=1.0e3)
RESYNC_CONFIRM: Setting[int] = Setting(
    "resync_confirm", int, 3, "-",
    "consecutive frames on a new timeline (a stamp jump forwards beyond max_gap or backwards) that make it the "
    "stream's timeline: the last of them restarts the state, the others are refused", minimum=2, maximum=1000)
MAX_WHEELS: Setting[int] = Setting(
    "max_wheels", int, 256, "-", "most wheels in a frame and in the wheel set (ids ever accepted)",
    minimum=1, maximum=100000)
#: The settings of the online input policy (:class:`clm_core.online.InputPolicy`), for the node and ``clm replay``.
ONLINE_POLICY: tuple[str, ...] = tuple(s.name for s in (
    MAX_WHEEL_FORCE, MAX_WHEEL_POSITION, MAX_WHEEL_SPEED, MAX_RESPONSE_FORCE, MAX_RESPONSE_DISPLACEMENT, RESYNC_CONFIRM,
    MAX_WHEELS))

# the run
DURATION: Setting[float] = Setting("duration", float, 3.0, "s", "simulated time", minimum=1e-3, maximum=3600.0)
OUTPUT_DT: Setting[float] = Setting("output_dt", float, 5e-4, "s",
                                    "interval of the written time histories, rounded to whole steps (peaks use "
                                    "every step)", minimum=1e-6, maximum=1.0)
STORAGE: Setting[str] = Setting("storage", str, "mcap", "-", "rosbag2 storage of written bags",
                                choices=("mcap", "sqlite3"))
START: Setting[float] = Setting("start", float, 0.0, "m", "position of the first axle at t = 0",
                                minimum=-1e7, maximum=1e7)
SPEED: Setting[float] = Setting("speed", float, 83.33, "m/s", "train speed (83.33 m/s = 300 km/h), towards +x",
                                minimum=0.0, maximum=150.0)

# moving constant loads (clm simulate without --vehicle)
LOAD: Setting[str] = Setting("load", str, "100e3", "N",
                             "wheel load(s), positive downwards: one value for every axle or one per axle, "
                             "comma-separated", rule=_numbers_rule)
AXLES: Setting[str] = Setting("axles", str, "0", "m",
                              "axle offsets behind the first axle, comma-separated (0: one load)", rule=_numbers_rule)
LOADS_FILE: Setting[str] = Setting(
    "loads_file", str, None, "-",
    "wheel-load time history (CSV: t_s, then x_m, F_N per wheel; empty = wheel not on the track); replaces "
    "load/speed/axles/start", none_means="none (moving constant loads)", ros_unset="",
)

# the vehicle (coupled vehicle-track run)
VEHICLE: Setting[str] = Setting("vehicle", str, "thalys", "-", "vehicle preset or vehicle YAML file", read_only=True)
CARS: Setting[int] = Setting("cars", int, 1, "-", "first N cars of the preset's composition (thalys: 10 = the "
                             "whole trainset)", minimum=1, maximum=20, read_only=True)
TRAIN: Setting[str] = Setting(
    "train", str, None, "-",
    "composition by vehicle-type names, comma-separated, front to rear; suffix '+' = articulated on the previous "
    "car's bogie, '~' = reversed (e.g. power_car,trailer_end,trailer+); replaces cars",
    none_means="the first `cars` cars of the preset", ros_unset="", read_only=True,
)
IRREGULARITY: Setting[str] = Setting(
    "irregularity", str, "german-low", "-",
    "rail profile: fra1..fra6, german-low, german-high (random, from the PSD), none, or a CSV file (position m, "
    "elevation m, elevation positive up); german-low is a high-speed line", read_only=True,
)
SEED: Setting[int] = Setting("seed", int, 1, "-", "random seed of the irregularity profile",
                             minimum=0, maximum=2**31 - 1, read_only=True)
WAVELENGTH_BAND: Setting[str] = Setting("wavelength_band", str, "1,50", "m",
                                        "wavelength band of the random profile, LMIN,LMAX", rule=_band_rule,
                                        read_only=True)
LEAD_IN: Setting[float] = Setting("lead_in", float, 5.0, "m", "distance over which the rail profile is ramped in",
                                  minimum=0.0, maximum=1e4, read_only=True)
HERTZ: Setting[float] = Setting("hertz", float, None, "N/m^1.5", "Hertz constant for every wheel",
                                minimum=1e6, maximum=1e15, none_means="from the wheel radius (UIC60 rail head)",
                                ros_unset=math.nan, read_only=True)
TRACK_ENGINE: Setting[str] = Setting(
    "track_engine", str, "stream", "-",
    "track engine: stream = moving window, fixed = long fixed reference track (validation; slower)",
    choices=("stream", "fixed"), read_only=True,
)

# free-field receivers (clm simulate --receivers, the receiver node; clm_core.freefield)
RECEIVERS: Setting[str] = Setting(
    "receivers", str, None, "m", "free-field receivers at these distances from the track axis, comma-separated "
    "(e.g. 8,16,32): velocity, PPV, KB_F,max (DIN 4150-2) and 1/3-octave levels", rule=_numbers_rule,
    none_means="none (no free-field output)", ros_unset="",
)
RECEIVERS_FILE: Setting[str] = Setting(
    "receivers_file", str, None, "-", "free-field receivers from a CSV file of x, y [m] rows (header optional)",
    none_means="none", ros_unset="",
)
RECEIVER_X: Setting[float] = Setting(
    "receiver_x", float, None, "m", "position along the track of the --receivers distances",
    none_means="the middle of the recorded stretch of sleepers", ros_unset=math.nan, minimum=-1e7, maximum=1e7,
)
RECEIVER_SOIL: Setting[str] = Setting(
    "receiver_soil", str, None, "-", "soil of the free-field computation: a soil preset, a profile YAML, or "
    "E=..,rho=..,nu=..[,beta=..] (homogeneous half-space)", none_means="the profile of --soil", ros_unset="",
)
RECEIVER_INFLUENCE: Setting[float] = Setting(
    "receiver_influence", float, 60.0, "m", "sleepers within this distance along the track of a receiver act on it",
    minimum=1.0, maximum=1000.0,
)

#: Every run setting by name (what the core runs; the ROS nodes' own settings, their real time, diagnostics, views,
#: schedule of trains, clm demo's and clm fleet's, are the table of ``clm_ros.parameters``).
SETTINGS: Mapping[str, Setting[Any]] = {
    s.name: s
    for s in (
        TRACK, SOIL, MODEL, PARAMS_FILE, DT, N_SLEEPERS, ELEMENTS_PER_BAY, LEAD_SLEEPERS, MAX_GAP,
        ACCEPT_NEW_WHEELS, INITIAL_STATE, MAX_WHEEL_FORCE, MAX_WHEEL_POSITION, MAX_WHEEL_SPEED, MAX_RESPONSE_FORCE,
        MAX_RESPONSE_DISPLACEMENT, RESYNC_CONFIRM, MAX_WHEELS, DURATION, OUTPUT_DT, STORAGE, START, SPEED, LOAD, AXLES,
        LOADS_FILE, VEHICLE, CARS, TRAIN, IRREGULARITY, SEED, WAVELENGTH_BAND, LEAD_IN, HERTZ, TRACK_ENGINE,
        RECEIVERS, RECEIVERS_FILE, RECEIVER_X, RECEIVER_SOIL, RECEIVER_INFLUENCE,
    )
}


def setting(name: str) -> Setting[Any]:
    """The setting called ``name`` (a model parameter ``<section>.<name>`` too); KeyError names the known ones."""
    if name in SETTINGS:
        return SETTINGS[name]
    model = MODEL_PARAMETERS.get(name)
    if model is not None:
        return model
    raise KeyError(f"unknown setting {name!r}; known: {', '.join(sorted(SETTINGS))}")


def _model_parameter_settings() -> dict[str, Setting[float]]:
    out: dict[str, Setting[float]] = {}
    for name, (section, unit, text) in PARAMETER_DOCS.items():
        key = f"{section}.{name}"
        out[key] = Setting(key, float, None, unit, text, none_means="from the preset or parameter file",
                           ros_unset=math.nan)
    return out


#: Per-run overrides of the scalar model parameters, ``<section>.<name>`` (``track.kb``, ``soil.kf``):
#: automatic (from the preset or parameter file) unless given. Validated by :class:`clm_core.params.ModelParams`.
MODEL_PARAMETERS: Mapping[str, Setting[float]] = _model_parameter_settings()
