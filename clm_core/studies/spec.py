"""The study file: a YAML that declares the cases of a parametric study (``clm study``).

Format (full description and examples in ``docs/studies.md`` and
``examples/studies/``)::

    name: critical-speed          # optional: a name and a description
    description: ...
    settings:                     # fixed for every case
      duration: 2.0               #   run settings of clm_core.settings (same names, units, ranges)
      track: soil-study           #   the model: track, soil, model, params_file
      soil.kf: 5.0e6              #   model parameters <section>.<name> (soil.kf, track.kb, rail.E)
    grid:                         # every combination of these values
      speed: {linspace: [20, 150, 14]}   # or a list, {range: [a, b(, step)]}, {geomspace: [a, b, n]}
      soil: [soft, medium, stiff]
    sample:                       # n random draws (seeded), crossed with the grid
      n: 50
      seed: 7
      vary:
        seed: {integers: [0, 100000]}    # uniform, loguniform, normal, integers, choice

Every case is one coupled vehicle–track run, the run of ``clm simulate
--vehicle`` with the same settings (:func:`simulate_argv` gives that command
line). Every name and value is checked when the file is read: an unknown
key, a value of the wrong type or outside its setting's range, an unknown
preset or a malformed grid or distribution is refused with a
:class:`~clm_core.errors.ParameterError` naming the key, the value and the
rule, before anything runs. What can only be known when a case is built (a
window too small for the train, a defect beyond the train) fails that case
alone, reported in its row.
"""

from __future__ import annotations

import itertools
import math
import re
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from clm_core import settings
from clm_core.errors import ParameterError
from clm_core.studies.inputs import CaseResolver, Shipped

#: Settings of the model a case runs on (:func:`clm_core.params.model_from_settings`).
MODEL_SETTINGS: tuple[str, ...] = ("track", "soil", "model", "params_file")

#: Top-level keys of a study file.
TOP_KEYS: tuple[str, ...] = ("name", "description", "settings", "grid", "sample")

#: Grid forms besides a list: name -> number of arguments (min, max).
GRID_FORMS: Mapping[str, tuple[int, int]] = {"range": (2, 3), "linspace": (3, 3), "geomspace": (3, 3)}

#: Sample distributions: name -> (number of arguments, what they are).
DISTRIBUTIONS: Mapping[str, tuple[int | None, str]] = {
    "uniform": (2, "[low, high], low < high"),
    "loguniform": (2, "[low, high], 0 < low < high"),
    "normal": (2, "[mean, standard deviation > 0]"),
    "integers": (2, "[low, high], integers, low <= k <= high"),
    "choice": (None, "a non-empty list of values, drawn with equal probability"),
}

#: Most cases a study may declare.
MAX_CASES = 1_000_000


def _vehicle_fields() -> tuple[str, ...]:
    from clm_core.vehicle.run import VehicleRunSpec

    return tuple(f.name for f in fields(VehicleRunSpec))


def study_settings() -> tuple[str, ...]:
    """Names a study may set or vary: the model, the vehicle-run settings and the model parameters."""
    return (*MODEL_SETTINGS, *_vehicle_fields(), *settings.MODEL_PARAMETERS)


@dataclass(frozen=True)
class Case:
    """One run of a study.

    Attributes
    ----------
    index : int
        Position in the study (0-based; the row order of the results).
    values : dict
        The varied parameters of this case, ``{name: value}`` (the table's
        parameter columns).
    settings : dict
        Every setting given for the case (fixed and varied), checked; the
        rest take the schema's defaults.
    key : str
        Identity of the run: a hash of every resolved setting (defaults
        included), the content of every file it reads, its resolved model
        parameter values and the clm_core code revision
        (:mod:`clm_core.studies.inputs`). Equal keys, equal results; the
        result store of a study is keyed by it.
    files : dict
        ``{setting: Shipped}``: the files the case reads, read by the client
        (relative paths from its working directory), shipped to the workers.
    code : str
        The client's code revision (:func:`clm_core.studies.inputs.code_revision`).
    """

    index: int
    values: dict[str, Any]
    settings: dict[str, Any]
    key: str
    files: dict[str, Shipped] = field(default_factory=dict)
    code: str = ""


