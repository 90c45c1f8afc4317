"""Validated parameter objects for rail, track and soil, with YAML I/O.

Every value is in SI units (N, m, s, kg, Pa). Each object checks its values at
construction and raises :class:`clm_core.errors.ParameterError` naming the
parameter, its value and the rule it broke. The stability of an assembled
system (damping matrix without a negative-dissipation direction, Kouroussis
et al. 2011, Sec. 4.2) is checked by :func:`clm_core.track.assemble` and
:func:`check_stability`, since it depends on the whole set.

A parameter file (YAML) has the sections ``rail``, ``track``, ``soil`` and an
optional ``overrides`` list of per-sleeper changes::

    rail:  {E: 210e9, I: 3.055e-5, rho: 7850, A: 7.69e-3}
    track: {spacing: 0.6, kp: 120e6, dp: 4e3, ms: 150, kb: 47e6, db: 72e3}
    soil:  {model: clm, mf: 380, kf: 72e6, df: 680e3, kc: 160e6, dc: -155e3}
    overrides:
      - {sleepers: [100], kb: 4.7e6}          # a hanging sleeper (global index)
      - {from: 200, to: 260, kf: 20e6}        # a soft soil patch (inclusive)

Presets ship in ``clm_core/presets/{tracks,soils}/NAME.yaml``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal, cast, get_args

import yaml

from clm_core.checks import SOIL_MODEL_PARAMETERS, soil_values, track_values
from clm_core.checks import finite as _check_finite
from clm_core.checks import positive as _check_positive
from clm_core.errors import ClmError, ParameterError, PresetError

SoilModel = Literal["rigid", "winkler", "lysmer", "clm"]
SOIL_MODELS: tuple[str, ...] = get_args(SoilModel)
#: The soil parameters each foundation model uses (the rules: :func:`clm_core.checks.soil_values`).
SOIL_USED: Mapping[str, tuple[str, ...]] = SOIL_MODEL_PARAMETERS
#: The five soil parameters, in the order of every chain Jacobian.
SOIL_NAMES = ("mf", "kf", "df", "kc", "dc")


@dataclass(frozen=True)
class RailParams:
    """Euler–Bernoulli rail (one rail line), paper Table 2.

    Parameters
    ----------
    E : float
        Young's modulus E_r [Pa].
    I : float
        Second moment of area I_r [m^4].
    rho : float
        Density rho_r [kg/m^3].
    A : float
        Cross-section area A_r [m^2].
    """

    E: float = 210.0e9
    I: float = 3055.0e-8
    rho: float = 7850.0
    A: float = 76.9e-4

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, _check_positive(f"rail.{f.name}", getattr(self, f.name)))

    @property
    def EI(self) -> float:
        """Bending stiffness E_r I_r [N m^2]."""
        return self.E * self.I

    @property
    def mass_per_length(self) -> float:
        """Rail mass per unit length rho_r A_r [kg/m]."""
        return self.rho * self.A


@dataclass(frozen=True)
class TrackParams:
    """Discretely supported track: railpads, sleepers, ballast (paper Sec. 5, Fig. 6).

    Parameters
    ----------
    spacing : float
        Sleeper spacing d [m].
    kp, dp : float
        Railpad stiffness [N/m] and damping [N s/m].
    ms : float
        Sleeper mass carried by one rail m [kg].
    kb, db : float
        Ballast stiffness [N/m] and damping [N s/m], between sleeper and soil
        contact area.
    contact_length, contact_width : float
        Sleeper–ballast contact area, across the track (2a) and along it (2b)
        [m]; used by the soil formulas (Eq. 6) and the half-space reference.
    """

    spacing: float = 0.6
    kp: float = 120.0e6
    dp: float = 4.0e3
    ms: float = 150.0
    kb: float = 47.0e6
    db: float = 72.0e3
    contact_length: float = 2.5
    contact_width: float = 0.285

    def __post_init__(self) -> None:
        for name, v in track_values({f.name: getattr(self, f.name) for f in fields(self)}).items():
            object.__setattr__(self, name, v)
        if self.contact_width > self.spacing:
            raise ParameterError(
                f"track.contact_width = {self.contact_width:g} m: must not exceed the sleeper "
                f"spacing {self.spacing:g} m (contact areas would overlap)"
            )


@dataclass(frozen=True)
class SoilParams:
    """Foundation under each sleeper contact area (paper Sec. 3–4).

    Parameters
    ----------
    model : {'rigid', 'winkler', 'lysmer', 'clm'}
        ``rigid``: the ballast stands on fixed ground. ``winkler``: spring
        ``kf`` and dashpot ``df`` (massless area). ``lysmer``: Lysmer's
        analogue (``mf``, ``kf``, ``df``), Eq. (2)–(3). ``clm``: Lysmer's
        analogue per area plus ``kc``, ``dc`` between neighbouring areas,
        Eq. (7)–(8).
    mf : float
        Added soil mass m_f [kg] (lysmer, clm).
    kf : float
        Foundation stiffness k_f [N/m].
    df : float
        Foundation damping d_f [N s/m].
    kc : float
        Coupling stiffness k_c [N/m] between neighbouring areas (clm).
    dc : float
        Coupling damping d_c [N s/m] (clm); normally negative (time lag, Sec. 4.2).

    Notes
    -----
    Parameters a model does not use must be zero; ``SoilParams.of_model``
    builds a set for another model, dropping what it does not use.
    """

    model: SoilModel = "clm"
    mf: float = 0.0
    kf: float = 0.0
    df: float = 0.0
    kc: float = 0.0
    dc: float = 0.0

    def __post_init__(self) -> None:
        if self.model not in SOIL_MODELS:
            raise ParameterError(f"soil.model = {self.model!r}: must be one of {', '.join(SOIL_MODELS)}")
        used = SOIL_USED[self.model]
        for name in SOIL_NAMES:
            v = _check_finite(f"soil.{name}", getattr(self, name))
            if name not in used and v != 0.0:
                raise ParameterError(
                    f"soil.{name} = {v:g}: not a parameter of the {self.model!r} model "
                    f"(which uses {', '.join(used) or 'none'}); set it to 0 or change the model"
                )
        values = soil_values(self.model, {n: getattr(self, n) for n in SOIL_NAMES}, prefix="soil.")
        for name, v in values.items():
            object.__setattr__(self, name, v)

    def of_model(self, model: SoilModel) -> SoilParams:
        """Return this soil seen through another model (drops unused parameters)."""
        used = SOIL_USED[model]
        values = {n: (getattr(self, n) if n in used else 0.0) for n in SOIL_NAMES}
        return SoilParams(model=model, **values)

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping with the model and the parameters it uses."""
        out: dict[str, Any] = {"model": self.model}
        out.update({n: getattr(self, n) for n in SOIL_USED[self.model]})
        return out


