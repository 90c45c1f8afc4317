"""One call from a bag to fitted parameters: :func:`calibrate`.

``calibrate(bag_path, method, options)`` reads the bag with its channel map,
checks the records, estimates transfer functions (impact, receptance) or
takes the wheel loads (pass-by), fits, and returns a frozen
:class:`CalibrationResult` (plain data: arrays and values, nothing kept on
a fitter). :func:`clm_core.outputs.calibration_report.write_outputs` writes it to a
directory; the ROS service is a thin wrapper around the same call.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.calibration.adequacy import adequacy_summary
from clm_core.calibration.bagio import WheelLoadRecord, read_bag
from clm_core.calibration.channels import ChannelMap, find_channel_map, load_channel_map
from clm_core.calibration.errors import BagError, CalibrationError
from clm_core.calibration.impact import SoilFit, fit_impact
from clm_core.calibration.lsq import FitControls, FitStats, ParameterEstimate
from clm_core.calibration.models import track_response
from clm_core.calibration.options import METHODS, CalibrationOptions
from clm_core.calibration.passby import DEFAULT_PASSBY_FIT, fit_passby
from clm_core.calibration.receptance import DEFAULT_FIT, TrackFit, fit_receptance, out_dofs
from clm_core.calibration.signals import Recording
from clm_core.calibration.spectra import TransferData, WindowSpec, transfer_functions
from clm_core.errors import ParameterError
from clm_core.io.files import dumps_json
from clm_core.params import ModelParams, SoilParams, load_model, load_params_file
from clm_core.soil.chain import chain_response
from clm_core.track import assemble

Progress = Callable[[str, float], None]


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of :func:`calibrate` (plain, immutable data).

    ``band``, ``norm``, ``parameters``, ``stats``, ``misfit``,
    ``first_estimate`` and ``first_estimate_method`` are those of
    :attr:`main_fit` (properties).

    Attributes
    ----------
    method : {'impact', 'receptance', 'passby'}
    bag : str
        Bag path.
    storage : str
        ``mcap`` or ``sqlite3``.
    channel_map : ChannelMap
        The channels read.
    options : CalibrationOptions
        Options used.
    model : str
        Fitted model: the soil model (impact) or ``track`` / ``track+soil``.
    params : ModelParams
        Full parameter set: base rail/track/soil with the fitted values.
    comparisons : tuple of SoilFit
        Impact: fits of the other soil models (comparison).
    main_fit : SoilFit or TrackFit
        The main fit with its model responses.
    data : TransferData or None
        Measured transfer functions (impact, receptance).
    recording : Recording
        The records on their common time grid.
    loads : WheelLoadRecord or None
        Pass-by wheel loads.
    time_model : (n_t, n_ch) array or None
        Fitted model's response to the measured excitation, in each
        channel's quantity [SI].
    warnings : tuple of str
        Everything the user should know (identifiability, constraints,
        record quality).
    notes : tuple of str
        What was done to the records.
    elapsed_s : float
        Wall time of the calibration [s].
    """

    method: str
    bag: str
    storage: str
    channel_map: ChannelMap
    options: CalibrationOptions
    model: str
    params: ModelParams
    comparisons: tuple[SoilFit, ...]
    main_fit: SoilFit | TrackFit
    data: TransferData | None
    recording: Recording
    loads: WheelLoadRecord | None
    time_model: Array | None
    warnings: tuple[str, ...]
    notes: tuple[str, ...]
    elapsed_s: float

    @property
    def band(self) -> tuple[float, float]:
        """Fit band [Hz] of :attr:`main_fit` (pass-by: 0 to fs/2, time domain)."""
        return self.main_fit.band

    @property
    def norm(self) -> str:
        """Error norm used by :attr:`main_fit`."""
        return self.main_fit.norm

    @property
    def parameters(self) -> tuple[ParameterEstimate, ...]:
        """Fitted parameters of :attr:`main_fit`, values [SI] and 95 % intervals."""
        return self.main_fit.parameters

    @property
    def stats(self) -> FitStats:
        """Residual statistics of :attr:`main_fit`."""
        return self.main_fit.stats

    @property
    def misfit(self) -> float:
        """Relative misfit of :attr:`main_fit` in its norm, ||W (model - data)|| / ||W data|| [-]."""
        return self.main_fit.misfit

    @property
    def first_estimate(self) -> Mapping[str, float]:
        """Starting values of :attr:`main_fit` [SI]."""
        return self.main_fit.first_estimate

    @property
    def first_estimate_method(self) -> str:
        """How the starting values were found."""
        return self.main_fit.first_estimate_method

    @property
    def soil(self) -> SoilParams:
        """The soil of :attr:`params`."""
        return self.params.soil

    def values(self) -> dict[str, float]:
        """Fitted values {name: value} [SI]."""
        return {p.name: p.value for p in self.parameters}

    def parameters_yaml(self) -> str:
        """The full parameter file (``clm_core.params.load_params_file`` format) as YAML text."""
        return yaml.safe_dump(self.params.to_dict(), sort_keys=False)

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary: values, intervals, band, norm, residuals, warnings."""
        def est(p: ParameterEstimate) -> dict[str, Any]:
            return {
                "value": p.value,
                "unit": p.unit,
                "initial": p.initial,
                "std": _num(p.std),
                "ci95": [_num(p.ci_low), _num(p.ci_high)],
                "rel_halfwidth": _num(p.rel_halfwidth),
                "at_bound": p.at_bound,
                "identifiable": p.identifiable,
            }

        out: dict[str, Any] = {
            "method": self.method,
            "model": self.model,
            "bag": self.bag,
            "storage": self.storage,
            "band_hz": list(self.band),
            "norm": self.norm,
            "parameters": {p.name: est(p) for p in self.parameters},
            "first_estimate": dict(self.first_estimate),
            "first_estimate_method": self.first_estimate_method,
            "fit": {
                "misfit": self.misfit,
                "rms_residual": self.stats.rms,
                "noise_ratio": _num(self.stats.noise_ratio),
                "residual_variance": self.stats.residual_variance,
                "n_residuals": self.stats.n_residuals,
                "n_params": self.stats.n_params,
                "jacobian_condition": _num(self.stats.condition),
                "covariance": self.stats.covariance,
                "nfev": self.stats.nfev,
                "status": self.stats.status,
            },
            "comparisons": {
                c.model: {
                    "parameters": {p.name: p.value for p in c.parameters},
                    "misfit_loaded_area": c.misfit_loaded,
                    "rms_residual": c.stats.rms,
                }
                for c in self.comparisons
            },
            "parameter_file": self.params.to_dict(),
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "elapsed_s": self.elapsed_s,
        }
        out["fit"]["interval_method"] = self.stats.interval
        if isinstance(self.main_fit, SoilFit):
            mf = self.main_fit
            if mf.first_estimate_parameters:
                out["first_estimate_ci95"] = {
                    p.name: [_num(p.ci_low), _num(p.ci_high)] for p in mf.first_estimate_parameters
                }
            out["fit"]["chain"] = {
                "n_areas": mf.n_areas,
                "selection": mf.chain_selection,
                "trials": [{"n_areas": n, "rms_residual": rr} for n, rr in mf.chain_trials],
            }
            if mf.whiteness is not None:
                w = mf.whiteness
                out["fit"]["residual_whiteness"] = {
                    "rms_whitened": w.rms,
                    "lag1_autocorrelation": w.lag1,
                    "ljung_box": w.ljung_box,
                    "ljung_box_lags": w.lags,
                    "p_value": w.p_value,
                }
            out["fit"]["adequacy"] = adequacy_summary(mf)
            if self.stats.inflation:
                out["fit"]["interval_inflation"] = {
                    name: c for name, c in zip(mf.channels_used, self.stats.inflation)
                }
            out["comparisons"][self.main_fit.model] = {
                "parameters": {p.name: p.value for p in self.main_fit.parameters},
                "misfit_loaded_area": self.main_fit.misfit_loaded,
                "rms_residual": self.main_fit.stats.rms,
            }
        rec = self.recording
        out["record"] = {
            "sample_rate_hz": rec.fs,
            "duration_s": rec.duration,
            "channels": [c.name for c in rec.channels],
        }
        if self.data is not None:
            out["record"].update(
                {
                    "hits": self.data.n_hits,
                    "hit_times_s": list(self.data.hit_times),
                    "segment_s": self.data.segment,
                    "window_decay_1_per_s": self.data.sigma,
                    "snr_db": [_num(x) for x in self.data.snr_db],
                    "force_snr_db": _num(self.data.force_snr_db),
                }
            )
        return out

    def summary_json(self) -> str:
        """:meth:`summary` as strict JSON text (:func:`clm_core.io.files.dumps_json`)."""
        return dumps_json(self.summary())


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _base_params(opts: CalibrationOptions) -> ModelParams:
    try:
        if opts.params:
            return load_params_file(opts.params)
        return load_model(opts.track, opts.base_soil, opts.base_model)  # type: ignore[arg-type]
    except ParameterError as exc:
        raise CalibrationError(f"base parameters: {exc}") from None


def _channel_map(bag_path: str | Path, opts: CalibrationOptions, method: str) -> ChannelMap:
    path = opts.channels or find_channel_map(bag_path)
    if path is None:
        raise CalibrationError(
            f"no channel map: give --channels MAP.yaml (or options 'channels'), or put channels.yaml in the bag "
            f"directory {str(bag_path)!r} (format: docs/calibration.md)"
        )
    cmap = load_channel_map(path)
    if cmap.test is not None and cmap.test != method:
        raise CalibrationError(f"channel map {cmap.source} is for the {cmap.test} test, not the {method} test")
    return cmap


def calibrate(
    bag_path: str | Path,
    method: str,
    options: CalibrationOptions | Mapping[str, Any] | str | None = None,
    progress: Progress | None = None,
    allow_partial: bool = False,
) -> CalibrationResult:
    """Fit model parameters to a recorded test.

    Parameters
    ----------
    bag_path : path
        rosbag2 bag (directory or ``.mcap`` file), mcap or sqlite3.
    method : {'impact', 'receptance', 'passby'}
        ``impact``: soil impact test, CLM (or Lysmer/Winkler) soil
        parameters; ``receptance``: hammer on the rail, track (and soil)
        parameters; ``passby``: wheel loads and responses, output-error fit
        through the time-domain engine.
    options : CalibrationOptions, mapping or YAML text, optional
        See :class:`~clm_core.calibration.options.CalibrationOptions`.
    progress : callable (stage, fraction), optional
        Progress reports (fraction in [0, 1]).
    allow_partial : bool
        Fit what is left of a damaged bag (missing or damaged chunks are
        listed in the warnings) instead of raising :class:`BagError`.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    BagError
        Unreadable bag, missing topics, clipped or badly sampled records.
    CalibrationError
        Bad options or channel map, records too short for the band, no
        usable first estimate.

    Examples
    --------
    The shipped rail receptance test (synthetic, 30 dB SNR; truth: paper
    Table 2, k_p = 120 MN/m, k_b = 47 MN/m):

    >>> from pathlib import Path
    >>> import clm_core
    >>> bag = Path(clm_core.__file__).parents[1] / "bags" / "calibration" / "receptance_mevergnies"
    >>> result = calibrate(bag, "receptance")
    >>> result.method, result.model
    ('receptance', 'track')
    >>> print(f"k_p = {result.values()['kp'] / 1e6:.0f} MN/m")
    k_p = 120 MN/m
    """
    t_start = time.perf_counter()
    if method not in METHODS:
        raise CalibrationError(f"method = {method!r}: must be one of {', '.join(METHODS)}")
    if isinstance(options, CalibrationOptions):
        opts = options
    elif isinstance(options, str):
        opts = CalibrationOptions.from_yaml(options)
    else:
        opts = CalibrationOptions.from_mapping(options)

    def report(stage: str, frac: float) -> None:
        if progress is not None:
            progress(stage, frac)

    def reporting(controls: FitControls, stage: str, lo: float, hi: float) -> FitControls:
        # `controls` reporting every model evaluation of a fit: `stage` from `lo` towards `hi` as the evaluations add
        # up (capped: finite differences and chain-length trials add evaluations beyond the budget); a cancel raised
        # by `progress` stops the fit there
        n = 0

        def tick() -> None:
            nonlocal n
            n += 1
            report(stage, min(hi, lo + (hi - lo) * n / (controls.max_nfev + 10)))

        return replace(controls, progress=tick)

    report("reading bag", 0.0)
    if not Path(bag_path).exists():
        raise BagError(f"bag {str(bag_path)!r} does not exist")
    cmap = _channel_map(bag_path, opts, method)
    contents = read_bag(
        bag_path, cmap, opts.sampling, need_force=method != "passby", need_loads=method == "passby",
        allow_partial=allow_partial,
    )
    rec = contents.recording
    warnings: list[str] = [f"partial bag: {d}" for d in contents.damage]
    notes = list(rec.notes)
    base = _base_params(opts)
    report("records checked", 0.15)
    if method == "passby":
        assert contents.loads is not None
        controls = opts.controls(60)
        fit = fit_passby(
            rec,
            contents.loads,
            base,
            opts.fit or DEFAULT_PASSBY_FIT,
            opts.soil,
            opts.initial,
            opts.dt,
            opts.quiet_distance,
            controls=reporting(controls, "fitting (time-domain simulations)", 0.2, 0.95),
        )
        warnings += fit.warnings
        report("done", 1.0)
        return _track_result(method, bag_path, contents.storage, cmap, opts, fit, None, rec, contents.loads,
                             np.asarray(fit.model_response, dtype=float), warnings, notes, t_start)
    fmin, fmax = opts.band(method, rec.fs)
    data, w = transfer_functions(rec, fmin, fmax, opts.window, opts.min_lines)
    warnings += w
    report("transfer functions", 0.25)
    if method == "impact":
        first, _ = transfer_functions(rec, fmin, fmax, _no_exp(opts.window), opts.min_lines)
        controls = opts.controls(200)
        main = fit_impact(
            data,
            opts.model,
            opts.norm,
            opts.n_areas,
            opts.initial,
            first,
            controls=reporting(controls, f"{opts.model} fit", 0.25, 0.6),
            interval=opts.interval,
            first=opts.first,
            delay=opts.delay,
            timing_accuracy=opts.timing_accuracy,
        )
        warnings += main.warnings
        report(f"{opts.model} fit", 0.6)
        comps: list[SoilFit] = []
        if opts.compare:
            for k, other in enumerate(m for m in ("clm", "lysmer", "winkler") if m != opts.model):
                stage = f"comparison fit {other}"
                try:
                    comps.append(
                        fit_impact(data, other, opts.norm, opts.n_areas, None, first,
                                   controls=reporting(controls, stage, 0.6 + 0.1 * k, 0.7 + 0.1 * k),
                                   interval=opts.interval, first=opts.first)
                    )
                except CalibrationError as exc:
                    warnings.append(f"{stage}: {exc}")
                report(stage, 0.7 + 0.1 * k)
        try:
            params = ModelParams(rail=base.rail, track=base.track, soil=main.soil, name="calibrated")
        except ParameterError as exc:  # pragma: no cover - a fitted soil is admissible by construction
            raise CalibrationError(f"fitted soil refused: {exc}") from None
        tm = _impact_time_model(main, rec)
        report("done", 1.0)
        return _result(method, bag_path, contents.storage, cmap, opts, main, opts.model, params, tuple(comps), data,
                       rec, None, tm, warnings, notes, t_start)
    # receptance
    controls = opts.controls(100)
    tfit = fit_receptance(
        data,
        base,
        opts.fit or DEFAULT_FIT,
        opts.soil,
        opts.norm,
        opts.n_sleepers,
        opts.initial,
        controls=reporting(controls, "track fit", 0.25, 0.9),
    )
    warnings += tfit.warnings
    report("track fit", 0.9)
    tm = _receptance_time_model(tfit, rec)
    report("done", 1.0)
    return _track_result(method, bag_path, contents.storage, cmap, opts, tfit, data, rec, None, tm, warnings, notes,
                         t_start)


def _track_result(
    method: str, bag_path: str | Path, storage: str, cmap: ChannelMap, opts: CalibrationOptions, fit: TrackFit,
    data: Any, rec: Recording, loads: Any, time_model: Array | None, warnings: list[str], notes: list[str],
    t_start: float,
) -> CalibrationResult:
    """The result of a track-parameter fit (receptance or pass-by)."""
    model = "track+soil" if opts.soil == "joint" else "track"
    return _result(method, bag_path, storage, cmap, opts, fit, model, fit.params, (), data, rec, loads, time_model,
                   warnings, notes, t_start)


def _result(
    method: str, bag_path: str | Path, storage: str, cmap: ChannelMap, opts: CalibrationOptions,
    fit: SoilFit | TrackFit, model: str, params: ModelParams, comparisons: tuple[SoilFit, ...], data: Any,
    rec: Recording, loads: Any, time_model: Array | None, warnings: list[str], notes: list[str], t_start: float,
) -> CalibrationResult:
    """The result of a fit: the main ``fit`` with its full parameter set ``params`` and the run's context.

    ``t_start`` is the :func:`time.perf_counter` value [s] at the start of the run.
    """
    return CalibrationResult(
        method=method,
        bag=str(bag_path),
        storage=storage,
        channel_map=cmap,
        options=opts,
        model=model,
        params=params,
        comparisons=comparisons,
        main_fit=fit,
        data=data,
        recording=rec,
        loads=loads,
        time_model=time_model,
        warnings=tuple(warnings),
        notes=tuple(notes),
        elapsed_s=time.perf_counter() - t_start,
    )


def _no_exp(w: WindowSpec) -> WindowSpec:
    from dataclasses import replace

    return replace(w, exp_end=1.0)


def _convolve(H: NDArray[np.complex128], f: NDArray[np.float64], force: Array, fs: float,
              powers: list[int]) -> Array:
    """Responses to ``force`` of receptances H given at the rfft lines of the doubled record."""
    n = force.size
    F = np.fft.rfft(force, 2 * n)
    s = 2j * np.pi * f
    conv = np.column_stack([s**p for p in powers])
    return np.asarray(np.fft.irfft(H * conv * F[:, None], 2 * n, axis=0)[:n])


def _impact_time_model(fit: SoilFit, rec: Recording) -> Array | None:
    """The fitted chain's response to the measured force, in each channel's quantity."""
    if rec.force is None:
        return None
    n = rec.force.size
    f = np.asarray(np.fft.rfftfreq(2 * n, 1.0 / rec.fs), dtype=np.float64)
    X, _ = chain_response(fit.soil, fit.n_areas, 2j * np.pi * f)
    c = fit.n_areas // 2
    H = X[:, [c + ch.index for ch in rec.channels]]
    powers = [{"displacement": 0, "velocity": 1, "acceleration": 2}[ch.quantity] for ch in rec.channels]
    return _convolve(H, f, rec.force, rec.fs, powers)


def _receptance_time_model(fit: TrackFit, rec: Recording) -> Array | None:
    """The fitted track's response to the measured force, in each channel's quantity."""
    if rec.force is None:
        return None
    n = rec.force.size
    f = np.asarray(np.fft.rfftfreq(2 * n, 1.0 / rec.fs), dtype=np.float64)
    system = assemble(fit.params, fit.n_sleepers)
    c = fit.n_sleepers // 2
    dofs = out_dofs(system, rec.channels, c)
    H = track_response(system, 2j * np.pi * f, int(system.rail_w[system.sleeper_node[c]]), dofs)
    powers = [{"displacement": 0, "velocity": 1, "acceleration": 2}[ch.quantity] for ch in rec.channels]
    return _convolve(H, f, rec.force, rec.fs, powers)
