"""Vehicle presets and user vehicle files (YAML).

A vehicle file has a ``vehicles`` mapping (vehicle types, fields of
:class:`clm_core.vehicle.multibody.VehicleType`) and an optional ``train``
list, the default composition front to rear::

    name: my-train
    vehicles:
      loco: {body_mass: 60000, body_pitch_inertia: 1.2e6, bogie_mass: 3000,
             bogie_pitch_inertia: 2500, wheelset_mass: 2000, wheel_radius: 0.46,
             primary_stiffness: 1.2e6, primary_damping: 1e4,
             secondary_stiffness: 0.6e6, secondary_damping: 3e4,
             bogie_spacing: 12.0, axle_spacing: 2.6, length: 19.0}
      coach: {...}
    train:
      - loco
      - {vehicle: coach, shares_front_bogie: false, reversed: false}

Without ``train`` a file with a single vehicle type is that one vehicle.
Units SI; masses and pitch inertias are full-vehicle values, suspensions per
axle box (primary) and per bogie side (secondary): the simulation uses the
half vehicle on one rail line (see :mod:`clm_core.vehicle.multibody`).
Presets ship in ``clm_core/presets/vehicles/NAME.yaml``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import MISSING, dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from clm_core.errors import ParameterError, PresetError
from clm_core.vehicle.multibody import CarSpec, Train, VehicleType, build_train

_TYPE_FIELDS = {f.name for f in fields(VehicleType)}
_REQUIRED = {
    f.name for f in fields(VehicleType) if f.default is MISSING and f.default_factory is MISSING
} - {"name"}
_TOP_KEYS = {"name", "description", "source", "vehicles", "train", "notes"}
_CAR_KEYS = {"vehicle", "shares_front_bogie", "reversed"}


@dataclass(frozen=True)
class VehicleFile:
    """A parsed vehicle file: named vehicle types and a default composition.

    Attributes
    ----------
    name : str
        File/preset name.
    vehicles : mapping str -> VehicleType
        The vehicle types.
    composition : tuple of CarSpec
        Default train, front to rear.
    description : str
        One-line description.
    """

    name: str
    vehicles: Mapping[str, VehicleType]
    composition: tuple[CarSpec, ...]
    description: str = ""

    def cars(self, n: int | None = None) -> tuple[CarSpec, ...]:
        """The first ``n`` cars of the composition (all if ``None``)."""
        if n is None:
            return self.composition
        if int(n) != n or n < 1:
            raise ParameterError(f"--cars {n!r}: must be an integer >= 1")
        if n > len(self.composition):
            raise ParameterError(
                f"--cars {n}: the {self.name!r} composition has only {len(self.composition)} cars"
            )
        return self.composition[: int(n)]

    def train(self, n: int | None = None) -> Train:
        """Assemble the train of the first ``n`` cars."""
        return build_train(self.cars(n))

    def compose(self, names: Sequence[str]) -> tuple[CarSpec, ...]:
        """A composition from vehicle-type names (``name``, ``name~`` = reversed, ``name+`` = articulated).

        ``+`` after a name means the car shares its front bogie with the
        previous one; ``~`` that it runs reversed (both may be combined).
        """
        out: list[CarSpec] = []
        for raw in names:
            s = raw.strip()
            rev = art = False
            while s and s[-1] in "~+":
                rev |= s[-1] == "~"
                art |= s[-1] == "+"
                s = s[:-1]
            if s not in self.vehicles:
                raise ParameterError(
                    f"train composition: unknown vehicle {s!r} in {self.name!r}; "
                    f"known: {', '.join(sorted(self.vehicles))}"
                )
            out.append(CarSpec(self.vehicles[s], shares_front_bogie=art, reversed=rev))
        if not out:
            raise ParameterError("train composition: empty")
        return tuple(out)


def _vehicles_dir() -> Any:
    return resources.files("clm_core") / "presets" / "vehicles"


def list_vehicle_presets() -> list[str]:
    """Names of the shipped vehicle presets."""
    return sorted(p.name[:-5] for p in _vehicles_dir().iterdir() if p.name.endswith(".yaml"))


def parse_vehicle_data(data: Mapping[str, Any], name: str = "") -> VehicleFile:
    """Build a :class:`VehicleFile` from a parsed YAML mapping (strict: unknown keys are refused)."""
    if not isinstance(data, Mapping):
        raise PresetError(f"vehicle file {name!r}: expected a mapping at the top level")
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise PresetError(f"vehicle file {name!r}: unknown key(s) {sorted(unknown)}; allowed {sorted(_TOP_KEYS)}")
    fname = str(data.get("name", name) or name)
    raw = data.get("vehicles")
    if not isinstance(raw, Mapping) or not raw:
        raise PresetError(f"vehicle file {fname!r}: needs a non-empty 'vehicles:' mapping of vehicle types")
    vehicles: dict[str, VehicleType] = {}
    for vname, vdata in raw.items():
        if not isinstance(vdata, Mapping):
            raise PresetError(f"vehicle file {fname!r}: vehicles.{vname}: expected a mapping of parameters")
        bad = set(vdata) - _TYPE_FIELDS
        if bad:
            raise PresetError(
                f"vehicle file {fname!r}: vehicles.{vname}: unknown parameter(s) {sorted(bad)}; "
                f"allowed {sorted(_TYPE_FIELDS - {'name'})}"
            )
        missing = _REQUIRED - set(vdata)
        if missing:
            raise PresetError(f"vehicle file {fname!r}: vehicles.{vname}: missing parameter(s) {sorted(missing)}")
        kw = {k: v for k, v in vdata.items() if k != "name"}
        try:
            vehicles[str(vname)] = VehicleType(name=str(vname), **kw)
        except ParameterError as exc:
            raise ParameterError(f"vehicle file {fname!r}: {exc}") from None
    comp_raw = data.get("train")
    if comp_raw is None:
        if len(vehicles) != 1:
            raise PresetError(
                f"vehicle file {fname!r}: several vehicle types ({', '.join(vehicles)}) and no 'train:' composition"
            )
        composition: tuple[CarSpec, ...] = (CarSpec(next(iter(vehicles.values()))),)
    else:
        if not isinstance(comp_raw, list) or not comp_raw:
            raise PresetError(f"vehicle file {fname!r}: 'train:' must be a non-empty list of cars")
        cars: list[CarSpec] = []
        for i, item in enumerate(comp_raw):
            entry = {"vehicle": item} if isinstance(item, str) else item
            if not isinstance(entry, Mapping) or "vehicle" not in entry:
                raise PresetError(
                    f"vehicle file {fname!r}: train[{i}] = {item!r}: a name or {{vehicle: NAME, ...}}"
                )
            extra = set(entry) - _CAR_KEYS
            if extra:
                raise PresetError(
                    f"vehicle file {fname!r}: train[{i}]: unknown key(s) {sorted(extra)}; allowed {sorted(_CAR_KEYS)}"
                )
            vn = str(entry["vehicle"])
            if vn not in vehicles:
                raise PresetError(
                    f"vehicle file {fname!r}: train[{i}]: unknown vehicle {vn!r}; known: {', '.join(vehicles)}"
                )
            for flag in ("shares_front_bogie", "reversed"):
                if flag in entry and not isinstance(entry[flag], bool):
                    raise PresetError(
                        f"vehicle file {fname!r}: train[{i}].{flag} = {entry[flag]!r}: must be true or false"
                    )
            art, rev = bool(entry.get("shares_front_bogie", False)), bool(entry.get("reversed", False))
            cars.append(CarSpec(vehicles[vn], shares_front_bogie=art, reversed=rev))
        composition = tuple(cars)
        build_train(composition)  # validates the articulation
    desc = str(data.get("description", ""))
    return VehicleFile(name=fname, vehicles=vehicles, composition=composition, description=desc)


def load_vehicle(name_or_path: str | Path) -> VehicleFile:
    """Load a vehicle preset (``thalys``, ``intercity``, ``tram``) or a user YAML file.

    Raises
    ------
    PresetError
        Unknown preset, missing/unreadable file, bad layout.
    ParameterError
        Invalid values (negative masses, NaN, inconsistent geometry, ...).
    """
    p = Path(str(name_or_path))
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise PresetError(f"vehicle file {str(p)!r} not found")
        text = p.read_text()
        label = p.stem
    else:
        res = _vehicles_dir() / f"{name_or_path}.yaml"
        if not res.is_file():
            raise PresetError(
                f"unknown vehicle preset {str(name_or_path)!r}; known: {', '.join(list_vehicle_presets())} "
                "(or give a path to a .yaml vehicle file)"
            )
        text = res.read_text()
        label = str(name_or_path)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise PresetError(f"vehicle file {label!r}: not valid YAML ({exc})") from None
    return parse_vehicle_data(data, label)


def save_vehicle_file(vf: VehicleFile, path: str | Path) -> None:
    """Write a vehicle file that :func:`load_vehicle` reads back."""
    names = {id(v): k for k, v in vf.vehicles.items()}
    train: list[str | dict[str, object]] = []
    for c in vf.composition:
        vn = names.get(id(c.vehicle), c.vehicle.name)
        if c.shares_front_bogie or c.reversed:
            train.append({"vehicle": vn, "shares_front_bogie": c.shares_front_bogie, "reversed": c.reversed})
        else:
            train.append(vn)
    data = {
        "name": vf.name,
        "description": vf.description,
        "vehicles": {k: {kk: vv for kk, vv in v.to_dict().items() if kk != "name"} for k, v in vf.vehicles.items()},
        "train": train,
    }
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False))
