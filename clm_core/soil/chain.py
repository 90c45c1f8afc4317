"""The CLM chain of 2n + 1 soil contact areas alone: the one solver (paper Sec. 4, Eq. 7-20).

Equations of motion of area i, Eq. (7)-(8), free chain ends (an end area
has one neighbour):

    m_f x_i'' + d_f x_i' + k_f x_i + sum_{j = i +- 1} [d_c (x_i' - x_j') + k_c (x_i - x_j)] = f_i(t)

At the Laplace variable s (s = j w for a harmonic response, exp(+j w t)
convention; s = sigma + j w for exponentially windowed records) they read
D(s) X = F with the tridiagonal dynamic stiffness

    D(s) = (k_f + s d_f + s^2 m_f) I + (k_c + s d_c) L,

L the path-graph Laplacian (diagonal 2, ends 1, off-diagonal -1). Everything
that needs the chain's frequency response calls :func:`chain_response`:
the soil command and the formulas' checks, the sums fit
(:mod:`clm_core.soil.fit`), the half-space calibration and the impact-test
calibration (with the Jacobian). Its analytic Jacobian with respect to
p = (m_f, k_f, d_f, k_c, d_c) is dX/dp = -D^-1 (dD/dp) X with
dD/dp = (s^2 I, I, s I, L, s L).

Sums over the areas, j counted from the loaded area (Eq. 15-20): the
impedance over the total sum F / sum_j X_j equals k_f - w^2 m_f + j w d_f
exactly for free ends and any chain length (Eq. 15-16; the coupling terms
cancel in the sum), and the impedance over the alternating sum
F / sum_j (-1)^j X_j tends to (k_f + 4 k_c) - w^2 m_f + j w (d_f + 4 d_c) as
n grows (Eq. 17-18; the end areas make it approximate for finite n).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal, TypeAlias, overload

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.linalg import lapack

from clm_core.arrays import Array, CArray
from clm_core.checks import chain_min_eigenvalue, finite, integer, odd_count, positive
from clm_core.errors import ParameterError
from clm_core.excitation import decay_pulse
from clm_core.newmark import NewmarkLinear
from clm_core.params import SoilParams

#: Order of the CLM parameters in every Jacobian: m_f [kg], k_f [N/m],
#: d_f [N s/m], k_c [N/m], d_c [N s/m].
CHAIN_PARAMS: tuple[str, ...] = ("mf", "kf", "df", "kc", "dc")

#: A soil for the chain: a validated :class:`SoilParams` (Winkler, Lysmer or
#: CLM), or plain values {name: value} of ``CHAIN_PARAMS`` (missing ones 0),
#: e.g. a fitted set with m_f = 0 or an iterate of a least-squares fit.
ChainSoil: TypeAlias = SoilParams | Mapping[str, float]

_ZGBTRF, _ZGBTRS = lapack.get_lapack_funcs(("gbtrf", "gbtrs"), dtype=np.complex128)


def chain_values(soil: ChainSoil) -> tuple[float, float, float, float, float]:
    """The five chain parameters (m_f, k_f, d_f, k_c, d_c) of ``soil`` as floats [SI].

    Raises
    ------
    ParameterError
        A rigid soil (it has no contact-area DOFs), an unknown name or a
        non-finite value.
    """
    if isinstance(soil, SoilParams):
        if soil.model == "rigid":
            raise ParameterError(f"soil.model = {soil.model!r}: the chain needs winkler, lysmer or clm")
        return soil.mf, soil.kf, soil.df, soil.kc, soil.dc
    unknown = set(soil) - set(CHAIN_PARAMS)
    if unknown:
        raise ParameterError(f"chain parameters: unknown name(s) {sorted(unknown)}; allowed {', '.join(CHAIN_PARAMS)}")
    mf, kf, df, kc, dc = (finite(name, soil.get(name, 0.0)) for name in CHAIN_PARAMS)
    return mf, kf, df, kc, dc


def laplace(f: ArrayLike, sigma: float = 0.0) -> CArray:
    """Laplace variable s = sigma + j 2 pi f [1/s] at frequencies ``f`` [Hz].

    ``sigma`` [1/s] is the decay rate of an exponential window exp(-sigma t)
    applied to force and response (0 for a harmonic response).

    Raises
    ------
    ParameterError
        A non-finite ``sigma``.
    """
    sigma = finite("sigma", sigma)
    return np.asarray(sigma + 2j * np.pi * np.asarray(f, dtype=float), dtype=np.complex128)


def _loaded_area(loaded: int | None, n_areas: int) -> int:
    """The loaded area's index: ``loaded``, or the centre one if None."""
    if loaded is None:
        return n_areas // 2
    return integer("loaded", loaded, 0, n_areas - 1, hint="an area index")


