"""Options of a calibration, one validated value object for the CLI, the service and Python.

Built from a mapping (the ``options_yaml`` of the ``clm_msgs/srv/Calibrate``
service, the ``--options`` file of ``clm calibrate``) with
:meth:`CalibrationOptions.from_mapping`; unknown keys are refused. Nested
sections ``window`` (:class:`~clm_core.calibration.spectra.WindowSpec`) and
``sampling`` (:class:`~clm_core.calibration.signals.SamplingRules`) tune the
signal processing and the record checks.

The scalar options are settings (:class:`clm_core.settings.Setting`) of one table,
:data:`CALIBRATION_SETTINGS`: their defaults are the dataclass's, and ``clm
calibrate`` generates its options from it (``--fmax``, ``--n-areas``, ...) as
the other commands do from :mod:`clm_core.settings`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import yaml

from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.lsq import INTERVALS, FitControls
from clm_core.calibration.residuals import NORMS
from clm_core.calibration.signals import SamplingRules
from clm_core.calibration.spectra import WindowSpec
from clm_core.settings import Setting

METHODS: tuple[str, ...] = ("impact", "receptance", "passby")
#: Default band [Hz] per method (fmax is further limited to 0.45 x the sample rate).
DEFAULT_BAND: Mapping[str, tuple[float, float]] = {"impact": (2.0, 150.0), "receptance": (10.0, 500.0)}
SOIL_MODELS: tuple[str, ...] = ("clm", "lysmer", "winkler")
BASE_MODELS: tuple[str, ...] = ("rigid", "winkler", "lysmer", "clm")


def _odd(v: int) -> str:
    return "" if v % 2 else "must be odd"


#: The scalar options of a calibration (every field of :class:`CalibrationOptions` but the nested ``window``,
#: ``sampling`` and ``initial``, which only an options file sets), in the order ``clm calibrate --help`` lists them.
CALIBRATION_SETTINGS: Mapping[str, Setting[Any]] = {s.name: s for s in (
    Setting("channels", str, None, "-", "channel map YAML", none_means="channels.yaml in the bag directory"),
    Setting("fmin", float, None, "Hz", "lowest fitted frequency", minimum=0.0,
            none_means="the method's: impact 2, receptance 10"),
    Setting("fmax", float, None, "Hz", "highest fitted frequency", minimum=0.0,
            none_means="the method's: impact 150, receptance 500, at most 0.45 x the sample rate"),
    Setting("norm", str, "weighted", "-", "error norm (weighted: by the measured noise)", choices=NORMS),
    Setting("model", str, "clm", "-", "impact test: soil model fitted", choices=SOIL_MODELS),
    Setting("compare", bool, True, "-", "impact test: also fit the other soil models, for comparison"),
    Setting("n_areas", int, None, "-", "impact test: areas of the model chain", minimum=3, rule=_odd,
            none_means="chosen from the data (2 max|index| + 1 up while the rms residual falls)"),
    Setting("first", str, "weighted", "-", "impact test: first estimate (weighted sums, or the paper's route)",
            choices=("weighted", "paper")),
    Setting("interval", str, "inflated", "-", "impact test: how the 95 % intervals are computed",
            choices=INTERVALS),
    Setting("delay", str, "check", "-", "impact test: force-to-response delay, estimated (check) or removed (fit)",
            choices=("check", "fit")),
    Setting("timing_accuracy", float, 0.0, "s", "impact test: stated force-to-response timing accuracy "
            "(widens the intervals; 0: none stated)", minimum=0.0),
    Setting("n_sleepers", int, 41, "-", "receptance test: sleepers of the model track", minimum=3, rule=_odd),
    Setting("fit", str, None, "-", "receptance/pass-by: parameters to fit, comma-separated (kp dp ms kb db, "
            "+ soil names with --soil joint)", none_means="kp,dp,kb,db (receptance), kp,kb (pass-by)"),
    Setting("soil", str, "fixed", "-", "track tests: keep the soil of the base set (fixed) or fit it (joint)",
            choices=("fixed", "joint")),
    Setting("params", str, None, "-", "base parameter file (rail, track, soil; replaces --track/--base-soil)",
            none_means="none: the base set is --track, --base-soil and --base-model"),
    Setting("track", str, "mevergnies", "-", "base track preset or file"),
    Setting("base_soil", str, "mevergnies", "-", "base soil preset or file"),
    Setting("base_model", str, "clm", "-", "soil model of the base set for track tests", choices=BASE_MODELS),
    Setting("min_lines", int, 16, "-", "least number of frequency lines in the band", minimum=4),
    Setting("dt", float, None, "s", "pass-by: integration step", minimum=0.0,
            none_means="the record's sample period divided into steps of at most 0.5 ms"),
    Setting("quiet_distance", float, 6.0, "m", "pass-by: distance beyond which a wheel leaves a sleeper at rest"),
    Setting("max_nfev", int, None, "-", "optimiser budget (model evaluations)", minimum=1,
            none_means="200 impact, 100 receptance, 60 pass-by"),
    Setting("ident_rel", float, 0.25, "-", "identifiability: 95 % half-width at most this fraction of the value",
            minimum=0.0),
    Setting("cond_max", float, 1e6, "-", "identifiability: largest condition number of the scaled Jacobian",
            minimum=1.0),
)}


def _d(name: str) -> Any:
    """The default of a calibration setting (the dataclass's field default)."""
    return CALIBRATION_SETTINGS[name].default


@dataclass(frozen=True)
class CalibrationOptions:
    """Everything a calibration can be told (SI units; None = the method's default).

    Attributes
    ----------
    fmin, fmax : float or None
        Fit band [Hz]; defaults in :data:`DEFAULT_BAND` (fmax at most 0.45 fs).
    norm : str
        Error norm: weighted, absolute, relative or log
        (:mod:`clm_core.calibration.residuals`).
    model : str
        Impact test: soil model to fit, clm, lysmer or winkler.
    compare : bool
        Impact test: also fit the other soil models, for comparison.
    n_areas : int or None
        Impact test: areas of the model chain (odd). Default (None): chosen
        automatically, from 2 max|index| + 1 up while the rms residual falls
        (:mod:`clm_core.calibration.impact`, "Chain length").
    first : str
        Impact test: first estimate of the CLM, ``weighted`` (noise-weighted
        fit of the Eq. 16/18 sums with intervals, :mod:`clm_core.calibration.sums`)
        or ``paper`` (the paper's unweighted route, relative norm, no window).
    interval : str
        Impact test: how the 95 % intervals are computed, ``inflated``
        (default), ``noise`` or ``hac`` (:mod:`clm_core.calibration.lsq`).
    delay : str
        Impact test: force-to-response delay, ``check`` (estimate it, warn
        when the data show one) or ``fit`` (remove it and widen the
        intervals by its uncertainty) (:mod:`clm_core.calibration.adequacy`).
    timing_accuracy : float
        Impact test: stated force-to-response timing accuracy [s]; its effect
        widens the intervals (0: none stated).
    n_sleepers : int
        Receptance test: sleepers of the model track (odd).
    fit : tuple of str or None
        Receptance / pass-by: parameters to fit (default kp dp kb db /
        kp kb); names kp dp ms kb db (+ soil names with ``soil: joint``).
    soil : str
        Receptance / pass-by: ``fixed`` (from the base set) or ``joint``.
    params : str or None
        Base parameter file (rail, track, soil); replaces ``track``/``base_soil``.
    track : str
        Base track preset or file (default mevergnies).
    base_soil : str
        Base soil preset or file (default mevergnies).
    base_model : str
        Soil model of the base set for track tests (default clm).
    initial : mapping or None
        Starting values {name: value} instead of the first estimate.
    channels : str or None
        Channel-map file (default: ``channels.yaml`` in the bag directory).
    window : WindowSpec
        Hit segmentation and windows.
    sampling : SamplingRules
        Record checks.
    min_lines : int
        Least number of frequency lines in the band.
    dt : float or None
        Pass-by: integration step [s].
    quiet_distance : float
        Pass-by: distance [m] beyond which a wheel leaves a sleeper at rest.
    max_nfev : int or None
        Optimiser budget (default 200 impact, 100 receptance, 60 pass-by).
    ident_rel : float
        Identifiability rule: 95 % half-width at most this fraction of the value.
    cond_max : float
        Identifiability rule: condition number of the scaled Jacobian.
    """

    fmin: float | None = _d("fmin")
    fmax: float | None = _d("fmax")
    norm: str = _d("norm")
    model: str = _d("model")
    compare: bool = _d("compare")
    n_areas: int | None = _d("n_areas")
    first: str = _d("first")
    interval: str = _d("interval")
    delay: str = _d("delay")
    timing_accuracy: float = _d("timing_accuracy")
    n_sleepers: int = _d("n_sleepers")
    fit: tuple[str, ...] | None = _d("fit")
    soil: str = _d("soil")
    params: str | None = _d("params")
    track: str = _d("track")
    base_soil: str = _d("base_soil")
    base_model: str = _d("base_model")
    initial: Mapping[str, float] | None = None
    channels: str | None = _d("channels")
    window: WindowSpec = field(default_factory=WindowSpec)
    sampling: SamplingRules = field(default_factory=SamplingRules)
    min_lines: int = _d("min_lines")
    dt: float | None = _d("dt")
    quiet_distance: float = _d("quiet_distance")
    max_nfev: int | None = _d("max_nfev")
    ident_rel: float = _d("ident_rel")
    cond_max: float = _d("cond_max")

    def __post_init__(self) -> None:
        if self.norm not in NORMS:
            raise CalibrationError(f"norm = {self.norm!r}: must be one of {', '.join(NORMS)}")
        if self.model not in SOIL_MODELS:
            raise CalibrationError(f"model = {self.model!r}: must be clm, lysmer or winkler")
        if self.soil not in ("fixed", "joint"):
            raise CalibrationError(f"soil = {self.soil!r}: must be fixed or joint")
        if self.base_model not in BASE_MODELS:
            raise CalibrationError(f"base_model = {self.base_model!r}: must be rigid, winkler, lysmer or clm")
        for name in ("fmin", "fmax", "dt"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise CalibrationError(f"{name} = {v!r}: must be a finite number >= 0")
        if self.fmin is not None and self.fmax is not None and not self.fmin < self.fmax:
            raise CalibrationError(f"fmin = {self.fmin:g} Hz, fmax = {self.fmax:g} Hz: need fmin < fmax")
        if self.first not in ("weighted", "paper"):
            raise CalibrationError(f"first = {self.first!r}: must be weighted or paper")
        if self.interval not in INTERVALS:
            raise CalibrationError(f"interval = {self.interval!r}: must be one of {', '.join(INTERVALS)}")
        if self.delay not in ("check", "fit"):
            raise CalibrationError(f"delay = {self.delay!r}: must be check or fit")
        ta = self.timing_accuracy
        if not (isinstance(ta, (int, float)) and math.isfinite(ta) and ta >= 0):
            raise CalibrationError(f"timing_accuracy = {ta!r} s: must be a finite number >= 0")
        if self.n_areas is not None and (self.n_areas < 3 or self.n_areas % 2 == 0):
            raise CalibrationError(f"n_areas = {self.n_areas}: must be odd and >= 3")
        if self.n_sleepers < 3 or self.n_sleepers % 2 == 0:
            raise CalibrationError(f"n_sleepers = {self.n_sleepers}: must be odd and >= 3")
        if self.min_lines < 4:
            raise CalibrationError(f"min_lines = {self.min_lines}: must be >= 4")
        self.controls(1)  # the rules of max_nfev, ident_rel, cond_max

    def controls(self, budget: int) -> FitControls:
        """The fit controls: :attr:`max_nfev` (else ``budget``, the method's), :attr:`ident_rel`, :attr:`cond_max`."""
        return FitControls(budget if self.max_nfev is None else self.max_nfev, self.ident_rel, self.cond_max)

    def band(self, method: str, fs: float | None = None) -> tuple[float, float]:
        """The fit band [Hz] for a method: the options' values or the defaults (fmax <= 0.45 fs)."""
        lo, hi = DEFAULT_BAND.get(method, (0.0, math.inf))
        fmin = self.fmin if self.fmin is not None else lo
        if self.fmax is not None:
            fmax = self.fmax
        else:
            fmax = hi if fs is None else min(hi, 0.45 * fs)
        if not fmin < fmax:
            raise CalibrationError(f"band {fmin:g}-{fmax:g} Hz is empty (sample rate {fs} Hz)")
        return float(fmin), float(fmax)

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | None) -> CalibrationOptions:
        """Build from a mapping (YAML); unknown keys are refused.

        Raises
        ------
        CalibrationError
            Unknown keys or invalid values (the message names them).
        """
        if data is None:
            return cls()
        if not isinstance(data, Mapping):
            raise CalibrationError(f"options: expected a mapping, got {type(data).__name__}")
        _refuse_unknown("options", data, cls)
        kw: dict[str, Any] = dict(data)
        for key, sub in (("window", WindowSpec), ("sampling", SamplingRules)):
            if key in kw and not isinstance(kw[key], (WindowSpec, SamplingRules)):
                raw = kw[key] or {}
                if not isinstance(raw, Mapping):
                    raise CalibrationError(f"options: {key} must be a mapping")
                _refuse_unknown(f"options: {key}", raw, sub)
                try:
                    kw[key] = sub(**raw)
                except TypeError as exc:
                    raise CalibrationError(f"options: {key}: {exc}") from None
        if "fit" in kw and kw["fit"] is not None:
            f = kw["fit"]
            kw["fit"] = tuple(x.strip() for x in f.split(",")) if isinstance(f, str) else tuple(str(x) for x in f)
        if "initial" in kw and kw["initial"] is not None:
            if not isinstance(kw["initial"], Mapping):
                raise CalibrationError("options: initial must be a mapping {name: value}")
            try:
                kw["initial"] = {str(k): float(v) for k, v in kw["initial"].items()}
            except (TypeError, ValueError):
                raise CalibrationError(f"options: initial = {kw['initial']!r}: values must be numbers") from None
        for key in ("fmin", "fmax", "dt", "quiet_distance", "ident_rel", "cond_max", "timing_accuracy"):
            if key in kw and kw[key] is not None:
                try:
                    kw[key] = float(kw[key])
                except (TypeError, ValueError):
                    raise CalibrationError(f"options: {key} = {kw[key]!r}: must be a number") from None
        for key in ("n_areas", "n_sleepers", "min_lines", "max_nfev"):
            if key in kw and kw[key] is not None:
                v = kw[key]
                if isinstance(v, bool) or not isinstance(v, int):
                    raise CalibrationError(f"options: {key} = {v!r}: must be an integer")
        return cls(**kw)

    @classmethod
    def from_yaml(cls, text: str | None) -> CalibrationOptions:
        """Build from YAML text (empty: defaults)."""
        if not text or not text.strip():
            return cls()
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise CalibrationError(f"options: not valid YAML ({exc})") from None
        return cls.from_mapping(data or {})

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (YAML/JSON-ready), the inverse of :meth:`from_mapping`."""
        d = asdict(self)
        d["fit"] = list(self.fit) if self.fit is not None else None
        d["initial"] = dict(self.initial) if self.initial is not None else None
        return d


def _refuse_unknown(where: str, data: Mapping[str, Any], cls: type) -> None:
    """Refuse keys of ``data`` that are not fields of the dataclass ``cls`` (the message lists the allowed ones)."""
    allowed = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise CalibrationError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
