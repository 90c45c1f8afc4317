"""Soil formulas and the CLM chain alone (paper Sec. 3-4)."""

import numpy as np
import pytest

from clm_core.params import SoilParams, load_soil
from clm_core.profile import load_profile
from clm_core.soil.chain import chain_frequency_response, chain_sums, chain_time_response
from clm_core.soil.formulas import (
    alternating_sum_impedance,
    layer_resonances,
    lysmer_from_soil,
    resonance_frequency,
    static_stiffness_circle,
    static_stiffness_rectangle,
    time_lag_coupling,
    time_lag_mulliken,
    time_lag_transmissibility,
    total_sum_impedance,
)

F = np.array([0.0, 5.0, 10.0, 50.0, 100.0, 150.0])


@pytest.mark.parametrize("name", ["mevergnies", "soft", "medium", "stiff", "haren"])
@pytest.mark.parametrize("n_areas", [3, 11, 41])
def test_eq16_exact_for_free_ends(name: str, n_areas: int) -> None:
    soil = load_soil(name)
    sums = chain_sums(F, chain_frequency_response(soil, n_areas, F))
    np.testing.assert_allclose(sums.total, total_sum_impedance(2 * np.pi * F, soil), rtol=1e-10)


@pytest.mark.parametrize("name", ["mevergnies", "soft", "medium", "stiff", "haren"])
def test_eq18_converges_with_n(name: str) -> None:
    soil = load_soil(name)
    ref = alternating_sum_impedance(2 * np.pi * F, soil)
    errs = []
    for n in (5, 11, 21, 41, 81):
        sums = chain_sums(F, chain_frequency_response(soil, n, F))
        errs.append(np.max(np.abs(sums.alternating / ref - 1)))
    assert all(b <= a * 1.0001 for a, b in zip(errs, errs[1:]))  # monotone
    assert errs[-1] < 1e-6
    if name == "mevergnies":  # n = 20 (41 areas), "seems to be sufficient" (Sec. 4.1)
        assert errs[3] < 1e-4


def test_eq18_fails_for_winkler_coupling_free_chain() -> None:
    # without coupling the alternating sum is just the single-area impedance
    soil = SoilParams(model="lysmer", mf=380, kf=72e6, df=680e3)
    sums = chain_sums(F, chain_frequency_response(soil, 11, F))
    np.testing.assert_allclose(sums.alternating, total_sum_impedance(2 * np.pi * F, soil), rtol=1e-12)


def test_static_stiffness_formulas() -> None:
    # Eq. (5): 2 R E / (1 - nu^2) = 4 G R / (1 - nu)
    E, nu, R = 129e6, 0.3, 0.5
    G = E / (2 * (1 + nu))
    assert static_stiffness_circle(R, E, nu) == pytest.approx(4 * G * R / (1 - nu))
    # Eq. (6) for a square tends to Gazetas' square value K/(G B) = (2/(1-nu)) (1.55 + 0.8) = 6.71 (nu = 1/3: 7.05)
    k = static_stiffness_rectangle(2.0, 2.0, E, 1 / 3)
    assert k / (E / (2 * (1 + 1 / 3)) * 1.0) == pytest.approx(2 * 2.35 / (1 - 1 / 3), rel=1e-12)
    # sides in any order
    assert static_stiffness_rectangle(2.5, 0.285, E, nu) == static_stiffness_rectangle(0.285, 2.5, E, nu)


def test_lysmer_from_soil_matches_circle_damping() -> None:
    layer = load_profile("mevergnies").layers[0]
    lys = lysmer_from_soil(layer, 2.5, 0.285)
    R = np.sqrt(2.5 * 0.285 / np.pi)
    assert lys.df == pytest.approx(3.4 * R**2 * np.sqrt(layer.rho * layer.G) / (1 - layer.nu))
    assert lys.kf == pytest.approx(static_stiffness_rectangle(2.5, 0.285, layer.E, layer.nu))
    assert lys.model == "lysmer" and lys.mf > 0


def test_time_lags_table1() -> None:
    soil = load_soil("mevergnies")
    cs = load_profile("mevergnies").layers[0].cs
    assert time_lag_mulliken(0.6, 0.285, cs) == pytest.approx(2.87e-3, rel=0.01)  # Eq. (21) ~ 2.8 ms
    assert time_lag_coupling(soil) == pytest.approx(0.30e-3, rel=0.01)  # Eq. (23) as printed ~ 0.3 ms
    # low-frequency group delay of Eq. (22): Eq. (23) plus the d_f term
    w = 2 * np.pi * 0.01
    h = (soil.kc + 1j * w * soil.dc) / ((soil.kf + soil.kc) - w**2 * soil.mf + 1j * w * (soil.df + soil.dc))
    assert -np.angle(h) / w == pytest.approx(time_lag_transmissibility(soil), rel=1e-4)


def test_pulse_delay_measured_from_model() -> None:
    soil = load_soil("mevergnies")
    resp = chain_time_response(soil, 41, dt=2e-5, duration=0.12)
    amps, times = resp.peaks(2)
    delays = np.diff(times)
    # the model's own delay lies between Eq. (23) (too small) and Eq. (21)
    assert 1.8e-3 < delays[0] < 2.6e-3 and 1.8e-3 < delays[1] < 2.6e-3
    assert amps[0] > amps[1] > amps[2] > 0
    # static check: late response returns to rest (pulse area A td = 1e-3 N s)
    assert np.max(np.abs(resp.x[-1])) < 1e-3 * amps[0]


def test_resonance_and_layers() -> None:
    soil = load_soil("mevergnies")
    assert resonance_frequency(soil) == pytest.approx(np.sqrt((72e6 + 320e6) / 380) / (2 * np.pi))
    np.testing.assert_allclose(layer_resonances(1.2, 120.0), [25.0, 75.0, 125.0])
