"""PPV, KB_F,max (DIN 4150-2) and one-third-octave levels against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clm_core.errors import InputError
from clm_core.freefield import kb_f, measures, third_octave_levels


def test_sine_measures() -> None:
    dt, f, A = 1 / 250.0, 12.5, 2e-3  # 2 mm/s amplitude
    t = np.arange(int(20 / dt)) * dt
    v = A * np.sin(2 * math.pi * f * t)
    m = measures(v[None, :], dt)
    assert m.ppv_mm_s[0] == pytest.approx(2.0, rel=1e-3)
    # KB weighting 1/sqrt(1+(5.6/12.5)^2); the FAST running rms of a steady sine -> rms (ripple at 2f ~ +-1.6 %)
    kb = 2.0 / math.sqrt(2) / math.sqrt(1 + (5.6 / f) ** 2)
    assert m.kb_fmax_mm_s[0] == pytest.approx(kb, rel=0.03)
    ib = list(m.band_centres_hz).index(12.5)
    assert m.lv_db[0, ib] == pytest.approx(20 * math.log10(A / math.sqrt(2) / 5e-8), abs=0.05)
    assert m.dominant_band_hz[0] == 12.5
    others = np.delete(m.lv_db[0], ib)
    assert np.nanmax(others) < m.lv_db[0, ib] - 20.0


def test_kb_weighting_suppresses_low_frequencies() -> None:
    dt = 1 / 250.0
    t = np.arange(int(30 / dt)) * dt
    # the exponential averaging keeps the mean square: mean(KB_F^2) = mean(KB^2) in steady state
    kb_low = math.sqrt(np.mean(kb_f(np.sin(2 * math.pi * 1.0 * t), dt)[-5000:] ** 2))
    kb_high = math.sqrt(np.mean(kb_f(np.sin(2 * math.pi * 40.0 * t), dt)[-5000:] ** 2))
    ratio = (1 / math.sqrt(1 + 5.6**2)) / (1 / math.sqrt(1 + (5.6 / 40) ** 2))
    assert kb_low / kb_high == pytest.approx(ratio, rel=0.01)


def test_levels_reject_bad_input() -> None:
    with pytest.raises(InputError, match="non-finite"):
        third_octave_levels(np.array([0.0, np.nan, 1.0]), 0.004)
    with pytest.raises(InputError, match="dt"):
        measures(np.zeros((1, 10)), 0.0)
