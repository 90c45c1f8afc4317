"""Soil impact test: CLM (or Lysmer, Winkler) parameters from measured area receptances.

A force on one soil contact area (index 0) and the vertical motion of the
areas around it (indices -n..n, or one side 0..n) give the receptances
H_j = X_j / F (:mod:`clm_core.calibration.spectra`). The fit follows the
paper's route (Kouroussis et al. 2011, Sec. 4.1) and then refines it:

1. First estimate: the total and alternating sums, Eq. (16) and (18),
   F / sum_j X_j = k_f - w^2 m_f + j w d_f and
   F / sum_j (-1)^j X_j = (k_f + 4 k_c) - w^2 m_f + j w (d_f + 4 d_c),
   with a quadratic fit of the real parts and a linear fit of the imaginary
   parts (:func:`clm_core.soil.fit.fit_clm_sums`). A one-sided record
   is completed by symmetry, Eq. (19)–(20).
2. Refinement: all five parameters by bounded nonlinear least squares on all
   measured receptances, model :func:`clm_core.soil.chain.chain_response`
   (the chain of :func:`clm_core.soil.chain.chain_matrices`, same number of
   areas) at the windowed complex frequency, over admissible sets only:
   m_f, k_f > 0, k_c >= 0, d_f >= 0 and d_f + 4 d_c >= 0 (damping matrix
   positive semi-definite, Sec. 4.2).

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
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.lsq import FitStats, ParameterEstimate, fit_bounded
from clm_core.calibration.residuals import make_sandwich, misfit, norm_weights, stack_residual
from clm_core.calibration.spectra import TransferData
from clm_core.errors import ParameterError
from clm_core.params import SoilParams
from clm_core.soil.chain import CHAIN_PARAMS, chain_response
from clm_core.soil.fit import fit_clm_sums, fit_lysmer

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

SOIL_FIT_MODELS: tuple[str, ...] = ("clm", "lysmer", "winkler")
SOIL_UNITS: Mapping[str, str] = {"mf": "kg", "kf": "N/m", "df": "N s/m", "kc": "N/m", "dc": "N s/m"}
_FREE: Mapping[str, tuple[str, ...]] = {
    "clm": ("mf", "kf", "df", "kc", "dc"),
    "lysmer": ("mf", "kf", "df"),
    "winkler": ("kf", "df"),
}


@dataclass(frozen=True)
class SoilFit:
    """Result of a soil fit to an impact test.

    Attributes
    ----------
    model : {'clm', 'lysmer', 'winkler'}
        Fitted foundation model.
    soil : SoilParams
        Fitted parameters (an admissible, stable set).
    parameters : tuple of ParameterEstimate
        Values, initial values, 95 % intervals, identifiability.
    stats : FitStats
        Residual and Jacobian statistics.
    norm : str
        Error norm used (see module docstring).
    band : tuple of float
        (fmin, fmax) [Hz] of the fitted lines.
    n_areas : int
        Areas in the model chain.
    channels_used : tuple of str
        Channels in the fit.
    H_model : (n_f, n_ch) complex array
        Fitted model receptances at the data's complex frequencies, every channel [m/N].
    misfit : float
        Relative misfit in the fit's norm, ||W (H_model - H)|| / ||W H||, over
        the channels used and the band [-] (:func:`~clm_core.calibration.residuals.misfit`).
    misfit_loaded : float
        The same for the loaded area alone (comparable across models) [-].
    first_estimate : mapping
        Starting values {name: value}.
    first_estimate_method : str
        How the starting values were found.
    warnings : tuple of str
        Identifiability, constraints, fallbacks.
    """

    model: str
    soil: SoilParams
    parameters: tuple[ParameterEstimate, ...]
    stats: FitStats
    norm: str
    band: tuple[float, float]
    n_areas: int
    channels_used: tuple[str, ...]
    H_model: CArray
    misfit: float
    misfit_loaded: float
    first_estimate: Mapping[str, float]
    first_estimate_method: str
    warnings: tuple[str, ...]


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
    idx = {c.index: k for k, c in enumerate(data.channels) if c.location == "area"}
    if 0 not in idx:
        return None

    def reach(sign: int) -> int:
        j = 0
        while sign * (j + 1) in idx:
            j += 1
        return j

    n_pos, n_neg = reach(1), reach(-1)
    n = max(n_pos, n_neg)
    if n == 0:
        return None
    H = data.H
    tot = H[:, idx[0]].copy()
    alt = H[:, idx[0]].copy()
    for j in range(1, n + 1):
        a = H[:, idx[j]] if j <= n_pos else None
        b = H[:, idx[-j]] if j <= n_neg else None
        pair = (a + b) if (a is not None and b is not None) else 2.0 * (a if a is not None else b)  # type: ignore[operator]
        tot += pair
        alt += (-1) ** j * pair
    how = (
        f"areas -{n_neg}..{n_pos}" + (" (completed by symmetry, Eq. 19-20)" if n_pos != n_neg else "")
    )
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


def fit_impact(
    data: TransferData,
    model: str = "clm",
    norm: str = "weighted",
    n_areas: int | None = None,
    initial: Mapping[str, float] | None = None,
    first_data: TransferData | None = None,
    *,
    max_nfev: int = 200,
    ident_rel: float = 0.25,
    cond_max: float = 1e6,
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
        Areas of the model chain (odd); default 2 max|index| + 1, at least 3.
    initial : mapping, optional
        Starting values; default: :func:`first_estimate`.
    first_data : TransferData, optional
        Receptances without exponential window for the first estimate
        (default ``data``; with a window the sums are slightly biased).
    max_nfev, ident_rel, cond_max
        See :func:`clm_core.calibration.lsq.fit_bounded`.

    Returns
    -------
    SoilFit

    Raises
    ------
    CalibrationError
        Unknown model or norm, channels not at areas, no area 0 for
        Lysmer/Winkler, bad ``n_areas`` or initial values.
    """
    if model not in SOIL_FIT_MODELS:
        raise CalibrationError(f"model = {model!r}: must be one of {', '.join(SOIL_FIT_MODELS)}")
    if not data.channels or any(c.location != "area" for c in data.channels):
        bad = [c.name for c in data.channels if c.location != "area"]
        raise CalibrationError(
            f"impact test: every response channel must be at a soil area (channel map 'area:'); not: {bad}"
        )
    idx = [c.index for c in data.channels]
    reach = max(abs(i) for i in idx)
    if n_areas is None:
        n_areas = max(3, 2 * reach + 1)
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
    if initial is None:
        vals, method, w0 = first_estimate(first_data or data, fmin, fmax, model)
        warns += w0
    else:
        missing = [k for k in free if k not in initial]
        if missing:
            raise CalibrationError(f"initial values: {missing} missing for the {model} model (needs {', '.join(free)})")
        vals = _admissible({k: float(initial[k]) for k in free}, warns)
        method = "given by the user"
    c = n_areas // 2
    cols_model = [c + idx[k] for k in used]
    W, norm_used, w1 = norm_weights(data, used, norm)
    warns += w1
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

    D = (1.0 / Hd) if W is None else W.astype(complex)
    sandwich = make_sandwich(data, used, D)

    n = len(free)
    A = np.eye(n)
    lo = np.zeros(n)
    hi = np.full(n, np.inf)
    p0 = np.array([vals[k] for k in free])
    for i, k in enumerate(free):
        if k in ("mf", "kf"):
            lo[i] = 1e-6 * abs(p0[i])
    if model == "clm":
        # z = (mf, kf, df, kc, e = df + 4 dc) -> dc = (e - df) / 4
        A[4, :] = [0, 0, -0.25, 0, 0.25]
    p, est, stats, w2 = fit_bounded(
        residual,
        free,
        [SOIL_UNITS[k] for k in free],
        p0,
        A,
        lo,
        hi,
        corr_factor=data.corr_factor if norm_used == "weighted" else 1.0,
        max_nfev=max_nfev,
        ident_rel=ident_rel,
        cond_max=cond_max,
        sandwich=sandwich,
    )
    warns += w2
    soil = _soil(model, dict(zip(free, p)))
    X, _ = chain_response(soil, n_areas, s)
    cols_all = [c + i for i in idx]
    Hm_all = X[:, cols_all]
    mis = misfit(Hm_all[:, used], Hd, W)
    k0 = [k for k, i in enumerate(idx) if i == 0]
    W0 = norm_weights(data, k0, norm_used)[0] if k0 else None
    mis0 = misfit(Hm_all[:, k0], data.H[:, k0], W0) if k0 else math.nan
    return SoilFit(
        model=model,
        soil=soil,
        parameters=est,
        stats=stats,
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
    )