#: Most sleepers all the per-sleeper overrides of one parameter file may name together: 1 000 000 (600 km of line
#: at 0.6 m spacing; a model holds at most ~330 000 sleepers, clm_core.track.MAX_DOFS). A range without a
#: bound (``{from: 0, to: 1e12}``) would be expanded into that many indices and exhaust the memory (issue 26.7:
#: 2.96 GB in 4 s); it is refused, with this bound, before anything is allocated.
MAX_OVERRIDE_SLEEPERS = 1_000_000
#: Largest ``|sleeper index|`` of an override (an index is a position on the line: 1e9 sleepers, 600 000 km).
MAX_SLEEPER_INDEX = 1_000_000_000


def _sleeper_index(value: Any, what: str) -> int:
    """A sleeper index of an override, checked: an integer with ``|i| <= MAX_SLEEPER_INDEX``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
        raise ParameterError(f"overrides: {what} = {value!r}: must be an integer sleeper index")
    i = int(value)
    if abs(i) > MAX_SLEEPER_INDEX:
        raise ParameterError(f"overrides: {what} = {i}: must be within +-{MAX_SLEEPER_INDEX} (a sleeper index)")
    return i


# Names accepted by `override()` / `--set NAME=VALUE` and per-sleeper overrides.
RAIL_NAMES = tuple(f.name for f in fields(RailParams))
TRACK_NAMES = tuple(f.name for f in fields(TrackParams))
PER_SLEEPER_NAMES = ("kp", "dp", "ms", "kb", "db", "mf", "kf", "df", "kc", "dc")
_ALIASES = {
    "Er": "E",
    "Ir": "I",
    "rhor": "rho",
    "Ar": "A",
    "d": "spacing",
    "m": "ms",
}


@dataclass(frozen=True)
class SleeperOverride:
    """A per-sleeper change of track or soil parameters (non-uniform track).

    Parameters
    ----------
    sleepers : tuple of int
        Global sleeper indices the change applies to.
    values : mapping
        Parameter name -> value, names from ``PER_SLEEPER_NAMES``. For ``kc``
        and ``dc`` the value applies to the link between the sleeper and the
        next one (index + 1).
    """

    sleepers: tuple[int, ...]
    values: Mapping[str, float]

    def __post_init__(self) -> None:
        if not self.sleepers:
            raise ParameterError("overrides[].sleepers = []: name at least one sleeper")
        for name, v in self.values.items():
            if name not in PER_SLEEPER_NAMES:
                raise ParameterError(
                    f"overrides: unknown per-sleeper parameter {name!r}; allowed: {', '.join(PER_SLEEPER_NAMES)}"
                )
            _check_finite(f"overrides.{name}", v)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SleeperOverride:
        """Build from ``{sleepers: [...]}`` or ``{from: i, to: j}`` plus values."""
        d = dict(data)
        bound = f"at most {MAX_OVERRIDE_SLEEPERS} sleepers in all the overrides of a file"
        if "sleepers" in d:
            raw = d.pop("sleepers")
            if isinstance(raw, (int, float)):
                raw = [raw]
            if not isinstance(raw, (list, tuple)):
                raise ParameterError(f"overrides: sleepers = {str(raw)[:80]!r}: must be a list of sleeper indices")
            if len(raw) > MAX_OVERRIDE_SLEEPERS:
                raise ParameterError(f"overrides: sleepers lists {len(raw)} sleepers: {bound}")
            sleepers = tuple(_sleeper_index(v, "sleepers[]") for v in raw)
        elif "from" in d and "to" in d:
            a, b = _sleeper_index(d.pop("from"), "from"), _sleeper_index(d.pop("to"), "to")
            if b < a:
                raise ParameterError(f"overrides: to = {b} < from = {a}")
            if b - a + 1 > MAX_OVERRIDE_SLEEPERS:
                raise ParameterError(f"overrides: from = {a} to = {b} spans {b - a + 1} sleepers: {bound}")
            sleepers = tuple(range(a, b + 1))
        else:
            raise ParameterError(f"overrides entry {dict(data)!r}: needs 'sleepers: [...]' or 'from'/'to'")
        return cls(sleepers=sleepers, values={k: float(v) for k, v in d.items()})

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping for YAML."""
        return {"sleepers": list(self.sleepers), **dict(self.values)}


