"""Validation (b): a constant load moving at sub-Rayleigh speed vs an independent wavenumber integral (issue 23.3).

Pipeline: a 100 kN load moving at 60 m/s along the track, shared between
point sources 0.1 m apart (hat functions; the sleeper-passing images at
600 Hz are far beyond the band), receiver 16 m from the track, Mevergnies
soil (homogeneous, c_R ~ 164 m/s). Reference: the steady-state velocity
by the double wavenumber integral of :func:`clm_core.freefield.reference.
moving_load_velocity` (its own Lamb kernel), with the model's band limit
(Butterworth response times the FIR's cosine taper) applied at k_x c.
Compared over +-0.5 s around the passage (the load enters the zone of
influence, 120 m, faded in, 2 s earlier). Measured: 1.73 % at 16 m; at 8 m
2.26 % (the radial interpolation of the Green's function and the model's
band limit near the fast sign change under the load; not asserted).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from clm_core.freefield import FreeFieldModel, receiver_velocity
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


def test_moving_load_within_2_percent() -> None:
    """Receiver 16 m from the track: within 2 % of the peak (1.73 % measured)."""
    err, peak = moving_load_error()
    assert peak > 1e-5  # m/s: a real signal
    assert err <= 0.02, f"moving load: {100 * err:.2f} % of the peak"
