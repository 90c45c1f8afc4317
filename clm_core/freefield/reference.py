"""Independent references for the free-field validation (docs/validation.md, tests/freefield).

Nothing here uses :mod:`clm_core.halfspace.green`:

- :func:`pekeris_step`: Pekeris' (1955) closed form of Lamb's problem, the
  surface vertical displacement under a vertical point load P H(t) on an
  elastic half-space with Poisson's ratio 1/4 (lambda = mu). With
  tau = c_s t / r, gamma^2 = (3 + sqrt 3)/4 (Rayleigh arrival,
  c_R = c_s / gamma) and kappa = (3 - sqrt 3)/4,

      u = P / (pi mu r) W(tau),   (downwards positive)

      W = 0                                                      tau < 1/sqrt 3
      W = (1/32) [6 - sqrt 3 / sqrt(tau^2 - 1/4)
                  - sqrt(3 sqrt 3 + 5) / sqrt(gamma^2 - tau^2)
                  + sqrt(3 sqrt 3 - 5) / sqrt(tau^2 - kappa)]    1/sqrt 3 < tau < 1
      W = (1/16) [6 - sqrt(3 sqrt 3 + 5) / sqrt(gamma^2 - tau^2)]   1 < tau < gamma
      W = 3/8                                                    tau > gamma

  (zero at the P arrival, continuous at the S arrival, the Rayleigh
  singularity at gamma, against the load, then at once the static
  Boussinesq value (1 - nu) / (2 pi mu r) = 3 / (8 pi mu r)). The sign of
  the branches between the P and the Rayleigh arrivals is checked by the
  Fourier transform of W against the frequency-domain Green's function
  (tests/freefield/test_validation_pekeris.py: agreement to ~1e-5).
  :func:`pekeris_step_integral` integrates W in time in closed form (the
  Rayleigh singularity is integrable), so that the response to a force
  history linear between samples is exact (:func:`pekeris_response`).
- :func:`lamb_flexibility`: the homogeneous half-space's vertical surface
  flexibility in the wavenumber domain (Rayleigh denominator), written anew.
- :func:`moving_load_velocity`: steady-state vertical surface velocity under
  a constant vertical point load moving at sub-Rayleigh speed along y = 0,
  by the double wavenumber integral

      v(xi, y) = (P / pi^2) Re int_0^inf dk_x (i k_x c) e^{-i k_x xi} B(k_x c)
                 int_0^inf dk_y cos(k_y y) G(sqrt(k_x^2 + k_y^2), k_x c),

  xi = x - c t the receiver's position relative to the load, B an optional
  band limit (the free-field model's filter, so that band-limited
  quantities are compared); the large-k term (1 - nu)/(mu* k) of G is
  integrated in closed form (int_0^inf cos(k_y y) / k dk_y = K_0(k_x |y|)).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike
from scipy import special

from clm_core.arrays import Array, CArray
from clm_core.errors import ParameterError
from clm_core.profile import Layer

__all__ = ["lamb_flexibility", "moving_load_velocity", "pekeris_response", "pekeris_step", "pekeris_step_integral"]

_S3 = math.sqrt(3.0)
_GAMMA2 = (3.0 + _S3) / 4.0
_GAMMA = math.sqrt(_GAMMA2)
_KAPPA = (3.0 - _S3) / 4.0
_A = math.sqrt(3.0 * _S3 + 5.0)
_B = math.sqrt(3.0 * _S3 - 5.0)
_TP = 1.0 / _S3


def pekeris_step(tau: ArrayLike) -> Array:
    """W(tau) of the module docstring: u = P W / (pi mu r) under a step point load (nu = 1/4) [-]."""
    t = np.asarray(tau, dtype=float)
    out = np.zeros_like(t)
    a = (t > _TP) & (t < 1.0)
    ta = t[a]
    out[a] = (6.0 - _S3 / np.sqrt(ta**2 - 0.25) - _A / np.sqrt(_GAMMA2 - ta**2) + _B / np.sqrt(ta**2 - _KAPPA)) / 32.0
    b = (t >= 1.0) & (t < _GAMMA)
    tb = t[b]
    out[b] = (6.0 - _A / np.sqrt(_GAMMA2 - tb**2)) / 16.0
    out[t > _GAMMA] = 3.0 / 8.0
    return out


def pekeris_step_integral(tau: ArrayLike) -> Array:
    """C(tau) = int_0^tau W(s) ds in closed form (antiderivatives ln(s + sqrt(s^2 - a)) and arcsin(s / gamma)) [-]."""
    t = np.asarray(tau, dtype=float)

    def lg(x: Array, a: float) -> Array:
        return np.asarray(np.log(x + np.sqrt(np.maximum(x * x - a, 0.0))), dtype=np.float64)

    def c1(x: Array) -> Array:  # int_{tau_P}^{x} of the P-S branch
        xp = np.full_like(x, _TP)
        return (6.0 * (x - xp) - _S3 * (lg(x, 0.25) - lg(xp, 0.25))
                 - _A * (np.arcsin(x / _GAMMA) - np.arcsin(xp / _GAMMA))
                 + _B * (lg(x, _KAPPA) - lg(xp, _KAPPA))) / 32.0

    one = np.ones(1)
    c_s = float(c1(one)[0])
    c_r = c_s + (6.0 * (_GAMMA - 1.0) - _A * (math.pi / 2 - math.asin(1.0 / _GAMMA))) / 16.0
    out = np.zeros_like(t)
    a = (t > _TP) & (t < 1.0)
    out[a] = c1(t[a])
    b = (t >= 1.0) & (t < _GAMMA)
    out[b] = c_s + (6.0 * (t[b] - 1.0) - _A * (np.arcsin(t[b] / _GAMMA) - math.asin(1.0 / _GAMMA))) / 16.0
    g = t >= _GAMMA
    out[g] = c_r + 3.0 / 8.0 * (t[g] - _GAMMA)
    return out


def pekeris_response(t: ArrayLike, force_t: ArrayLike, force: ArrayLike, r: float, cs: float, mu: float) -> Array:
    """Displacement [m] at distance ``r`` [m] under the force history ``force`` [N] (linear between samples).

    u(t) = P-weighted Stieltjes sum: sum over the force intervals of
    (dF_i / dt_i) int W over the interval, with C = :func:`pekeris_step_integral`;
    ``cs`` shear-wave speed [m/s], ``mu`` shear modulus [Pa].
    """
    tt = np.asarray(t, dtype=float)
    ft = np.asarray(force_t, dtype=float)
    F = np.asarray(force, dtype=float)
    if ft.shape != F.shape or ft.ndim != 1:
        raise ParameterError("force_t and force: need two 1-D arrays of the same length")
    slope = np.diff(F) / np.diff(ft)
    scale = cs / r
    lags = (tt[:, None] - ft[None, :]) * scale  # tau of each force sample seen from each output time
    C = pekeris_step_integral(np.maximum(lags, 0.0).ravel()).reshape(lags.shape) / scale
    # int over [ft_i, ft_{i+1}] of W(c_s (t - s) / r) ds = C(t - ft_i) - C(t - ft_{i+1})
    return np.asarray((C[:, :-1] - C[:, 1:]) @ slope / (math.pi * mu * r), dtype=np.float64)


def lamb_flexibility(layer: Layer, k: ArrayLike, omega: float) -> CArray:
    """Vertical surface flexibility of a homogeneous half-space [m^3/N] at real wavenumbers ``k`` > 0 [1/m].

    G = ks^2 alpha / (mu* [4 k^2 alpha beta - (2 k^2 - ks^2)^2]), alpha = sqrt(k^2 - kp^2), beta = sqrt(k^2 - ks^2)
    (Re >= 0), with the complex moduli of ``layer`` at ``omega`` [rad/s] >= 0; time dependence exp(+i w t).
    """
    kk = np.asarray(k, dtype=float)
    f = complex(1.0, omega * layer.beta + 2.0 * layer.xi)
    mu = layer.G * f
    M = layer.M * f
    if omega == 0.0:
        return np.asarray((1.0 - layer.nu) / (mu * kk) + 0j, dtype=np.complex128)
    kp2 = layer.rho * omega**2 / M
    ks2 = layer.rho * omega**2 / mu

    def root(x: CArray) -> CArray:
        s = np.sqrt(x.astype(np.complex128))
        return np.where(s.real < 0, -s, s)

    al = root(kk * kk - kp2)
    be = root(kk * kk - ks2)
    return np.asarray(ks2 * al / (mu * (4 * kk * kk * al * be - (2 * kk * kk - ks2) ** 2)), dtype=np.complex128)


def moving_load_velocity(
    layer: Layer, speed: float, xi: ArrayLike, y: float, load: float = 1.0,
    band: Callable[[Array], CArray] | None = None, k_max: float | None = None,
    n_kx: int = 1200, n_ky: int = 4000, ky_max: float | None = None,
) -> Array:
    """Steady-state vertical surface velocity [m/s] under a point load ``load`` [N] moving at ``speed`` [m/s].

    Parameters
    ----------
    layer : Layer
        Homogeneous half-space (damped: ``beta`` or ``xi`` > 0 keeps the kernel smooth).
    speed : float
        Load speed c [m/s], below the Rayleigh speed.
    xi : array_like
        Receiver position minus load position along the track [m].
    y : float
        Receiver distance from the load's line [m], > 0.
    load : float
        Magnitude of the moving point load [N] (default 1 N: the response per newton).
    band : callable, optional
        Band limit B(f) applied at the frequency f = k_x c / (2 pi) [Hz].
    k_max : float, optional
        Upper k_x [1/m] (default: where e^{-k_x y} < 1e-12, at most 60 / y).
    n_kx, n_ky : int
        Gauss–Legendre points in k_x and k_y.
    ky_max : float, optional
        Upper k_y of the remainder integral [1/m] (default max(40 / y, 10 ks at the top frequency)).
    """
    cr_bound = 0.87 * layer.cs
    if not 0.0 < speed < cr_bound:
        raise ParameterError(f"speed = {speed:g} m/s: must lie in (0, {cr_bound:.1f}) m/s (sub-Rayleigh)")
    if y <= 0:
        raise ParameterError(f"y = {y:g} m: must be > 0")
    kx_top = k_max if k_max is not None else min(60.0 / y, 28.0 / y)
    xg, wg = np.polynomial.legendre.leggauss(n_kx)
    # cluster the k_x points near 0 (log singularity of K_0) with s -> k = kx_top s^2
    s = 0.5 * (xg + 1.0)
    kx = kx_top * s * s
    wkx = wg * 0.5 * 2.0 * kx_top * s
    ky_top = ky_max if ky_max is not None else max(40.0 / y, 10.0 * kx_top * speed / layer.cs)
    yg, wy = np.polynomial.legendre.leggauss(n_ky)
    ky = 0.5 * ky_top * (yg + 1.0)
    wky = 0.5 * ky_top * wy
    inner = np.zeros(kx.size, dtype=np.complex128)
    f = complex(1.0, 0.0)
    for i, kxi in enumerate(kx):
        w = kxi * speed
        f = complex(1.0, w * layer.beta + 2.0 * layer.xi)
        mu = layer.G * f
        k = np.sqrt(kxi * kxi + ky * ky)
        rem = lamb_flexibility(layer, k, w) - (1.0 - layer.nu) / (mu * k)
        inner[i] = (1.0 - layer.nu) / mu * special.k0(kxi * y) + np.sum(wky * np.cos(ky * y) * rem)
    weight = 1j * kx * speed * inner * wkx
    if band is not None:
        weight = weight * band(kx * speed / (2.0 * math.pi))
    x = np.asarray(xi, dtype=float)
    phase = np.exp(-1j * np.outer(x.ravel(), kx))
    v = load / math.pi**2 * np.real(phase @ weight)
    return np.asarray(v.reshape(x.shape), dtype=np.float64)
