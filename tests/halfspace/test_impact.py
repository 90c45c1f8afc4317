"""Reference impact histories by inverse FFT of a flexibility."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clm_core.errors import InputError
from clm_core.halfspace.impact import impact_response, save_impact_npz

M, K, C = 400.0, 72e6, 680e3


def sdof_flexibility(f: np.ndarray) -> np.ndarray:
    w = 2 * np.pi * f
    return 1.0 / (K - w**2 * M + 1j * w * C)


def test_sdof_equation_of_motion_holds_for_the_returned_force() -> None:
    """m a + c v + k x = force(t) for the band-limited pulse that is returned."""
    f = np.arange(0.0, 151.0, 1.0)
    H = np.stack([sdof_flexibility(f), 0.5 * sdof_flexibility(f)], axis=1)
    r = impact_response(f, H, positions=[0.0, 0.6], oversample=16.0)
    x, v = r.displacement[0], r.velocity[0]
    dt = r.time[1] - r.time[0]
    a = np.gradient(v, dt)
    lhs = M * a + C * v + K * x
    assert np.max(np.abs(lhs - r.force)) < 0.02 * np.max(np.abs(r.force))
    np.testing.assert_allclose(np.gradient(x, dt), v, atol=0.02 * np.max(np.abs(v)))
    np.testing.assert_allclose(r.displacement[1], 0.5 * x, rtol=1e-12, atol=1e-20)
    # static level: int x dt = H(0) int F dt, int F dt = A td (the taper keeps w = 0)
    assert np.sum(x) * dt == pytest.approx(H[0, 0].real * 1.0 * 0.001, rel=1e-9)
    assert np.sum(r.force) * dt == pytest.approx(0.001, rel=1e-9)


def test_causality_and_band_limit() -> None:
    f = np.arange(0.0, 151.0, 1.0)
    r = impact_response(f, sdof_flexibility(f))
    assert r.precursor < 3e-3
    assert r.wrap_residual < 1e-3
    # the applied force is Eq. (1) low-passed: same area, peak lower than A = 1 N
    assert 0.1 < r.force.max() < 1.0
    i0 = np.argmax(r.force)
    assert 0.05 < r.time[i0] < 0.07  # group delay of the causal low-pass (~13 ms)
    assert np.max(np.abs(r.force[r.time < 0.049])) < 1e-3 * r.force.max()
    assert r.pulse_exact.max() == pytest.approx(1.0)


def test_amplitude_scales(tmp_path: Path) -> None:
    f = np.arange(0.0, 101.0, 1.0)
    r1 = impact_response(f, sdof_flexibility(f))
    r2 = impact_response(f, sdof_flexibility(f), amplitude=1e4)
    np.testing.assert_allclose(r2.displacement, 1e4 * r1.displacement, rtol=1e-12, atol=1e-16)
    p = save_impact_npz(r2, tmp_path / "impact.npz")
    with np.load(p) as d:
        np.testing.assert_array_equal(d["displacement"], r2.displacement)
        assert float(d["amplitude"]) == 1e4


@pytest.mark.parametrize(
    ("freqs", "match"),
    [
        (np.arange(1.0, 50.0), "start at 0"),
        (np.r_[0.0, np.cumsum(np.linspace(1, 2, 40))], "uniform"),
    ],
)
def test_bad_grids(freqs: np.ndarray, match: str) -> None:
    with pytest.raises(InputError, match=match):
        impact_response(freqs, np.ones(freqs.size, complex))
