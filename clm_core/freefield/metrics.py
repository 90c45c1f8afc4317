"""Vibration measures of a receiver velocity: PPV, KB_F,max (DIN 4150-2), one-third-octave levels.

- PPV: peak particle velocity max |v(t)| [mm/s] (vertical component).
- KB_F,max (DIN 4150-2:1999, "bewertete Schwingstärke"): the velocity is
  weighted by the KB filter, a first-order high-pass with f_0 = 5.6 Hz,
  |H_KB(f)| = 1 / sqrt(1 + (f_0 / f)^2) (here its bilinear-transform
  digital form, causal), then the running rms with exponential time
  weighting "FAST", tau = 0.125 s:
  KB_F(t) = sqrt((1/tau) int_{-inf}^t KB^2(s) e^{-(t - s)/tau} ds);
  KB_F,max is its maximum [mm/s] (DIN uses mm/s for KB).
- One-third-octave velocity levels L_v = 10 log10(v_rms,band^2 / v_0^2)
  [dB re v_0 = 5e-8 m/s] in the base-10 bands of nominal centre 1 .. 80 Hz
  (exact centres 10^(n/10), edges x 10^(+-1/20)); v_rms,band^2 is the part
  of the mean square over the whole record that falls in the band
  (Parseval on the record zero-padded to at least 10 s; a band with no
  frequency line is null).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import signal

from clm_core.arrays import Array
from clm_core.errors import InputError

__all__ = [
    "KB_F0",
    "KB_TAU",
    "THIRD_OCTAVE_NOMINAL",
    "V_REF",
    "VibrationMeasures",
    "kb_f",
    "measures",
    "third_octave_levels",
]

#: Corner frequency of the KB weighting, DIN 4150-2 [Hz].
KB_F0 = 5.6
#: Time constant of the running rms "FAST" [s].
KB_TAU = 0.125
#: Reference velocity of L_v [m/s].
V_REF = 5.0e-8
#: Nominal one-third-octave centres 1 .. 80 Hz [Hz].
THIRD_OCTAVE_NOMINAL = (1.0, 1.25, 1.6, 2.0, 2.5, 3.15, 4.0, 5.0, 6.3, 8.0, 10.0, 12.5, 16.0, 20.0, 25.0, 31.5,
                        40.0, 50.0, 63.0, 80.0)


def _check(v: ArrayLike, dt: float) -> Array:
    x = np.asarray(v, dtype=float)
    if x.ndim not in (1, 2) or x.shape[-1] < 2:
        raise InputError(f"velocity: need (n,) or (R, n) with n >= 2, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError("velocity: contains non-finite values")
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"dt = {dt}: must be > 0 s")
    return x


def kb_f(velocity: ArrayLike, dt: float) -> Array:
    """KB_F(t) of DIN 4150-2 [mm/s] from a velocity [m/s] sampled every ``dt`` [s] (module docstring)."""
    v = _check(velocity, dt) * 1e3
    b, a = signal.butter(1, KB_F0, btype="high", fs=1.0 / dt)
    kb = signal.lfilter(b, a, v, axis=-1)
    alpha = math.exp(-dt / KB_TAU)
    ms = signal.lfilter([1.0 - alpha], [1.0, -alpha], kb * kb, axis=-1)
    return np.asarray(np.sqrt(np.maximum(ms, 0.0)), dtype=np.float64)


def third_octave_levels(velocity: ArrayLike, dt: float) -> tuple[Array, Array]:
    """One-third-octave velocity levels L_v [dB re 5e-8 m/s], 1-80 Hz bands; returns (nominal centres [Hz], levels).

    ``levels`` has shape (n_bands,) or (R, n_bands); NaN where a band holds no frequency line.
    """
    v = _check(velocity, dt)
    n = v.shape[-1]
    nfft = max(n, int(2 ** math.ceil(math.log2(10.0 / dt))))
    X = np.fft.rfft(v, n=nfft, axis=-1)
    f = np.fft.rfftfreq(nfft, dt)
    power = np.abs(X) ** 2
    power[..., 1:] *= 2.0
    if nfft % 2 == 0:
        power[..., -1] /= 2.0
    power /= nfft * n  # mean square over the record: sum(v^2)/n = sum(power)
    centres = 10.0 ** (np.arange(len(THIRD_OCTAVE_NOMINAL)) / 10.0)
    out = np.full((*v.shape[:-1], centres.size), np.nan)
    for i, fc in enumerate(centres):
        sel = (f >= fc * 10 ** (-0.05)) & (f < fc * 10 ** 0.05)
        if sel.any():
            ms = power[..., sel].sum(axis=-1)
            with np.errstate(divide="ignore"):
                out[..., i] = 10.0 * np.log10(ms / V_REF**2)
    return np.asarray(THIRD_OCTAVE_NOMINAL), out


@dataclass(frozen=True)
class VibrationMeasures:
    """Measures per receiver.

    Attributes
    ----------
    ppv_mm_s : ndarray (R,)
        Peak particle velocity [mm/s].
    kb_fmax_mm_s : ndarray (R,)
        KB_F,max, DIN 4150-2 [mm/s].
    band_centres_hz : ndarray (20,)
        Nominal one-third-octave centres [Hz].
    lv_db : ndarray (R, 20)
        L_v [dB re 5e-8 m/s] (NaN: empty band).
    dominant_band_hz : ndarray (R,)
        Centre of the band with the highest L_v [Hz].
    """

    ppv_mm_s: Array
    kb_fmax_mm_s: Array
    band_centres_hz: Array
    lv_db: Array
    dominant_band_hz: Array


def measures(velocity: ArrayLike, dt: float) -> VibrationMeasures:
    """PPV, KB_F,max and L_v of receiver velocities ``velocity`` (R, n) [m/s] sampled every ``dt`` [s]."""
    v = np.atleast_2d(_check(velocity, dt))
    ppv = np.max(np.abs(v), axis=1) * 1e3
    kb = np.max(kb_f(v, dt), axis=1)
    fc, lv = third_octave_levels(v, dt)
    dom = np.array([fc[int(np.nanargmax(row))] if np.isfinite(row).any() else np.nan for row in lv])
    return VibrationMeasures(ppv_mm_s=ppv, kb_fmax_mm_s=kb, band_centres_hz=fc, lv_db=lv, dominant_band_hz=dom)