@dataclass(frozen=True)
class StudySpec:
    """A parsed, checked study file.

    Attributes
    ----------
    name, description : str
    fixed : dict
        The ``settings`` section.
    grid : dict
        ``{name: [values]}`` (forms expanded).
    sample_n, sample_seed : int
        Draws of the ``sample`` section (0: none) and their seed.
    vary : dict
        ``{name: (distribution, arguments)}``.
    source : str
        Where it was read from (for messages).
    """

    name: str
    description: str
    fixed: dict[str, Any]
    grid: dict[str, list[Any]]
    sample_n: int
    sample_seed: int
    vary: dict[str, tuple[str, list[Any]]]
    source: str = "study"

    @property
    def varied(self) -> list[str]:
        """Names of the varied parameters, grid first, in file order (the table's parameter columns)."""
        return [*self.grid, *self.vary]

    def cases(self, base: str | Path | None = None) -> list[Case]:
        """Every case: the grid's combinations (last name fastest) crossed with the sample's draws.

        The files the cases name are read here (relative paths from ``base``,
        default the working directory), once each, and their contents go into
        the cases (:class:`clm_core.studies.inputs.CaseResolver`).

        Raises
        ------
        ParameterError
            A combination that breaks a rule, or a file a case names that cannot be read.
        """
        resolver = CaseResolver(base)
        draws = self._draws()
        out: list[Case] = []
        grid_points = itertools.product(*self.grid.values()) if self.grid else [()]
        for point in grid_points:
            g = dict(zip(self.grid, point))
            for d in draws:
                values = {**g, **d}
                where = f"{self.source}: case {len(out)} ({_describe(values)}): "
                case_settings = check_settings({**self.fixed, **values}, where)
                ci = resolver.resolve(case_settings, where)
                out.append(Case(len(out), {k: case_settings[k] for k in values}, case_settings, ci.key, ci.files,
                                ci.code))
        return out

    def _draws(self) -> list[dict[str, Any]]:
        if not self.vary:
            return [{}]
        cols = {name: _draw(name, dist, args, self.sample_n, self.sample_seed) for name, (dist, args) in
                self.vary.items()}
        return [{name: cols[name][i] for name in self.vary} for i in range(self.sample_n)]


def _describe(values: Mapping[str, Any]) -> str:
    return ", ".join(f"{k} = {v!r}" for k, v in values.items()) or "the fixed settings"


def _draw(name: str, dist: str, args: list[Any], n: int, seed: int) -> list[Any]:
    """``n`` draws of one parameter; its own stream (seed, name): adding a parameter changes no other's draws."""
    import numpy as np

    rng = np.random.default_rng([seed, zlib.crc32(name.encode())])
    if dist == "uniform":
        return [float(v) for v in rng.uniform(args[0], args[1], n)]
    if dist == "loguniform":
        return [float(v) for v in np.exp(rng.uniform(math.log(args[0]), math.log(args[1]), n))]
    if dist == "normal":
        return [float(v) for v in rng.normal(args[0], args[1], n)]
    if dist == "integers":
        return [int(v) for v in rng.integers(args[0], args[1], n, endpoint=True)]
    return [args[int(i)] for i in rng.integers(0, len(args), n)]


# ----------------------------------------------------------------------------- reading and checking


def load_study(path: str | Path) -> StudySpec:
    """Read and check a study file.

    Raises
    ------
    ParameterError
        Not found, not YAML, or any key or value that breaks a rule (the
        message names the file, the key, the value and the rule).
    """
    from clm_core.params import read_yaml_mapping

    return parse_study(read_yaml_mapping(path, "study file"), str(path))


