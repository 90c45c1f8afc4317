"""Soil profiles for the rigorous half-space computations.

A profile is a stack of horizontal viscoelastic layers over a half-space,
read from the ``profile: layers:`` list of the soil presets
(``clm_core/presets/soils/NAME.yaml``) or from a YAML file with the same
layout (a whole preset file, or a mapping with a ``layers`` list)::

    profile:
      layers:
        - {thickness: 1.2,  E: 61.0e6,  rho: 1876.0, nu: 0.13, beta: 0.0004}
        - {thickness: null, E: 465.0e6, rho: 1992.0, nu: 0.48, beta: 0.0004}

``thickness: null`` marks the underlying half-space (last entry, exactly once).

Material damping
----------------
Time convention exp(+i w t) (a dashpot has impedance +i w d). Each layer has
the complex Young's modulus

    E*(w) = E (1 + i w beta + 2 i xi),

with ``beta`` [s] the viscous (Kelvin–Voigt, stiffness-proportional) damping
of the paper's presets (Kouroussis et al. 2011, Tables 1, 3, 4:
beta = 0.0004 s, i.e. an equivalent damping ratio w beta / 2 = 1.3 % at
10 Hz and 19 % at 150 Hz) and ``xi`` [-] an optional frequency-independent
hysteretic damping ratio. Poisson's ratio is real, so the Lamé constants
and both body-wave moduli carry the same factor. Wave speeds ``cp``, ``cs``
in a preset are informative and never used: the elastic speeds follow from
E, nu and rho. A given speed that differs from the computed one by more than
5 % is recorded in :attr:`SoilProfile.notes` (the Haren preset, Table 4 of
the paper, gives c_s = 170 m/s for layer 2 where E = 84 MPa, nu = 0.13,
rho = 1876 kg/m^3 give 140.8 m/s; its c_p = 215 m/s agrees with E, so the
table's c_s is the inconsistent entry: c_p / c_s = 1.26 < sqrt(2) would
need a negative Poisson's ratio).

This loader is independent of :mod:`clm_core.params` on purpose (the two are
developed in parallel); both read the same files.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from clm_core.checks import finite as _finite
from clm_core.errors import ParameterError, PresetError

__all__ = ["Layer", "SoilProfile", "list_soil_presets", "load_profile", "profile_from_mapping"]

#: Relative tolerance of the consistency check of preset cp, cs against E, nu, rho.
SPEED_TOLERANCE = 0.05


@dataclass(frozen=True)
class Layer:
    """One homogeneous viscoelastic layer (or the underlying half-space).

    Parameters
    ----------
    thickness : float or None
        Layer thickness h [m]; ``None`` for the half-space.
    E : float
        Young's modulus [Pa], > 0.
    rho : float
        Mass density [kg/m^3], > 0.
    nu : float
        Poisson's ratio [-], 0 <= nu < 0.5.
    beta : float
        Viscous damping coefficient [s], >= 0: E* = E (1 + i w beta).
    xi : float
        Hysteretic damping ratio [-], >= 0: E* = E (1 + 2 i xi).
    """

    thickness: float | None
    E: float
    rho: float
    nu: float
    beta: float = 0.0
    xi: float = 0.0

    def __post_init__(self) -> None:
        if self.thickness is not None:
            h = _finite("thickness", self.thickness)
            if h <= 0.0:
                raise ParameterError(f"thickness = {h:g} m: a layer must be thicker than 0 (null = half-space)")
        if _finite("E", self.E) <= 0.0:
            raise ParameterError(f"E = {self.E:g} Pa: must be > 0")
        if _finite("rho", self.rho) <= 0.0:
            raise ParameterError(f"rho = {self.rho:g} kg/m^3: must be > 0")
        nu = _finite("nu", self.nu)
        if not 0.0 <= nu < 0.5:
            raise ParameterError(f"nu = {nu:g}: must satisfy 0 <= nu < 0.5")
        if _finite("beta", self.beta) < 0.0:
            raise ParameterError(f"beta = {self.beta:g} s: viscous damping must be >= 0")
        if _finite("xi", self.xi) < 0.0:
            raise ParameterError(f"xi = {self.xi:g}: hysteretic damping ratio must be >= 0")

    @property
    def G(self) -> float:
        """Elastic shear modulus E / (2 (1 + nu)) [Pa]."""
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def M(self) -> float:
        """Elastic constrained modulus lambda + 2 G [Pa]."""
        return self.E * (1.0 - self.nu) / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))

    @property
    def cs(self) -> float:
        """Elastic shear-wave speed sqrt(G / rho) [m/s]."""
        return math.sqrt(self.G / self.rho)

    @property
    def cp(self) -> float:
        """Elastic compression-wave speed sqrt((lambda + 2 G) / rho) [m/s]."""
        return math.sqrt(self.M / self.rho)

    @property
    def cr(self) -> float:
        """Elastic Rayleigh-wave speed of a half-space of this layer [m/s].

        The root 0 < x < 1 of Rayleigh's equation in x = (c_R / c_s)^2,
        x^3 - 8 x^2 + (24 - 16 q) x - 16 (1 - q) = 0 with q = (c_s / c_p)^2
        (c_R = 0.9194 c_s at nu = 0.25, 0.9553 c_s at nu = 0.5), by bisection.
        """
        q = (self.cs / self.cp) ** 2
        lo, hi = 0.0, 1.0  # f(0) = -16 (1 - q) < 0, f(1) = 1 > 0: one root between
        for _ in range(60):
            x = 0.5 * (lo + hi)
            if x**3 - 8.0 * x**2 + (24.0 - 16.0 * q) * x - 16.0 * (1.0 - q) < 0.0:
                lo = x
            else:
                hi = x
        return self.cs * math.sqrt(0.5 * (lo + hi))

    def damping_factor(self, omega: float) -> complex:
        """Complex modulus factor 1 + i (w beta + 2 xi) [-] at circular frequency ``omega`` [rad/s]."""
        return complex(1.0, omega * self.beta + 2.0 * self.xi)

    def lame(self, omega: float) -> tuple[complex, complex]:
        """Complex Lamé constants (lambda*, mu*) [Pa] at ``omega`` [rad/s]."""
        f = self.damping_factor(omega)
        mu = self.G * f
        lam = (self.M - 2.0 * self.G) * f
        return lam, mu


@dataclass(frozen=True)
class SoilProfile:
    """Horizontally layered viscoelastic half-space.

    Parameters
    ----------
    layers : tuple of Layer
        Top to bottom; every layer but the last has a thickness, the last
        (``thickness=None``) is the half-space.
    name : str
        Label (preset name or file stem).
    source : str
        Where the data come from.
    notes : tuple of str
        Remarks found while reading (e.g. wave speeds inconsistent with E, nu, rho).
    """

    layers: tuple[Layer, ...]
    name: str = "profile"
    source: str = ""
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if len(self.layers) == 0:
            raise ParameterError("profile.layers = []: need at least the half-space")
        for i, layer in enumerate(self.layers[:-1]):
            if layer.thickness is None:
                raise ParameterError(f"profile.layers[{i}].thickness = null: only the last entry may be the half-space")
        if self.layers[-1].thickness is not None:
            raise ParameterError(
                f"profile.layers[{len(self.layers) - 1}].thickness = {self.layers[-1].thickness}: "
                "the last entry must be the half-space (thickness null)"
            )

    @property
    def top(self) -> Layer:
        """The surface layer (the half-space itself for a homogeneous profile)."""
        return self.layers[0]

    @property
    def halfspace(self) -> Layer:
        """The underlying half-space."""
        return self.layers[-1]

    @property
    def n_layers(self) -> int:
        """Number of finite layers above the half-space."""
        return len(self.layers) - 1

    @property
    def is_homogeneous(self) -> bool:
        """True when there is no finite layer (Lamb's problem)."""
        return len(self.layers) == 1

    @property
    def min_cs(self) -> float:
        """Smallest elastic shear-wave speed of all layers [m/s]."""
        return min(layer.cs for layer in self.layers)

    @property
    def first_interface_depth(self) -> float | None:
        """Depth of the first layer interface [m] (None if homogeneous)."""
        return self.layers[0].thickness

    def to_dict(self) -> dict[str, Any]:
        """The ``profile`` mapping of a preset file (``{'layers': [...]}``)."""
        out: list[dict[str, Any]] = []
        for layer in self.layers:
            d: dict[str, Any] = {
                "thickness": layer.thickness,
                "E": layer.E,
                "rho": layer.rho,
                "nu": layer.nu,
                "cp": round(layer.cp, 1),
                "cs": round(layer.cs, 1),
                "beta": layer.beta,
            }
            if layer.xi:
                d["xi"] = layer.xi
            out.append(d)
        return {"layers": out}


_LAYER_KEYS = {"thickness", "E", "rho", "nu", "beta", "xi", "cp", "cs"}


def _layer_from_mapping(i: int, data: Mapping[str, Any], notes: list[str]) -> Layer:
    if not isinstance(data, Mapping):
        raise PresetError(f"profile.layers[{i}] = {data!r}: must be a mapping")
    unknown = set(data) - _LAYER_KEYS
    if unknown:
        raise PresetError(f"profile.layers[{i}]: unknown key(s) {sorted(unknown)}; allowed: {sorted(_LAYER_KEYS)}")
    for key in ("E", "rho", "nu"):
        if key not in data:
            raise PresetError(f"profile.layers[{i}].{key}: missing")
    thickness = data.get("thickness")
    try:
        layer = Layer(
            thickness=None if thickness is None else float(thickness),
            E=float(data["E"]),
            rho=float(data["rho"]),
            nu=float(data["nu"]),
            beta=float(data.get("beta", 0.0) or 0.0),
            xi=float(data.get("xi", 0.0) or 0.0),
        )
    except ParameterError as exc:
        raise ParameterError(f"profile.layers[{i}].{exc}") from None
    except (TypeError, ValueError):
        raise PresetError(f"profile.layers[{i}] = {dict(data)!r}: values must be numbers") from None
    for key, value in (("cs", layer.cs), ("cp", layer.cp)):
        given = data.get(key)
        if given is None:
            continue
        g = _finite(f"profile.layers[{i}].{key}", given)
        if abs(g - value) > SPEED_TOLERANCE * value:
            notes.append(
                f"layers[{i}].{key} = {g:g} m/s differs from {value:.1f} m/s computed from E, nu, rho "
                f"by {100 * (g / value - 1):+.0f} %; E, nu, rho are used"
            )
    return layer


def profile_from_mapping(data: Mapping[str, Any], name: str = "profile", source: str = "") -> SoilProfile:
    """Build a :class:`SoilProfile` from a preset mapping.

    Parameters
    ----------
    data : mapping
        A whole preset (with ``profile: {layers: [...]}``) or the ``profile``
        mapping itself (``{layers: [...]}``).
    name, source : str
        Defaults for the label if ``data`` has no ``name`` / ``source``.
    """
    if not isinstance(data, Mapping):
        raise PresetError(f"profile data = {data!r}: must be a mapping")
    name = str(data.get("name", name))
    source = str(data.get("source", source))
    prof = data.get("profile", data)
    if not isinstance(prof, Mapping) or "layers" not in prof:
        raise PresetError(f"profile '{name}': no 'profile: layers:' list")
    layers_data = prof["layers"]
    if not isinstance(layers_data, Sequence) or isinstance(layers_data, str | bytes):
        raise PresetError(f"profile '{name}'.layers = {layers_data!r}: must be a list")
    notes: list[str] = []
    layers = tuple(_layer_from_mapping(i, d, notes) for i, d in enumerate(layers_data))
    return SoilProfile(layers=layers, name=name, source=source, notes=tuple(notes))


def list_soil_presets() -> list[str]:
    """Names of the soil presets shipped in ``clm_core/presets/soils``."""
    base = resources.files("clm_core") / "presets" / "soils"
    return sorted(p.name[: -len(".yaml")] for p in base.iterdir() if p.name.endswith(".yaml"))


def load_profile(name_or_path: str | Path) -> SoilProfile:
    """Load a soil profile from a preset name or a YAML file.

    Parameters
    ----------
    name_or_path : str or Path
        A preset name (``mevergnies``, ``soft``, ``medium``, ``stiff``,
        ``haren``), resolved with :mod:`importlib.resources` on
        ``clm_core/presets/soils/NAME.yaml``, or a path to a YAML file.

    Raises
    ------
    PresetError
        Unknown preset, unreadable file or malformed content.
    ParameterError
        A value breaks a rule (e.g. nu >= 0.5).
    """
    path = Path(name_or_path)
    text: str
    name = path.stem
    if path.suffix in (".yaml", ".yml") or path.exists():
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise PresetError(f"profile file '{path}': cannot read ({exc.strerror})") from None
    else:
        res = resources.files("clm_core") / "presets" / "soils" / f"{name_or_path}.yaml"
        if not res.is_file():
            raise PresetError(
                f"soil preset '{name_or_path}': unknown; presets: {', '.join(list_soil_presets())} "
                "(or give a YAML file path)"
            )
        text = res.read_text(encoding="utf-8")
        name = str(name_or_path)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise PresetError(f"profile '{name_or_path}': invalid YAML ({exc})") from None
    return profile_from_mapping(data, name=name, source=str(name_or_path))