@dataclass(frozen=True)
class ModelParams:
    """Everything that defines a track–soil model: rail, track, soil, overrides."""

    rail: RailParams = field(default_factory=RailParams)
    track: TrackParams = field(default_factory=TrackParams)
    soil: SoilParams = field(default_factory=lambda: SoilParams(model="rigid"))
    overrides: tuple[SleeperOverride, ...] = ()
    name: str = ""

    def with_model(self, model: SoilModel) -> ModelParams:
        """The same set with another soil model."""
        return replace(self, soil=self.soil.of_model(model))

    def override(self, **values: float) -> ModelParams:
        """Return a copy with named parameters changed, e.g. ``override(kb=50e6)``.

        Names: rail ``E I rho A`` (aliases ``Er Ir rhor Ar``), track
        ``spacing kp dp ms kb db contact_length contact_width`` (aliases ``d``,
        ``m``), soil ``mf kf df kc dc``.
        """
        rail, track, soil = asdict(self.rail), asdict(self.track), self.soil.to_dict()
        for raw_name, value in values.items():
            name = _ALIASES.get(raw_name, raw_name)
            if name in SOIL_NAMES:
                soil[name] = value
            elif name in TRACK_NAMES:
                track[name] = value
            elif name in RAIL_NAMES:
                rail[name] = value
            else:
                known = sorted(set(RAIL_NAMES + TRACK_NAMES + SOIL_NAMES + tuple(_ALIASES)))
                raise ParameterError(f"unknown parameter {raw_name!r}; known: {', '.join(known)}")
        return replace(self, rail=RailParams(**rail), track=TrackParams(**track), soil=SoilParams(**soil))

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping in the parameter-file layout."""
        out: dict[str, Any] = {
            "rail": asdict(self.rail),
            "track": asdict(self.track),
            "soil": self.soil.to_dict(),
        }
        if self.name:
            out["name"] = self.name
        if self.overrides:
            out["overrides"] = [o.to_dict() for o in self.overrides]
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ModelParams:
        """Build from a parameter-file mapping (unknown keys are refused)."""
        allowed = {"rail", "track", "soil", "overrides", "name", "source", "profile"}
        unknown = set(data) - allowed
        if unknown:
            raise ParameterError(f"parameter file: unknown section(s) {sorted(unknown)}; allowed {sorted(allowed)}")
        rail = _build(RailParams, data.get("rail", {}), "rail")
        track = _build(TrackParams, data.get("track", {}), "track")
        soil_data = dict(data.get("soil", {"model": "rigid"}))
        soil_data.setdefault("model", "clm")
        soil = _build(SoilParams, soil_data, "soil")
        raw_overrides = data.get("overrides", []) or []
        if not isinstance(raw_overrides, list) or not all(isinstance(o, Mapping) for o in raw_overrides):
            raise ParameterError("parameter file: overrides must be a list of mappings ({sleepers: [...], kb: ...})")
        built: list[SleeperOverride] = []
        total = 0
        for o in raw_overrides:  # the bound checked as they are built: never more than it in memory
            built.append(SleeperOverride.from_dict(o))
            total += len(built[-1].sleepers)
            if total > MAX_OVERRIDE_SLEEPERS:
                raise ParameterError(f"overrides name more than {MAX_OVERRIDE_SLEEPERS} sleepers in all (at entry "
                                     f"{len(built)}): at most {MAX_OVERRIDE_SLEEPERS} sleepers in all the overrides "
                                     "of a file")
        overrides = tuple(built)
        return cls(rail=rail, track=track, soil=soil, overrides=overrides, name=str(data.get("name", "")))


def _build(cls: Any, data: Mapping[str, Any], section: str) -> Any:
    names = {f.name for f in fields(cls)}
    mapped = {_ALIASES.get(k, k): v for k, v in dict(data).items()}
    unknown = set(mapped) - names
    if unknown:
        raise ParameterError(f"{section}: unknown parameter(s) {sorted(unknown)}; allowed {sorted(names)}")
    return cls(**mapped)


# ---------------------------------------------------------------- presets and files


def _preset_dir(kind: str) -> Any:
    return resources.files("clm_core") / "presets" / kind


def list_presets(kind: Literal["tracks", "soils"]) -> list[str]:
    """Names of the shipped presets of one kind."""
    return sorted(p.name[:-5] for p in _preset_dir(kind).iterdir() if p.name.endswith(".yaml"))


def _load_yaml(path_or_name: str | Path, kind: Literal["tracks", "soils"]) -> dict[str, Any]:
    p = Path(path_or_name)
    text: str
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise PresetError(f"{kind[:-1]} file {str(p)!r} not found")
        text = p.read_text()
    else:
        res = _preset_dir(kind) / f"{path_or_name}.yaml"
        if not res.is_file():
            raise PresetError(
                f"unknown {kind[:-1]} preset {str(path_or_name)!r}; known: {', '.join(list_presets(kind))}"
            )
        text = res.read_text()
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise PresetError(f"{path_or_name}: not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise PresetError(f"{path_or_name}: expected a mapping at the top level")
    return cast(dict[str, Any], data)


def load_track(name_or_path: str | Path) -> tuple[RailParams, TrackParams]:
    """Load a track preset (``mevergnies``, ``soil-study``) or file."""
    data = _load_yaml(name_or_path, "tracks")
    return _build(RailParams, data.get("rail", {}), "rail"), _build(TrackParams, data.get("track", {}), "track")


def load_soil(name_or_path: str | Path, model: SoilModel = "clm") -> SoilParams:
    """Load a soil preset's CLM parameters, seen through ``model``."""
    data = _load_yaml(name_or_path, "soils")
    clm = dict(data.get("clm", {}))
    if not clm:
        raise PresetError(f"soil {str(name_or_path)!r}: no 'clm' section")
    return _build(SoilParams, {"model": "clm", **clm}, "soil").of_model(model)  # type: ignore[no-any-return]