def parse_study(data: Any, source: str = "study") -> StudySpec:
    """Check a parsed study mapping (:func:`load_study`) and return the :class:`StudySpec`."""
    if not isinstance(data, Mapping):
        raise ParameterError(f"{source}: expected a mapping with keys {', '.join(TOP_KEYS)}")
    unknown = [str(k) for k in data if k not in TOP_KEYS]
    if unknown:
        raise ParameterError(f"{source}: unknown key(s) {unknown}; a study file has {', '.join(TOP_KEYS)}")
    fixed = _mapping(data.get("settings"), f"{source}: settings")
    grid_in = _mapping(data.get("grid"), f"{source}: grid")
    sample = _mapping(data.get("sample"), f"{source}: sample")
    for section, names in (("settings", fixed), ("grid", grid_in)):
        for k in names:
            _check_name(k, f"{source}: {section}.{k}")
    grid = {str(k): _grid_values(v, f"{source}: grid.{k}") for k, v in grid_in.items()}
    n, seed, vary = _sample(sample, f"{source}: sample")
    for k in fixed:
        if k in grid or k in vary:
            where = "grid" if k in grid else "sample"
            raise ParameterError(f"{source}: {k} is both fixed (settings) and varied ({where}); give it in one place")
    for k in grid:
        if k in vary:
            raise ParameterError(f"{source}: {k} is in the grid and in the sample; give it in one place")
    # every value alone (the combinations are checked again when the cases are built)
    fixed = check_settings(fixed, f"{source}: settings.")
    for k, vals in grid.items():
        grid[k] = [_check_one(k, v, f"{source}: grid.{k}[{i}]") for i, v in enumerate(vals)]
    for k, (dist, args) in vary.items():
        if dist == "choice":
            for i, v in enumerate(args):
                _check_one(k, v, f"{source}: sample.vary.{k}.choice[{i}]")
    count = math.prod(len(v) for v in grid.values()) * (n if vary else 1)
    if count > MAX_CASES:
        raise ParameterError(f"{source}: {count} cases: at most {MAX_CASES}")
    name = data.get("name", Path(source).stem)
    desc = data.get("description", "")
    if not isinstance(name, str) or not isinstance(desc, str):
        raise ParameterError(f"{source}: name and description must be strings")
    return StudySpec(name, desc, dict(fixed), grid, n, seed, vary, source)


def _mapping(value: Any, where: str) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ParameterError(f"{where}: expected a mapping (name: value), got {type(value).__name__}")
    return {str(k): v for k, v in value.items()}


def _check_name(name: str, where: str) -> None:
    if name in study_settings():
        return
    if name in settings.SETTINGS:
        raise ParameterError(
            f"{where}: {name!r} is a run setting that a study does not vary: a case is a coupled vehicle run "
            "(clm simulate --vehicle); known: " + ", ".join(study_settings())
        )
    if name in _PARAMETER_SHORT:
        raise ParameterError(f"{where}: write the model parameter with its section, {_PARAMETER_SHORT[name]!r}")
    raise ParameterError(f"{where}: unknown setting {name!r}; known: {', '.join(study_settings())}")


_PARAMETER_SHORT = {k.split(".", 1)[1]: k for k in settings.MODEL_PARAMETERS}


#: A number written as YAML 1.2 reads it; PyYAML (YAML 1.1) leaves ``5e6`` or ``2.5e6`` (no exponent sign) a string.
_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def _yaml_number(v: Any) -> Any:
    """``v`` as a float if it is a string that YAML 1.2 reads as a number (``5e6``), else unchanged."""
    if isinstance(v, str) and _NUMBER.fullmatch(v.strip()):
        return float(v)
    return v


def _number(v: Any, where: str) -> float:
    v = _yaml_number(v)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ParameterError(f"{where} = {v!r}: must be a finite number")
    return float(v)


