"""Soil impact test: CLM (or Lysmer, Winkler) parameters from measured area receptances.

A force on one soil contact area (index 0) and the vertical motion of the
areas around it (indices -n..n, or one side 0..n) give the receptances
H_j = X_j / F (:mod:`clm_core.calibration.spectra`). The fit follows the
paper's route (Kouroussis et al. 2011, Sec. 4.1) and then refines it:

1. First estimate: the total and alternating sums, Eq. (16) and (18),
   F / sum_j X_j = k_f + s d_f + s^2 m_f and
   F / sum_j (-1)^j X_j = (k_f + 4 k_c) + s (d_f + 4 d_c) + s^2 m_f.
   Default (``first='weighted'``): a noise-weighted output-error fit of both
   sums at the windowed complex frequency, areas below their noise left out
   of the sums, with 95 % intervals (:func:`clm_core.calibration.sums.fit_sums`).
   ``first='paper'`` (and without a noise estimate): the paper's route on
   the unwindowed receptances, a quadratic fit of the real parts and a
   linear fit of the imaginary parts, relative norm
   (:func:`clm_core.soil.fit.fit_clm_sums`, total-first route); under noise it
   underestimates k_c by tens of percent (issue 14, docs/calibration.md). A
   one-sided record is completed by symmetry, Eq. (19)–(20).
2. Refinement: all five parameters by bounded nonlinear least squares on all
   measured receptances, model :func:`clm_core.soil.chain.chain_response`
   (the chain of :func:`clm_core.soil.chain.chain_matrices`) at the windowed
   complex frequency, over admissible sets only: m_f, k_f > 0, k_c >= 0,
   d_f >= 0 and d_f + 4 d_c >= 0 (damping matrix positive semi-definite,
   Sec. 4.2). 95 % intervals: :mod:`clm_core.calibration.lsq` (default
   ``inflated``: the noise-model sandwich, each channel's noise covariance
   scaled by its excess of residual power).

Chain length. The soil goes on beyond the last geophone, so the chain of
the model may need more areas than the record spans (a chain of
2 max|index| + 1 areas with free ends reflects what the soil carries away).
By default (``n_areas=None``) the chain starts at 2 max|index| + 1 areas and
grows by 2 max(5, ceil(max|index| / 2)) areas while the rms residual falls by
more than ``grow_tol`` (0.5 %); the trials are kept in
:attr:`SoilFit.chain_trials`. After the fit, the residuals are whitened
with the noise model and tested
(:func:`clm_core.calibration.residuals.residual_whiteness`): an rms
residual above 1.2 or a lag-1 autocorrelation of the whitened residuals
along frequency above 0.05 (Ljung–Box p < 1e-3) gives a warning that names
the channels with the largest misfit and, for a fixed chain, the rms a
longer chain reaches.

Lysmer's analogue (m_f, k_f, d_f; Eq. 2–3) and the Winkler model (k_f, d_f)
have no coupling: they predict only the loaded area, and are fitted to the
receptance of area 0 for comparison.

Error norms (residual per frequency line and channel, real and imaginary
parts):

- ``weighted`` (default): (H_model - H) / std(H), std from the noise before
  the hit (maximum likelihood for Gaussian noise; rms residual ~ 1 when the
  model explains the data);
- ``absolute``: (H_model - H) / max |H| (near areas dominate);
- ``relative``: (H_model - H) / |H| (every line counts alike; biased at low
  SNR, where |H| is noisy);
- ``log``: log(H_model / H) (log-amplitude and phase differences).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array, CArray
from clm_core.calibration.adequacy import (
    DELAY_MODES,
    ExtensionTest,
    FirstVsFit,
    adequacy_warnings,
    first_vs_refined,
    model_checks,
    widen,
)
from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.lsq import FitControls, FitResult, FitStats, ParameterEstimate, Sandwich, fit_constrained
from clm_core.calibration.residuals import (
    WhitenessCheck,
    channel_noise_power,
    corr_factor,
    make_sandwich,
    misfit,
    norm_weights,
    residual_layout,
    residual_whiteness,
    stack_residual,
)
from clm_core.calibration.spectra import TransferData
from clm_core.calibration.sums import area_columns, fit_sums
from clm_core.errors import ParameterError
from clm_core.params import SoilParams
from clm_core.soil.chain import CHAIN_PARAMS, chain_response
from clm_core.soil.fit import fit_clm_sums, fit_lysmer

SOIL_FIT_MODELS: tuple[str, ...] = ("clm", "lysmer", "winkler")
#: First-estimate methods of the CLM fit (:func:`fit_impact`).
FIRST_ESTIMATES: tuple[str, ...] = ("weighted", "paper")
#: Residuals pass as noise when their rms (weighted norm) is at most this [-] ...
WHITE_RMS = 1.2
#: ... and their lag-1 autocorrelation is at most this [-], or not significant at WHITE_P.
WHITE_LAG1 = 0.05
WHITE_P = 1e-3
_FREE: Mapping[str, tuple[str, ...]] = {
    "clm": ("mf", "kf", "df", "kc", "dc"),
    "lysmer": ("mf", "kf", "df"),
    "winkler": ("kf", "df"),
}


@dataclass(frozen=True)
class SoilFit(FitResult):
    """Result of a soil fit to an impact test: :class:`~clm_core.calibration.lsq.FitResult` and the following.

    Attributes
    ----------
    model : {'clm', 'lysmer', 'winkler'}
        Fitted foundation model.
    soil : SoilParams
        Fitted parameters (an admissible, stable set).
    n_areas : int
        Areas in the model chain.
    H_model : (n_f, n_ch) complex array
        Fitted model receptances at the data's complex frequencies, every channel [m/N].
    misfit_loaded : float
        :attr:`misfit` for the loaded area alone (comparable across models) [-]
        (:func:`~clm_core.calibration.residuals.misfit`).
    first_estimate_parameters : tuple of ParameterEstimate
        The first estimate with its own 95 % intervals (noise-weighted sums,
        :mod:`clm_core.calibration.sums`); () when not computed.
    chain_selection : {'auto', 'fixed'}
        Whether the chain length was chosen automatically.
    chain_trials : tuple of (int, float)
        (n_areas, rms residual) of every chain length tried.
    whiteness : WhitenessCheck or None
        Test of the residuals against the noise model (``weighted`` norm).
    delay : ExtensionTest or None
        Force-to-response delay tau [s] that the data show (linearised
        estimate, its standard error and Wald test;
        :mod:`clm_core.calibration.adequacy`); with ``delay='fit'``, the
        delay that was removed (``delay_applied``) and its uncertainty.
    coupling2 : ExtensionTest or None
        Second-neighbour coupling (k_c2, d_c2) that the data show: a test of
        the CLM family.
    first_vs_fit : FirstVsFit or None
        The Eq. (16)/(18) first estimate against the refined fit (sigma per parameter).
    delay_applied : float
        Delay removed from the responses before the fit (``delay='fit'``) [s].
    timing_accuracy : float
        Stated force-to-response timing accuracy whose effect widens the
        intervals [s].
    """

    model: str
    soil: SoilParams
    n_areas: int
    H_model: CArray
    misfit_loaded: float
    first_estimate_parameters: tuple[ParameterEstimate, ...] = ()
    chain_selection: str = "fixed"
    chain_trials: tuple[tuple[int, float], ...] = ()
    whiteness: WhitenessCheck | None = None
    delay: ExtensionTest | None = None
    coupling2: ExtensionTest | None = None
    first_vs_fit: FirstVsFit | None = None
    delay_applied: float = 0.0
    timing_accuracy: float = 0.0


def _soil(model: str, values: Mapping[str, float]) -> SoilParams:
    return SoilParams(model=model, **{k: float(values.get(k, 0.0)) for k in CHAIN_PARAMS})  # type: ignore[arg-type]


def measured_sums(data: TransferData) -> tuple[CArray, CArray, int, str] | None:
    """The impedance sums F / sum X_j and F / sum (-1)^j X_j of the measured areas, Eq. (16), (18).

    Areas 1..n (and -1..-n) must be measured without holes from the loaded
    area outwards; a side measured less far is completed by symmetry,
    X_-j = X_j (Eq. 19–20).

    Returns
    -------
    (total, alternating, n_areas, description) or None when area 0 is
    missing or no neighbour is measured.
    """
    areas = area_columns(data)
    if areas is None:
        return None
    H, idx, n = data.H, areas.column, areas.reach
    tot = H[:, idx[0]].copy()
    alt = H[:, idx[0]].copy()
    for j in range(1, n + 1):
        a = H[:, idx[j]] if j <= areas.n_pos else None
        b = H[:, idx[-j]] if j <= areas.n_neg else None
        pair = (a + b) if (a is not None and b is not None) else 2.0 * (a if a is not None else b)  # type: ignore[operator]
        tot += pair
        alt += (-1) ** j * pair
    symmetric = areas.n_pos == areas.n_neg
    how = f"areas -{areas.n_neg}..{areas.n_pos}" + ("" if symmetric else " (completed by symmetry, Eq. 19-20)")
    return 1.0 / tot, 1.0 / alt, 2 * n + 1, how


def first_estimate(
    data: TransferData, fmin: float, fmax: float, model: str = "clm"
) -> tuple[dict[str, float], str, list[str]]:
    """Starting values by the paper's route (Eq. 16/18 sums, or Lysmer's Eq. 3 on area 0).

    Parameters
    ----------
    data : TransferData
        Receptances at real frequencies (no exponential window), so that the
        sums have the form of Eq. (16) and (18).
    fmin, fmax : float
        Band [Hz].
    model : {'clm', 'lysmer', 'winkler'}

    Returns
    -------
    values : dict
        Starting values of the model's parameters.
    method : str
        Description (band, norm).
    warnings : list of str
    """
    warns: list[str] = []
    f = data.frequency
    idx0 = [k for k, c in enumerate(data.channels) if c.location == "area" and c.index == 0]
    sums = measured_sums(data) if model == "clm" else None
    if sums is not None:
        tot, alt, n_sum, how = sums
        try:
            fit = fit_clm_sums(
                f, tot, alt, fmin=fmin, fmax=fmax, norm="relative", on_unstable="clip", n_areas=n_sum,
                route="total-first",
            )
            vals = dict(fit.params)
            note = f" ({', '.join(fit.constrained)})" if fit.constrained else ""
            method = (
                f"Eq. (16)/(18) sums of {how}: quadratic fit of the real parts, linear fit of the imaginary parts "
                f"(clm_core.soil.fit, total-first route, relative norm, {fmin:g}-{fmax:g} Hz){note}"
            )
            return _admissible(vals, warns), method, warns
        except ParameterError as exc:
            warns.append(f"first estimate from the sums failed ({exc}); starting from Lysmer's analogue of area 0")
    elif model == "clm":
        warns.append(
            "the areas around the loaded one are not measured without holes: Eq. (16)/(18) sums cannot be formed; "
            "starting from Lysmer's analogue of area 0 with k_c = k_f, d_c = -d_f / 8"
        )
    if not idx0:
        raise CalibrationError(
            "no channel at area 0 (the loaded area): the fit needs its response (channel map: area: 0)"
        )
    Z0 = 1.0 / data.H[:, idx0[0]]
    try:
        ly = fit_lysmer(f, Z0, fmin=fmin, fmax=fmax, norm="relative")
    except ParameterError as exc:
        raise CalibrationError(f"no first estimate: Lysmer fit of area 0 failed ({exc})") from None
    vals = {"mf": ly.mf, "kf": ly.kf, "df": ly.df}
    method = (
        "Lysmer's analogue, Eq. (3), fitted to F / X_0 (clm_core.soil.fit.fit_lysmer, relative norm, "
        f"{fmin:g}-{fmax:g} Hz)"
    )
    if model == "clm":
        # an isolated-area fit sees k_f + coupling: split it as a guess
        vals = {"mf": ly.mf, "kf": ly.kf / 3.0, "df": ly.df / 2.0, "kc": ly.kf / 3.0, "dc": -ly.df / 16.0}
    if model == "winkler":
        vals = {"kf": ly.kf, "df": ly.df}
    return _admissible(vals, warns), method, warns


def _admissible(vals: dict[str, float], warns: list[str]) -> dict[str, float]:
    """Move a first estimate inside the constraints of the refinement."""
    out = dict(vals)
    kf = out.get("kf", 0.0)
    if not kf > 0:
        raise CalibrationError(
            f"first estimate k_f = {kf:g} N/m is not positive: the data do not look like a soil receptance"
        )
    if "mf" in out and not out["mf"] > 0:
        out["mf"] = 1e-3 * kf / (2 * math.pi * 50.0) ** 2
        warns.append(f"first estimate m_f <= 0 replaced by {out['mf']:.3g} kg")
    if out.get("df", 1.0) <= 0:
        out["df"] = 1e-3 * kf
        warns.append(f"first estimate d_f <= 0 replaced by {out['df']:.3g} N s/m")
    if "kc" in out:
        if out["kc"] <= 0:
            out["kc"] = 0.1 * kf
        if out["df"] + 4 * out["dc"] <= 0.02 * out["df"]:
            out["dc"] = -0.24 * out["df"]
    return out


@dataclass(frozen=True)
class _ChainFit:
    """One refinement at a given chain length (internal)."""

    n_areas: int
    p: Array
    est: tuple[ParameterEstimate, ...]
    stats: FitStats
    warnings: list[str]
    r: Array
    J: Array


def fit_impact(
    data: TransferData,
    model: str = "clm",
    norm: str = "weighted",
    n_areas: int | None = None,
    initial: Mapping[str, float] | None = None,
    first_data: TransferData | None = None,
    *,
    controls: FitControls | None = None,
    interval: str = "inflated",
    first: str = "weighted",
    grow_tol: float = 0.005,
    max_areas: int | None = None,
    delay: str = "check",
    timing_accuracy: float = 0.0,
) -> SoilFit:
    """Fit a soil model to the receptances of an impact test.

    Parameters
    ----------
    data : TransferData
        Measured receptances (channels located at areas).
    model : {'clm', 'lysmer', 'winkler'}
        Foundation model. ``lysmer`` and ``winkler`` use area 0 only.
    norm : {'weighted', 'absolute', 'relative', 'log'}
        Error norm (module docstring).
    n_areas : int, optional
        Areas of the model chain (odd, >= 2 max|index| + 1). Default (None):
        chosen automatically for the CLM (module docstring, "Chain length");
        2 max|index| + 1 (at least 3) for Lysmer and Winkler.
    initial : mapping, optional
        Starting values; default: the first estimate (``first``).
    first_data : TransferData, optional
        Receptances without exponential window for the ``paper`` first
        estimate (default ``data``).
    controls : FitControls, optional
        Budget and identifiability rules (default: :class:`~clm_core.calibration.lsq.FitControls`,
        200 evaluations).
    interval : {'inflated', 'noise', 'hac'}
        Interval method (:mod:`clm_core.calibration.lsq`); ``inflated``
        groups the residuals by channel.
    first : {'weighted', 'paper'}
        First estimate of the CLM: the noise-weighted fit of the Eq. (16)/(18)
        sums (:func:`clm_core.calibration.sums.fit_sums`, with intervals), or
        the paper's unweighted route (:func:`first_estimate`).
    grow_tol : float
        Automatic chain length: a longer chain is kept while it lowers the
        rms residual by more than this fraction [-].
    max_areas : int, optional
        Automatic chain length: longest chain tried (default
        2 max|index| + 1 + 8 steps, at most 201).
    delay : {'check', 'fit'}
        Force-to-response delay: ``check`` estimates it after the fit and
        warns when the data show one; ``fit`` also removes it from the
        responses, fits again, and widens the intervals by its uncertainty
        (:mod:`clm_core.calibration.adequacy`).
    timing_accuracy : float
        Stated accuracy of the force-to-response timing [s]: a delay
        anywhere in +-timing_accuracy (uniform) adds its effect on each
        parameter to the variance.

    Returns
    -------
    SoilFit

    Raises
    ------
    CalibrationError
        Unknown model, norm, interval or first-estimate method, channels not
        at areas, no area 0 for Lysmer/Winkler, bad ``n_areas`` or initial
        values.
    """
    if model not in SOIL_FIT_MODELS:
        raise CalibrationError(f"model = {model!r}: must be one of {', '.join(SOIL_FIT_MODELS)}")
    if first not in FIRST_ESTIMATES:
        raise CalibrationError(f"first = {first!r}: must be one of {', '.join(FIRST_ESTIMATES)}")
    if delay not in DELAY_MODES:
        raise CalibrationError(f"delay = {delay!r}: must be one of {', '.join(DELAY_MODES)}")
    if not (math.isfinite(timing_accuracy) and timing_accuracy >= 0):
        raise CalibrationError(f"timing_accuracy = {timing_accuracy!r} s: must be finite and >= 0")
    if not data.channels or any(c.location != "area" for c in data.channels):
        bad = [c.name for c in data.channels if c.location != "area"]
        raise CalibrationError(
            f"impact test: every response channel must be at a soil area (channel map 'area:'); not: {bad}"
        )
    idx = [c.index for c in data.channels]
    reach = max(abs(i) for i in idx)
    n_min = max(3, 2 * reach + 1)
    auto = n_areas is None and model == "clm"
    if n_areas is None:
        n_areas = n_min
    if n_areas % 2 == 0 or n_areas < 2 * reach + 1:
        raise CalibrationError(
            f"n_areas = {n_areas}: must be odd and >= {2 * reach + 1} (the measured areas reach index {reach})"
        )
    used = list(range(len(idx))) if model == "clm" else [k for k, i in enumerate(idx) if i == 0]
    if not used:
        raise CalibrationError(f"model {model!r} is fitted to area 0 (the loaded area), which is not measured")
    fmin, fmax = data.band if data.band[1] > 0 else (float(data.frequency[0]), float(data.frequency[-1]))
    warns: list[str] = []
    free = _FREE[model]
    fe_params: tuple[ParameterEstimate, ...] = ()
    if initial is None:
        sums = fit_sums(data) if (model == "clm" and first == "weighted") else None
        if sums is not None:
            vals = _admissible(dict(sums.values), warns)
            method = sums.description
            fe_params = sums.parameters
            if sums.noise_ratio > 4.0:
                warns.append(
                    f"the impedance sums do not follow the Eq. (16)/(18) form down to the noise (residual power "
                    f"{sums.noise_ratio:.3g} x the noise): the first estimate's intervals are widened accordingly"
                )
        else:
            if model == "clm" and first == "weighted" and data.std is None:
                warns.append("no noise estimate: the first estimate uses the paper's unweighted route")
            vals, method, w0 = first_estimate(first_data or data, fmin, fmax, model)
            warns += w0
    else:
        missing = [k for k in free if k not in initial]
        if missing:
            raise CalibrationError(f"initial values: {missing} missing for the {model} model (needs {', '.join(free)})")
        vals = _admissible({k: float(initial[k]) for k in free}, warns)
        method = "given by the user"
    W, norm_used, w1 = norm_weights(data, used, norm)
    warns += w1
    Hd = data.H[:, used]
    D = (1.0 / Hd) if W is None else W.astype(complex)
    sandwich = make_sandwich(data, used, D)
    lines, chans = residual_layout(data.frequency.size, len(used))
    power = channel_noise_power(data, used, D) if W is not None else None
    p0 = np.array([vals[k] for k in free])

    def run(n: int, start: Array) -> _ChainFit:
        return _fit_chain(
            data, model, n, used, W, start, sandwich, norm_used, controls or FitControls(), interval, lines, chans,
            power,
        )

    fit = run(n_areas, p0)
    tried = [(fit.n_areas, fit.stats.rms)]
    if auto:
        step = 2 * max(5, (reach + 1) // 2)
        n_max = max_areas if max_areas is not None else min(201, n_min + 8 * step)
        while fit.n_areas + step <= n_max:
            longer = run(fit.n_areas + step, fit.p)
            tried.append((longer.n_areas, longer.stats.rms))
            if not longer.stats.rms < fit.stats.rms * (1.0 - grow_tol):
                break
            fit = longer
    warns += fit.warnings
    n_areas = fit.n_areas
    p = fit.p
    white = (
        residual_whiteness(data, used, D, fit.r)
        if (norm_used == "weighted" and model == "clm" and W is not None)
        else None
    )
    if white is not None and not _looks_white(fit.stats.rms, white):
        warns.append(_whiteness_warning(data, used, fit, white, auto, tried, run, grow_tol))
    checks = (
        model_checks(data, used, W, fit.n_areas, fit.p, fit.r, fit.J, fit.est, fe_params, sandwich=sandwich,
                     interval=interval, corr=corr_factor(data, norm_used), groups=chans, group_power=power)
        if (model == "clm" and W is not None)
        else (None, None, None)
    )
    applied = 0.0
    if delay == "fit" and checks[0] is not None:
        tau = float(checks[0].estimate[0])
        shifted = replace(data, H=data.H * np.exp(data.s * tau)[:, None])
        again = fit_impact(
            shifted, model, norm, n_areas, initial, first_data, controls=controls, interval=interval, first=first,
            delay="check",
        )
        refit = _ChainFit(again.n_areas, np.array([getattr(again.soil, k) for k in free]), again.parameters,
                          again.stats, list(again.warnings), fit.r, fit.J)
        est = widen(refit.est, checks[0].shift[:, 0], float(checks[0].std[0]) ** 2)
        fit = replace(refit, est=est)
        data, p, applied = shifted, fit.p, tau
        warns.append(
            f"delay fitted: the responses were advanced by {1e6 * tau:.3g} us (+- {1e6 * checks[0].std[0]:.2g} us) "
            "before the fit; the intervals include its uncertainty"
        )
        fe_params, method, p0 = again.first_estimate_parameters, again.first_estimate_method, np.array(
            [again.first_estimate[k] for k in free]
        )
        checks = (checks[0], again.coupling2, first_vs_refined(fe_params, fit.est))
    if timing_accuracy > 0 and checks[0] is not None:
        fit = replace(fit, est=widen(fit.est, checks[0].shift[:, 0], timing_accuracy**2 / 3.0))
    warns += adequacy_warnings(checks, applied, fit.est)
    soil = _soil(model, dict(zip(free, p)))
    X, _ = chain_response(soil, n_areas, data.s)
    c = n_areas // 2
    cols_all = [c + i for i in idx]
    Hm_all = X[:, cols_all]
    mis = misfit(Hm_all[:, used], Hd, W)
    k0 = [k for k, i in enumerate(idx) if i == 0]
    W0 = norm_weights(data, k0, norm_used)[0] if k0 else None
    mis0 = misfit(Hm_all[:, k0], data.H[:, k0], W0) if k0 else math.nan
    return SoilFit(
        model=model,
        soil=soil,
        parameters=fit.est,
        stats=fit.stats,
        norm=norm_used,
        band=(fmin, fmax),
        n_areas=n_areas,
        channels_used=tuple(data.channels[k].name for k in used),
        H_model=Hm_all,
        misfit=mis,
        misfit_loaded=mis0,
        first_estimate=dict(zip(free, p0.tolist())),
        first_estimate_method=method,
        warnings=tuple(warns),
        first_estimate_parameters=fe_params,
        chain_selection="auto" if auto else "fixed",
        chain_trials=tuple(tried),
        whiteness=white,
        delay=checks[0],
        coupling2=checks[1],
        first_vs_fit=checks[2],
        delay_applied=applied,
        timing_accuracy=timing_accuracy,
    )


def _fit_chain(
    data: TransferData,
    model: str,
    n_areas: int,
    used: list[int],
    W: Array | None,
    p0: Array,
    sandwich: Sandwich | None,
    norm_used: str,
    controls: FitControls,
    interval: str,
    lines: NDArray[np.int64],
    chans: NDArray[np.int64],
    power: Array | None,
) -> _ChainFit:
    """Refine the soil parameters on a chain of ``n_areas`` areas (bounded least squares, Sec. 4.2 constraints)."""
    free = _FREE[model]
    idx = [c.index for c in data.channels]
    c = n_areas // 2
    cols_model = [c + idx[k] for k in used]
    Hd = data.H[:, used]
    s = data.s
    pick = [CHAIN_PARAMS.index(k) for k in free]

    def residual(p: Array) -> tuple[Array, Array]:
        soil = _soil(model, dict(zip(free, p)))
        X, dX = chain_response(soil, n_areas, s, jacobian=True)
        assert dX is not None
        Hm = X[:, cols_model]
        dH = dX[pick][:, :, cols_model]
        if W is None:
            e = np.log(Hm / Hd)
            de = dH / Hm[None]
        else:
            e = (Hm - Hd) * W
            de = dH * W[None]
        r, J = stack_residual(e, de)
        assert J is not None
        return r, J

    p, est, stats, w2 = fit_constrained(
        residual,
        free,
        p0,
        corr_factor=corr_factor(data, norm_used),
        controls=controls,
        sandwich=sandwich,
        interval=interval,
        lines=lines,
        groups=chans,
        group_power=power,
    )
    r, J = residual(p)
    return _ChainFit(n_areas, p, est, stats, w2, r, J)


def _looks_white(rms: float, w: WhitenessCheck) -> bool:
    """Residuals pass as the noise: rms <= 1.2 and no lag-1 correlation of the whitened residuals (> 0.05, p < 1e-3)."""
    return bool(rms <= WHITE_RMS and w.white(WHITE_LAG1, WHITE_P))


def _whiteness_warning(
    data: TransferData,
    used: list[int],
    fit: _ChainFit,
    w: WhitenessCheck,
    auto: bool,
    tried: list[tuple[int, float]],
    run: Callable[[int, Array], _ChainFit],
    grow_tol: float,
) -> str:
    """The warning for residuals that are not the noise, with a chain-length suggestion when it helps."""
    names = [data.channels[k] for k in used]
    order = np.argsort(w.channel_rms)[::-1][:3]
    worst = ", ".join(f"area {names[k].index} ({w.channel_rms[k]:.2g})" for k in order)
    reach = max(abs(ch.index) for ch in names)
    at_end = any(abs(names[k].index) >= max(1, reach - 1) for k in order)
    msg = (
        f"the residuals are not the measurement noise: rms {fit.stats.rms:.3g} (whitened {w.rms:.3g}; expected about "
        f"1), lag-1 autocorrelation along frequency {w.lag1:.2f} (Ljung-Box p = {w.p_value:.2g}); largest at {worst}. "
    )
    if auto:
        trials = ", ".join(f"{n}: {r:.3g}" for n, r in tried)
        return msg + (
            f"Longer chains did not remove it (areas: rms {trials}): the record is not explained by a CLM chain "
            "(model error: a real soil, sensor dynamics) or the noise is not white (coloured noise, a noise level "
            "that changes after the hit); the 95 % intervals are widened by the excess (interval 'inflated')"
        )
    step = 2 * max(5, (reach + 1) // 2)
    longer = run(fit.n_areas + 2 * step, fit.p)
    if longer.stats.rms < fit.stats.rms * (1.0 - grow_tol):
        where = " (the misfit is largest at the outer areas)" if at_end else ""
        return msg + (
            f"The chain of {fit.n_areas} areas is too short{where}"
            f": a chain of {longer.n_areas} areas gives rms {longer.stats.rms:.3g}. Use a longer chain "
            "(options n_areas), or leave n_areas unset to choose it automatically"
        )
    return msg + (
        f"A longer chain ({longer.n_areas} areas: rms {longer.stats.rms:.3g}) does not help: model error or noise that "
        "is not white; the 95 % intervals are widened by the excess (interval 'inflated')"
    )
