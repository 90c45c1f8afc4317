"""Fit of CLM soil parameters to impedance sums (Kouroussis et al. 2011, Sec. 4.1).

For a chain of 2n + 1 coupled lumped masses (the CLM model, Eq. 7–8) with a
force F on the centre area (index 0), summing the equations of motion gives
(time convention exp(+i w t), Eq. 15–18)

    S(w) = F / sum_j X_j         = k_f - w^2 m_f + i w d_f                  (16)
    A(w) = F / sum_j (-1)^j X_j  = (k_f + 4 k_c) - w^2 m_f + i w (d_f + 4 d_c)  (18)

(16) is exact for a chain with free ends of any length; (18) is exact for an
infinite chain and converges quickly with n. Given a rigorous S and A (e.g.
from :mod:`clm_core.halfspace.calibrate`), the parameters follow from
linear least squares in a stated frequency band and norm:

1. from S: Re S ~ k_f - w^2 m_f (two unknowns), Im S ~ w d_f (one unknown);
2. from A with m_f, k_f, d_f fixed: Re A - (k_f - w^2 m_f) ~ 4 k_c,
   Im A - w d_f ~ 4 w d_c.

Norms (per frequency w_i in [fmin, fmax]):

- ``"ls"``: absolute least squares, minimises sum |Z_fit - Z|^2;
- ``"relative"``: minimises sum |Z_fit - Z|^2 / |Z|^2 (each frequency counts
  alike, the low-frequency range is not swamped by the large high-frequency
  impedances).

Real and imaginary parts decouple in both norms, so every step is an exact
weighted linear least-squares problem.

Physical constraints
--------------------
- ``mass="nonnegative"`` (default): if the unconstrained m_f < 0 the fit is
  redone with m_f = 0 (the exact constrained optimum of the 2-parameter
  problem) and ``"mf=0"`` is recorded in ``constrained``; ``mass="free"``
  keeps the unconstrained value, and a negative m_f is then refused by the
  admissibility check (it cannot be clipped).
- Damping matrix of the chain (free ends): C = d_f I + d_c L with L the
  path-graph Laplacian (diagonal 2, ends 1, off-diagonal -1), eigenvalues
  2 - 2 cos(pi k / N), k = 0..N-1, in [0, 4). So C is positive definite for
  every N iff d_f > 0 and d_f + 4 d_c > 0 (for d_c < 0 the bound is reached
  as N -> inf; for d_c >= 0 only d_f > 0 matters). The same holds for the
  stiffness matrix with k_f, k_c. ``on_unstable="raise"`` (default) raises
  :class:`clm_core.errors.StabilityError`; ``"clip"`` moves d_c (k_c) to the
  boundary with a 5 % margin, d_c = -0.95 d_f / 4, and records it in
  ``constrained``. d_f <= 0, k_f <= 0 or m_f < 0 cannot be clipped and
  always raise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import solve_banded

from clm_core.errors import ParameterError, StabilityError

__all__ = [
    "ClmSumFit",
    "LysmerFit",
    "Norm",
    "chain_matrix_min_eigenvalue",
    "check_chain_positive_definite",
    "clm_chain_response",
    "fit_clm_sums",
    "fit_lysmer",
]

Norm = Literal["ls", "relative"]
NORMS: tuple[str, ...] = ("ls", "relative")
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

    def impedance(self, freqs: ArrayLike) -> NDArray[np.complex128]:
        """K(w) = k_f - w^2 m_f + i w d_f at ``freqs`` [Hz] -> [N/m]."""
        w = 2.0 * np.pi * np.asarray(freqs, dtype=float)
        return np.asarray(self.kf - w**2 * self.mf + 1j * w * self.df)

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
        Relative RMS residuals of the S and A fits in the fit norm [-].
    max_rel_error_total, max_rel_error_alternating : float
        Largest pointwise relative errors |Z_fit - Z| / |Z| in the band [-].
    constrained : tuple of str
        Active constraints (``"mf=0"``, ``"dc clipped"``, ``"kc clipped"``).
    damping_min_eigenvalue : float
        d_f + 4 min(d_c, 0): lower bound of the chain damping eigenvalues [N s/m].
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

    def total_sum(self, freqs: ArrayLike) -> NDArray[np.complex128]:
        """Eq. (16): k_f - w^2 m_f + i w d_f at ``freqs`` [Hz] -> [N/m]."""
        w = 2.0 * np.pi * np.asarray(freqs, dtype=float)
        return np.asarray(self.kf - w**2 * self.mf + 1j * w * self.df)

    def alternating_sum(self, freqs: ArrayLike) -> NDArray[np.complex128]:
        """Eq. (18): (k_f + 4 k_c) - w^2 m_f + i w (d_f + 4 d_c) at ``freqs`` [Hz] -> [N/m]."""
        w = 2.0 * np.pi * np.asarray(freqs, dtype=float)
        return np.asarray(self.kf + 4 * self.kc - w**2 * self.mf + 1j * w * (self.df + 4 * self.dc))

    @property
    def params(self) -> dict[str, float]:
        """The five CLM parameters {mf, kf, df, kc, dc} in SI units."""
        return {"mf": self.mf, "kf": self.kf, "df": self.df, "kc": self.kc, "dc": self.dc}

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
) -> tuple[NDArray[np.float64], list[NDArray[np.complex128]]]:
    f = np.asarray(freqs, dtype=float)
    if f.ndim != 1:
        raise ParameterError(f"freqs: must be 1-D, got shape {f.shape}")
    if not (math.isfinite(fmin) and math.isfinite(fmax)) or fmin < 0 or fmax <= fmin:
        raise ParameterError(f"band [fmin, fmax] = [{fmin:g}, {fmax:g}] Hz: need 0 <= fmin < fmax")
    out = []
    for i, v in enumerate(values):
        z = np.asarray(v, dtype=np.complex128)
        if z.shape != f.shape:
            raise ParameterError(f"{name}[{i}]: shape {z.shape} differs from freqs {f.shape}")
        out.append(z)
    sel = (f >= fmin - 1e-12) & (f <= fmax + 1e-12)
    if sel.sum() < 3:
        raise ParameterError(f"band [{fmin:g}, {fmax:g}] Hz: holds {int(sel.sum())} frequencies of the data, need >= 3")
    for i, z in enumerate(out):
        if not np.all(np.isfinite(z[sel])):
            raise ParameterError(f"{name}[{i}]: non-finite values in the band")
    return f[sel], [z[sel] for z in out]


def _weights(z: NDArray[np.complex128], norm: str) -> NDArray[np.float64]:
    if norm not in NORMS:
        raise ParameterError(f"norm = {norm!r}: must be one of {NORMS}")
    if norm == "ls":
        return np.ones(z.shape)
    mag = np.abs(z)
    if np.any(mag == 0):
        raise ParameterError("norm = 'relative': the data vanish at some frequency of the band")
    return np.asarray(1.0 / mag)


def _fit_real_quadratic(
    w: NDArray[np.float64], y: NDArray[np.float64], wt: NDArray[np.float64], mass: str
) -> tuple[float, float, bool]:
    """min sum wt^2 (k - w^2 m - y)^2 -> (k, m, constrained)."""
    Amat = np.stack([np.ones_like(w), -(w**2)], axis=1) * wt[:, None]
    sol, *_ = np.linalg.lstsq(Amat, y * wt, rcond=None)
    k, m = float(sol[0]), float(sol[1])
    if mass == "nonnegative" and m < 0:
        k = float(np.sum(wt**2 * y) / np.sum(wt**2))
        return k, 0.0, True
    return k, m, False


def _fit_slope(w: NDArray[np.float64], y: NDArray[np.float64], wt: NDArray[np.float64]) -> float:
    """min sum wt^2 (w d - y)^2 -> d."""
    den = float(np.sum(wt**2 * w**2))
    if den == 0:
        raise ParameterError("band: contains only w = 0; a dashpot cannot be fitted")
    return float(np.sum(wt**2 * w * y) / den)


def _residuals(
    fit: NDArray[np.complex128], data: NDArray[np.complex128], wt: NDArray[np.float64]
) -> tuple[float, float]:
    rms = math.sqrt(float(np.sum(wt**2 * np.abs(fit - data) ** 2) / np.sum(wt**2 * np.abs(data) ** 2)))
    mx = float(np.max(np.abs(fit - data) / np.abs(data)))
    return rms, mx


def chain_matrix_min_eigenvalue(diag: float, coupling: float, n_areas: int | None = None) -> float:
    """Smallest eigenvalue of the CLM chain matrix a I + c L (free ends).

    ``diag`` a (d_f or k_f), ``coupling`` c (d_c or k_c); L is the path
    Laplacian of ``n_areas`` nodes (None: infinite chain, bound a + 4 min(c, 0)).
    """
    if coupling >= 0:
        return diag
    if n_areas is None:
        return diag + 4.0 * coupling
    if n_areas < 1:
        raise ParameterError(f"n_areas = {n_areas}: must be >= 1")
    lam_max = 2.0 - 2.0 * math.cos(math.pi * (n_areas - 1) / n_areas)
    return diag + coupling * lam_max


def check_chain_positive_definite(
    df: float, dc: float, kf: float, kc: float, mf: float, n_areas: int | None = None
) -> None:
    """Raise :class:`StabilityError` unless the CLM chain's M, C and K are admissible.

    Rules: m_f >= 0; d_f + 4 min(d_c, 0) > 0 and k_f + 4 min(k_c, 0) > 0
    (positive definite for any chain length; with ``n_areas`` the exact
    finite-chain bound is used).
    """
    if not mf >= 0:
        raise StabilityError(f"mf = {mf:.6g} kg: the mass matrix of the chain must be positive semidefinite (mf >= 0)")
    lam_c = chain_matrix_min_eigenvalue(df, dc, n_areas)
    if not lam_c > 0:
        raise StabilityError(
            f"dc = {dc:.6g} N s/m with df = {df:.6g} N s/m: the chain damping matrix is not positive definite "
            f"(smallest eigenvalue {lam_c:.6g} N s/m; rule: df > 0 and df + 4 dc > 0 for dc < 0)"
        )
    lam_k = chain_matrix_min_eigenvalue(kf, kc, n_areas)
    if not lam_k > 0:
        raise StabilityError(
            f"kc = {kc:.6g} N/m with kf = {kf:.6g} N/m: the chain stiffness matrix is not positive definite "
            f"(smallest eigenvalue {lam_k:.6g} N/m; rule: kf > 0 and kf + 4 kc > 0 for kc < 0)"
        )


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
    mass: Literal["nonnegative", "free"] = "nonnegative",
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
    """
    if mass not in ("nonnegative", "free"):
        raise ParameterError(f"mass = {mass!r}: must be 'nonnegative' or 'free'")
    f, (K,) = _band(freqs, [impedance], fmin, fmax, "impedance")
    wt = _weights(K, norm)
    w = 2.0 * np.pi * f
    kf, mf, con = _fit_real_quadratic(w, K.real, wt, mass)
    df = _fit_slope(w, K.imag, wt)
    fitK = kf - w**2 * mf + 1j * w * df
    res, mx = _residuals(fitK, K, wt)
    return LysmerFit(
        mf=mf,
        kf=kf,
        df=df,
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
    mass: Literal["nonnegative", "free"] = "nonnegative",
    on_unstable: Literal["raise", "clip"] = "raise",
    n_areas: int | None = None,
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
        Constraint on m_f (fitted from S only).
    on_unstable : {"raise", "clip"}
        What to do if the chain damping (or stiffness) matrix is not
        positive definite: raise :class:`StabilityError`, or clip d_c (k_c)
        to 95 % of the boundary and record it.
    n_areas : int, optional
        Chain length for the exact finite-chain check (default: the
        length-independent bound d_f + 4 d_c > 0).

    Returns
    -------
    ClmSumFit

    Raises
    ------
    ParameterError
        Bad band, shapes or norm.
    StabilityError
        Non-admissible parameters (see the module docstring).
    """
    if on_unstable not in ("raise", "clip"):
        raise ParameterError(f"on_unstable = {on_unstable!r}: must be 'raise' or 'clip'")
    if mass not in ("nonnegative", "free"):
        raise ParameterError(f"mass = {mass!r}: must be 'nonnegative' or 'free'")
    f, (S, A) = _band(freqs, [total, alternating], fmin, fmax, "sums")
    w = 2.0 * np.pi * f
    wS = _weights(S, norm)
    wA = _weights(A, norm)
    constrained: list[str] = []
    kf, mf, con = _fit_real_quadratic(w, S.real, wS, mass)
    if con:
        constrained.append("mf=0")
    df = _fit_slope(w, S.imag, wS)
    kc = 0.25 * float(np.sum(wA**2 * (A.real - kf + w**2 * mf)) / np.sum(wA**2))
    dc = 0.25 * (_fit_slope(w, A.imag, wA) - df)
    if not df > 0:
        raise StabilityError(
            f"df = {df:.6g} N s/m fitted in [{fmin:g}, {fmax:g}] Hz ({norm}): must be > 0 "
            "(positive definite damping matrix)"
        )
    if not kf > 0:
        raise StabilityError(f"kf = {kf:.6g} N/m fitted in [{fmin:g}, {fmax:g}] Hz ({norm}): must be > 0")
    if on_unstable == "clip":
        lam_c = chain_matrix_min_eigenvalue(df, dc, n_areas)
        if lam_c <= CLIP_MARGIN * df:
            lam_max = 4.0 if n_areas is None else 2.0 - 2.0 * math.cos(math.pi * (n_areas - 1) / n_areas)
            dc = -(1.0 - CLIP_MARGIN) * df / lam_max
            constrained.append("dc clipped")
        lam_k = chain_matrix_min_eigenvalue(kf, kc, n_areas)
        if lam_k <= CLIP_MARGIN * kf:
            lam_max = 4.0 if n_areas is None else 2.0 - 2.0 * math.cos(math.pi * (n_areas - 1) / n_areas)
            kc = -(1.0 - CLIP_MARGIN) * kf / lam_max
            constrained.append("kc clipped")
    check_chain_positive_definite(df, dc, kf, kc, mf, n_areas)
    fitS = kf - w**2 * mf + 1j * w * df
    fitA = kf + 4 * kc - w**2 * mf + 1j * w * (df + 4 * dc)
    rS, mS = _residuals(fitS, S, wS)
    rA, mA = _residuals(fitA, A, wA)
    return ClmSumFit(
        mf=mf,
        kf=kf,
        df=df,
        kc=kc,
        dc=dc,
        band=(float(fmin), float(fmax)),
        norm=norm,
        n_points=int(f.size),
        residual_total=rS,
        residual_alternating=rA,
        max_rel_error_total=mS,
        max_rel_error_alternating=mA,
        constrained=tuple(constrained),
        damping_min_eigenvalue=chain_matrix_min_eigenvalue(df, dc, n_areas),
    )


def clm_chain_response(
    freqs: ArrayLike, mf: float, kf: float, df: float, kc: float, dc: float, n_areas: int
) -> NDArray[np.complex128]:
    """Displacements of a free CLM chain for a unit force on its centre area (Eq. 7–13).

    Parameters
    ----------
    freqs : array_like, shape (nf,)
        Frequencies [Hz].
    mf, kf, df, kc, dc : float
        CLM parameters [kg, N/m, N s/m, N/m, N s/m].
    n_areas : int
        Odd chain length 2n + 1 (end areas have one neighbour).

    Returns
    -------
    ndarray of complex, shape (nf, n_areas)
        X_j / F [m/N], centre at index n.
    """
    if n_areas < 1 or n_areas % 2 == 0:
        raise ParameterError(f"n_areas = {n_areas}: must be odd and >= 1")
    f = np.atleast_1d(np.asarray(freqs, dtype=float))
    N = n_areas
    out = np.zeros((f.size, N), dtype=np.complex128)
    rhs = np.zeros(N, dtype=np.complex128)
    rhs[N // 2] = 1.0
    nb = np.full(N, 2.0)
    nb[0] = nb[-1] = 1.0
    if N == 1:
        nb[:] = 0.0
    for i, fi in enumerate(f):
        w = 2.0 * math.pi * fi
        zc = kc + 1j * w * dc
        ab = np.zeros((3, N), dtype=np.complex128)
        ab[1] = kf - w**2 * mf + 1j * w * df + nb * zc
        ab[0, 1:] = -zc
        ab[2, :-1] = -zc
        out[i] = solve_banded((1, 1), ab, rhs)
    return out
