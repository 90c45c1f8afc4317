"""Surface Green's functions: Lamb's problem, Boussinesq, layered identities, quadrature."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import special

from clm_core.errors import ParameterError
from clm_core.halfspace.bessel import j0_complex
from clm_core.halfspace.green import (
    KernelEngine,
    _halfspace_dynamic,
    asymptotic_coefficient,
    radial_kernel,
    surface_flexibility_k,
)
from clm_core.profile import Layer, SoilProfile

NU = 0.33
#: mu r u_z / P for a vertical point load on an elastic half-space, nu = 0.33, against
#: a = w r / c_s (Wong 1975, tabulated by Apsel 1979); the sign of the imaginary part is
#: that of the exp(+i w t) convention (displacement lags the force).
WONG = {
    0.5: 0.087 - 0.062j,
    1.0: 0.037 - 0.102j,
    2.0: -0.087 - 0.077j,
    3.0: -0.114 + 0.053j,
    4.0: -0.001 + 0.134j,
    5.0: 0.127 + 0.064j,
    5.5: 0.144 - 0.013j,
}


def unit_halfspace(nu: float = NU, beta: float = 0.0, xi: float = 0.0) -> SoilProfile:
    """mu = 1 Pa, rho = 1 kg/m^3 (c_s = 1 m/s)."""
    return SoilProfile((Layer(None, 2.0 * (1.0 + nu), 1.0, nu, beta=beta, xi=xi),))


@pytest.mark.parametrize("a", sorted(WONG))
def test_point_load_matches_wong_table(a: float) -> None:
    """mu r u_z / P within 0.003 of Wong's table (r = 1 m, w = a rad/s, c_s = 1 m/s)."""
    ker = radial_kernel(unit_halfspace(), a, 1.5, 0.005)
    val = complex(ker(np.array([1.0]))[0])
    assert abs(val - WONG[a]) < 0.003, (a, val)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"r_max": 0.0}, r"^r_max = 0 m: must be > 0$"),
        ({"dr": math.inf}, r"^dr = inf: must be finite"),
        ({"f_max": -5.0}, r"^f_max = -5 Hz: must be >= 0$"),
    ],
)
def test_kernel_engine_refuses_a_bad_grid(kwargs: dict[str, float], message: str) -> None:
    grid = {"r_max": 10.0, "dr": 0.5, "f_max": 50.0, **kwargs}
    with pytest.raises(ParameterError, match=message):
        KernelEngine(SoilProfile((Layer(None, 129e6, 1600.0, 0.3, beta=0.0004),)),
                     grid["r_max"], grid["dr"], grid["f_max"])


def test_point_load_static_is_boussinesq() -> None:
    """a = 0: mu r u_z / P = (1 - nu) / (2 pi) = 0.1066."""
    ker = radial_kernel(unit_halfspace(), 0.0, 2.0, 0.01)
    r = np.array([0.3, 1.0, 1.7])
    np.testing.assert_allclose((ker(r) * r).real, (1 - NU) / (2 * math.pi), rtol=1e-12)
    assert abs((1 - NU) / (2 * math.pi) - 0.106) < 0.001


def test_quadrature_converged() -> None:
    """Doubling the density of the wavenumber quadrature changes u_z by < 1e-6 (relative)."""
    prof = unit_halfspace(beta=0.01)
    r = np.array([0.2, 1.0, 3.0])
    a = radial_kernel(prof, 4.0, 3.5, 0.005)(r)
    b = radial_kernel(prof, 4.0, 3.5, 0.005, resolution=2.0)(r)
    c = radial_kernel(prof, 4.0, 3.5, 0.005, k_factor=24.0)(r)
    assert np.max(np.abs(a - b) / np.abs(b)) < 1e-6
    assert np.max(np.abs(a - c) / np.abs(c)) < 1e-4


def test_halfspace_stiffness_matrix_equals_lamb_closed_form() -> None:
    """The 2x2 half-space stiffness matrix gives the Rayleigh-function closed form."""
    prof = unit_halfspace(beta=0.02)
    k = np.linspace(0.05, 30.0, 17) + 0.2j
    om = 3.0
    K = _halfspace_dynamic(k, prof.top, om)
    rhs = np.zeros((k.size, 2, 1), dtype=complex)
    rhs[:, 1, 0] = 1.0
    u = np.linalg.solve(K, rhs)[:, 1, 0]
    np.testing.assert_allclose(u, surface_flexibility_k(prof, k, om), rtol=1e-11)