def soil_track(name_or_path: str | Path) -> str | None:
    """The track preset a soil preset (or preset-format file) was studied with: its ``track:`` key.

    The soft, medium and stiff soils of Sec. 5.2 go with the ``soil-study``
    track (d = 0.72 m), Mevergnies (and, by the project's choice, Haren) with
    the ``mevergnies`` track (d = 0.6 m). Used wherever a soil-only figure
    needs a track quantity, e.g. the sleeper spacing of Eq. (21).

    Returns
    -------
    str or None
        The track preset name, None if the soil names none.

    Raises
    ------
    PresetError
        Unknown soil preset or unreadable file; a ``track`` that is not a known track preset.
    """
    track = _load_yaml(name_or_path, "soils").get("track")
    if track is None:
        return None
    if not (_preset_dir("tracks") / f"{track}.yaml").is_file():
        raise PresetError(
            f"soil {str(name_or_path)!r}: track = {track!r} is not a track preset; known: "
            f"{', '.join(list_presets('tracks'))}"
        )
    return str(track)


def load_model(
    track: str | Path = "mevergnies",
    soil: str | Path | None = "mevergnies",
    model: SoilModel = "clm",
    overrides: Mapping[str, float] | None = None,
) -> ModelParams:
    """Build a model from a track preset/file and a soil preset/file.

    ``soil=None`` or ``model='rigid'`` gives a rigid foundation.
    ``overrides`` changes named parameters (see :meth:`ModelParams.override`).
    """
    rail, trk = load_track(track)
    if model == "rigid" or soil is None:
        sp = SoilParams(model="rigid")
    else:
        sp = load_soil(soil, model)
    name = f"{Path(str(track)).stem}/{Path(str(soil)).stem if soil else 'rigid'}/{model}"
    mp = ModelParams(rail=rail, track=trk, soil=sp, name=name)
    if overrides:
        mp = mp.override(**overrides)
    return mp