def _neighbours(n_areas: int) -> Array:
    """Number of neighbours of each area of a free chain: the diagonal of L (1 at the ends, 0 for one area)."""
    nb = np.full(n_areas, 2.0)
    nb[0] = nb[-1] = 1.0
    if n_areas == 1:
        nb[:] = 0.0
    return nb


def chain_matrices(soil: ChainSoil, n_areas: int) -> tuple[sp.csr_matrix, sp.csr_matrix, sp.csr_matrix]:
    """Mass, damping and stiffness matrices of a free-ended chain of ``n_areas`` areas, Eq. (7)-(8).

    M = m_f I, C = d_f I + d_c L, K = k_f I + k_c L (L the path-graph Laplacian).

    Parameters
    ----------
    soil : SoilParams or mapping
        Winkler, Lysmer or CLM soil (see :data:`ChainSoil`).
    n_areas : int
        Number of areas 2n + 1 (odd).

    Returns
    -------
    M, C, K : scipy.sparse.csr_matrix, shape (n_areas, n_areas)
        [kg], [N s/m], [N/m].
    """
    mf, kf, df, kc, dc = chain_values(soil)
    n = odd_count("n_areas", n_areas)
    nb = _neighbours(n)
    off = np.ones(n - 1)
    K = sp.diags([kf + kc * nb, -kc * off, -kc * off], [0, -1, 1])
    C = sp.diags([df + dc * nb, -dc * off, -dc * off], [0, -1, 1])
    M = sp.diags([np.full(n, mf)], [0])
    return M.tocsr(), C.tocsr(), K.tocsr()


@overload
def chain_response(
    soil: ChainSoil, n_areas: int, s: ArrayLike, jacobian: Literal[False] = ..., *, loaded: int | None = ...
) -> tuple[CArray, None]: ...


@overload
def chain_response(
    soil: ChainSoil, n_areas: int, s: ArrayLike, jacobian: Literal[True], *, loaded: int | None = ...
) -> tuple[CArray, CArray]: ...


@overload
def chain_response(
    soil: ChainSoil, n_areas: int, s: ArrayLike, jacobian: bool, *, loaded: int | None = ...
) -> tuple[CArray, CArray | None]: ...