def _grid_values(v: Any, where: str) -> list[Any]:
    """A grid entry: a non-empty list, or one of :data:`GRID_FORMS` expanded."""
    import numpy as np

    if isinstance(v, list):
        if not v:
            raise ParameterError(f"{where} = []: needs at least one value")
        return list(v)
    if not (isinstance(v, Mapping) and len(v) == 1 and next(iter(v)) in GRID_FORMS):
        raise ParameterError(
            f"{where} = {v!r}: expected a list of values or one of {{range: [start, stop(, step)]}}, "
            "{linspace: [start, stop, num]}, {geomspace: [start, stop, num]} (a single value goes in settings)"
        )
    form, args = next(iter(v.items()))
    lo, hi = GRID_FORMS[form]
    if not (isinstance(args, list) and lo <= len(args) <= hi):
        raise ParameterError(f"{where}.{form} = {args!r}: expected a list of {lo}{'' if lo == hi else f'-{hi}'} "
                             "numbers")
    nums = [_number(a, f"{where}.{form}[{i}]") for i, a in enumerate(args)]
    if form == "range":
        if not all(float(a).is_integer() for a in nums):
            raise ParameterError(f"{where}.range = {args!r}: expected integers (start, stop exclusive, step)")
        if len(nums) == 3 and nums[2] == 0:
            raise ParameterError(f"{where}.range = {args!r}: step must not be 0")
        r = range(*(int(a) for a in nums))
        if not r:
            raise ParameterError(f"{where}.range = {args!r}: no values (Python range: start <= k < stop)")
        return list(r)
    num = nums[2]
    if not (num.is_integer() and num >= 1):
        raise ParameterError(f"{where}.{form} = {args!r}: num must be an integer >= 1")
    if form == "geomspace":
        if not (nums[0] > 0 and nums[1] > 0):
            raise ParameterError(f"{where}.geomspace = {args!r}: start and stop must be > 0")
        return [float(x) for x in np.geomspace(nums[0], nums[1], int(num))]
    return [float(x) for x in np.linspace(nums[0], nums[1], int(num))]


def _sample(sample: Mapping[str, Any], where: str) -> tuple[int, int, dict[str, tuple[str, list[Any]]]]:
    if not sample:
        return 0, 0, {}
    unknown = [k for k in sample if k not in ("n", "seed", "vary")]
    if unknown:
        raise ParameterError(f"{where}: unknown key(s) {unknown}; a sample has n, seed, vary")
    n, seed = sample.get("n"), sample.get("seed")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ParameterError(f"{where}.n = {n!r}: must be an integer >= 1 (the number of draws)")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ParameterError(f"{where}.seed = {seed!r}: must be an integer >= 0 (the random sample is seeded, "
                             "so a study is repeatable)")
    vary_in = _mapping(sample.get("vary"), f"{where}.vary")
    if not vary_in:
        raise ParameterError(f"{where}.vary: give at least one parameter to draw, e.g. seed: {{integers: [0, 1000]}}")
    vary: dict[str, tuple[str, list[Any]]] = {}
    for k, v in vary_in.items():
        w = f"{where}.vary.{k}"
        _check_name(k, w)
        if not (isinstance(v, Mapping) and len(v) == 1 and next(iter(v)) in DISTRIBUTIONS):
            raise ParameterError(f"{w} = {v!r}: expected one distribution, {{name: [arguments]}}: " + "; ".join(
                f"{d}: {text}" for d, (_, text) in DISTRIBUTIONS.items()))
        dist, args = next(iter(v.items()))
        count, text = DISTRIBUTIONS[dist]
        if not isinstance(args, list) or (count is not None and len(args) != count) or not args:
            raise ParameterError(f"{w}.{dist} = {args!r}: expected {text}")
        if dist != "choice":
            a, b = (_number(x, f"{w}.{dist}[{i}]") for i, x in enumerate(args))
            bad = {
                "uniform": not a < b,
                "loguniform": not 0 < a < b,
                "normal": not b > 0,
                "integers": not (a.is_integer() and b.is_integer() and a <= b),
            }[dist]
            if bad:
                raise ParameterError(f"{w}.{dist} = {args!r}: expected {text}")
            args = [int(a), int(b)] if dist == "integers" else [a, b]
        vary[k] = (dist, list(args))
    return n, seed, vary