def model_from_settings(
    track: str | Path = "mevergnies",
    soil: str | Path | None = "mevergnies",
    model: SoilModel = "clm",
    params_file: str | Path | None = None,
    overrides: Mapping[str, float] | None = None,
) -> ModelParams:
    """The model that the run settings ``track``, ``soil``, ``model`` and ``params_file`` describe.

    A full parameter file (``params_file``) replaces the three presets;
    ``overrides`` (``{name: value}``, :meth:`ModelParams.override`) apply on
    top of either. The one rule of ``clm simulate``, ``clm receptance`` and
    ``clm study``.
    """
    if params_file:
        mp = load_params_file(params_file)
        return mp.override(**overrides) if overrides else mp
    return load_model(track, soil, model, overrides)


def yaml_problem(exc: yaml.YAMLError) -> str:
    """The problem of a YAML error and where it is (line, column), on one line, without the file's text."""
    problem = getattr(exc, "problem", None) or getattr(exc, "context", None) or type(exc).__name__
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return " ".join(f"{problem}{where}".split())


def read_yaml_mapping(
    path: str | Path, what: str = "parameter file", error: type[ClmError] = PresetError
) -> dict[str, Any]:
    """The top-level mapping of the YAML file ``path``.

    Parameters
    ----------
    path : path
        The YAML file.
    what : str
        What the file is, for the messages (e.g. ``"study file"``).
    error : type
        The exception raised (default :class:`~clm_core.errors.PresetError`).

    Raises
    ------
    PresetError
        (or ``error``) ``"<what> '<path>' not found"``, not valid YAML, or not a mapping at the top level.
    """
    p = Path(path)
    if not p.is_file():
        raise error(f"{what} {str(p)!r} not found")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise error(f"{p}: not valid YAML ({yaml_problem(exc)})") from None
    except RecursionError:
        raise error(f"{p}: nested too deeply to be read (Python's recursion limit reached)") from None
    if not isinstance(data, dict):
        raise error(f"{p}: expected a mapping at the top level")
    return cast(dict[str, Any], data)