def chain_response(
    soil: ChainSoil, n_areas: int, s: ArrayLike, jacobian: bool = False, *, loaded: int | None = None
) -> tuple[CArray, CArray | None]:
    """Displacements of every area per unit force on one area, at the Laplace variable s (Eq. 9-13).

    Solves D(s) X = e_loaded, D(s) = K + s C + s^2 M of :func:`chain_matrices`,
    by banded LU with partial pivoting (LAPACK ``zgbtrf``) at each s; the
    Jacobian reuses the factorisation.

    Parameters
    ----------
    soil : SoilParams or mapping
        Winkler, Lysmer or CLM soil, or plain values of ``CHAIN_PARAMS``.
    n_areas : int
        Number of areas 2n + 1 (odd), free ends.
    s : complex array_like, shape (n_f,)
        Laplace variable [1/s]: ``laplace(f)`` for the frequency response,
        ``laplace(f, sigma)`` for exponentially windowed records.
    jacobian : bool
        Also return the derivatives with respect to ``CHAIN_PARAMS``.
    loaded : int, optional
        Index of the loaded area (default the centre one, ``n_areas // 2``).

    Returns
    -------
    X : complex ndarray, shape (n_f, n_areas)
        Receptances X_j / F [m/N].
    dX : complex ndarray, shape (5, n_f, n_areas), or None
        dX/dp for p = (m_f, k_f, d_f, k_c, d_c) [m/N per kg, per N/m, per N s/m, ...]:
        dX/dp = -D^-1 (dD/dp) X.

    Raises
    ------
    ParameterError
        Bad ``n_areas`` or ``loaded``, an empty, not 1-D or non-finite ``s``, or D(s) singular at some s (e.g. an
        undamped resonance or a zero stiffness at s = 0).

    Examples
    --------
    One area alone is Lysmer's analogue: 1 / k_f at s = 0 (Eq. 7); a chain
    loaded at its centre answers symmetrically.

    >>> import numpy as np
    >>> from clm_core.params import load_soil
    >>> soil = load_soil("mevergnies")  # CLM soil, paper Table 1
    >>> X, _ = chain_response(soil, 1, [0.0])
    >>> bool(np.isclose(X[0, 0], 1 / soil.kf, rtol=1e-12))
    True
    >>> X, _ = chain_response(soil, 41, laplace([0.0, 50.0]))
    >>> X.shape, bool(np.allclose(X, X[:, ::-1])), bool(abs(X[0, 20]) > abs(X[0, 21]) > 0)
    ((2, 41), True, True)
    """
    mf, kf, df, kc, dc = chain_values(soil)
    n = odd_count("n_areas", n_areas)
    c = _loaded_area(loaded, n)
    try:
        s = np.atleast_1d(np.asarray(s, dtype=np.complex128))
    except (TypeError, ValueError):
        raise ParameterError(f"s = {s!r}: must be complex numbers") from None
    if s.ndim != 1 or s.size == 0:
        raise ParameterError(f"s: must be a non-empty 1-D array, got shape {s.shape}")
    if not np.all(np.isfinite(s)):
        raise ParameterError(f"s = {s[~np.isfinite(s)][0]}: must be finite (no NaN or infinity)")
    nb = _neighbours(n)
    X = np.empty((s.size, n), dtype=np.complex128)
    dX = np.empty((5, s.size, n), dtype=np.complex128) if jacobian else None
    e = np.zeros((n, 1), dtype=np.complex128)
    e[c, 0] = 1.0
    ab = np.zeros((4, n), dtype=np.complex128)  # LAPACK band storage, kl = ku = 1 (row 0: fill-in)
    rhs = np.empty((n, 5), dtype=np.complex128)
    for i, si in enumerate(s):
        zc = kc + si * dc
        ab[0] = 0.0
        ab[2] = kf + si * df + si * si * mf + nb * zc
        ab[1, 1:] = -zc
        ab[3, :-1] = -zc
        lu, piv, info = _ZGBTRF(ab, 1, 1)
        if info != 0:
            raise ParameterError(
                f"chain_response: D(s) is singular at s = {si:.6g} 1/s (f = {si.imag / (2 * np.pi):.6g} Hz) "
                f"with mf = {mf:g}, kf = {kf:g}, df = {df:g}, kc = {kc:g}, dc = {dc:g}"
            )
        x = _ZGBTRS(lu, 1, 1, e, piv)[0][:, 0]
        X[i] = x
        if dX is not None:
            lap = nb * x
            if n > 1:
                lap[:-1] -= x[1:]
                lap[1:] -= x[:-1]
            rhs[:, 0] = si * si * x  # dD/dmf X
            rhs[:, 1] = x  # dD/dkf X
            rhs[:, 2] = si * x  # dD/ddf X
            rhs[:, 3] = lap  # dD/dkc X
            rhs[:, 4] = si * lap  # dD/ddc X
            dX[:, i, :] = -_ZGBTRS(lu, 1, 1, rhs, piv)[0].T
    return X, dX


def chain_frequency_response(soil: ChainSoil, n_areas: int, f: ArrayLike, *, loaded: int | None = None) -> CArray:
    """Receptances X_j / F of every area for a unit harmonic force on one area [m/N].

    :func:`chain_response` at s = j 2 pi f.

    Parameters
    ----------
    soil : SoilParams or mapping
        Winkler, Lysmer or CLM soil.
    n_areas : int
        Number of areas 2n + 1 (odd).
    f : array_like, shape (n_f,)
        Frequencies [Hz].
    loaded : int, optional
        Loaded area (default the centre one).

    Returns
    -------
    complex ndarray, shape (n_f, n_areas)
        Column ``n_areas // 2`` is the loaded area by default.
    """
    return chain_response(soil, n_areas, laplace(f), loaded=loaded)[0]


