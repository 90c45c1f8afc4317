"""Fit of CLM (and Lysmer) soil parameters to impedance sums (Kouroussis et al. 2011, Sec. 4.1).

For a chain of 2n + 1 coupled lumped masses (the CLM model, Eq. 7-8) with a
force F on the centre area (index 0), summing the equations of motion gives
(time convention exp(+i w t), Eq. 15-18)

    S(w) = F / sum_j X_j         = k_f - w^2 m_f + i w d_f                      (16)
    A(w) = F / sum_j (-1)^j X_j  = (k_f + 4 k_c) - w^2 m_f + i w (d_f + 4 d_c)  (18)

(16) is exact for a chain with free ends of any length; (18) is exact for an
infinite chain and converges quickly with n. Both are linear in
p = (m_f, k_f, d_f, k_c, d_c), with the constant Jacobian of
:func:`clm_core.soil.formulas.sum_impedance_jacobian`; given rigorous or
measured S and A (e.g. from :mod:`clm_core.halfspace.calibrate`), every fit
below is an exact weighted linear least-squares problem in a stated
frequency band and norm, with that Jacobian as design matrix.

Routes
------
- ``"joint"`` (default): all five parameters at once from both sums,
  minimising sum_i wS_i^2 |S_fit - S|^2 + wA_i^2 |A_fit - A|^2. The CLM is
  defined by both sums: they share m_f, k_f and d_f (A adds 4 k_c and
  4 d_c), so the curvature of both real parts determines m_f.
- ``"total-first"`` (the paper's reading): m_f, k_f, d_f from S alone, then
  k_c, d_c from A with those fixed. m_f then rests on the curvature of Re S
  only, which for a half-space is often upward (negative m_f).

Norms (per frequency w_i in [fmin, fmax]):

- ``"ls"``: absolute least squares, weights 1: sum |Z_fit - Z|^2;
- ``"relative"``: weights 1/|Z|: sum |Z_fit - Z|^2 / |Z|^2 (each frequency counts
  alike, the low-frequency range is not swamped by the large high-frequency
  impedances).

Physical constraints
--------------------
- ``mass="nonnegative"`` (default): if the unconstrained m_f < 0 the fit is
  redone with m_f = 0 (the exact constrained optimum: the problem is a
  convex quadratic with one bound) and ``"mf=0"`` is recorded in
  ``constrained``; the unconstrained value is kept in ``mf_unconstrained``.
  ``mass="free"`` keeps the unconstrained value, and a negative m_f is then
  refused by the admissibility check (it cannot be clipped).
- The chain damping and stiffness matrices must be positive definite
  (:func:`clm_core.checks.clm_chain_admissible`: d_f > 0 and d_f + 4 d_c > 0
  for every chain length, the same for k_f, k_c). ``on_unstable="raise"``
  (default) raises :class:`clm_core.errors.StabilityError`; ``"clip"`` moves
  d_c (k_c) to the boundary with a 5 % margin, d_c = -0.95 d_f / 4, and
  records it in ``constrained``. d_f <= 0, k_f <= 0 or m_f < 0 cannot be
  clipped and always raise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from clm_core.arrays import Array, CArray
from clm_core.checks import chain_min_eigenvalue, clm_chain_admissible, finite, odd_count
from clm_core.errors import ParameterError, StabilityError
from clm_core.soil.chain import CHAIN_PARAMS
from clm_core.soil.formulas import sum_impedance_jacobian, sum_impedances

__all__ = [
    "CLIP_MARGIN",
    "NORMS",
    "ROUTES",
    "ClmSumFit",
    "LysmerFit",
    "Norm",
    "Route",
    "fit_clm_sums",
    "fit_lysmer",
]

Norm = Literal["ls", "relative"]
NORMS: tuple[str, ...] = ("ls", "relative")
Route = Literal["joint", "total-first"]
ROUTES: tuple[Route, ...] = ("joint", "total-first")
MassRule = Literal["nonnegative", "free"]
#: Margin kept from the stability boundary when clipping d_c or k_c.
CLIP_MARGIN = 0.05



@dataclass(frozen=True)
class LysmerFit:
    """Lysmer's analogue K(w) = k_f - w^2 m_f + i w d_f fitted to an impedance (Eq. 3).

    Attributes
    ----------
    mf : float
        Added mass m_f [kg].
    kf : float
        Stiffness k_f [N/m].
    df : float
        Dashpot d_f [N s/m].
    band : tuple of float
        Fit band (fmin, fmax) [Hz].
    norm : str
        ``"ls"`` or ``"relative"``.
    n_points : int
        Frequencies in the band.
    residual : float
        Relative RMS residual in the fit norm,
        sqrt(sum w_i^2 |K_fit - K|^2 / sum w_i^2 |K|^2) [-].
    max_rel_error : float
        max_i |K_fit - K| / |K| in the band [-].
    constrained : tuple of str
        Constraints that were active (e.g. ``"mf=0"``).
    """

    mf: float
    kf: float
    df: float
    band: tuple[float, float]
    norm: str
    n_points: int
    residual: float
    max_rel_error: float
    constrained: tuple[str, ...] = ()

    def impedance(self, freqs: ArrayLike) -> CArray:
        """K(w) = k_f - w^2 m_f + i w d_f at ``freqs`` [Hz] -> [N/m] (Eq. 3)."""
        s = 2j * np.pi * np.asarray(freqs, dtype=float)
        return sum_impedances(s, {"mf": self.mf, "kf": self.kf, "df": self.df})[0]

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (JSON-ready)."""
        d = asdict(self)
        d["band"] = list(self.band)
        d["constrained"] = list(self.constrained)
        return d