def load_params_file(path: str | Path) -> ModelParams:
    """Load a full parameter file (rail, track, soil, overrides)."""
    return ModelParams.from_dict(read_yaml_mapping(path))


def save_params_file(params: ModelParams, path: str | Path) -> None:
    """Write a full parameter file that :func:`load_params_file` reads back."""
    Path(path).write_text(yaml.safe_dump(params.to_dict(), sort_keys=False))


def parse_assignments(items: Iterable[str]) -> dict[str, float]:
    """Parse ``NAME=VALUE`` strings (the CLI's ``--set``)."""
    out: dict[str, float] = {}
    for item in items:
        if "=" not in item:
            raise ParameterError(f"--set {item!r}: expected NAME=VALUE")
        name, _, value = item.partition("=")
        out[name.strip()] = _check_finite(name.strip(), value.strip())
    return out


#: Every scalar model parameter: name -> (section, unit, description). The
#: single source for CLI help, ROS parameter descriptors and docs.
PARAMETER_DOCS: Mapping[str, tuple[str, str, str]] = {
    "E": ("rail", "Pa", "rail Young's modulus E_r"),
    "I": ("rail", "m^4", "rail second moment of area I_r"),
    "rho": ("rail", "kg/m^3", "rail density rho_r"),
    "A": ("rail", "m^2", "rail cross-section area A_r"),
    "spacing": ("track", "m", "sleeper spacing d"),
    "kp": ("track", "N/m", "railpad stiffness k_p"),
    "dp": ("track", "N s/m", "railpad damping d_p"),
    "ms": ("track", "kg", "sleeper mass per rail m"),
    "kb": ("track", "N/m", "ballast stiffness k_b"),
    "db": ("track", "N s/m", "ballast damping d_b"),
    "contact_length": ("track", "m", "sleeper-ballast contact length across the track 2a"),
    "contact_width": ("track", "m", "sleeper-ballast contact width along the track 2b"),
    "mf": ("soil", "kg", "soil added mass m_f (Lysmer, CLM)"),
    "kf": ("soil", "N/m", "soil stiffness k_f"),
    "df": ("soil", "N s/m", "soil damping d_f"),
    "kc": ("soil", "N/m", "CLM coupling stiffness k_c between neighbouring areas"),
    "dc": ("soil", "N s/m", "CLM coupling damping d_c (normally negative, Sec. 4.2)"),
}