def _sum_signs(n_areas: int, loaded: int | None) -> tuple[Array, Array]:
    """Weights of the total and alternating sums, (+1)_j and (-1)^j with j from the loaded area."""
    j = np.arange(n_areas) - _loaded_area(loaded, n_areas)
    return np.ones(n_areas), np.where(j % 2 == 0, 1.0, -1.0)


@dataclass(frozen=True)
class ChainSums:
    """Impedances over the total and the alternating sum of a chain response (Eq. 16 and 18).

    Attributes
    ----------
    frequency : ndarray, shape (n_f,)
        [Hz].
    total : complex ndarray, shape (n_f,)
        F / sum_j X_j [N/m].
    alternating : complex ndarray, shape (n_f,)
        F / sum_j (-1)^j X_j [N/m], j = 0 at the loaded area.
    d_total, d_alternating : complex ndarray, shape (5, n_f), or None
        Derivatives with respect to ``CHAIN_PARAMS`` (model sums with
        ``jacobian=True`` only) [N/m per unit of the parameter].
    """

    frequency: Array
    total: CArray
    alternating: CArray
    d_total: CArray | None = None
    d_alternating: CArray | None = None


def chain_sums(frequency: ArrayLike, X: ArrayLike, force: ArrayLike = 1.0, *, loaded: int | None = None) -> ChainSums:
    """Form F / sum_j X_j and F / sum_j (-1)^j X_j from area responses (Eq. 16, 18).

    Parameters
    ----------
    frequency : array_like, shape (n_f,)
        [Hz].
    X : complex array_like, shape (n_f, 2n + 1)
        Area displacements (measured or modelled) [m or m/N].
    force : scalar or array_like, shape (n_f,)
        Force spectrum F [N] (1 for receptances).
    loaded : int, optional
        Column of the loaded area (default the centre one).

    Returns
    -------
    ChainSums

    Raises
    ------
    ParameterError
        ``X`` not a non-empty complex array of shape (n_f, 2n + 1) matching
        ``frequency``, ``force`` neither a scalar nor of shape (n_f,), or
        ``loaded`` not an area index.
    """
    try:
        Xa = np.asarray(X, dtype=np.complex128)
        fa = np.asarray(frequency, dtype=float)
        F = np.asarray(force, dtype=np.complex128)
    except (TypeError, ValueError):
        raise ParameterError("chain_sums: frequency, X and force must be numbers") from None
    if Xa.ndim != 2 or Xa.shape[0] == 0:
        raise ParameterError(f"X: shape {Xa.shape}: must be (n_f, 2n + 1) with n_f >= 1")
    n = Xa.shape[1]
    if n % 2 == 0:
        raise ParameterError(f"X has {n} areas: need 2n + 1 with the loaded area at the centre")
    if fa.shape != (Xa.shape[0],):
        raise ParameterError(f"frequency: shape {fa.shape}: must be ({Xa.shape[0]},), one per row of X")
    if F.ndim > 1 or (F.ndim == 1 and F.shape != fa.shape):
        raise ParameterError(f"force: shape {F.shape}: must be a scalar or ({Xa.shape[0]},)")
    plus, sign = _sum_signs(n, loaded)
    total = np.asarray(F / (Xa @ plus), dtype=np.complex128)
    alternating = np.asarray(F / (Xa @ sign), dtype=np.complex128)
    return ChainSums(fa, total, alternating)


