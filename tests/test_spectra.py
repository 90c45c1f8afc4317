"""Spectra for reports (clm_core.spectra): amplitudes of known harmonics, Parseval over one-third-octave bands."""

from __future__ import annotations

import numpy as np
import pytest

from clm_core.errors import InputError
from clm_core.spectra import amplitude_spectrum, band_level_db, third_octave_bands


def test_amplitude_of_harmonics_on_their_lines() -> None:
    dt, n = 1e-3, 4000  # T = 4 s, lines every 0.25 Hz
    t = np.arange(n) * dt
    x = 83e3 + 5e3 * np.sin(2 * np.pi * 10.0 * t) + 2e3 * np.cos(2 * np.pi * 62.5 * t + 0.3)
    s = amplitude_spectrum(x, dt, reference=83e3)
    assert s.frequency[1] == pytest.approx(0.25)
    a = dict(zip(np.round(s.frequency, 6), s.amplitude, strict=True))
    assert a[10.0] == pytest.approx(5e3, rel=1e-9) and a[62.5] == pytest.approx(2e3, rel=1e-9)
    others = np.delete(s.amplitude, [int(10.0 / 0.25), int(62.5 / 0.25)])
    assert others.max() < 1e-6 * 5e3
    assert s.mean == 83e3 and amplitude_spectrum(x, dt).mean == pytest.approx(83e3, rel=1e-12)


def test_third_octave_band_mean_squares_sum_to_the_total() -> None:
    rng = np.random.default_rng(3)
    dt, n = 1e-3, 20000
    x = rng.normal(size=n) * 1e3
    # white noise: the bands from 0.1 Hz up to the last below Nyquist hold every line but the top few
    b = third_octave_bands(x, dt, f_min=0.1)
    f = np.fft.rfftfreq(n, dt)
    covered = (f >= b.lower[0]) & (f < b.upper[-1])
    X = np.fft.rfft(x - x.mean())
    p = 2 * np.abs(X) ** 2 / n**2
    p[-1] /= 2
    assert b.mean_square.sum() == pytest.approx(p[covered].sum(), rel=1e-12)
    assert b.total_mean_square == pytest.approx(np.mean((x - x.mean()) ** 2), rel=1e-12)  # Parseval
    # a record band-limited to 2..300 Hz: the bands 1..400 Hz hold all of it
    X[(f < 2) | (f > 300)] = 0
    y = np.fft.irfft(X, n)
    c = third_octave_bands(y, dt, f_min=1.0, f_max=400.0)
    assert c.mean_square.sum() == pytest.approx(np.mean(y**2), rel=1e-10)
    assert c.nominal[0] == 1.0 and list(c.nominal[:4]) == [1.0, 1.25, 1.6, 2.0] and c.nominal[-1] == 400.0
    np.testing.assert_allclose(c.upper[:-1], c.lower[1:], rtol=1e-12)  # contiguous bands


def test_a_tone_falls_in_its_band() -> None:
    dt, n = 1e-3, 8000
    t = np.arange(n) * dt
    b = third_octave_bands(3.0 * np.sin(2 * np.pi * 31.25 * t), dt, f_max=100.0)
    k = int(np.argmax(b.mean_square))
    assert b.nominal[k] == 31.5 and b.rms[k] == pytest.approx(3.0 / np.sqrt(2), rel=1e-9)
    lv = band_level_db(b.rms, 5e-8)
    assert lv[k] == pytest.approx(20 * np.log10(3.0 / np.sqrt(2) / 5e-8), rel=1e-12)


@pytest.mark.parametrize(("x", "dt", "fragment"), [
    ([1.0], 1e-3, "1 sample"), ([1.0, np.nan, 2.0], 1e-3, "1 sample(s) are NaN"), ([1.0, 2.0], 0.0, "dt = 0"),
])
def test_bad_records_are_refused(x: list[float], dt: float, fragment: str) -> None:
    with pytest.raises(InputError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        amplitude_spectrum(x, dt)
    with pytest.raises(InputError, match="no band"):
        third_octave_bands(np.ones(100), 1e-3, f_min=300.0, f_max=200.0)