def test_large_k_expansion() -> None:
    """G(k) = (1 - nu)/(mu k) + A/k^3 + O(k^-5): the coefficient A is right."""
    prof = unit_halfspace(beta=0.01)
    om = 2.0
    k = np.array([200.0, 400.0]) + 0j
    _, mu = prof.top.lame(om)
    G = surface_flexibility_k(prof, k, om)
    A = asymptotic_coefficient(prof.top, om)
    ratio = (G - (1 - NU) / (mu * k)) * k**3 / A
    np.testing.assert_allclose(ratio, 1.0, atol=2e-4)


def test_layers_of_identical_material_equal_homogeneous() -> None:
    """A stack of identical layers over the same half-space = Lamb's problem (to 1e-6)."""
    lay = Layer(None, 129e6, 1600.0, 0.3, beta=0.0004)
    hom = SoilProfile((lay,))
    layered = SoilProfile(
        (Layer(0.7, lay.E, lay.rho, lay.nu, beta=lay.beta), Layer(2.1, lay.E, lay.rho, lay.nu, beta=lay.beta), lay)
    )
    k = np.concatenate([np.linspace(0.01, 60.0, 41) + 0.3j, np.linspace(0.5, 300.0, 31) + 0j])
    for om in (2 * math.pi * 5.0, 2 * math.pi * 80.0):
        np.testing.assert_allclose(surface_flexibility_k(layered, k, om), surface_flexibility_k(hom, k, om), rtol=1e-7)
    kr = np.linspace(0.01, 100.0, 50)
    np.testing.assert_allclose(surface_flexibility_k(layered, kr, 0.0), surface_flexibility_k(hom, kr, 0.0), rtol=1e-10)
    # space domain: the same quadrature for both (a layered profile extends the real tail to
    # 24 / h_1; k_factor = 60 puts the homogeneous truncation beyond that too)
    r = np.array([0.1, 0.6, 3.0, 6.0])
    for f in (0.0, 20.0, 60.0):
        om = 2 * math.pi * f
        u_h = KernelEngine(hom, 6.0, 0.03, max(f, 1.0), k_factor=60.0)(om)(r)
        u_l = KernelEngine(layered, 6.0, 0.03, max(f, 1.0), k_factor=60.0)(om)(r)
        assert np.max(np.abs(u_l - u_h) / np.abs(u_h)) < 1e-6, f


def test_static_layered_limit_of_small_frequency() -> None:
    """The static layer matrices are the w -> 0 limit of the dynamic ones."""
    prof = SoilProfile((Layer(1.5, 60e6, 1800.0, 0.25), Layer(None, 400e6, 1900.0, 0.35)))
    k = np.array([0.3, 1.0, 3.0, 10.0])
    Gs = surface_flexibility_k(prof, k, 0.0)
    Gd = surface_flexibility_k(prof, k + 0j, 2 * math.pi * 0.005)
    np.testing.assert_allclose(Gd, Gs, rtol=1e-5)
    # k -> infinity: the top layer alone (Boussinesq with its modulus)
    top = prof.top
    kk = np.array([200.0])
    np.testing.assert_allclose(surface_flexibility_k(prof, kk, 0.0), (1 - top.nu) / (top.G * kk), rtol=1e-10)


def test_damping_makes_the_response_lag() -> None:
    """exp(+i w t): with material damping the point response has Im < 0 at small a."""
    ker = radial_kernel(unit_halfspace(xi=0.05), 0.3, 1.5, 0.005)
    assert ker(np.array([1.0]))[0].imag < 0


def test_j0_complex_matches_scipy() -> None:
    rng = np.random.default_rng(1)
    z = np.concatenate(
        [
            rng.uniform(0, 40, 3000) + 1j * rng.uniform(0, 3, 3000),
            rng.uniform(0, 400, 3000) + 1j * rng.uniform(0, 1, 3000),
        ]
    )
    ref = special.jv(0, z)
    scale = np.maximum(np.abs(ref), np.exp(np.abs(z.imag)) / np.sqrt(np.abs(z) + 1.0))
    assert np.max(np.abs(j0_complex(z) - ref) / scale) < 1e-10
