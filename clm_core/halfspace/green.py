"""Surface Green's functions of a layered viscoelastic half-space (vertical load).

Conventions
-----------
- Time dependence exp(+i w t); a dashpot has impedance +i w d; outgoing
  waves behave as exp(i (w t - k r)) and the wavenumbers of a damped medium
  have a negative imaginary part (poles and branch points lie in the fourth
  quadrant of the complex k plane).
- z downwards, vertical load and displacement positive downwards (a
  downward load P > 0 gives u_z > 0 at the static limit).
- Material damping through complex Lamé constants (see
  :mod:`clm_core.profile`).

Method
------
Wavenumber domain: a vertical surface traction q(x) = q e^{-i k x} (plane
strain; the same function serves the axisymmetric problem) gives the surface
displacement u_z = G(k, w) q. G is obtained from the P-SV dynamic stiffness
matrices of the layers and of the half-space (Kausel & Roesset 1981,
"Stiffness matrices for layered soils", BSSA 71(6)); the layer matrices are
built from normalised exponentials (down-going waves referred to the top of
the layer, up-going ones to its bottom), so no entry grows with k h. For a
homogeneous half-space (Lamb's problem)

    G(k) = ks^2 alpha / (mu [4 k^2 alpha beta - (2 k^2 - ks^2)^2]),

alpha = sqrt(k^2 - kp^2), beta = sqrt(k^2 - ks^2), Re >= 0. At w = 0 the
static layer matrices (solutions (a + b z) e^{-+k z}) are used instead.

Space domain: a vertical point load P at the surface gives

    u_z(r) = P / (2 pi) int_0^inf G(k) J0(k r) k dk.

The integral is evaluated as

    u_z(r) / P = c0 / r + g_s(r),   c0 = (1 - nu_1) / (2 pi mu_1*)

(c0 / r: Boussinesq with the complex modulus of the top layer, the k -> inf
limit G ~ (1 - nu_1)/(mu_1 k)), where the smooth remainder g_s(r) is

    g_s(r) = A e^{-s r} / (2 pi s) + 1/(2 pi) int_0^inf R(k) J0(k r) k dk,

A / (k^2 + s^2)^{3/2} being the next term of the large-k expansion of G
(A = (1 - nu_1) c ks_1^2 / mu_1, c from the Rayleigh function, see
:func:`asymptotic_coefficient`) and R = G - (1-nu_1)/(mu_1 k) - A/(k^2+s^2)^{3/2}
= O(k^-5). The remaining integral runs on a half-ellipse in the first
quadrant from k = 0 to k = K_e (beyond all poles and branch points, which
lie in the fourth quadrant or on the real axis for an elastic medium, so the
path is valid for any material damping including none), then along the
real axis to K_max (composite Gauss–Legendre). The ellipse height is kept
below 2.5 / r_max so that the growth of J0 off the real axis (e^{|Im k| r})
costs at most a factor ~ 12 in cancellation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import sparse, special

from clm_core.arrays import Array, CArray
from clm_core.checks import nonnegative, positive
from clm_core.errors import ParameterError
from clm_core.halfspace.bessel import j0_matvec, j0_outer
from clm_core.profile import Layer, SoilProfile

__all__ = [
    "KernelEngine",
    "RadialKernel",
    "asymptotic_coefficient",
    "default_k_max",
    "point_load_displacement",
    "radial_kernel",
    "surface_flexibility_k",
]


_GL_N = 10
_GL_X, _GL_W = np.polynomial.legendre.leggauss(_GL_N)


# ----------------------------------------------------------------------------
# wavenumber domain
# ----------------------------------------------------------------------------


def _wavenumbers(layer: Layer, omega: float) -> tuple[complex, complex, complex, complex]:
    lam, mu = layer.lame(omega)
    kp2 = layer.rho * omega**2 / (lam + 2.0 * mu)
    ks2 = layer.rho * omega**2 / mu
    return lam, mu, kp2, ks2


def _sqrt_branch(x: CArray) -> CArray:
    """sqrt with Re >= 0 (decaying in depth); on the cut the +i root (outgoing for exp(+i w t))."""
    s = np.sqrt(x)
    flip = (s.real < 0.0) | ((s.real == 0.0) & (s.imag < 0.0))
    return np.where(flip, -s, s)


def _layer_dynamic(k: CArray, layer: Layer, omega: float) -> CArray:
    """Dynamic stiffness of a finite layer, shape (nk, 4, 4), DOFs (u_x, u_z)_top, (u_x, u_z)_bottom."""
    assert layer.thickness is not None
    h = layer.thickness
    _, mu, kp2, ks2 = _wavenumbers(layer, omega)
    al = _sqrt_branch(k * k - kp2)
    be = _sqrt_branch(k * k - ks2)
    ea = np.exp(-al * h)
    eb = np.exp(-be * h)
    t = 2.0 * k * k - ks2
    nk = k.shape[0]
    ik = 1j * k
    # columns: down P (e^{-al z}), down S (e^{-be z}), up P (e^{al (z-h)}), up S (e^{be (z-h)})
    # at z = 0 factors (1, 1, ea, eb); at z = h factors (ea, eb, 1, 1)
    ux = np.stack([-ik, be, -ik, -be], axis=-1)
    uz = np.stack([-al, -ik, al, -ik], axis=-1)
    sxz = mu * np.stack([2.0 * ik * al, -t, -2.0 * ik * al, -t], axis=-1)
    szz = mu * np.stack([t + 0.0 * k, 2.0 * ik * be, t + 0.0 * k, -2.0 * ik * be], axis=-1)
    ftop = np.stack([np.ones(nk), np.ones(nk), ea, eb], axis=-1)
    fbot = np.stack([ea, eb, np.ones(nk), np.ones(nk)], axis=-1)
    D = np.stack([ux * ftop, uz * ftop, ux * fbot, uz * fbot], axis=1)
    S = np.stack([-sxz * ftop, -szz * ftop, sxz * fbot, szz * fbot], axis=1)
    # K = S D^{-1}  <=>  K^T = D^{-T} S^T
    KT = np.linalg.solve(np.swapaxes(D, 1, 2), np.swapaxes(S, 1, 2))
    return np.swapaxes(KT, 1, 2)


def _halfspace_dynamic(k: CArray, layer: Layer, omega: float) -> CArray:
    """Dynamic stiffness of the half-space, shape (nk, 2, 2), DOFs (u_x, u_z) at its top."""
    _, mu, kp2, ks2 = _wavenumbers(layer, omega)
    al = _sqrt_branch(k * k - kp2)
    be = _sqrt_branch(k * k - ks2)
    t = 2.0 * k * k - ks2
    ik = 1j * k
    D = np.stack([np.stack([-ik, be], -1), np.stack([-al, -ik], -1)], axis=1)
    S = np.stack([np.stack([-mu * 2.0 * ik * al, mu * t], -1), np.stack([-mu * t, -mu * 2.0 * ik * be], -1)], axis=1)
    KT = np.linalg.solve(np.swapaxes(D, 1, 2), np.swapaxes(S, 1, 2))
    return np.swapaxes(KT, 1, 2)


def _static_basis(k: Array, layer: Layer, z: float, ref_top: bool, h: float) -> tuple[CArray, ...]:
    """Static solution basis at depth z: returns (ux, uz, sxz, szz), each (nk, 4) (or (nk, 2))."""
    lam, mu = layer.lame(0.0)
    M = lam + 2.0 * mu
    kap = (lam + 3.0 * mu) / (lam + mu)
    ik = 1j * k
    cols_ux = []
    cols_uz = []
    cols_sxz = []
    cols_szz = []
    # decaying, referred to the top (z = 0)
    e = np.exp(-k * z)
    cols_ux += [1j * e, ik * z * e]
    cols_uz += [e, (kap + k * z) * e]
    cols_sxz += [-2.0 * mu * ik * e, mu * ik * (1.0 - kap - 2.0 * k * z) * e]
    cols_szz += [-2.0 * mu * k * e, k * (M * (1.0 - kap) - 2.0 * mu * k * z) * e]
    if not ref_top:
        zeta = z - h
        g = np.exp(k * zeta)
        cols_ux += [1j * g, -ik * zeta * g]
        cols_uz += [-g, (-kap + k * zeta) * g]
        cols_sxz += [2.0 * mu * ik * g, -mu * ik * (1.0 - kap + 2.0 * k * zeta) * g]
        cols_szz += [-2.0 * mu * k * g, k * (M * (1.0 - kap) + 2.0 * mu * k * zeta) * g]
    return tuple(np.stack(c, axis=-1).astype(np.complex128) for c in (cols_ux, cols_uz, cols_sxz, cols_szz))


def _layer_static(k: Array, layer: Layer) -> CArray:
    assert layer.thickness is not None
    h = layer.thickness
    ux0, uz0, sx0, sz0 = _static_basis(k, layer, 0.0, False, h)
    uxh, uzh, sxh, szh = _static_basis(k, layer, h, False, h)
    D = np.stack([ux0, uz0, uxh, uzh], axis=1)
    S = np.stack([-sx0, -sz0, sxh, szh], axis=1)
    KT = np.linalg.solve(np.swapaxes(D, 1, 2), np.swapaxes(S, 1, 2))
    return np.swapaxes(KT, 1, 2)


def _halfspace_static(k: Array, layer: Layer) -> CArray:
    ux0, uz0, sx0, sz0 = _static_basis(k, layer, 0.0, True, 0.0)
    D = np.stack([ux0, uz0], axis=1)
    S = np.stack([-sx0, -sz0], axis=1)
    KT = np.linalg.solve(np.swapaxes(D, 1, 2), np.swapaxes(S, 1, 2))
    return np.swapaxes(KT, 1, 2)


def surface_flexibility_k(
    profile: SoilProfile, k: NDArray[np.complex128] | NDArray[np.float64], omega: float
) -> CArray:
    """Vertical surface flexibility G(k, w) of the layered half-space [m^3/N · 1/m^2 = m/N per (N/m^2) ...].

    u_z(k) = G(k, w) q_z(k) for a vertical surface traction q_z e^{-i k x}
    [N/m^2] giving a surface displacement [m]: G has units m^3/N.

    Parameters
    ----------
    profile : SoilProfile
        The layered half-space.
    k : array_like
        Horizontal wavenumbers [1/m]: complex on the first quadrant, or
        real > 0 (for ``omega = 0`` real > 0 only).
    omega : float
        Circular frequency [rad/s], >= 0.

    Returns
    -------
    ndarray of complex, shape of ``k``
        G(k, w) [m^3/N], positive real at the static limit.
    """
    kk = np.atleast_1d(np.asarray(k)).ravel()
    if omega < 0:
        raise ParameterError(f"omega = {omega}: must be >= 0")
    if omega == 0.0:
        if np.any(np.abs(np.imag(kk)) > 0) or np.any(np.real(kk) <= 0):
            raise ParameterError("static flexibility: wavenumbers must be real and > 0")
        kr = np.real(kk).astype(np.float64)
        if profile.is_homogeneous:
            lay = profile.top
            _, mu = lay.lame(0.0)
            out = (1.0 - lay.nu) / (mu * kr) + 0j
            return np.asarray(out, dtype=np.complex128).reshape(np.shape(k))
        blocks = [_layer_static(kr, lay) for lay in profile.layers[:-1]]
        hs = _halfspace_static(kr, profile.halfspace)
    else:
        kc = kk.astype(np.complex128)
        if profile.is_homogeneous:
            lay = profile.top
            _, mu, kp2, ks2 = _wavenumbers(lay, omega)
            al = _sqrt_branch(kc * kc - kp2)
            be = _sqrt_branch(kc * kc - ks2)
            t = 2.0 * kc * kc - ks2
            out = ks2 * al / (mu * (4.0 * kc * kc * al * be - t * t))
            return np.asarray(out, dtype=np.complex128).reshape(np.shape(k))
        blocks = [_layer_dynamic(kc, lay, omega) for lay in profile.layers[:-1]]
        hs = _halfspace_dynamic(kc, profile.halfspace, omega)
    nk = kk.shape[0]
    nl = len(blocks)
    n = 2 * (nl + 1)
    K = np.zeros((nk, n, n), dtype=np.complex128)
    for i, B in enumerate(blocks):
        K[:, 2 * i : 2 * i + 4, 2 * i : 2 * i + 4] += B
    K[:, n - 2 :, n - 2 :] += hs
    rhs = np.zeros((nk, n, 1), dtype=np.complex128)
    rhs[:, 1, 0] = 1.0
    u = np.linalg.solve(K, rhs)
    return np.asarray(u[:, 1, 0], dtype=np.complex128).reshape(np.shape(k))


def asymptotic_coefficient(layer: Layer, omega: float) -> complex:
    """Coefficient A of the second term of the large-k expansion of G [m^3/N · 1/m^2].

    G(k) = (1 - nu)/(mu k) + A / k^3 + O(k^-5) with
    A = (1 - nu) ks^2 / mu [1 / (2 (1 - g)) + (1 - g)/4 - g/2],  g = kp^2 / ks^2
    (expansion of the Rayleigh function for k >> ks).
    """
    lam, mu, kp2, ks2 = _wavenumbers(layer, omega)
    if omega == 0.0:
        return 0.0j
    g = kp2 / ks2
    c = 1.0 / (2.0 * (1.0 - g)) + (1.0 - g) / 4.0 - g / 2.0
    return complex((1.0 - layer.nu) * ks2 / mu * c)


# ----------------------------------------------------------------------------
# quadrature helpers
# ----------------------------------------------------------------------------


def _gl_panels(a: float, b: float, n_panels: int) -> tuple[Array, Array]:
    """Composite 10-point Gauss–Legendre nodes and weights on [a, b] with equal panels."""
    edges = np.linspace(a, b, n_panels + 1)
    half = 0.5 * np.diff(edges)
    mid = 0.5 * (edges[1:] + edges[:-1])
    x = (mid[:, None] + half[:, None] * _GL_X[None, :]).ravel()
    w = (half[:, None] * _GL_W[None, :]).ravel()
    return x, w


# ----------------------------------------------------------------------------
# space domain
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class RadialKernel:
    """Surface vertical displacement per unit vertical point load, u_z(r)/P [m/N].

    u_z(r) / P = c0 / r + g_s(r), with g_s given on a uniform radial grid
    and evaluated by 4-point Lagrange interpolation.

    Attributes
    ----------
    omega : float
        Circular frequency [rad/s].
    c0 : complex
        Coefficient of the Boussinesq term (1 - nu_1) / (2 pi mu_1*) [m^2/N · 1/m = m/N · m].
    r : ndarray
        Uniform radial grid [m], r[0] = 0.
    gs : ndarray of complex
        Smooth remainder g_s on the grid [m/N].
    """

    omega: float
    c0: complex
    r: Array
    gs: CArray

    def smooth(self, rq: NDArray[np.float64]) -> CArray:
        """The smooth part g_s at radii ``rq`` [m] (0 <= rq <= r[-1])."""
        W = lagrange_weights(self.r, np.asarray(rq, dtype=float).ravel())
        return np.asarray(W @ self.gs, dtype=np.complex128).reshape(np.shape(rq))

    def __call__(self, rq: NDArray[np.float64]) -> CArray:
        """u_z(r)/P at radii ``rq`` > 0 [m/N]."""
        rq = np.asarray(rq, dtype=float)
        return np.asarray(self.c0 / rq + self.smooth(rq), dtype=np.complex128)


def lagrange_weights(grid: Array, rq: Array) -> sparse.csr_matrix:
    """Sparse matrix (len(rq), len(grid)) of 4-point Lagrange interpolation weights on a uniform grid.

    The stencil is clamped at both ends (one-sided near r = 0, so that the
    cone term ~ r of the Green's function is reproduced exactly).
    """

    n = grid.shape[0]
    dr = grid[1] - grid[0]
    u = (rq - grid[0]) / dr
    if np.any(u < -1e-9) or np.any(u > n - 1 + 1e-9):
        raise ParameterError(f"interpolation radius outside [0, {grid[-1]:.4g}] m: max {rq.max():.4g} m")
    i0 = np.clip(np.floor(u).astype(np.int64) - 1, 0, n - 4)
    rows = np.repeat(np.arange(rq.shape[0]), 4)
    cols = (i0[:, None] + np.arange(4)[None, :]).ravel()
    x = u[:, None] - (i0[:, None] + np.arange(4)[None, :])
    w = np.empty_like(x)
    nodes = np.arange(4)
    for j in range(4):
        wj = np.ones(x.shape[0])
        for m in range(4):
            if m != j:
                wj = wj * (x[:, 0] - nodes[m]) / (nodes[j] - nodes[m])
        w[:, j] = wj
    return sparse.csr_matrix((w.ravel(), (rows, cols)), shape=(rq.shape[0], n))


def default_k_max(profile: SoilProfile, omega: float, r_max: float, factor: float = 12.0) -> float:
    """Truncation of the real tail of the wavenumber integral [1/m].

    max(factor |ks|_max, 1.5 K_e, 24 / h_1, 20 / r_max): the remainder R(k)
    decays as k^-5 beyond the shear wavenumbers (relative truncation error
    ~ (ks / k_max)^3 / 3) and the static layer terms as exp(-2 k h_1).
    """
    ks_max = omega / profile.min_cs
    k_max = max(factor * ks_max, 2.25 * ks_max, 20.0 / r_max)
    h1 = profile.first_interface_depth
    if h1 is not None:
        k_max = max(k_max, 24.0 / h1)
    return k_max


class KernelEngine:
    """Radial Green's functions of one profile on a fixed radial grid, for many frequencies.

    The real-axis tail of the wavenumber integral uses a fixed,
    frequency-independent Gauss–Legendre panel grid (panel length
    min(2 pi / r_max, 4 / h_1), 10 points), whose J0(k r) table is computed
    once; per frequency only the half-ellipse (complex k, from 0 to the
    first panel edge beyond 1.5 |ks|_max, panels no longer than 2.5 times
    its height, than the real panels and than 1/6 of 1.5 |ks|_max) is
    evaluated anew. This is what makes a 151-frequency sweep cheap.

    Parameters
    ----------
    profile : SoilProfile
        Soil.
    r_max : float
        Largest radius needed [m].
    dr : float
        Radial grid step [m] (<= lambda_R,min / 16 at the highest frequency).
    f_max : float
        Highest frequency [Hz] (sets the extent of the fixed k grid).
    resolution : float
        Multiplies the density of the k quadrature (convergence checks).
    k_factor : float
        k_max = k_factor |ks|_max (see :func:`default_k_max`).
    """

    def __init__(
        self,
        profile: SoilProfile,
        r_max: float,
        dr: float,
        f_max: float,
        *,
        resolution: float = 1.0,
        k_factor: float = 12.0,
    ) -> None:
        r_max, dr = positive("r_max", r_max, unit="m"), positive("dr", dr, unit="m")
        f_max = nonnegative("f_max", f_max, unit="Hz")
        self.profile = profile
        self.dr = float(dr)
        n = int(math.ceil(r_max / dr)) + 4
        self.r: Array = np.arange(n, dtype=np.float64) * self.dr
        self.r_top = float(self.r[-1])
        self.resolution = resolution
        self.k_factor = k_factor
        panel = 2.0 * math.pi / self.r_top
        h1 = profile.first_interface_depth
        if h1 is not None:
            panel = min(panel, 4.0 / h1)
        self.panel = panel / resolution
        self.f_max = f_max
        k_top = default_k_max(profile, 2.0 * math.pi * f_max, self.r_top, k_factor)
        self.n_panels = int(math.ceil(k_top / self.panel)) + 1
        edges = np.arange(self.n_panels + 1) * self.panel
        self.edges = edges
        x, w = _gl_panels(0.0, float(edges[-1]), self.n_panels)
        self.k_real = x
        self.w_real = w
        self._J0_real: Array | None = None
        self._ellipse_cache: tuple[int, CArray, CArray, CArray] | None = None

    @property
    def J0_real(self) -> Array:
        """J0(k r) on the fixed real grid, shape (n_r, n_k) (computed on first use)."""
        if self._J0_real is None:
            self._J0_real = np.asarray(special.j0(np.outer(self.r, self.k_real)), dtype=np.float64)
        return self._J0_real

    def _ellipse_shape(self, omega: float) -> tuple[int, float, float]:
        """(first real panel p_start, height, panel length) of the half-ellipse at ``omega`` > 0 [rad/s]."""
        ks_max = omega / self.profile.min_cs
        k_max = default_k_max(self.profile, omega, self.r_top, self.k_factor)
        p_end = min(self.n_panels, int(math.ceil(k_max / self.panel)))
        p_start = max(min(int(math.ceil(1.5 * ks_max / self.panel)), p_end - 1), 1)
        k_nom = 1.5 * ks_max
        s = 2.0 * omega / self.profile.top.cs
        height = min(0.25 * k_nom, 2.5 / self.r_top, 0.5 * s)
        panel_len = min(2.5 * height, self.panel * self.resolution, k_nom / 6.0) / self.resolution
        return p_start, height, panel_len

    def _ellipse(self, p_start: int, height: float, panel_len: float) -> tuple[CArray, CArray]:
        """Nodes k and weights dk of the half-ellipse from 0 to the panel edge ``p_start`` (composite Gauss)."""
        k_e = float(self.edges[p_start])
        arc = 0.5 * math.pi * math.sqrt(0.5 * ((0.5 * k_e) ** 2 + height**2)) * 2.0
        n_ell = max(6, math.ceil(arc / panel_len))
        t, wt = _gl_panels(0.0, 1.0, n_ell)
        ke = k_e * 0.5 * (1.0 - np.cos(math.pi * t)) + 1j * height * np.sin(math.pi * t)
        dk = k_e * 0.5 * math.pi * np.sin(math.pi * t) + 1j * height * math.pi * np.cos(math.pi * t)
        return np.asarray(ke, dtype=np.complex128), np.asarray(wt * dk, dtype=np.complex128)

    def _contour(self, omega: float) -> tuple[int, CArray, CArray, CArray | None]:
        """The complex part of the path at ``omega`` > 0: (p_start, k, weights, J0(k r) table or None).

        Every frequency whose ellipse has the height and panel length of the
        top frequency's (in practice all but the lowest few hertz) integrates
        on the top frequency's ellipse (it reaches beyond their poles too,
        lies below their branch points i s, and is resolved as finely), so its
        J0(k r) table is computed once (:attr:`ellipse_table`) and each such
        frequency costs one matrix-vector product; the others get their own
        (short) ellipse, summed by :func:`~clm_core.halfspace.bessel.j0_matvec`.
        """
        shape = self._ellipse_shape(omega)
        top = self._ellipse_shape(2.0 * math.pi * self.f_max) if self.f_max > 0 else None
        if top is not None and math.isclose(shape[1], top[1], rel_tol=1e-12) and \
                math.isclose(shape[2], top[2], rel_tol=1e-12):
            if self._ellipse_cache is None:
                ke, w = self._ellipse(*top)
                self._ellipse_cache = (top[0], ke, w, j0_outer(self.r, ke))
            return self._ellipse_cache
        ke, w = self._ellipse(*shape)
        return shape[0], ke, w, None

    def __call__(self, omega: float) -> RadialKernel:
        """The radial kernel u_z(r)/P at circular frequency ``omega`` [rad/s]."""
        profile = self.profile
        if omega < 0 or omega > 2.0 * math.pi * self.f_max * (1 + 1e-9) + 1e-12:
            raise ParameterError(f"omega = {omega:g} rad/s: must lie in [0, 2 pi f_max = {2 * math.pi * self.f_max:g}]")
        top = profile.top
        _, mu1 = top.lame(omega)
        c0 = complex((1.0 - top.nu) / (2.0 * math.pi * mu1))
        n = self.r.size
        gs = np.zeros(n, dtype=np.complex128)
        if omega == 0.0 and profile.is_homogeneous:
            return RadialKernel(omega=omega, c0=c0, r=self.r, gs=gs)
        k_max = default_k_max(profile, omega, self.r_top, self.k_factor)
        p_end = min(self.n_panels, int(math.ceil(k_max / self.panel)))
        A = asymptotic_coefficient(top, omega)
        s = 2.0 * omega / top.cs
        if omega == 0.0:
            p_start = 0
        else:
            p_start, ke, wdk, Jell = self._contour(omega)
            G = surface_flexibility_k(profile, ke, omega)
            R = G - (1.0 - top.nu) / (mu1 * ke) - A / (ke**2 + s**2) ** 1.5
            f_ell = R * ke * wdk / (2.0 * math.pi)
            gs += (Jell @ f_ell) if Jell is not None else j0_matvec(self.r, ke, f_ell)
            p_end = max(p_end, p_start + 1)
        sl = slice(p_start * _GL_N, p_end * _GL_N)
        kr = self.k_real[sl]
        if kr.size:
            G = surface_flexibility_k(profile, kr, omega)
            R = G - (1.0 - top.nu) / (mu1 * kr)
            if omega > 0:
                R = R - A / (kr**2 + s**2) ** 1.5
            f = R * kr * self.w_real[sl] / (2.0 * math.pi)
            J = self.J0_real[:, sl]
            gs += J @ f.real + 1j * (J @ f.imag)
        if omega > 0:
            gs += A * np.exp(-s * self.r) / (2.0 * math.pi * s)
        return RadialKernel(omega=omega, c0=c0, r=self.r, gs=gs)


def radial_kernel(
    profile: SoilProfile,
    omega: float,
    r_max: float,
    dr: float,
    *,
    resolution: float = 1.0,
    k_factor: float = 12.0,
) -> RadialKernel:
    """Point-load surface Green's function on a radial grid (one frequency), see the module docstring.

    Parameters
    ----------
    profile : SoilProfile
        Soil.
    omega : float
        Circular frequency [rad/s], >= 0.
    r_max : float
        Largest radius needed [m] (the grid extends 3 steps beyond).
    dr : float
        Grid step [m]; the smooth part varies on the scale of the shortest
        wavelength and of the top layer thickness: dr <= lambda_R,min / 16.
    resolution, k_factor
        See :class:`KernelEngine`.
    """
    eng = KernelEngine(profile, r_max, dr, omega / (2.0 * math.pi), resolution=resolution, k_factor=k_factor)
    return eng(omega)


def point_load_displacement(
    profile: SoilProfile,
    r: NDArray[np.float64],
    omega: float,
    **kwargs: float,
) -> CArray:
    """Surface vertical displacement per unit vertical point load, u_z(r)/P [m/N].

    Parameters
    ----------
    profile : SoilProfile
        Soil.
    r : array_like
        Radii > 0 [m].
    omega : float
        Circular frequency [rad/s].
    **kwargs
        ``dr`` (grid step, default min(r_max/400, lambda_min/30)) and the
        options of :class:`KernelEngine` (``resolution``, ``k_factor``).
    """
    rr = np.asarray(r, dtype=float)
    r_max = float(rr.max())
    lam_min = 2.0 * math.pi * profile.min_cs / omega if omega > 0 else math.inf
    dr = float(kwargs.pop("dr", min(r_max / 400.0, lam_min / 30.0)))
    ker = radial_kernel(profile, omega, r_max, dr, **kwargs)
    return ker(rr)
