"""Noise spectra of the channels from the record before the hit (issue 24).

Sensor noise is rarely white: a geophone's preamplifier, the mains, ground
vibration from traffic colour it. Before issue 24 every channel's noise was
taken as white at the level measured before the first hit, so lines where
the noise is strong counted as much as lines where it is weak, and the 95 %
intervals assumed the wrong covariance.

Here the record before the first hit (at least 32 samples) is fitted with an
autoregressive model x_n = sum_{i=1..p} a_i x_{n-i} + e_n by the Yule–Walker
equations (Levinson recursion, :func:`scipy.linalg.solve_toeplitz`), the
order p <= ``max_order`` chosen by the Bayesian information criterion
BIC(p) = n log s_p^2 + p log n (s_p^2 the innovation variance): a white
record keeps p = 0 (a white spectrum) unless the data show colour. The
spectrum P(f) = s_p^2 / |1 - sum a_i exp(-2 pi j f i / fs)|^2 is positive
everywhere and its autocovariance is the sample autocovariance at lags
0..p, so P / r(0) (:meth:`NoiseSpectrum.shape`) has mean 1 over
(-fs/2, fs/2) and the level is the channel's variance as before.

Use (:mod:`clm_core.calibration.spectra`):

- response channels (exponential window, narrow in frequency): the variance
  of line k is scaled by shape(f_k), the covariance of lines k, l by
  sqrt(shape(f_k) shape(f_l)) (the window's line correlation R(k - l) is
  kept);
- force channel (a window of a few dozen samples, broad in frequency): its
  covariance is computed exactly, E[N_k conj(N_l)] = (E W T W E^H)_kl with
  T the Toeplitz matrix of the model's autocovariance
  (:meth:`NoiseSpectrum.autocovariance`), W the window, E the DFT rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array


@dataclass(frozen=True)
class NoiseSpectrum:
    """An autoregressive noise model of one channel.

    Attributes
    ----------
    variance : float
        r(0), the variance of the record before the hit [SI unit^2].
    ar : (p,) array
        Coefficients a_1..a_p (empty: white noise).
    innovation : float
        s_p^2, the innovation variance [SI unit^2].
    n_samples : int
        Samples the model was fitted to.
    """

    variance: float
    ar: Array
    innovation: float
    n_samples: int

    @property
    def order(self) -> int:
        """p, the AR order (0: white)."""
        return int(self.ar.size)

    def psd(self, frequency: Array, fs: float) -> Array:
        """Two-sided spectral density P(f) / fs per sample, s_p^2 / |A(f)|^2 [SI unit^2]; mean r(0) over the circle."""
        w = 2 * np.pi * np.asarray(frequency, dtype=float) / fs
        a = np.ones_like(w, dtype=complex)
        for i, c in enumerate(self.ar, start=1):
            a -= c * np.exp(-1j * w * i)
        return np.asarray(self.innovation / np.abs(a) ** 2, dtype=float)

    def shape(self, frequency: Array, fs: float) -> Array:
        """P(f) / r(0) [-]: 1 for white noise; the factor on each line's noise variance."""
        if self.order == 0 or self.variance <= 0:
            return np.ones(np.shape(frequency))
        return self.psd(frequency, fs) / self.variance

    def autocovariance(self, n_lags: int) -> Array:
        """c(0..n_lags-1) of the model [SI unit^2], a positive definite sequence (c(0) = r(0))."""
        if self.order == 0:
            c = np.zeros(n_lags)
            c[0] = self.variance
            return c
        N = max(4096, 4 * n_lags)
        P = self.psd(np.asarray(np.fft.fftfreq(N), dtype=np.float64), 1.0)
        c = np.fft.ifft(P).real[:n_lags]
        return np.asarray(c * (self.variance / c[0]), dtype=float)

    def describe(self) -> str:
        """One line: order and the spectrum's range over the band, for the report."""
        if self.order == 0:
            return "white"
        return f"AR({self.order})"


def fit_noise(x: Array, max_order: int = 8) -> NoiseSpectrum:
    """Fit an AR noise model to a record of noise (the samples before the hit), order by BIC.

    Parameters
    ----------
    x : (n,) array
        Noise samples (the mean is removed) [SI unit].
    max_order : int
        Highest order tried (0: white); at most n / 8.

    Returns
    -------
    NoiseSpectrum
    """
    from scipy.linalg import solve_toeplitz  # here: importing this module stays light

    x = np.asarray(x, dtype=float) - float(np.mean(x))
    n = x.size
    r = np.array([float(np.dot(x[: n - k], x[k:])) / n for k in range(min(max_order, n // 8) + 1)])
    r0 = float(r[0])
    best = NoiseSpectrum(r0, np.zeros(0), r0, n)
    if r0 <= 0 or r.size == 1:
        return best
    bic = n * math.log(r0)
    for p in range(1, r.size):
        a = np.asarray(solve_toeplitz(r[:p], r[1 : p + 1]), dtype=float)
        s2 = float(r0 - np.dot(a, r[1 : p + 1]))
        if not s2 > 0:
            break
        b = n * math.log(s2) + p * math.log(n)
        if b < bic:
            bic, best = b, NoiseSpectrum(r0, a, s2, n)
    return best


def windowed_cov(model: NoiseSpectrum, w: Array, lines: NDArray[np.int64], L: int) -> tuple[Array, Array]:
    """Covariance and pseudo-covariance of the windowed DFT of the noise at ``lines`` (exact, any colour).

    N_k = sum_n w_n e_n exp(-2 pi j k n / L); returns E[N_k conj(N_l)] and
    E[N_k N_l] for the lines k, l of ``lines`` [SI unit^2]. The window's
    support (up to its last nonzero sample) sets the cost: meant for the
    short force window.
    """
    nz = np.nonzero(w)[0]
    S = int(nz[-1]) + 1 if nz.size else 1
    from scipy.linalg import toeplitz

    c = model.autocovariance(S)
    ws = w[:S]
    A = ws[:, None] * toeplitz(c) * ws[None, :]
    E = np.exp(-2j * np.pi * np.outer(lines, np.arange(S)) / L)
    EA = E @ A
    return np.asarray(EA @ np.conj(E).T), np.asarray(EA @ E.T)
