"""Validation (a): point pulse on a homogeneous half-space (nu = 0.25) vs Pekeris' closed form (issue 23.3).

The two-step pipeline (Green's functions of clm_core.halfspace.green, causal
FIR, band limit, decimation) is run for a point load with a 60 ms Hann force
pulse; its surface velocity, integrated in time, is compared with Pekeris'
step response (clm_core.freefield.reference, independent of green.py)
convolved with the same force after the same band-limit filter.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, signal

from clm_core.freefield import FreeFieldModel, receiver_velocity
from clm_core.freefield.reference import pekeris_response
from clm_core.profile import Layer, SoilProfile

RHO, CS = 1800.0, 200.0
MU = RHO * CS**2
SOIL = SoilProfile(layers=(Layer(thickness=None, E=2 * MU * 1.25, rho=RHO, nu=0.25),), name="elastic nu=0.25")


def pulse(t: np.ndarray, t0: float = 0.05, width: float = 0.06, amp: float = 1e3) -> np.ndarray:
    """Hann force pulse [N]."""
    u = (t - t0) / width
    return np.where((u >= 0) & (u <= 1), amp * np.sin(math.pi * u) ** 2, 0.0)


def pekeris_errors() -> dict[float, float]:
    """max |u_pipeline - u_Pekeris| / max |u_Pekeris| at r = 10 and 30 m (also used by docs/validation_numbers.py)."""
    dt = 1e-3
    radii = (10.0, 30.0)
    model = FreeFieldModel(SOIL, [[0.0, r] for r in radii], 1.0, dt, contact_length=0.0, contact_width=0.0,
                           influence_length=0.5)
    t = np.arange(700) * dt
    f = pulse(t)
    rec = receiver_velocity(model, t, np.zeros(t.size, dtype=np.int64), f[:, None])
    u_num = integrate.cumulative_trapezoid(rec.velocity, dx=model.model_dt, axis=1, initial=0.0)
    y = signal.sosfilt(model.sos, f)  # the model's band limit, applied to the reference's force
    out = {}
    for i, r in enumerate(radii):
        u_ref = pekeris_response(rec.t, t, y, r, CS, MU)
        out[r] = float(np.max(np.abs(u_num[i] - u_ref)) / np.max(np.abs(u_ref)))
    return out


def test_pekeris_within_2_percent() -> None:
    err = pekeris_errors()
    for r, e in err.items():
        assert e <= 0.02, f"r = {r} m: error {100 * e:.2f} % of the peak"


def test_pekeris_closed_form_limits() -> None:
    from clm_core.freefield.reference import pekeris_step, pekeris_step_integral

    # zero before the P wave, continuous at the P and S arrivals, static (1 - nu)/(2 pi mu r) = 3/8 (x P/(pi mu r))
    g = math.sqrt((3 + math.sqrt(3)) / 4)
    w = pekeris_step(np.array([0.5, 1 / math.sqrt(3) + 1e-9, 1 - 1e-12, 1.0, g + 1e-9, 10.0]))
    assert w[0] == 0.0 and abs(w[1]) < 1e-3
    assert w[2] == pytest.approx(w[3], rel=1e-9)
    assert w[4] == w[5] == 0.375
    # the closed-form time integral against a Riemann sum away from the singularity
    s = np.linspace(0.6, 1.05, 200001)
    riemann = float(np.sum(0.5 * (pekeris_step(s[1:]) + pekeris_step(s[:-1])) * np.diff(s)))
    C = pekeris_step_integral(np.array([0.6, 1.05]))
    assert C[1] - C[0] == pytest.approx(riemann, rel=1e-6)


def test_pekeris_fourier_transform_matches_green() -> None:
    """The Fourier transform of the closed form equals green.py's frequency-domain point-load Green's function."""
    from scipy import integrate as quad_mod

    from clm_core.freefield.reference import pekeris_step_integral
    from clm_core.halfspace.green import point_load_displacement

    r, w = 10.0, 2 * math.pi * 20.0
    s = CS / r
    g = math.sqrt((3 + math.sqrt(3)) / 4)
    t_p, t_r = r / CS / math.sqrt(3), g * r / CS

    def c(t: float) -> float:
        return float(pekeris_step_integral(np.array([s * t]))[0]) / s

    # U = i w int W e^{-iwt} dt / (pi mu r), by parts on [t_P, t_R] (C = int W), the static 3/8 after t_R
    re = quad_mod.quad(lambda t: c(t) * math.cos(w * t), t_p, t_r, limit=400)[0]
    im = quad_mod.quad(lambda t: -c(t) * math.sin(w * t), t_p, t_r, limit=400)[0]
    inner = c(t_r) * np.exp(-1j * w * t_r) + 1j * w * (re + 1j * im) + 0.375 * np.exp(-1j * w * t_r) / (1j * w)
    u_pk = 1j * w * inner / (math.pi * MU * r)
    u_gr = point_load_displacement(SOIL, np.array([r]), w)[0]
    assert abs(u_pk - u_gr) <= 1e-4 * abs(u_gr)
