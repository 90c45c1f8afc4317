"""Layered soil: the layer resonance of Eq. (26)."""

from __future__ import annotations

import numpy as np

from clm_core.halfspace.bem import disk_impedance
from clm_core.profile import Layer, SoilProfile

NU = 1.0 / 3.0
RHO = 1800.0
H = 2.0  # layer thickness [m]


def _layer(cs: float, thickness: float | None) -> Layer:
    return Layer(thickness, 2.0 * (1.0 + NU) * RHO * cs**2, RHO, NU, xi=0.02)


def test_soft_layer_over_stiff_halfspace_resonates_between_cs_4h_and_cp_4h() -> None:
    """Which configuration resonates, and where.

    Waves are trapped only in a layer that is SOFTER than what lies below it: its
    lower boundary then reflects most of the energy back, so below the layer's
    vertical cut-off little energy radiates (small Im K / w) and the vertical
    compliance peaks near the layer frequency of Eq. (26), f = c / (4 h). For a
    vertical load the relevant speed lies between c_s and c_p (Lysmer's analogue
    speed 3.4 c_s / (pi (1 - nu)) = 1.62 c_s here; Gazetas 1991), so the peak must
    lie in [c_s / (4 h), c_p / (4 h)] = [12.5, 25] Hz for c_s = 100 m/s, c_p = 200 m/s,
    h = 2 m. A STIFF layer over a SOFT half-space transmits the energy downwards
    (impedance ratio < 1 at its base): no trapped resonance, the compliance just
    decreases with frequency. That is what the paper's Eq. (26) is about (the
    Haren site, Table 4, with stiffness increasing with depth).
    """
    soft_on_stiff = SoilProfile((_layer(100.0, H), _layer(400.0, None)))
    stiff_on_soft = SoilProfile((_layer(400.0, H), _layer(100.0, None)))
    homogeneous = SoilProfile((_layer(100.0, None),))
    f = np.arange(2.0, 34.0, 2.0)
    K1 = disk_impedance(soft_on_stiff, 0.5, f, n_rings=6)
    K2 = disk_impedance(stiff_on_soft, 0.5, f, n_rings=6)
    K0 = disk_impedance(homogeneous, 0.5, f, n_rings=6)
    C1 = np.abs(1.0 / K1)
    C2 = np.abs(1.0 / K2)
    f_s, f_p = 100.0 / (4 * H), 200.0 / (4 * H)
    peak = f[np.argmax(C1)]
    assert f_s <= peak <= f_p, peak
    assert C1.max() > 1.5 * C1[0]
    # radiation damping suppressed below the cut-off (c_s / (4 h) = 12.5 Hz): the radiated part
    # of Im K (Im K - 2 xi Re K, the rest is the hysteretic material damping) is much smaller
    # than on the homogeneous half-space of the layer material
    below = (f >= 4.0) & (f <= 10.0)
    rad1 = K1.imag - 0.04 * K1.real
    rad0 = K0.imag - 0.04 * K0.real
    assert np.all(rad1[below] < 0.35 * rad0[below])
    # stiff over soft: no peak, the compliance decreases monotonically
    assert np.all(np.diff(C2) < 0)