def check_settings(values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Check ``{name: value}`` of a case with the rules of :mod:`clm_core.settings`; return them normalised.

    Messages name ``<prefix><name>``. ``train`` may be a list of names or a
    comma-separated string (kept as the string); ``defects`` a list of defect
    specifications or one string (kept as a tuple); presets must exist (or
    be files).
    """
    return {name: _check_one(name, value, f"{prefix}{name}") for name, value in values.items()}


def _check_one(name: str, value: Any, label: str) -> Any:
    """One checked, normalised value of the setting ``name`` (errors say ``label = value: rule``)."""
    from clm_core.vehicle.irregularity import parse_defect

    if name == "defects":
        items = (value,) if isinstance(value, str) else value
        if not isinstance(items, (list, tuple)) or not all(isinstance(s, str) for s in items):
            raise ParameterError(f"{label} = {value!r}: expected a list of defect specifications (strings)")
        for s in items:
            try:
                parse_defect(s)
            except ParameterError as exc:
                raise ParameterError(f"{label}: {exc}") from None
        return tuple(items)
    if name == "train" and isinstance(value, list):
        value = ",".join(str(s) for s in value)
    if name == "n_sleepers":
        return settings.N_SLEEPERS.check(_yaml_number(value), label)
    s = settings.setting(name)
    if s.kind in (int, float):
        value = _yaml_number(value)
    v = s.check(value, label)
    if name in ("track", "soil", "vehicle"):
        _check_preset(name, str(v), label)
    return v


def _check_preset(kind: str, value: str, label: str) -> None:
    from clm_core.params import list_presets
    from clm_core.vehicle.presets import list_vehicle_presets

    if Path(value).is_file():
        return
    known = list_vehicle_presets() if kind == "vehicle" else list_presets("tracks" if kind == "track" else "soils")
    if value not in known:
        raise ParameterError(f"{label} = {value!r}: not a {kind} preset ({', '.join(known)}) nor an existing file")


def resolved(case_settings: Mapping[str, Any]) -> dict[str, Any]:
    """Every setting of a case with the schema's defaults filled in (what the run uses; JSON-ready)."""
    out = {n: case_settings.get(n, settings.setting(n).default) for n in MODEL_SETTINGS}
    for n in _vehicle_fields():
        if n == "defects":
            out[n] = list(case_settings.get(n, ()))
        elif n == "n_sleepers":
            out[n] = case_settings.get(n)
        elif n == "train":
            out[n] = case_settings.get(n) or ""
        else:
            out[n] = case_settings.get(n, settings.setting(n).default)
    out.update({k: v for k, v in case_settings.items() if k in settings.MODEL_PARAMETERS})
    return out


def case_key(case_settings: Mapping[str, Any], base: str | Path | None = None) -> str:
    """Identity of a case: :data:`~clm_core.studies.inputs.KEY_DIGITS` hex digits of a SHA-256 of its resolved
    settings, the contents of the files it reads, its model parameter values and the clm_core code revision
    (:meth:`clm_core.studies.inputs.CaseResolver.resolve`)."""
    return CaseResolver(base).resolve(case_settings).key


def _text(v: Any) -> str:
    return repr(v) if isinstance(v, float) else str(v)


def simulate_argv(case_settings: Mapping[str, Any]) -> list[str]:
    """The ``clm simulate --vehicle`` arguments of the same run alone (without ``--out``).

    ``clm simulate`` then writes a ``summary.json`` with the very numbers of
    the case's row (both call :func:`clm_core.vehicle.run.simulate_vehicle`).
    """
    argv = ["simulate", "--vehicle", str(case_settings.get("vehicle", settings.VEHICLE.default))]
    for name, value in case_settings.items():
        if name == "vehicle" or value is None:
            continue
        if name in settings.MODEL_PARAMETERS:
            argv += ["--set", f"{name.split('.', 1)[1]}={_text(value)}"]
        elif name == "defects":
            for d in value:
                argv += ["--defect", d]
        elif name == "n_sleepers":
            argv += ["--sleepers", str(value)]
        else:
            argv += [settings.setting(name).option, _text(value)]
    return argv


def column_text(value: Any) -> Any:
    """A case value as a table cell: defects joined with `` ; ``, everything else as is."""
    if isinstance(value, (list, tuple)):
        return " ; ".join(str(v) for v in value)
    return value
