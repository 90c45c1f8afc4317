"""Bounded nonlinear least squares with confidence intervals and identifiability checks.

The fitted physical parameters p are a linear image p = A z of internal
variables z that carry simple bounds (e.g. z = d_f + 4 d_c >= 0 for the
stability of the CLM chain, Kouroussis et al. 2011, Sec. 4.2), so every
iterate is an admissible set. :func:`scipy.optimize.least_squares` (trust
region reflective) minimises 1/2 sum r_i^2 over the scaled z / |z_0|.

Uncertainty (linearised at the optimum, Gauss–Newton):

    cov(p) = c (J^T J)^-1 J^T Sigma J (J^T J)^-1

with J = dr/dp at the optimum and Sigma the covariance of the residuals
that the measurement noise causes (the "sandwich" form: windowing
correlates neighbouring frequency lines, so Sigma is not diagonal), given by
the caller from its noise model; c = max(1, sum r_i^2 / E[sum r_i^2]) widens
the interval when the residuals exceed the noise (model error, or noise
underestimated). Without a noise model, the classical

    cov(p) = kappa s^2 (J^T J)^-1,   s^2 = sum r_i^2 / (m - n_p)

is used, kappa >= 1 accounting for the correlation of neighbouring lines
(:attr:`clm_core.calibration.spectra.TransferData.corr_factor`). The 95 %
interval is p +- t_{0.975, m - n_p} sqrt(cov_ii). It covers noise (and, by c,
a misfit larger than the noise), not a biased model; a parameter on a bound
has no two-sided interval.

Interval methods (``interval``; compared by measurement on independent
records, docs/calibration.md "How honest are the intervals"):

- ``noise``: the sandwich above with one global factor c;
- ``inflated`` (the impact fit's default): the same sandwich with the noise
  covariance of every residual group g (a channel) scaled by
  c_g = max(1, sum_{i in g} r_i^2 / E[sum_{i in g} r_i^2] x m / (m - n_p)),
  i.e. an inflated residual model, cov = (J^T J)^-1 (D J)^T Sigma (D J) (J^T J)^-1,
  D = diag(sqrt(c_g)): a misfit confined to some channels (the chain ends,
  a noisier sensor) widens the interval by what those channels contribute;
- ``hac``: heteroskedasticity and autocorrelation consistent (Newey–West)
  meat from the residuals themselves, S = sum_{|l| <= L} (1 - |l| / (L + 1))
  sum_k g_k g_{k+l}^T over the parameter scores g_k = sum_{i at line k} J_i r_i
  of each frequency line (all channels together), L = ``hac_lags``. It needs
  no noise model, but measured on impact records it covers 50-80 % instead
  of 95 %: the force noise, common to every channel and confined to a few
  milliseconds, is correlated over the whole band, which no lag window
  shorter than the band captures.

Identifiability: a parameter whose 95 % half-width exceeds ``ident_rel`` of
its value, or that dominates a singular direction of the column-scaled
Jacobian whose singular value is below ``1 / cond_max`` of the largest, is
reported as not identifiable from the data.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.calibration.errors import CalibrationError
from clm_core.errors import ParameterError
from clm_core.params import PARAMETER_DOCS

Residual = Callable[[Array], tuple[Array, Array | None]]
#: J -> (J^T Sigma J, trace Sigma): the residual covariance of the noise, applied to a Jacobian.
Sandwich = Callable[[Array], tuple[Array, float]]
#: Called with no argument after every residual evaluation (it may raise to stop the fit).
Tick = Callable[[], None]


@dataclass(frozen=True)
class ParameterEstimate:
    """One fitted (or fixed) parameter.

    Attributes
    ----------
    name : str
        Parameter name (``kf``, ``kb``, ...).
    unit : str
        SI unit.
    value : float
        Fitted value.
    initial : float
        Starting value (first estimate).
    std : float
        Standard error (NaN if fixed or not computable).
    ci_low, ci_high : float
        95 % confidence interval.
    fitted : bool
        False for a parameter held fixed.
    at_bound : bool
        The optimum lies on a constraint (positivity, stability).
    identifiable : bool
        False when the data do not determine the parameter (see module doc).
    """

    name: str
    unit: str
    value: float
    initial: float
    std: float = math.nan
    ci_low: float = math.nan
    ci_high: float = math.nan
    fitted: bool = True
    at_bound: bool = False
    identifiable: bool = True

    @property
    def rel_halfwidth(self) -> float:
        """Half-width of the 95 % interval over |value| [-]."""
        if self.value == 0 or not math.isfinite(self.ci_high):
            return math.nan
        return 0.5 * (self.ci_high - self.ci_low) / abs(self.value)

    def contains(self, x: float) -> bool:
        """Whether ``x`` lies in the 95 % interval."""
        return bool(self.ci_low <= x <= self.ci_high)


@dataclass(frozen=True)
class FitStats:
    """Quality of a least-squares fit.

    Attributes
    ----------
    n_residuals : int
        Number of real residuals m.
    n_params : int
        Number of fitted parameters.
    cost : float
        1/2 sum r_i^2 at the optimum.
    rms : float
        sqrt(sum r_i^2 / m): in the ``weighted`` norm about 1 when the model
        explains the data down to the noise.
    residual_variance : float
        s^2 = sum r_i^2 / (m - n_p).
    corr_factor : float
        kappa, the covariance inflation for correlated residuals (classical form).
    noise_ratio : float
        sum r_i^2 / E[sum r_i^2] under the noise model (about 1 when the
        model explains the data down to the noise; NaN without a noise model).
    covariance : str
        ``sandwich`` (noise model) or ``classical``.
    interval : str
        Interval method used (module docstring): ``noise``, ``inflated``,
        ``hac`` or ``classical``.
    inflation : tuple of float
        c_g of each residual group (``inflated``), else ().
    condition : float
        Condition number of the column-scaled Jacobian (columns x |p|).
    singular_values : tuple of float
        Its singular values, largest first.
    nfev : int
        Residual evaluations.
    status : str
        Optimiser message.
    """

    n_residuals: int
    n_params: int
    cost: float
    rms: float
    residual_variance: float
    corr_factor: float
    noise_ratio: float
    covariance: str
    condition: float
    singular_values: tuple[float, ...]
    nfev: int
    status: str
    interval: str = "noise"
    inflation: tuple[float, ...] = ()


@dataclass(frozen=True)
class FitResult:
    """What every calibration fit gives: the estimates, their statistics and the fit's settings.

    The base of :class:`~clm_core.calibration.impact.SoilFit` (impact test)
    and :class:`~clm_core.calibration.receptance.TrackFit` (receptance and
    pass-by tests), which add the fitted set and the model's response.

    Attributes
    ----------
    parameters : tuple of ParameterEstimate
        Fitted values [SI], initial values, 95 % intervals, identifiability.
    stats : FitStats
        Residual and Jacobian statistics.
    norm : str
        Error norm used (``weighted``, ``relative``, ..., see
        :mod:`clm_core.calibration.residuals`).
    band : tuple of float
        (fmin, fmax) [Hz] of the fitted lines; (0, fs/2) for a pass-by fit
        (time domain).
    channels_used : tuple of str
        Channels in the fit.
    misfit : float
        Relative misfit in the fit's norm, ||W (model - data)|| / ||W data||,
        over the channels used and the band [-] (pass-by: W = 1 / noise of
        each channel).
    first_estimate : mapping
        Starting values {name: value} [SI].
    first_estimate_method : str
        How the starting values were found.
    warnings : tuple of str
        Identifiability, constraints, fallbacks, residuals that are not noise.
    """

    parameters: tuple[ParameterEstimate, ...]
    stats: FitStats
    norm: str
    band: tuple[float, float]
    channels_used: tuple[str, ...]
    misfit: float
    first_estimate: Mapping[str, float]
    first_estimate_method: str
    warnings: tuple[str, ...]


INTERVALS: tuple[str, ...] = ("noise", "inflated", "hac")


def covariance(
    J: Array,
    r: Array,
    p: Array,
    method: str = "noise",
    sandwich: Sandwich | None = None,
    *,
    corr_factor: float = 1.0,
    lines: NDArray[np.int64] | None = None,
    groups: NDArray[np.int64] | None = None,
    group_power: Array | None = None,
    hac_lags: int = 3,
) -> tuple[Array | None, float, tuple[float, ...], str]:
    """Covariance of the parameters of a least-squares fit at its optimum (module docstring).

    Parameters
    ----------
    J : (m, n_p) array
        Jacobian dr/dp at the optimum.
    r : (m,) array
        Residuals at the optimum.
    p : (n_p,) array
        Parameters (for the column scaling; the result is in physical units).
    method : {'noise', 'inflated', 'hac'}
        Interval method; ``noise`` and ``inflated`` need ``sandwich`` (else
        the classical kappa s^2 (J^T J)^-1 is used), ``inflated`` also
        ``groups`` and ``group_power``, ``hac`` needs ``lines``.
    sandwich : callable, optional
        J -> (J^T Sigma J, trace Sigma) from the noise model.
    corr_factor : float
        kappa of the classical form.
    lines : (m,) int array, optional
        Position of each residual along the correlation axis (frequency line).
    groups : (m,) int array, optional
        Inflation group of each residual (e.g. channel), values 0..G-1.
    group_power : (G,) array, optional
        E[sum r_i^2] of each group under the noise model.
    hac_lags : int
        L of the Bartlett window (``hac``).

    Returns
    -------
    cov : (n_p, n_p) array or None
        Covariance [units of p squared]; None for a singular Jacobian.
    noise_ratio : float
        sum r^2 / E[sum r^2] (NaN without a noise model).
    inflation : tuple of float
        c_g per group (``inflated``), else ().
    used : str
        The method actually used (``classical`` without a noise model).
    """
    m, n = J.shape
    dof = max(m - n, 1)
    pscale = np.where(p != 0, np.abs(p), 1.0)
    Js = J * pscale[None, :]
    U, sv, Vt = np.linalg.svd(Js, full_matrices=False)
    if not sv[-1] > sv[0] * 1e-14:
        return None, math.nan, (), method
    inv = (Vt.T / sv[None, :] ** 2) @ Vt  # (Js^T Js)^-1
    rr = float(r @ r)
    if method not in INTERVALS:
        raise CalibrationError(f"interval = {method!r}: must be one of {', '.join(INTERVALS)}")
    if method == "hac":
        if lines is None:
            raise CalibrationError("interval 'hac' needs the frequency line of every residual")
        n_l = int(lines.max()) + 1
        G = np.stack(
            [np.bincount(lines, weights=Js[:, k] * r, minlength=n_l) for k in range(n)], axis=1
        ).astype(np.float64)
        S: Array = G.T @ G
        for lag in range(1, hac_lags + 1):
            Gl = G[lag:].T @ G[:-lag]
            S += (1.0 - lag / (hac_lags + 1)) * (Gl + Gl.T)
        cov_s = n_l / max(n_l - n, 1) * inv @ S @ inv
        ratio = math.nan
        if sandwich is not None:
            ratio = rr / sandwich(J)[1]
        return cov_s * np.outer(pscale, pscale), ratio, (), "hac"
    if sandwich is None:
        s2 = rr / dof
        return max(1.0, float(corr_factor)) * s2 * inv * np.outer(pscale, pscale), math.nan, (), "classical"
    B, trace = sandwich(J)
    noise_ratio = rr / trace if trace > 0 else math.inf
    infl: tuple[float, ...] = ()
    if method == "inflated" and groups is not None and group_power is not None:
        num = np.bincount(groups, weights=r * r, minlength=group_power.size)
        cg = np.maximum(1.0, num / np.maximum(group_power, 1e-300) * m / dof)
        D = np.sqrt(cg[groups])
        B = sandwich(J * D[:, None])[0]
        infl = tuple(float(x) for x in cg)
        c = 1.0
    else:
        method = "noise"
        c = max(1.0, noise_ratio * m / dof)
    Bs = B * np.outer(pscale, pscale)
    cov_s = c * inv @ Bs @ inv
    return cov_s * np.outer(pscale, pscale), noise_ratio, infl, method


@dataclass(frozen=True)
class FitControls:
    """Budget of the optimiser, identifiability rules and progress hook of a bounded fit (module docstring).

    The defaults are the impact fit's; the receptance and pass-by fits take 100
    and 60 evaluations (:meth:`clm_core.calibration.options.CalibrationOptions.controls`
    gives the user's values with the method's budget).

    Attributes
    ----------
    max_nfev : int
        Evaluation budget of the optimiser.
    ident_rel : float
        Largest 95 % half-width, relative to the value, of an identifiable parameter.
    cond_max : float
        Largest condition number of the scaled Jacobian before the weakest
        direction is reported.
    progress : callable or None
        Called with no argument after every evaluation of the residual
        (finite differences included); an exception it raises stops the fit
        and propagates (how a calibration is canceled).

    Raises
    ------
    CalibrationError
        max_nfev < 1, ident_rel <= 0 or cond_max <= 1.
    """

    max_nfev: int = 200
    ident_rel: float = 0.25
    cond_max: float = 1e6
    progress: Tick | None = None

    def __post_init__(self) -> None:
        if not 0 < self.ident_rel:
            raise CalibrationError(f"ident_rel = {self.ident_rel}: must be > 0")
        if not self.cond_max > 1:
            raise CalibrationError(f"cond_max = {self.cond_max}: must be > 1")
        if self.max_nfev < 1:
            raise CalibrationError(f"max_nfev = {self.max_nfev}: must be >= 1")


def fit_bounded(
    residual: Residual,
    names: Sequence[str],
    units: Sequence[str],
    p0: Array,
    A: Array,
    z_lower: Array,
    z_upper: Array,
    *,
    corr_factor: float = 1.0,
    controls: FitControls | None = None,
    fd_step: float = 1e-6,
    jacobian: bool = True,
    sandwich: Sandwich | None = None,
    interval: str = "noise",
    lines: NDArray[np.int64] | None = None,
    groups: NDArray[np.int64] | None = None,
    group_power: Array | None = None,
) -> tuple[Array, tuple[ParameterEstimate, ...], FitStats, list[str]]:
    """Minimise sum r(p)^2 over p = A z with l <= z <= u; intervals and identifiability.

    Parameters
    ----------
    residual : callable p -> (r, J)
        Residual vector (m,) and its Jacobian dr/dp (m, n_p), or None for
        a finite-difference Jacobian.
    names, units : sequence of str
        Parameter names and SI units (n_p).
    p0 : (n_p,) array
        Starting point (must satisfy the bounds after mapping to z).
    A : (n_p, n_p) array
        Invertible map z -> p.
    z_lower, z_upper : (n_p,) arrays
        Bounds of z.
    corr_factor : float
        kappa (>= 1) for correlated residuals.
    controls : FitControls, optional
        Budget and identifiability rules (default: :class:`FitControls` defaults).
    fd_step : float
        Relative step of finite differences.
    jacobian : bool
        Whether ``residual`` returns the Jacobian (else finite differences).
    sandwich : callable, optional
        J -> (J^T Sigma J, trace Sigma) from the noise model; selects the
        sandwich covariance (module docstring).
    interval : {'noise', 'inflated', 'hac'}
        Interval method (module docstring, :func:`covariance`).
    lines, groups, group_power : arrays, optional
        Frequency line and inflation group of every residual, expected
        residual power of every group (:func:`covariance`).

    Returns
    -------
    p : (n_p,) array
        Optimum.
    estimates : tuple of ParameterEstimate
    stats : FitStats
    warnings : list of str

    Raises
    ------
    CalibrationError
        A starting point outside the bounds or non-finite residuals there.
    """
    from scipy.optimize import least_squares  # lazy: importing this module (options, the CLI parser) stays light
    from scipy.stats import t as student_t

    ctl = controls or FitControls()
    if ctl.progress is not None:
        residual = _reporting(residual, ctl.progress)
    p0 = np.asarray(p0, dtype=float)
    n = p0.size
    Ainv = np.linalg.inv(A)
    z0 = Ainv @ p0
    lo, hi = np.asarray(z_lower, dtype=float), np.asarray(z_upper, dtype=float)
    scale = np.where(np.abs(z0) > 0, np.abs(z0), np.maximum(np.abs(A).sum(axis=0), 1.0))
    # start strictly inside: least_squares needs lb < x0 < ub
    span = np.where(np.isfinite(hi - lo), hi - lo, np.abs(z0) + 1.0)
    z0 = np.clip(z0, lo + 1e-6 * span, hi - 1e-6 * span)
    z0 = np.where((z0 <= lo) | (z0 >= hi), lo + 1e-3 * np.maximum(scale, 1e-30), z0)
    r0, _ = residual(A @ z0)
    if not np.all(np.isfinite(r0)):
        raise CalibrationError(f"the first estimate {dict(zip(names, (A @ z0).tolist()))} gives non-finite residuals")
    cache: dict[str, Array | None] = {}

    def fun(x: Array) -> Array:
        r, J = residual(A @ (x * scale))
        cache["x"] = x.copy()
        cache["J"] = J
        return r

    def jac(x: Array) -> Array:
        xc = cache.get("x")
        if xc is None or not np.array_equal(xc, x) or cache.get("J") is None:
            r, J = residual(A @ (x * scale))
            cache["x"], cache["J"] = x.copy(), J
        J = cache["J"]
        assert J is not None
        return J @ A * scale[None, :]

    sol = least_squares(
        fun,
        z0 / scale,
        jac=jac if jacobian else "2-point",
        bounds=(lo / scale, hi / scale),
        x_scale="jac",
        max_nfev=ctl.max_nfev,
        method="trf",
    )
    z = sol.x * scale
    p = A @ z
    r, J = residual(p)
    if J is None:
        J = _fd_jacobian(residual, p, r, fd_step)
    m = r.size
    dof = max(m - n, 1)
    s2 = float(r @ r) / dof
    pscale = np.where(p != 0, np.abs(p), 1.0)
    Js = J * pscale[None, :]
    U, sv, Vt = np.linalg.svd(Js, full_matrices=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    kappa = max(1.0, float(corr_factor))
    cov_p, noise_ratio, infl, used = covariance(
        J, r, p, interval, sandwich, corr_factor=kappa, lines=lines, groups=groups, group_power=group_power
    )
    cov_s = None if cov_p is None else cov_p / np.outer(pscale, pscale)
    tq = float(student_t.ppf(0.975, dof))
    at_bound_z = (np.abs(z - lo) <= 1e-6 * np.maximum(np.abs(z), scale)) | (
        np.abs(z - hi) <= 1e-6 * np.maximum(np.abs(z), scale)
    )
    # a parameter is at a bound if it depends on a z at a bound
    at_bound_p = (np.abs(A) > 0) @ at_bound_z.astype(float) > 0
    warnings: list[str] = []
    weak = set()
    if cond > ctl.cond_max and cov_s is not None:
        v = Vt[-1]
        dom = [names[i] for i in np.argsort(-np.abs(v)) if abs(v[i]) > 0.3]
        weak.update(dom)
        warnings.append(
            "the data constrain only a combination of "
            + ", ".join(dom)
            + f" (Jacobian condition number {cond:.3g}, rule <= {ctl.cond_max:.3g}): these parameters are not "
            "identifiable separately; fix some of them or measure more channels/a wider band"
        )
    if cov_s is None:
        warnings.append(
            "the Jacobian is singular at the optimum: at least one parameter has no influence on the fitted data"
        )
    est = []
    for i in range(n):
        if cov_s is not None:
            std = math.sqrt(max(cov_s[i, i], 0.0)) * pscale[i]
        else:
            std = math.inf
        lo_ci, hi_ci = p[i] - tq * std, p[i] + tq * std
        rel = tq * std / abs(p[i]) if p[i] != 0 else math.inf
        ident = bool(rel <= ctl.ident_rel) and names[i] not in weak
        if not rel <= ctl.ident_rel:
            warnings.append(
                f"{names[i]} is not identifiable from these data: 95 % interval {p[i]:.4g} +- {tq * std:.3g} {units[i]}"
                f" (+-{100 * rel:.0f} % of the value; rule: within +-{100 * ctl.ident_rel:.0f} %)"
            )
        est.append(
            ParameterEstimate(
                name=names[i],
                unit=units[i],
                value=float(p[i]),
                initial=float(p0[i]),
                std=float(std),
                ci_low=float(lo_ci),
                ci_high=float(hi_ci),
                fitted=True,
                at_bound=bool(at_bound_p[i]),
                identifiable=ident,
            )
        )
        if at_bound_p[i]:
            warnings.append(
                f"{names[i]} = {p[i]:.4g} {units[i]} lies on a constraint (positivity or the stability rule "
                "d_f + 4 d_c >= 0): the interval is one-sided in truth, and the data may favour an inadmissible set"
            )
    stats = FitStats(
        n_residuals=m,
        n_params=n,
        cost=0.5 * float(r @ r),
        rms=math.sqrt(float(r @ r) / m),
        residual_variance=s2,
        corr_factor=kappa,
        noise_ratio=noise_ratio,
        covariance="sandwich" if sandwich is not None else "classical",
        condition=cond,
        singular_values=tuple(float(x) for x in sv),
        nfev=int(sol.nfev),
        status=str(sol.message),
        interval=used,
        inflation=infl,
    )
    return p, tuple(est), stats, warnings


def _reporting(residual: Residual, progress: Tick) -> Residual:
    """``residual`` that calls ``progress()`` after each evaluation."""

    def evaluate(p: Array) -> tuple[Array, Array | None]:
        out = residual(p)
        progress()
        return out

    return evaluate


def _fd_jacobian(residual: Residual, p: Array, r: Array, step: float) -> Array:
    """Central-difference Jacobian dr/dp (relative steps)."""
    J = np.empty((r.size, p.size))
    for i in range(p.size):
        h = step * max(abs(p[i]), 1e-12)
        pp, pm = p.copy(), p.copy()
        pp[i] += h
        pm[i] -= h
        try:
            J[:, i] = (residual(pp)[0] - residual(pm)[0]) / (2 * h)
        except ParameterError:  # a step crosses a constraint: one-sided difference inward
            try:
                J[:, i] = (residual(pp)[0] - r) / h
            except ParameterError:
                J[:, i] = (r - residual(pm)[0]) / h
    return J


#: Parameters that stay strictly positive (stiffnesses, masses): z >= 1e-6 |p0|.
_POSITIVE = frozenset({"kp", "ms", "kb", "mf", "kf"})


def transform(names: Sequence[str], p0: Array) -> tuple[Array, Array, Array]:
    """Map p = A z and bounds of z for the admissibility constraints.

    Stiffnesses and masses (``kp ms kb mf kf``) stay > 0 (z >= 1e-6 |p0|),
    dampings >= 0, and with both ``df`` and ``dc`` free, z_dc = d_f + 4 d_c >= 0
    (damping matrix of the CLM chain positive semi-definite, Sec. 4.2).

    Parameters
    ----------
    names : sequence of str
        Free parameter names (n_p).
    p0 : (n_p,) array
        Starting values (SI units).

    Returns
    -------
    A : (n_p, n_p) array
        Invertible map z -> p.
    z_lower, z_upper : (n_p,) arrays
        Bounds of z.
    """
    n = len(names)
    A = np.eye(n)
    lo = np.zeros(n)
    hi = np.full(n, np.inf)
    for i, k in enumerate(names):
        if k in _POSITIVE:
            lo[i] = 1e-6 * abs(p0[i])
    if "dc" in names and "df" in names:
        i_dc, i_df = names.index("dc"), names.index("df")
        A[i_dc, :] = 0.0
        A[i_dc, i_df] = -0.25
        A[i_dc, i_dc] = 0.25  # z_dc = d_f + 4 d_c >= 0
    return A, lo, hi


def fit_constrained(
    residual: Residual,
    names: Sequence[str],
    p0: Array,
    **options: Any,
) -> tuple[Array, tuple[ParameterEstimate, ...], FitStats, list[str]]:
    """:func:`fit_bounded` under the admissibility constraints of :func:`transform`.

    Parameters
    ----------
    residual, names, p0
        As in :func:`fit_bounded` (model parameter names; their units are
        those of :data:`clm_core.params.PARAMETER_DOCS`).
    **options
        Keywords of :func:`fit_bounded` (``corr_factor``, ``controls``,
        ``jacobian``, ``sandwich``, ...).

    Returns
    -------
    As :func:`fit_bounded`.
    """
    A, lo, hi = transform(names, p0)
    return fit_bounded(residual, names, [PARAMETER_DOCS[k][1] for k in names], p0, A, lo, hi, **options)
