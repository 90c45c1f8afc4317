"""Does the impact fit's model hold, and are its channels simultaneous? (issue 24).

The refined CLM fit (:mod:`clm_core.calibration.impact`) can be wrong in two
ways its residuals do not show, because the five parameters absorb most of
the error:

- **timing**: a skew tau between the force and the response channels
  (separate converters, a filter's group delay on one channel) multiplies
  every receptance by exp(-s tau); 10 us at 1 kHz moved m_f by -0.5 % with
  no warning;
- **model**: a soil outside the CLM family (here: with 1 % second-neighbour
  coupling) is fitted with k_c +2.2 % and 38 % coverage, residuals white.

Both are tested the same way, by the nearest *extension* of the model: the
fit is linearised at its optimum and extended by the extra parameters delta
(tau; or the second-neighbour stiffness and damping k_c2, d_c2, springs and
dampers between areas i and i +- 2 like the first-neighbour ones), whose
columns E = d r / d delta at delta = 0 are

- delay: d H / d tau = -s H (the model H exp(-s tau));
- coupling: d H / d k_c2 = -Z^-1 L_2 H, d H / d d_c2 = s d H / d k_c2, with
  Z = m_f s^2 + k_f + s d_f + (k_c + s d_c) L_1 the chain's impedance and
  L_1, L_2 the first- and second-neighbour Laplacians.

The linearised joint estimate [dp; delta] = -(A^T A)^-1 A^T r, A = [J E],
with its covariance from the same noise model as the intervals
(:func:`clm_core.calibration.lsq.covariance`), gives a Wald statistic
delta^T Cov^-1 delta ~ chi^2(dim delta) under the CLM (a Lagrange-multiplier
test of the extension, one linear step). Its shift of the five parameters,
d p / d delta = -(J^T J)^-1 J^T E, says how far a given extension (or a
stated timing accuracy) moves them.

The third test compares the paper's Eq. (16)/(18) first estimate with the
refined fit (:func:`first_vs_refined`): both estimate the same parameters
under the model; the refined fit is the efficient one, so the difference of
an estimator and the efficient one has variance var(first) - var(refined)
(Hausman, 1978). A soil outside the family moves them apart.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array, CArray
from clm_core.calibration.lsq import ParameterEstimate, Sandwich, covariance
from clm_core.calibration.spectra import TransferData

#: Warn about a delay when its test's p-value is below this [-] (3 sigma for one degree of freedom).
ADEQUACY_P = 2.7e-3
#: Warn about data outside the CLM when the second-neighbour test's p-value is below this [-].
COUPLING_P = 0.01
#: Warn when the first estimate and the refined fit differ by more than this many sigma on a parameter [-].
FIRST_VS_FIT_Z = 3.0


@dataclass(frozen=True)
class ExtensionTest:
    """Linearised test of one extension of the fitted model (module docstring).

    Attributes
    ----------
    name : str
        ``delay`` or ``coupling2``.
    names : tuple of str
        The extra parameters (``tau`` [s]; ``kc2`` [N/m], ``dc2`` [N s/m]).
    estimate : (n_e,) array
        Their linearised estimate [SI].
    std : (n_e,) array
        Its standard error [SI].
    statistic : float
        Wald statistic delta^T Cov^-1 delta [-] (chi^2 with ``dof`` degrees under the model).
    dof : int
    p_value : float
        P(chi^2_dof > statistic) [-].
    shift : (n_p, n_e) array
        d p / d delta, the move of the fitted parameters per unit of each extra parameter [SI].
    """

    name: str
    names: tuple[str, ...]
    estimate: Array
    std: Array
    statistic: float
    dof: int
    p_value: float
    shift: Array

    @property
    def sigma(self) -> float:
        """The statistic as a one-sided normal deviate (sigma) [-]."""
        from scipy.stats import norm

        return float(norm.isf(max(self.p_value, 1e-300)))

    def rejects(self, p: float = ADEQUACY_P) -> bool:
        """Whether the data show the extension (p-value below ``p``)."""
        return bool(self.p_value < p)


def extension_test(
    name: str,
    names: Sequence[str],
    J: Array,
    E: Array,
    r: Array,
    p: Array,
    *,
    sandwich: Sandwich | None,
    method: str,
    groups: NDArray[np.int64] | None = None,
    group_power: Array | None = None,
    corr_factor: float = 1.0,
    scale: Sequence[float] | None = None,
) -> ExtensionTest | None:
    """Wald test of the extension columns ``E`` (m, n_e) of a fit with Jacobian ``J`` and residuals ``r``.

    ``scale``: a typical size of each extra parameter (their value is 0 at
    the fit; the covariance is column-scaled by it). None when the joint
    Jacobian is singular.
    """
    from scipy.stats import chi2

    n_p, n_e = J.shape[1], E.shape[1]
    A = np.concatenate([J, E], axis=1)
    sc = np.asarray(scale if scale is not None else np.ones(n_e), dtype=float)
    pe = np.concatenate([p, sc])
    cov = covariance(
        A, r, pe, method, sandwich, corr_factor=corr_factor, groups=groups, group_power=group_power
    )[0]
    if cov is None:
        return None
    As = A * np.where(pe != 0, np.abs(pe), 1.0)[None, :]
    step = -np.linalg.lstsq(As, r, rcond=None)[0] * np.where(pe != 0, np.abs(pe), 1.0)
    d = step[n_p:]
    Ce = cov[n_p:, n_p:]
    try:
        W = float(d @ np.linalg.solve(Ce, d))
    except np.linalg.LinAlgError:
        return None
    Js = J * np.where(p != 0, np.abs(p), 1.0)[None, :]
    shift = -np.linalg.lstsq(Js, E, rcond=None)[0] * np.where(p != 0, np.abs(p), 1.0)[:, None]
    return ExtensionTest(
        name=name,
        names=tuple(names),
        estimate=d,
        std=np.sqrt(np.diag(Ce)),
        statistic=W,
        dof=n_e,
        p_value=float(chi2.sf(W, n_e)),
        shift=np.asarray(shift, dtype=np.float64),
    )


def coupling2_columns(mf: float, kf: float, df: float, kc: float, dc: float, n_areas: int, s: CArray,
                      cols: Sequence[int]) -> tuple[CArray, CArray]:
    """d H / d k_c2 and d H / d d_c2 at k_c2 = d_c2 = 0, (n_f, len(cols)) each [m/N per N/m, per N s/m].

    Dense solves of the chain impedance (module docstring), an independent
    route from :func:`clm_core.soil.chain.chain_response` (whose H it
    reproduces: tested).
    """
    n = n_areas
    L1 = np.diag(np.r_[1.0, 2.0 * np.ones(n - 2), 1.0]) - np.eye(n, k=1) - np.eye(n, k=-1)
    deg2 = np.full(n, 2.0)
    deg2[[0, 1, -2, -1]] = 1.0
    L2 = np.diag(deg2) - np.eye(n, k=2) - np.eye(n, k=-2)
    c = n // 2
    dk = np.zeros((s.size, len(cols)), dtype=complex)
    e = np.zeros(n)
    e[c] = 1.0
    for i, si in enumerate(s):
        Z = (mf * si * si + kf + df * si) * np.eye(n) + (kc + dc * si) * L1
        H = np.linalg.solve(Z, e)
        dH = -np.linalg.solve(Z, L2 @ H)
        dk[i] = dH[list(cols)]
    return dk, dk * s[:, None]


@dataclass(frozen=True)
class FirstVsFit:
    """The Eq. (16)/(18) first estimate against the refined fit (module docstring).

    Attributes
    ----------
    z : (n_p,) array
        (first - refined) / sqrt(var_first - var_refined) per parameter [-]
        (the denominator at least half the first estimate's standard error).
    statistic : float
        max |z| [-].
    chi2 : float
        sum z^2 [-] (about chi^2 with n_p degrees under the model, the
        parameters' correlations neglected).
    """

    z: Array
    statistic: float
    chi2: float

    def rejects(self, z_max: float = FIRST_VS_FIT_Z) -> bool:
        """Whether the two differ by more than ``z_max`` sigma on a parameter."""
        return bool(self.statistic > z_max)


def first_vs_refined(first: Sequence[ParameterEstimate], refined: Sequence[ParameterEstimate]) -> FirstVsFit | None:
    """Compare the first estimate (with its intervals) to the refined fit; None without intervals."""
    if not first or len(first) != len(refined):
        return None
    a = np.array([e.value for e in first])
    b = np.array([e.value for e in refined])
    sa = np.array([e.std for e in first])
    sb = np.array([e.std for e in refined])
    if not (np.all(np.isfinite(sa)) and np.all(np.isfinite(sb))):
        return None
    den = np.sqrt(np.maximum(sa**2 - sb**2, 0.25 * sa**2))
    z = (a - b) / den
    return FirstVsFit(z=z, statistic=float(np.max(np.abs(z))), chi2=float(np.sum(z**2)))


def delay_columns(Hm: CArray, W: Array, s: CArray) -> CArray:
    """d (W H exp(-s tau)) / d tau at tau = 0, (n_f, n_ch) [1/s x residual units]."""
    return np.asarray(-s[:, None] * Hm * W)


#: Delay handling of the impact fit (:func:`clm_core.calibration.impact.fit_impact`).
DELAY_MODES: tuple[str, ...] = ("check", "fit")
Checks = tuple[ExtensionTest | None, ExtensionTest | None, FirstVsFit | None]


def model_checks(
    data: TransferData,
    used: Sequence[int],
    W: Array,
    n_areas: int,
    p: Array,
    r: Array,
    J: Array,
    refined: Sequence[ParameterEstimate],
    first: Sequence[ParameterEstimate],
    *,
    sandwich: Sandwich | None,
    interval: str,
    corr: float,
    groups: NDArray[np.int64] | None,
    group_power: Array | None,
) -> Checks:
    """The delay, second-neighbour and first-vs-refined tests of a CLM fit (weighted-norm residuals r, J at p).

    ``p`` are (m_f, k_f, d_f, k_c, d_c); ``W`` the residual weights of the
    channels ``used``; the intervals' noise model (``sandwich``,
    ``interval``, ``groups``, ``group_power``) is the fit's.
    """
    from clm_core.calibration.residuals import stack_residual
    from clm_core.params import SoilParams
    from clm_core.soil.chain import chain_response

    idx = [data.channels[k].index for k in used]
    c = n_areas // 2
    cols = [c + i for i in idx]
    s = data.s
    soil = SoilParams(model="clm", mf=float(p[0]), kf=float(p[1]), df=float(p[2]), kc=float(p[3]), dc=float(p[4]))
    X, _ = chain_response(soil, n_areas, s)
    Hm = X[:, cols]
    kw = {"sandwich": sandwich, "method": interval, "groups": groups, "group_power": group_power, "corr_factor": corr}
    Ed = stack_residual(delay_columns(Hm, W, s))[0][:, None]
    dl = extension_test("delay", ("tau",), J, Ed, r, p, scale=(1e-5,), **kw)  # type: ignore[arg-type]
    dk, dd = coupling2_columns(float(p[0]), float(p[1]), float(p[2]), float(p[3]), float(p[4]), n_areas, s, cols)
    Ec = np.column_stack([stack_residual(dk * W)[0], stack_residual(dd * W)[0]])
    cp = extension_test("coupling2", ("kc2", "dc2"), J, Ec, r, p, scale=(0.01 * abs(p[3]), 0.01 * abs(p[4])),
                        **kw)  # type: ignore[arg-type]
    return dl, cp, first_vs_refined(first, refined)


def widen(est: Sequence[ParameterEstimate], shift: Array, var: float) -> tuple[ParameterEstimate, ...]:
    """Intervals widened by an extra variance ``shift_i^2 var`` on each parameter (same quantile)."""
    from dataclasses import replace

    out = []
    for e, g in zip(est, shift):
        if not (e.fitted and math.isfinite(e.std) and e.std > 0):
            out.append(e)
            continue
        std = math.sqrt(e.std**2 + float(g) ** 2 * var)
        q = 0.5 * (e.ci_high - e.ci_low) / e.std
        out.append(replace(e, std=std, ci_low=e.value - q * std, ci_high=e.value + q * std))
    return tuple(out)


def adequacy_warnings(checks: Checks, applied: float, est: Sequence[ParameterEstimate]) -> list[str]:
    """Warnings for a delay the data show and for data outside the CLM family, naming what to try."""
    dl, cp, fv = checks
    out: list[str] = []
    names = [e.name for e in est]
    if dl is not None and dl.rejects() and not applied:
        tau = float(dl.estimate[0])
        moves = ", ".join(
            f"{n} {100 * g * tau / e.value:+.2g} %" for n, g, e in zip(names, dl.shift[:, 0], est) if e.value
        )
        out.append(
            f"the data show a force-to-response delay of {1e6 * tau:+.3g} us (+- {1e6 * dl.std[0]:.2g} us, "
            f"{dl.sigma:.1f} sigma): the force and the response "
            f"channels are not simultaneous (separate converters, a filter or conditioner delaying one channel). "
            f"It moves the fit by {moves}. Fix the acquisition's timing, or fit it (options delay: fit), or state the "
            "timing accuracy (options timing_accuracy) so that the intervals cover it"
        )
    parts = []
    if cp is not None and cp.rejects(COUPLING_P):
        parts.append(
            f"second-neighbour coupling k_c2 = {cp.estimate[0]:.3g} +- {cp.std[0]:.2g} N/m, "
            f"d_c2 = {cp.estimate[1]:.3g} +- {cp.std[1]:.2g} N s/m "
            f"(chi^2 = {cp.statistic:.3g} with {cp.dof} degrees, p = {cp.p_value:.2g})"
        )
    if fv is not None and fv.rejects():
        k = int(np.argmax(np.abs(fv.z)))
        parts.append(
            f"the Eq. (16)/(18) first estimate and the refined fit differ by {fv.z[k]:+.2g} sigma on {names[k]}"
        )
    if parts:
        if dl is not None and dl.rejects() and not applied:
            parts.append("the delay warned above moves them apart too: fix or fit it (delay: fit) first")
        out.append(
            "the data are outside the CLM model: " + "; ".join(parts) + ". The 95 % intervals do not cover this model "
            "error. Try a narrower band (fmax) where the CLM holds, compare the norms (relative, log), check the "
            "sensors (mounting, cross-talk between neighbouring areas), or use a soil model with longer-range "
            "coupling (outside the CLM family: the fitted values are then an equivalent CLM, not the soil's)"
        )
    return out


def adequacy_summary(fit: Any) -> dict[str, Any]:
    """The checks of a :class:`~clm_core.calibration.impact.SoilFit` for ``summary.json`` (``fit.adequacy``)."""
    out: dict[str, Any] = {"delay_applied_s": fit.delay_applied, "timing_accuracy_s": fit.timing_accuracy}
    for key, t, level in (("delay", fit.delay, ADEQUACY_P), ("second_neighbour_coupling", fit.coupling2, COUPLING_P)):
        if t is not None:
            out[key] = {
                "parameters": list(t.names),
                "estimate": [float(x) for x in t.estimate],
                "std": [float(x) for x in t.std],
                "chi2": t.statistic,
                "dof": t.dof,
                "p_value": t.p_value,
                "sigma": t.sigma,
                "warned": t.rejects(level),
                "warn_below_p": level,
            }
    fv = fit.first_vs_fit
    if fv is not None:
        out["first_vs_refined"] = {
            "z": {e.name: float(z) for e, z in zip(fit.parameters, fv.z)},
            "max_abs_z": fv.statistic,
            "chi2": fv.chi2,
            "warned": fv.rejects(),
        }
    return out