def chain_impedance_sums(
    soil: ChainSoil, n_areas: int, f: ArrayLike, *, sigma: float = 0.0, jacobian: bool = False
) -> ChainSums:
    """The chain's own sums F / sum_j X_j and F / sum_j (-1)^j X_j, with their Jacobian (Eq. 15-18).

    For free ends the total sum equals Eq. (16), k_f + s d_f + s^2 m_f, for any
    chain length, and so does its Jacobian (s^2, 1, s, 0, 0); the alternating
    sum and its Jacobian tend to Eq. (18) and (s^2, 1, s, 4, 4 s) as n grows.

    Parameters
    ----------
    soil : SoilParams or mapping
        Winkler, Lysmer or CLM soil.
    n_areas : int
        Number of areas 2n + 1 (odd), centre one loaded.
    f : array_like, shape (n_f,)
        Frequencies [Hz].
    sigma : float
        Decay rate of an exponential window [1/s] (s = sigma + j 2 pi f).
    jacobian : bool
        Also return the derivatives with respect to ``CHAIN_PARAMS``:
        d(F / sum) = -(F / sum)^2 sum dX.

    Returns
    -------
    ChainSums
    """
    fa = np.atleast_1d(np.asarray(f, dtype=float))
    X, dX = chain_response(soil, n_areas, laplace(fa, sigma), jacobian)
    plus, sign = _sum_signs(n_areas, None)
    tot, alt = 1.0 / (X @ plus), 1.0 / (X @ sign)
    d_tot = d_alt = None
    if dX is not None:
        d_tot = -(tot**2) * (dX @ plus)
        d_alt = -(alt**2) * (dX @ sign)
    return ChainSums(fa, tot, alt, d_tot, d_alt)


@dataclass(frozen=True)
class ChainTimeResponse:
    """Time response of a chain to a force on the centre area.

    Attributes
    ----------
    t : (n_t,) array [s]
    force : (n_t,) array [N]
    x, v : (n_t, n_areas) arrays [m], [m/s]
    """

    t: Array
    force: Array
    x: Array
    v: Array

    def peaks(self, n_neighbours: int = 2) -> tuple[list[float], list[float]]:
        """Peak displacement [m] and its time [s] for the loaded area and its ``n_neighbours`` following ones.

        Raises
        ------
        ParameterError
            ``n_neighbours`` not an integer in 0..n_areas // 2.
        """
        c = self.x.shape[1] // 2
        n_neighbours = integer("n_neighbours", n_neighbours, 0, c, hint="areas past the centre")
        amps, times = [], []
        for k in range(n_neighbours + 1):
            col = self.x[:, c + k]
            i = int(np.argmax(np.abs(col)))
            amps.append(float(col[i]))
            times.append(float(self.t[i]))
        return amps, times


def chain_time_response(
    soil: SoilParams,
    n_areas: int = 41,
    dt: float = 1.0e-5,
    duration: float = 0.15,
    A: float = 1.0,
    t0: float = 0.05,
    td: float = 0.001,
) -> ChainTimeResponse:
    """Response of the chain to the Eq. (1) pulse on the centre area (Newmark, from rest).

    Parameters
    ----------
    soil : SoilParams
        Winkler, Lysmer or CLM soil.
    n_areas : int
        Number of areas 2n + 1 (odd).
    dt, duration : float
        Time step and record length [s].
    A, t0, td : float
        Pulse amplitude [N], time [s] and duration parameter [s] of Eq. (1).

    Raises
    ------
    ParameterError
        Bad ``n_areas``, ``dt`` or ``duration`` not finite and > 0, a record
        shorter than one step, or a bad pulse (:func:`~clm_core.excitation.decay_pulse`).
    """
    M, C, K = chain_matrices(soil, n_areas)
    dt = positive("dt", dt, unit="s")
    duration = positive("duration", duration, unit="s")
    if duration < dt:
        raise ParameterError(f"duration = {duration:g} s: must be >= dt = {dt:g} s (at least one step)")
    n_steps = int(round(duration / dt))
    t = np.arange(n_steps + 1) * dt
    p = decay_pulse(t, A, t0, td)
    F = np.zeros((n_steps + 1, n_areas))
    F[:, n_areas // 2] = p
    _, x, v = NewmarkLinear(M, C, K, dt).run(F, n_steps)
    return ChainTimeResponse(np.asarray(t, dtype=np.float64), p, x, v)


def chain_damping_min_eigenvalue(soil: ChainSoil, n_areas: int) -> float:
    """Smallest eigenvalue of the chain damping matrix d_f I + d_c L [N s/m] (stability, Sec. 4.2)."""
    _, _, df, _, dc = chain_values(soil)
    return chain_min_eigenvalue(df, dc, odd_count("n_areas", n_areas))
