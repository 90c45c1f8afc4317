"""Spectra of recorded histories for reports: amplitude spectra and one-third-octave bands.

One home for the frequency content of a time history (wheel loads, sleeper
soil forces, rail deflections, receiver velocities), used by the figures of
:mod:`clm_core.outputs.plots` and the summaries:

- :func:`amplitude_spectrum`: single-sided amplitude spectrum of the dynamic
  part of a uniformly sampled record (the amplitude of the harmonic at each
  frequency line of the record, in the unit of the signal);
- :func:`third_octave_bands`: one-third-octave band levels (base-10 bands of
  IEC 61260-1: centre frequencies 1000 x 10^(n/10) Hz, edges at 10^(+-1/20)
  of the centre), computed exactly from the record's FFT lines, so that the
  band mean squares of bands covering every line sum to the mean square of
  the record (Parseval);
- :func:`band_level_db`: a band rms as a level in dB re a reference.

Records are rectangular-windowed (no taper): a pass-by is a transient that
starts and ends near rest, and Parseval's identity holds exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from clm_core.arrays import Array
from clm_core.checks import positive
from clm_core.errors import InputError

#: Reference velocity of velocity levels L_v [m/s] (DIN 45669, ISO 1683: 5e-8 m/s).
VELOCITY_REFERENCE = 5e-8


def _record(x: ArrayLike, dt: float, what: str) -> tuple[Array, float]:
    dt = positive("dt", dt, InputError, unit="s")
    a = np.asarray(x, dtype=float).reshape(-1)
    if a.size < 2:
        raise InputError(f"{what}: {a.size} sample(s); a spectrum needs at least 2")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{what}: {int(np.count_nonzero(~np.isfinite(a)))} sample(s) are NaN or infinite; "
                         "give the finite stretch of the record")
    return a, dt


@dataclass(frozen=True)
class AmplitudeSpectrum:
    """Single-sided amplitude spectrum of a record.

    Attributes
    ----------
    frequency : (m,) array
        Frequency lines k / T [Hz], k = 0 .. n // 2 (T = n dt).
    amplitude : (m,) array
        Amplitude of the harmonic at each line, in the unit of the record
        (2 |X_k| / n; |X_0| / n at 0 Hz and at the Nyquist line of an even n).
    mean : float
        Mean removed before the transform (the ``reference``, or the record's mean).
    """

    frequency: Array
    amplitude: Array
    mean: float


def amplitude_spectrum(x: ArrayLike, dt: float, reference: float | None = None) -> AmplitudeSpectrum:
    """Single-sided amplitude spectrum of the dynamic part of ``x`` (rectangular window).

    Parameters
    ----------
    x : (n,) array_like
        Uniformly sampled record, finite values (any unit).
    dt : float
        Sampling interval [s].
    reference : float, optional
        Value removed before the transform (e.g. the static wheel load);
        default the record's mean.

    Returns
    -------
    AmplitudeSpectrum

    Raises
    ------
    InputError
        Fewer than 2 samples, a non-finite sample, or ``dt`` not > 0.
    """
    a, dt = _record(x, dt, "amplitude_spectrum")
    ref = float(np.mean(a)) if reference is None else float(reference)
    n = a.size
    X = np.abs(np.fft.rfft(a - ref)) / n
    X[1:] *= 2.0
    if n % 2 == 0:
        X[-1] /= 2.0  # the Nyquist line is its own mirror
    return AmplitudeSpectrum(frequency=np.asarray(np.fft.rfftfreq(n, dt), dtype=np.float64), amplitude=X, mean=ref)


@dataclass(frozen=True)
class ThirdOctaveBands:
    """One-third-octave band contents of a record.

    Attributes
    ----------
    centre, lower, upper : (b,) arrays
        Exact centre frequency 1000 x 10^(n/10) and band edges [Hz].
    nominal : (b,) array
        Nominal centre frequency (1, 1.25, 1.6, 2, ... 80, 100 Hz).
    mean_square : (b,) array
        Mean square of the record's content in each band over the record
        duration, in the unit of the record squared.
    rms : (b,) array
        sqrt(mean_square), in the unit of the record.
    total_mean_square : float
        Mean square of the (mean-removed) record.
    lines : (b,) int array
        FFT lines in each band (0: the band is narrower than the line spacing 1 / T; its mean square is 0).
    """

    centre: Array
    lower: Array
    upper: Array
    nominal: Array
    mean_square: Array
    rms: Array
    total_mean_square: float
    lines: NDArray[np.int64]


_NOMINAL = np.array([1.0, 1.25, 1.6, 2.0, 2.5, 3.15, 4.0, 5.0, 6.3, 8.0])


def nominal_frequency(centre: Array) -> Array:
    """Nominal centre frequencies (1, 1.25, 1.6, 2, 2.5, 3.15, 4, 5, 6.3, 8 x 10^k Hz) of exact band centres."""
    dec = np.floor(np.log10(centre) + 1e-9)
    mant = centre / 10.0**dec
    k = np.argmin(np.abs(np.log(mant[:, None] / _NOMINAL[None, :])), axis=1)
    out: Array = np.asarray(_NOMINAL[k] * 10.0**dec, dtype=float)
    return out


def third_octave_bands(
    x: ArrayLike, dt: float, f_min: float = 1.0, f_max: float | None = None, reference: float | None = None
) -> ThirdOctaveBands:
    """One-third-octave band mean squares of the dynamic part of ``x``, from its FFT lines.

    Each FFT line of the record (single-sided power 2 |X_k|^2 / n^2, the 0 Hz
    and Nyquist lines once) is given to the band whose edges hold it (a line
    on an edge to the upper band). Bands run from the one whose centre is
    nearest ``f_min`` to the last whose centre is at most ``f_max``.

    Parameters
    ----------
    x : (n,) array_like
        Uniformly sampled record, finite values.
    dt : float
        Sampling interval [s].
    f_min : float
        Lowest band centre [Hz] (default 1 Hz).
    f_max : float, optional
        Highest band centre [Hz]; default the last band below the Nyquist frequency.
    reference : float, optional
        Value removed first (default the record's mean).

    Returns
    -------
    ThirdOctaveBands

    Raises
    ------
    InputError
        A bad record (:func:`amplitude_spectrum`), ``f_min`` not > 0, or no
        band between ``f_min`` and ``f_max``.
    """
    a, dt = _record(x, dt, "third_octave_bands")
    f_min = positive("f_min", f_min, InputError, unit="Hz")
    nyq = 0.5 / dt
    top = nyq / 10 ** (1 / 20) if f_max is None else positive("f_max", f_max, InputError, unit="Hz")
    n_lo = int(np.round(10.0 * np.log10(f_min / 1000.0)))
    n_hi = int(np.floor(10.0 * np.log10(top / 1000.0) + 1e-9))
    if n_hi < n_lo:
        raise InputError(f"third_octave_bands: no band between f_min = {f_min:g} Hz and f_max = {top:g} Hz")
    nb = np.arange(n_lo, n_hi + 1)
    centre = 1000.0 * 10.0 ** (nb / 10.0)
    lower, upper = centre * 10 ** (-1 / 20), centre * 10 ** (1 / 20)
    ref = float(np.mean(a)) if reference is None else float(reference)
    n = a.size
    X = np.fft.rfft(a - ref)
    power = 2.0 * np.abs(X) ** 2 / n**2
    power[0] /= 2.0
    if n % 2 == 0:
        power[-1] /= 2.0
    f = np.fft.rfftfreq(n, dt)
    which = np.searchsorted(lower, f, side="right") - 1  # band whose lower edge is at or below the line
    inside = (which >= 0) & (f < upper[np.clip(which, 0, None)])
    ms = np.asarray(np.bincount(which[inside], weights=power[inside], minlength=nb.size)[: nb.size], dtype=np.float64)
    lines = np.bincount(which[inside], minlength=nb.size)[: nb.size].astype(np.int64)
    return ThirdOctaveBands(centre=centre, lower=lower, upper=upper, nominal=nominal_frequency(centre), mean_square=ms,
                            rms=np.sqrt(ms), total_mean_square=float(np.sum(power)), lines=lines)


def band_level_db(rms: ArrayLike, reference: float) -> Array:
    """Levels 20 log10(rms / reference) [dB re ``reference``] (-inf for a zero rms)."""
    ref = positive("reference", reference, InputError)
    r = np.asarray(rms, dtype=float)
    with np.errstate(divide="ignore"):
        out: Array = 20.0 * np.log10(r / ref)
    return out
