"""Channel maps: which bag topic holds which measured quantity, where, in which unit.

A channel map is a YAML file (or mapping) that tells the calibration how to
read a bag recorded by a user's logger. Format (see docs/calibration.md)::

    format: clm-calibration-channels/1
    test: impact                     # impact | receptance | passby (optional check)
    force:                           # impact, receptance: the hammer
      topic: /hammer/force
      units: N                       # N | kN | lbf
      field: wrench.force.z          # optional, default by message type
      sign: 1                        # optional, +1 or -1 (to positive downwards)
      full_scale: 20000              # optional sensor limit, in 'units'
    loads:                           # passby: wheel loads
      topic: /clm/wheel_loads        # clm_msgs/msg/WheelLoads
    channels:                        # responses
      - {topic: /geophone/a+00, area: 0, quantity: velocity, units: m/s}
      - {topic: /rail/acc_0, sleeper: 0, location: rail, quantity: acceleration, units: g}
      - {topic: /clm/sleeper_response, sleeper: 3, location: rail,
         quantity: displacement, units: m, field: rail_deflection}

Every value read is multiplied by ``sign * unit factor`` to give SI units,
positive downwards (the suite's convention). Flipping the sign of the force
and of every response together leaves the transfer functions unchanged.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, get_args

from clm_core.calibration.errors import CalibrationError
from clm_core.checks import positive
from clm_core.params import read_yaml_mapping

Quantity = Literal["force", "displacement", "velocity", "acceleration"]
Location = Literal["area", "rail", "sleeper", "soil"]
QUANTITIES: tuple[str, ...] = get_args(Quantity)
LOCATIONS: tuple[str, ...] = get_args(Location)
FORMAT = "clm-calibration-channels/1"

_G = 9.80665
#: Accepted unit names per quantity and their factor to SI.
UNITS: Mapping[str, Mapping[str, float]] = {
    "force": {"N": 1.0, "kN": 1e3, "MN": 1e6, "lbf": 4.4482216152605},
    "displacement": {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "micron": 1e-6, "nm": 1e-9, "in": 0.0254},
    "velocity": {"m/s": 1.0, "mm/s": 1e-3, "um/s": 1e-6, "µm/s": 1e-6, "nm/s": 1e-9, "in/s": 0.0254},
    "acceleration": {
        "m/s^2": 1.0,
        "m/s2": 1.0,
        "m/s**2": 1.0,
        "mm/s^2": 1e-3,
        "mm/s2": 1e-3,
        "g": _G,
        "g0": _G,
        "mg": 1e-3 * _G,
    },
}

_CHANNEL_KEYS = {"topic", "name", "area", "sleeper", "location", "quantity", "units", "field", "sign",
                 "full_scale", "sample_rate", "stamp"}
_FORCE_KEYS = {"topic", "name", "units", "field", "sign", "full_scale", "sample_rate", "stamp"}
_LOADS_KEYS = {"topic", "units"}
_TOP_KEYS = {"format", "test", "force", "loads", "channels", "description"}


def unit_factor(quantity: str, units: str, where: str) -> float:
    """Factor from ``units`` to SI for a quantity.

    Parameters
    ----------
    quantity : {'force', 'displacement', 'velocity', 'acceleration'}
    units : str
        Unit name as written in the channel map (e.g. ``'mm/s'``, ``'g'``).
    where : str
        Description of the channel for the error message.

    Raises
    ------
    CalibrationError
        Unknown quantity or a unit that is not one of ``UNITS[quantity]``.
    """
    if quantity not in UNITS:
        raise CalibrationError(f"{where}: quantity {quantity!r} unknown; allowed: {', '.join(QUANTITIES)}")
    table = UNITS[quantity]
    u = str(units).strip()
    if u not in table:
        raise CalibrationError(
            f"{where}: unknown unit {u!r} for a {quantity}; allowed: {', '.join(table)}"
        )
    return table[u]


@dataclass(frozen=True)
class ChannelSpec:
    """One recorded channel.

    Attributes
    ----------
    name : str
        Label used in reports (default: the topic, plus the field for shared topics).
    topic : str
        Bag topic.
    quantity : {'force', 'displacement', 'velocity', 'acceleration'}
        What the channel measures.
    units : str
        Unit as recorded; ``factor`` converts it to SI.
    factor : float
        ``sign * unit factor``: recorded value -> SI, positive downwards.
    location : {'area', 'rail', 'sleeper', 'soil'}
        Where the sensor is: a soil contact area (impact test), the rail
        above a sleeper, the sleeper itself or the soil contact area under
        it (receptance, pass-by).
    index : int
        Area index relative to the loaded area (impact, 0 = loaded area,
        negative on the other side) or sleeper index (receptance: relative
        to the hammered sleeper; pass-by: global index along the line).
    field : str or None
        Dotted path of the value in the message (``None``: the default for
        the message type).
    full_scale : float or None
        Sensor limit in SI units (clipping check), if known.
    sample_rate : float or None
        Sample rate [Hz] of block messages (``Float64MultiArray``).
    stamp : {'auto', 'header', 'log'}
        Time of a sample: the header stamp (``auto`` when the message has a
        header) or the bag's log time.
    """

    name: str
    topic: str
    quantity: Quantity
    units: str
    factor: float
    location: Location
    index: int
    field: str | None = None
    full_scale: float | None = None
    sample_rate: float | None = None
    stamp: str = "auto"


@dataclass(frozen=True)
class ChannelMap:
    """The channels of one test: the force (or wheel loads) and the responses.

    Attributes
    ----------
    force : ChannelSpec or None
        Hammer force (impact, receptance).
    loads_topic : str or None
        Topic of ``clm_msgs/msg/WheelLoads`` (pass-by).
    channels : tuple of ChannelSpec
        Responses.
    test : str or None
        The test the map is meant for, if stated.
    source : str
        Where the map came from (path or ``'<mapping>'``).
    """

    force: ChannelSpec | None
    loads_topic: str | None
    channels: tuple[ChannelSpec, ...]
    test: str | None = None
    source: str = "<mapping>"

    def to_dict(self) -> dict[str, Any]:
        """Mapping in the channel-map file format (round-trips through :func:`parse_channel_map`)."""
        out: dict[str, Any] = {"format": FORMAT}
        if self.test:
            out["test"] = self.test
        if self.force is not None:
            out["force"] = spec_dict(self.force, with_location=False)
        if self.loads_topic:
            out["loads"] = {"topic": self.loads_topic}
        out["channels"] = [spec_dict(c, with_location=True) for c in self.channels]
        return out


def spec_dict(c: ChannelSpec, with_location: bool) -> dict[str, Any]:
    """One channel-map entry (the file format, values in the recorded unit) for a channel.

    Parameters
    ----------
    c : ChannelSpec
        The channel.
    with_location : bool
        Write ``area`` or ``sleeper``/``location`` and ``quantity`` (response
        channels; not the force).

    Returns
    -------
    dict
        Keys of the channel-map format (module docstring); defaults left out.
    """
    d: dict[str, Any] = {"topic": c.topic}
    if c.name != c.topic:
        d["name"] = c.name
    if with_location:
        if c.location == "area":
            d["area"] = c.index
        else:
            d["sleeper"] = c.index
            d["location"] = c.location
        d["quantity"] = c.quantity
    d["units"] = c.units
    base = unit_factor(c.quantity, c.units, c.name)
    sign = 1 if c.factor / base > 0 else -1
    if sign != 1:
        d["sign"] = sign
    if c.field:
        d["field"] = c.field
    if c.full_scale is not None:
        d["full_scale"] = c.full_scale / abs(c.factor)
    if c.sample_rate is not None:
        d["sample_rate"] = c.sample_rate
    if c.stamp != "auto":
        d["stamp"] = c.stamp
    return d


def _optional_positive(entry: Mapping[str, Any], key: str, where: str, unit: str = "") -> float | None:
    """``entry[key]`` as a finite float > 0 (:func:`clm_core.checks.positive`), or None when absent."""
    value = entry.get(key)
    return None if value is None else positive(f"{where}: {key}", value, CalibrationError, unit)


def _spec(entry: Any, where: str, kind: Literal["force", "channel"]) -> ChannelSpec:
    if not isinstance(entry, Mapping):
        raise CalibrationError(f"{where}: expected a mapping with at least 'topic', got {entry!r}")
    keys = _FORCE_KEYS if kind == "force" else _CHANNEL_KEYS
    unknown = set(entry) - keys
    if unknown:
        raise CalibrationError(f"{where}: unknown key(s) {sorted(unknown)}; allowed: {sorted(keys)}")
    topic = entry.get("topic")
    if not isinstance(topic, str) or not topic.startswith("/"):
        raise CalibrationError(f"{where}: topic = {topic!r}: must be a string starting with '/'")
    field = entry.get("field")
    if field is not None and (not isinstance(field, str) or not field):
        raise CalibrationError(f"{where}: field = {field!r}: must be a dotted path such as 'vector.z'")
    name = str(entry.get("name") or (f"{topic}:{field}" if field and kind == "channel" else topic))
    where = f"{where} ({name})"
    if kind == "force":
        quantity = "force"
        location: str = "area"
        index = 0
    else:
        quantity = str(entry.get("quantity", ""))
        if quantity not in ("displacement", "velocity", "acceleration"):
            raise CalibrationError(
                f"{where}: quantity = {entry.get('quantity')!r}: must be displacement, velocity or acceleration"
            )
        if ("area" in entry) == ("sleeper" in entry):
            raise CalibrationError(f"{where}: give exactly one of 'area' (impact test) or 'sleeper' (track tests)")
        if "area" in entry:
            location = str(entry.get("location", "area"))
            if location != "area":
                raise CalibrationError(f"{where}: location = {location!r} with 'area': only 'area' is possible")
            raw_index = entry["area"]
        else:
            location = str(entry.get("location", "rail"))
            if location not in ("rail", "sleeper", "soil"):
                raise CalibrationError(
                    f"{where}: location = {location!r}: must be 'rail' (rail above the sleeper), 'sleeper' or "
                    "'soil' (the soil contact area under the sleeper)"
                )
            raw_index = entry["sleeper"]
        if isinstance(raw_index, bool) or not isinstance(raw_index, int):
            raise CalibrationError(f"{where}: index = {raw_index!r}: must be an integer")
        index = int(raw_index)
    if "units" not in entry:
        raise CalibrationError(f"{where}: 'units' missing; allowed for a {quantity}: {', '.join(UNITS[quantity])}")
    units = str(entry["units"])
    base = unit_factor(quantity, units, where)
    sign = entry.get("sign", 1)
    if sign not in (1, -1):
        raise CalibrationError(f"{where}: sign = {sign!r}: must be 1 or -1")
    full_scale = _optional_positive(entry, "full_scale", where)
    fs_si = None if full_scale is None else full_scale * base
    rate_v = _optional_positive(entry, "sample_rate", where, "Hz")
    stamp = str(entry.get("stamp", "auto"))
    if stamp not in ("auto", "header", "log"):
        raise CalibrationError(f"{where}: stamp = {stamp!r}: must be auto, header or log")
    return ChannelSpec(
        name=name,
        topic=topic,
        quantity=quantity,  # type: ignore[arg-type]
        units=units,
        factor=float(sign) * base,
        location=location,  # type: ignore[arg-type]
        index=index,
        field=field,
        full_scale=fs_si,
        sample_rate=rate_v,
        stamp=stamp,
    )


def parse_channel_map(data: Mapping[str, Any], source: str = "<mapping>") -> ChannelMap:
    """Validate a channel-map mapping.

    Parameters
    ----------
    data : mapping
        The parsed YAML (see the module docstring for the format).
    source : str
        Path or description for error messages.

    Returns
    -------
    ChannelMap

    Raises
    ------
    CalibrationError
        Unknown keys, missing topics or units, unknown units or quantities,
        two channels at the same place, a response channel listed twice.
    """
    if not isinstance(data, Mapping):
        raise CalibrationError(f"channel map {source}: expected a mapping at the top level, got {type(data).__name__}")
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise CalibrationError(f"channel map {source}: unknown key(s) {sorted(unknown)}; allowed: {sorted(_TOP_KEYS)}")
    fmt = data.get("format", FORMAT)
    if fmt != FORMAT:
        raise CalibrationError(f"channel map {source}: format = {fmt!r}: this version reads {FORMAT!r}")
    test = data.get("test")
    if test is not None and test not in ("impact", "receptance", "passby"):
        raise CalibrationError(f"channel map {source}: test = {test!r}: must be impact, receptance or passby")
    force = _spec(data["force"], f"channel map {source}: force", "force") if data.get("force") is not None else None
    loads_topic = None
    if data.get("loads") is not None:
        loads = data["loads"]
        ok = isinstance(loads, Mapping) and not set(loads) - _LOADS_KEYS
        if not ok or not str(loads.get("topic", "")).startswith("/"):
            raise CalibrationError(
                f"channel map {source}: loads = {loads!r}: expected {{topic: /name}} of clm_msgs/msg/WheelLoads"
            )
        loads_topic = str(loads["topic"])
    raw = data.get("channels") or []
    if not isinstance(raw, list) or not raw:
        raise CalibrationError(f"channel map {source}: 'channels' must be a non-empty list of response channels")
    specs = tuple(_spec(e, f"channel map {source}: channels[{i}]", "channel") for i, e in enumerate(raw))
    seen: dict[tuple[str, str | None, int], str] = {}
    places: dict[tuple[str, int, str], str] = {}
    for s in specs:
        key = (s.topic, s.field, s.index)
        if key in seen:
            raise CalibrationError(
                f"channel map {source}: topic {s.topic} (field {s.field}, index {s.index}) is listed twice "
                f"({seen[key]} and {s.name})"
            )
        seen[key] = s.name
        place = (s.location, s.index, s.quantity)
        if place in places:
            raise CalibrationError(
                f"channel map {source}: channels {places[place]} and {s.name} both measure the {s.quantity} "
                f"of {s.location} {s.index}; keep one"
            )
        places[place] = s.name
    return ChannelMap(force=force, loads_topic=loads_topic, channels=specs, test=test, source=source)


def load_channel_map(path: str | Path) -> ChannelMap:
    """Read and validate a channel-map YAML file.

    Parameters
    ----------
    path : path
        The YAML file (format: module docstring, docs/calibration.md).

    Returns
    -------
    ChannelMap

    Raises
    ------
    CalibrationError
        File missing, not YAML, or an invalid map (see :func:`parse_channel_map`).
    """
    p = Path(path)
    data = read_yaml_mapping(p, "channel map", error=CalibrationError)
    return parse_channel_map(data, str(p))


def find_channel_map(bag_path: str | Path) -> Path | None:
    """The channel map stored with a bag, if any.

    Looks for ``channels.yaml`` inside a bag directory, then for
    ``<stem>.channels.yaml`` and ``channels.yaml`` next to a bag file.
    """
    p = Path(bag_path)
    if p.is_dir():
        cands = [p / "channels.yaml"]
    else:
        cands = [p.with_name(f"{p.stem}.channels.yaml"), p.parent / "channels.yaml"]
    for c in cands:
        if c.is_file():
            return c
    return None