@dataclass(frozen=True)
class ClmSumFit:
    """CLM parameters fitted to the impedance sums S (Eq. 16) and A (Eq. 18).

    Attributes
    ----------
    mf : float
        Added mass m_f [kg].
    kf : float
        Foundation stiffness k_f [N/m].
    df : float
        Foundation dashpot d_f [N s/m].
    kc : float
        Coupling stiffness k_c [N/m].
    dc : float
        Coupling dashpot d_c [N s/m] (normally negative).
    band : tuple of float
        Fit band (fmin, fmax) [Hz].
    norm : str
        ``"ls"`` or ``"relative"``.
    n_points : int
        Frequencies in the band.
    residual_total, residual_alternating : float
        Relative RMS residuals of the S and A fits in the fit norm,
        sqrt(sum w_i^2 |Z_fit - Z|^2 / sum w_i^2 |Z|^2) [-].
    max_rel_error_total, max_rel_error_alternating : float
        Largest pointwise relative errors |Z_fit - Z| / |Z| in the band [-].
    constrained : tuple of str
        Active constraints (``"mf=0"``, ``"dc clipped"``, ``"kc clipped"``).
    damping_min_eigenvalue : float
        Smallest eigenvalue of the chain damping matrix, d_f + 4 min(d_c, 0)
        (or the exact value for the ``n_areas`` of the fit) [N s/m].
    route : str
        ``"joint"`` or ``"total-first"`` (module docstring).
    mf_unconstrained : float
        m_f of the same route without the constraint m_f >= 0 [kg].
    """

    mf: float
    kf: float
    df: float
    kc: float
    dc: float
    band: tuple[float, float]
    norm: str
    n_points: int
    residual_total: float
    residual_alternating: float
    max_rel_error_total: float
    max_rel_error_alternating: float
    constrained: tuple[str, ...] = ()
    damping_min_eigenvalue: float = math.nan
    route: str = "joint"
    mf_unconstrained: float = math.nan

    def total_sum(self, freqs: ArrayLike) -> CArray:
        """Eq. (16): k_f - w^2 m_f + i w d_f at ``freqs`` [Hz] -> [N/m]."""
        return sum_impedances(2j * np.pi * np.asarray(freqs, dtype=float), self.params)[0]

    def alternating_sum(self, freqs: ArrayLike) -> CArray:
        """Eq. (18): (k_f + 4 k_c) - w^2 m_f + i w (d_f + 4 d_c) at ``freqs`` [Hz] -> [N/m]."""
        return sum_impedances(2j * np.pi * np.asarray(freqs, dtype=float), self.params)[1]

    @property
    def params(self) -> dict[str, float]:
        """The five CLM parameters {mf, kf, df, kc, dc} in SI units."""
        return {"mf": self.mf, "kf": self.kf, "df": self.df, "kc": self.kc, "dc": self.dc}

    def quality(self) -> dict[str, dict[str, float]]:
        """Fit quality of both sums: {"total" | "alternating": {"residual", "max_rel_error"}} [-]."""
        return {
            "total": {"residual": self.residual_total, "max_rel_error": self.max_rel_error_total},
            "alternating": {"residual": self.residual_alternating, "max_rel_error": self.max_rel_error_alternating},
        }

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (JSON-ready)."""
        d = asdict(self)
        d["band"] = list(self.band)
        d["constrained"] = list(self.constrained)
        return d


# ----------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------


def _band(
    freqs: ArrayLike, values: Sequence[ArrayLike], fmin: float, fmax: float, name: str
) -> tuple[Array, list[CArray]]:
    try:
        f = np.asarray(freqs, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"freqs = {freqs!r}: must be real numbers [Hz]") from None
    if f.ndim != 1:
        raise ParameterError(f"freqs: must be 1-D, got shape {f.shape}")
    if not np.all(np.isfinite(f)):
        raise ParameterError(f"freqs = {f[~np.isfinite(f)][0]} Hz: must be finite")
    fmin, fmax = finite("fmin", fmin), finite("fmax", fmax)
    if fmin < 0 or fmax <= fmin:
        raise ParameterError(f"band [fmin, fmax] = [{fmin:g}, {fmax:g}] Hz: need 0 <= fmin < fmax")
    out = []
    for i, v in enumerate(values):
        try:
            z = np.asarray(v, dtype=np.complex128)
        except (TypeError, ValueError):
            raise ParameterError(f"{name}[{i}] = {v!r}: must be complex numbers [N/m]") from None
        if z.shape != f.shape:
            raise ParameterError(f"{name}[{i}]: shape {z.shape} differs from freqs {f.shape}")
        out.append(z)
    sel = (f >= fmin - 1e-12) & (f <= fmax + 1e-12)
    n_distinct = np.unique(f[sel]).size
    if n_distinct < 3:
        raise ParameterError(
            f"band [{fmin:g}, {fmax:g}] Hz: holds {n_distinct} distinct frequencies of the data, need >= 3"
        )
    for i, z in enumerate(out):
        if not np.all(np.isfinite(z[sel])):
            raise ParameterError(f"{name}[{i}]: non-finite values in the band")
        if not np.any(z[sel]):
            raise ParameterError(f"{name}[{i}]: zero at every frequency of the band: nothing to fit")
    return f[sel], [z[sel] for z in out]


def _weights(z: CArray, norm: str) -> Array:
    if norm not in NORMS:
        raise ParameterError(f"norm = {norm!r}: must be one of {NORMS}")
    if norm == "ls":
        return np.ones(z.shape)
    mag = np.abs(z)
    if np.any(mag == 0):
        raise ParameterError("norm = 'relative': the data vanish at some frequency of the band")
    return np.asarray(1.0 / mag)


#: One block of a linear fit: design matrix dZ/dp (5, n), data Z (n,), weights (n,).
_Block = tuple[CArray, CArray, Array]


def _linear_fit(blocks: Sequence[_Block], free: Sequence[str], fixed: dict[str, float]) -> dict[str, float]:
    """Weighted linear least squares over real parameters: min sum_b ||W_b (J_b p - Z_b)||^2.

    ``free`` names the unknown columns of ``CHAIN_PARAMS``; the others take
    their value from ``fixed`` (missing: 0). Real and imaginary parts are
    stacked, so the fit is exact for complex data with real parameters.
    """
    cols = [CHAIN_PARAMS.index(k) for k in free]
    p_fix = np.array([0.0 if k in free else fixed.get(k, 0.0) for k in CHAIN_PARAMS])
    rows, rhs = [], []
    for J, Z, wt in blocks:
        r = (Z - p_fix @ J) * wt
        G = (J[cols].T * wt[:, None])
        rows += [G.real, G.imag]
        rhs += [r.real, r.imag]
    G = np.vstack(rows)
    y = np.concatenate(rhs)
    scale = np.linalg.norm(G, axis=0)
    if np.any(scale == 0):
        bad = [free[int(i)] for i in np.nonzero(scale == 0)[0]]
        raise ParameterError(f"band: the data do not determine {', '.join(bad)} (e.g. only w = 0 for a dashpot)")
    sol = np.linalg.lstsq(G / scale, y, rcond=None)[0] / scale
    out = dict(fixed)
    out.update({k: float(v) for k, v in zip(free, sol, strict=True)})
    return out


def _fit_with_mass_rule(
    blocks: Sequence[_Block], free: Sequence[str], fixed: dict[str, float], mass: str
) -> tuple[dict[str, float], float, bool]:
    """:func:`_linear_fit`, redone with m_f = 0 when ``mass="nonnegative"`` and the free m_f < 0."""
    p = _linear_fit(blocks, free, fixed)
    mf_free = p.get("mf", 0.0)
    if "mf" in free and mass == "nonnegative" and mf_free < 0:
        p = _linear_fit(blocks, [k for k in free if k != "mf"], {**fixed, "mf": 0.0})
        return p, mf_free, True
    return p, mf_free, False


def _residuals(fit: CArray, data: CArray, wt: Array) -> tuple[float, float]:
    rms = math.sqrt(float(np.sum(wt**2 * np.abs(fit - data) ** 2) / np.sum(wt**2 * np.abs(data) ** 2)))
    mx = float(np.max(np.abs(fit - data) / np.abs(data)))
    return rms, mx


def _check_mass(mass: str) -> None:
    if mass not in ("nonnegative", "free"):
        raise ParameterError(f"mass = {mass!r}: must be 'nonnegative' or 'free'")


# ----------------------------------------------------------------------------
# fits
# ----------------------------------------------------------------------------


def fit_lysmer(
    freqs: ArrayLike,
    impedance: ArrayLike,
    *,
    fmin: float,
    fmax: float,
    norm: Norm = "ls",
    mass: MassRule = "nonnegative",
) -> LysmerFit:
    """Fit Lysmer's analogue (Eq. 3) to the impedance of one isolated area.

    Parameters
    ----------
    freqs : array_like, shape (nf,)
        Frequencies [Hz].
    impedance : array_like of complex, shape (nf,)
        K(w) = F / X [N/m].
    fmin, fmax : float
        Fit band [Hz], inclusive.
    norm : {"ls", "relative"}
        Error norm, see the module docstring.
    mass : {"nonnegative", "free"}
        Constraint on m_f.

    Returns
    -------
    LysmerFit

    Raises
    ------
    ParameterError
        Bad band, shapes, non-finite frequencies or data, norm or mass rule.
    """
    _check_mass(mass)
    f, (K,) = _band(freqs, [impedance], fmin, fmax, "impedance")
    wt = _weights(K, norm)
    s = 2j * np.pi * f
    dS, _ = sum_impedance_jacobian(s)
    p, _, con = _fit_with_mass_rule([(dS, K, wt)], ("mf", "kf", "df"), {}, mass)
    fitK = sum_impedances(s, p)[0]
    res, mx = _residuals(fitK, K, wt)
    return LysmerFit(
        mf=p["mf"],
        kf=p["kf"],
        df=p["df"],
        band=(float(fmin), float(fmax)),
        norm=norm,
        n_points=int(f.size),
        residual=res,
        max_rel_error=mx,
        constrained=("mf=0",) if con else (),
    )


def fit_clm_sums(
    freqs: ArrayLike,
    total: ArrayLike,
    alternating: ArrayLike,
    *,
    fmin: float,
    fmax: float,
    norm: Norm = "ls",
    mass: MassRule = "nonnegative",
    on_unstable: Literal["raise", "clip"] = "raise",
    n_areas: int | None = None,
    route: Route = "joint",
) -> ClmSumFit:
    """Fit the five CLM parameters to the sums S (Eq. 16) and A (Eq. 18).

    Parameters
    ----------
    freqs : array_like, shape (nf,)
        Frequencies [Hz].
    total : array_like of complex, shape (nf,)
        S(w) = F / sum_j X_j [N/m].
    alternating : array_like of complex, shape (nf,)
        A(w) = F / sum_j (-1)^j X_j [N/m] (j = 0 at the loaded area).
    fmin, fmax : float
        Fit band [Hz], inclusive; the same band is used for S and A.
    norm : {"ls", "relative"}
        Error norm, see the module docstring.
    mass : {"nonnegative", "free"}
        Constraint on m_f.
    on_unstable : {"raise", "clip"}
        What to do if the chain damping (or stiffness) matrix is not
        positive definite: raise :class:`StabilityError`, or clip d_c (k_c)
        to 95 % of the boundary and record it.
    n_areas : int, optional
        Chain length for the exact finite-chain check (default: the
        length-independent bound d_f + 4 d_c > 0).
    route : {"joint", "total-first"}
        Both sums at once (default), or m_f, k_f, d_f from S then k_c, d_c
        from A (module docstring).

    Returns
    -------
    ClmSumFit

    Raises
    ------
    ParameterError
        Bad band, shapes, non-finite frequencies, norm, route, option or
        ``n_areas`` (an odd count >= 1).
    StabilityError
        Non-admissible parameters (see the module docstring).
    """
    if on_unstable not in ("raise", "clip"):
        raise ParameterError(f"on_unstable = {on_unstable!r}: must be 'raise' or 'clip'")
    _check_mass(mass)
    if route not in ROUTES:
        raise ParameterError(f"route = {route!r}: must be one of {ROUTES}")
    if n_areas is not None:
        n_areas = odd_count("n_areas", n_areas)
    f, (S, A) = _band(freqs, [total, alternating], fmin, fmax, "sums")
    s = 2j * np.pi * f
    dS, dA = sum_impedance_jacobian(s)
    block_S = (dS, S, _weights(S, norm))
    block_A = (dA, A, _weights(A, norm))
    constrained: list[str] = []
    if route == "joint":
        p, mf_free, con = _fit_with_mass_rule([block_S, block_A], CHAIN_PARAMS, {}, mass)
    else:
        p, mf_free, con = _fit_with_mass_rule([block_S], ("mf", "kf", "df"), {}, mass)
        p = _linear_fit([block_A], ("kc", "dc"), p)
    if con:
        constrained.append("mf=0")
    where = f"fitted in [{fmin:g}, {fmax:g}] Hz ({norm}, {route})"
    if on_unstable == "clip" and p["df"] > 0 and p["kf"] > 0:
        lam_max = 4.0 if n_areas is None else 2.0 - 2.0 * math.cos(math.pi * (n_areas - 1) / n_areas)
        for diag, coupling, label in (("df", "dc", "dc clipped"), ("kf", "kc", "kc clipped")):
            if chain_min_eigenvalue(p[diag], p[coupling], n_areas) <= CLIP_MARGIN * p[diag]:
                p[coupling] = -(1.0 - CLIP_MARGIN) * p[diag] / lam_max
                constrained.append(label)
    try:
        clm_chain_admissible(p["mf"], p["kf"], p["df"], p["kc"], p["dc"], n_areas)
    except StabilityError as exc:
        raise StabilityError(f"{exc}; {where}") from None
    fitS, fitA = sum_impedances(s, p)
    rS, mS = _residuals(fitS, S, block_S[2])
    rA, mA = _residuals(fitA, A, block_A[2])
    return ClmSumFit(
        mf=p["mf"],
        kf=p["kf"],
        df=p["df"],
        kc=p["kc"],
        dc=p["dc"],
        band=(float(fmin), float(fmax)),
        norm=norm,
        n_points=int(f.size),
        residual_total=rS,
        residual_alternating=rA,
        max_rel_error_total=mS,
        max_rel_error_alternating=mA,
        constrained=tuple(constrained),
        damping_min_eigenvalue=chain_min_eigenvalue(p["df"], p["dc"], n_areas),
        route=route,
        mf_unconstrained=mf_free,
    )
