"""Public entry point of the free-field computation: :func:`free_field`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from clm_core.arrays import Array
from clm_core.freefield.convolve import receiver_velocity
from clm_core.freefield.metrics import VibrationMeasures, measures
from clm_core.freefield.model import FreeFieldModel
from clm_core.profile import SoilProfile

__all__ = ["FreeFieldResult", "free_field"]


@dataclass(frozen=True)
class FreeFieldResult:
    """Receiver velocities and their vibration measures.

    Attributes
    ----------
    receivers : ndarray (R, 2)
        (x, y) of each receiver [m].
    t : ndarray (n,)
        Output times [s] (model step ``model.model_dt``).
    velocity : ndarray (R, n)
        Vertical surface velocity [m/s], positive downwards.
    measures : VibrationMeasures
        PPV [mm/s], KB_F,max [mm/s] (DIN 4150-2), L_v [dB re 5e-8 m/s].
    model : FreeFieldModel
        The filters used (kept for a streaming run on the same receivers).
    """

    receivers: Array
    t: Array
    velocity: Array
    measures: VibrationMeasures
    model: FreeFieldModel

    def summary(self) -> list[dict[str, Any]]:
        """One JSON-ready mapping per receiver (position, PPV, KB_F,max, dominant band, L_v by band)."""
        m = self.measures
        out = []
        for r in range(self.receivers.shape[0]):
            out.append({
                "x_m": float(self.receivers[r, 0]), "y_m": float(self.receivers[r, 1]),
                "ppv_mm_per_s": float(m.ppv_mm_s[r]), "kb_fmax_mm_per_s": float(m.kb_fmax_mm_s[r]),
                "dominant_third_octave_hz": float(m.dominant_band_hz[r]),
                "lv_db_re_5e-8_m_per_s": {f"{fc:g}": (None if not np.isfinite(lv) else round(float(lv), 2))
                                          for fc, lv in zip(m.band_centres_hz, m.lv_db[r], strict=True)},
            })
        return out


def free_field(
    profile: SoilProfile,
    receivers: ArrayLike,
    t: ArrayLike,
    first_sleeper: ArrayLike,
    soil_force: ArrayLike,
    spacing: float,
    **options: Any,
) -> FreeFieldResult:
    """Free-field vertical velocity at receivers from sleeper soil forces (two-step method).

    The ballast forces on the sleepers' contact areas (step 1, the CLM track
    model, Kouroussis et al. 2011 Sec. 2) act as uniform pressures on the
    free surface of the layered half-space; the surface velocity at each
    receiver is the sum over sleepers of causal FIR convolutions of their
    force histories with the pair's velocity impulse response, built from
    the half-space Green's functions (:mod:`clm_core.freefield.model`).

    Parameters
    ----------
    profile : SoilProfile
        Soil (``clm_core.profile.load_profile('mevergnies')``, any preset, a
        YAML profile, or a one-layer homogeneous half-space).
    receivers : array_like, shape (R, 2)
        (x along the track, y from the track axis) [m].
    t : array_like, shape (n,)
        Uniform times of the force records [s].
    first_sleeper : array_like of int, shape (n,)
        Global index of column 0 of ``soil_force`` at each time (sleeper j at x = j d).
    soil_force : array_like, shape (n, N)
        Ballast force on the soil under each window sleeper [N], positive downwards.
    spacing : float
        Sleeper spacing d [m].
    **options
        Passed to :class:`~clm_core.freefield.model.FreeFieldModel`:
        ``contact_length`` (2.5 m), ``contact_width`` (0.285 m),
        ``influence_length`` (60 m), ``band`` (100 Hz), ``model_rate``
        (250 Hz), ``tail`` (0.25 s).

    Returns
    -------
    FreeFieldResult
        Velocity histories [m/s] at the model rate, PPV and KB_F,max [mm/s],
        one-third-octave levels L_v [dB re 5e-8 m/s], 1-80 Hz.

    Examples
    --------
    A 10 kN load stepping onto one sleeper, receiver 8 m from the track:

    >>> import numpy as np
    >>> from clm_core.profile import load_profile
    >>> from clm_core.freefield import free_field
    >>> t = np.arange(400) * 0.002
    >>> force = np.where(t >= 0.1, 10e3, 0.0)[:, None]          # one sleeper (index 0)
    >>> res = free_field(load_profile("mevergnies"), [[0.0, 8.0]], t, np.zeros(400, int), force, 0.6,
    ...                  influence_length=3.0, band=40.0, model_rate=100.0)
    >>> res.velocity.shape
    (1, 65)
    >>> bool(0.0 < res.measures.ppv_mm_s[0] < 1.0)
    True
    """
    tt = np.asarray(t, dtype=float).reshape(-1)
    dt = float(np.median(np.diff(tt))) if tt.size > 1 else float("nan")
    model = FreeFieldModel(profile, receivers, spacing, dt, **options)
    rec = receiver_velocity(model, tt, first_sleeper, soil_force)
    return FreeFieldResult(receivers=model.receivers, t=rec.t, velocity=rec.velocity,
                           measures=measures(rec.velocity, model.model_dt), model=model)
