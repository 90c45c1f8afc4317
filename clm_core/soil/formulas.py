"""Closed-form soil formulas of Kouroussis et al. (2011), Sec. 3–5.

All inputs and outputs in SI units. Frequencies ``f`` in Hz, circular
frequencies ``w`` in rad/s. Time convention exp(+j w t): a dashpot has
impedance +j w d.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.errors import ParameterError
from clm_core.params import SoilParams
from clm_core.profile import Layer
from clm_core.soil.chain import ChainSoil, chain_values


def sum_impedances(s: ArrayLike, soil: ChainSoil) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """The CLM impedances over the total and the alternating sum, Eq. (16) and (18), at Laplace s [N/m].

    S = k_f + s d_f + s^2 m_f (Eq. 16) and A = (k_f + 4 k_c) + s (d_f + 4 d_c) + s^2 m_f
    (Eq. 18); with s = j w they read k_f - w^2 m_f + j w d_f and
    (k_f + 4 k_c) - w^2 m_f + j w (d_f + 4 d_c). Eq. (16) is exact for a free
    chain of any length, Eq. (18) for the infinite chain
    (:func:`clm_core.soil.chain.chain_impedance_sums` gives the finite chain's).

    Parameters
    ----------
    s : complex array_like
        Laplace variable [1/s] (:func:`clm_core.soil.chain.laplace`).
    soil : SoilParams or mapping
        Soil, or plain values of ``CHAIN_PARAMS`` (e.g. a fitted set).

    Returns
    -------
    total, alternating : complex ndarray, shape of ``s``
    """
    mf, kf, df, kc, dc = chain_values(soil)
    sa = np.asarray(s, dtype=np.complex128)
    total = kf + sa * df + sa * sa * mf
    return np.asarray(total), np.asarray(total + 4.0 * (kc + sa * dc))


def sum_impedance_jacobian(s: ArrayLike) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Derivatives of Eq. (16) and (18) with respect to ``CHAIN_PARAMS`` (m_f, k_f, d_f, k_c, d_c).

    The formulas are linear in the parameters, so the Jacobian does not
    depend on them: dS/dp = (s^2, 1, s, 0, 0), dA/dp = (s^2, 1, s, 4, 4 s).
    It is the design matrix of the sums fit (:mod:`clm_core.soil.fit`).

    Parameters
    ----------
    s : complex array_like, shape (n,)
        Laplace variable [1/s].

    Returns
    -------
    d_total, d_alternating : complex ndarray, shape (5, n)
        [N/m per unit of each parameter].
    """
    sa = np.atleast_1d(np.asarray(s, dtype=np.complex128))
    one, zero = np.ones_like(sa), np.zeros_like(sa)
    d_total = np.stack([sa * sa, one, sa, zero, zero])
    d_alternating = np.stack([sa * sa, one, sa, 4.0 * one, 4.0 * sa])
    return d_total, d_alternating


def total_sum_impedance(w: ArrayLike, soil: ChainSoil) -> NDArray[np.complex128]:
    """CLM impedance over the total sum, Eq. (15)-(16): F / sum_j X_j = k_f - w^2 m_f + j w d_f [N/m].

    ``w`` [rad/s]; exact for a free chain of any length.
    """
    return sum_impedances(1j * np.asarray(w, dtype=float), soil)[0]


def alternating_sum_impedance(w: ArrayLike, soil: ChainSoil) -> NDArray[np.complex128]:
    """CLM impedance over the alternating sum, Eq. (18): F / sum_j (-1)^j X_j [N/m].

    (k_f + 4 k_c) - w^2 m_f + j w (d_f + 4 d_c) at ``w`` [rad/s]; exact for an infinite chain.
    """
    return sum_impedances(1j * np.asarray(w, dtype=float), soil)[1]


def static_stiffness_circle(R: float, E: float, nu: float) -> float:
    """Static vertical stiffness of a rigid circular surface foundation, Eq. (5) [N/m].

    k_f = 2 R E / (1 - nu^2) (= 4 G R / (1 - nu)).
    """
    if R <= 0 or E <= 0 or not -1 < nu < 0.5:
        raise ParameterError(f"static_stiffness_circle: R = {R}, E = {E}, nu = {nu}: need R, E > 0, -1 < nu < 0.5")
    return 2.0 * R * E / (1.0 - nu**2)


def static_stiffness_rectangle(length: float, width: float, E: float, nu: float) -> float:
    """Static vertical stiffness of a rigid rectangular surface area, Eq. (6) [N/m].

    k_f = E b / (1 - nu^2) [1.55 (a/b)^0.75 + 0.8] for a 2a x 2b rectangle
    with a >= b (Gazetas 1991, the paper's ref. [22]).

    Parameters
    ----------
    length, width : float
        Sides 2a and 2b [m] (their order does not matter).
    E, nu : float
        Young's modulus [Pa] and Poisson's ratio of the half-space.
    """
    a, b = max(length, width) / 2.0, min(length, width) / 2.0
    if b <= 0 or E <= 0 or not -1 < nu < 0.5:
        raise ParameterError(
            f"static_stiffness_rectangle: length = {length}, width = {width}, E = {E}, nu = {nu}: "
            "need positive sides and modulus, -1 < nu < 0.5"
        )
    return float(E * b / (1.0 - nu**2) * (1.55 * (a / b) ** 0.75 + 0.8))


def lysmer_from_soil(layer: Layer, length: float, width: float) -> SoilParams:
    """Lysmer's analogue (m_f, k_f, d_f) of one rigid rectangular area on a half-space.

    - k_f: Eq. (6) for the rectangle.
    - d_f: Lysmer's analogue dashpot 3.4 R^2 sqrt(rho G) / (1 - nu) with the
      radius R = sqrt(A / pi) of the circle of equal area (Lysmer & Richart 1966).
    - m_f: the trapped soil mass of Wolf's cone model, 2.4 (nu - 1/3) rho A R,
      zero for nu <= 1/3 (Wolf 1994, "Foundation vibration analysis using
      simple physical models"); a small floor of 1e-6 of the sleeper-size soil
      block keeps the mass matrix positive definite.

    These are textbook estimates for an isolated area; the coupled chain
    needs a CLM calibration (Sec. 4.1), see :mod:`clm_core.halfspace`.
    """
    area = length * width
    R = math.sqrt(area / math.pi)
    kf = static_stiffness_rectangle(length, width, layer.E, layer.nu)
    df = 3.4 * R**2 * math.sqrt(layer.rho * layer.G) / (1.0 - layer.nu)
    mf = max(2.4 * (layer.nu - 1.0 / 3.0), 0.0) * layer.rho * area * R
    mf = max(mf, 1e-6 * layer.rho * area * R)
    return SoilParams(model="lysmer", mf=mf, kf=kf, df=df)


def resonance_frequency(soil: SoilParams) -> float:
    """Soil resonance of the CLM chain, Eq. (24): f_R = sqrt((k_f + 2 k_c) / m_f) / (2 pi) [Hz]."""
    if soil.mf <= 0:
        raise ParameterError(f"soil.mf = {soil.mf}: Eq. (24) needs a positive added mass")
    return math.sqrt((soil.kf + 2 * soil.kc) / soil.mf) / (2 * math.pi)


def time_lag_mulliken(spacing: float, width: float, cs: float) -> float:
    """Wave-propagation delay between neighbouring areas, Eq. (21) [s].

    tau = 3 (d + b/2) / (4 c_s), with d the sleeper spacing and b the half
    width of the 2a x 2b area along the track (Mulliken & Karabalis 1998).
    The paper writes b; we take b as the half-width, as in its Eq. (6) notation.
    """
    b = width / 2.0
    return 3.0 * (spacing + b / 2.0) / (4.0 * cs)


def time_lag_coupling(soil: SoilParams) -> float:
    """Low-frequency delay due to d_c, Eq. (23) as printed [s].

    tau_c = -d_c (1/k_c - 1/(k_c + k_f)). As the model notes point out, this
    leaves out the lag from d_f, so it underestimates the delay the model
    produces (compare :func:`time_lag_transmissibility`).
    """
    if soil.kc <= 0:
        raise ParameterError(f"soil.kc = {soil.kc}: Eq. (23) needs k_c > 0")
    return -soil.dc * (1.0 / soil.kc - 1.0 / (soil.kc + soil.kf))


def time_lag_transmissibility(soil: SoilParams) -> float:
    """Low-frequency group delay of the two-area transmissibility, Eq. (22) [s].

    X2/X1 = (k_c + j w d_c) / ((k_f + k_c) - w^2 m_f + j w (d_f + d_c)); for
    w -> 0 its phase is -w tau with tau = (d_f + d_c)/(k_f + k_c) - d_c / k_c.
    This is Eq. (23) with the d_f term kept.
    """
    if soil.kc <= 0:
        raise ParameterError(f"soil.kc = {soil.kc}: the two-area delay needs k_c > 0")
    return (soil.df + soil.dc) / (soil.kf + soil.kc) - soil.dc / soil.kc


def layer_resonances(thickness: float, c: float, n_max: int = 3) -> NDArray[np.float64]:
    """Layer resonance frequencies, Eq. (26): f_n = (2n - 1) c / (4 h), n = 1..n_max [Hz].

    Parameters
    ----------
    thickness : float
        Layer thickness h [m] (the paper writes d).
    c : float
        Body-wave speed (c_p or c_s) of the layer [m/s].
    n_max : int
        Resonances returned (n = 1 .. n_max).
    """
    if thickness <= 0 or c <= 0:
        raise ParameterError(f"layer_resonances: thickness = {thickness}, c = {c}: both must be > 0")
    n = np.arange(1, n_max + 1)
    return np.asarray((2 * n - 1) * c / (4.0 * thickness), dtype=np.float64)
