"""Validation (b): a constant load moving at sub-Rayleigh speed vs an independent wavenumber integral (issue 23.3).

Pipeline: a 100 kN load moving at 60 m/s along the track, shared between
point sources 0.1 m apart (hat functions; the sleeper-passing images at
600 Hz are far beyond the band), receiver 16 m from the track, Mevergnies
soil (homogeneous, c_R ~ 164 m/s). Reference: the steady-state velocity
by the double wavenumber integral of :func:`clm_core.freefield.reference.
moving_load_velocity` (its own Lamb kernel), with the model's band limit
(Butterworth response times the FIR's cosine taper) applied at k_x c.
Compared over +-0.5 s around the passage (the load enters the zone of
influence, 120 m, faded in, 2 s earlier). The error is discretisation: the
part of the band limit's zero-phase precursor the causal FIR leaves out
(``PRECURSOR_CYCLES``): at 8 m 2.26 % with 3 periods, 1.66 % with 6 (the
default), 1.58 % with 12; the reference is converged (twice the points:
+0.001 %), and so is the radial grid (twice as fine: -0.06 %).
docs/validation.md (b) gives the convergence table.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from clm_core.freefield import FreeFieldModel, receiver_velocity
from clm_core.freefield import model as ff_model
from clm_core.freefield.reference import moving_load_velocity
from clm_core.profile import load_profile

SPEED, Y, LOAD, D = 60.0, 16.0, 100e3, 0.1


def moving_load_error(y: float = Y) -> tuple[float, float]:
    """(max |v_pipeline - v_reference| / max |v_reference| over the passage, peak reference velocity [m/s])."""
    soil = load_profile("mevergnies")
    dt = 5e-4
    model = FreeFieldModel(soil, [[0.0, y]], D, dt, contact_length=0.0, contact_width=0.0,
                           influence_length=120.0, band=40.0, model_rate=200.0)
    x0 = -150.0
    n = int(round((0.0 - x0) / SPEED / dt)) + int(round(1.0 / dt))
    t = np.arange(n) * dt
    x = x0 + SPEED * t
    j = np.floor(x / D).astype(np.int64)
    frac = x / D - j
    first = j - 1
    F = np.zeros((n, 4))
    F[:, 1] = LOAD * (1.0 - frac)
    F[:, 2] = LOAD * frac
    rec = receiver_velocity(model, t, first, F)
    sel = np.abs(rec.t - (0.0 - x0) / SPEED) <= 0.5
    xi = 0.0 - (x0 + SPEED * rec.t[sel])

    def band(f: np.ndarray) -> np.ndarray:
        _, hb = signal.sosfreqz(model.sos, worN=f, fs=1.0 / dt)
        fb = model.band
        taper = np.where(f <= fb, 1.0, np.where(f < 1.25 * fb, 0.5 * (1 + np.cos(math.pi * (f - fb) / (0.25 * fb))),
                                                0.0))
        return np.asarray(hb * taper)

    ref = moving_load_velocity(soil.halfspace, SPEED, xi, y, load=LOAD, band=band)
    peak = float(np.max(np.abs(ref)))
    return float(np.max(np.abs(rec.velocity[0, sel] - ref)) / peak), peak


@pytest.mark.parametrize("y", [8.0, 16.0])
def test_moving_load_within_2_percent(y: float) -> None:
    """Receivers 8 and 16 m from the track: within 2 % of the peak (1.66 % and 1.7 % measured)."""
    err, peak = moving_load_error(y)
    assert peak > 1e-5  # m/s: a real signal
    assert err <= 0.02, f"moving load at y = {y:g} m: {100 * err:.2f} % of the peak"


def test_precursor_error_converges() -> None:
    """The error at 8 m falls as the FIR keeps more of the band limit's precursor (3 -> 12 periods)."""
    saved = ff_model.PRECURSOR_CYCLES
    try:
        errs = []
        for cycles in (3.0, 12.0):
            ff_model.PRECURSOR_CYCLES = cycles
            errs.append(moving_load_error(8.0)[0])
    finally:
        ff_model.PRECURSOR_CYCLES = saved
    assert errs[0] > 0.02 > errs[1] and errs[1] < 0.8 * errs[0], errs
