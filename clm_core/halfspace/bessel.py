"""Bessel function J0 of complex argument, fast (numba), for wavenumber integrals.

The wavenumber integrals of :mod:`clm_core.halfspace.green` run on a contour
in the upper half of the complex k plane, where J0(k r) must be evaluated
for complex arguments of modest imaginary part (|Im z| <~ 3) on large
(k points x radii) grids. ``scipy.special.jv`` handles complex arguments but
is slow for millions of values; this module evaluates

- the power series  J0(z) = sum_m (-z^2/4)^m / (m!)^2  for |z| < 12, and
- Hankel's asymptotic expansion
  J0(z) = sqrt(2/(pi z)) [P(z) cos(z - pi/4) - Q(z) sin(z - pi/4)]
  for |z| >= 12 (|arg z| < pi/2 here),

both to about 1e-13 relative to max(|J0|, e^{|Im z|}/sqrt(|z|)) (checked
against scipy in the tests).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from numpy.typing import NDArray

__all__ = ["j0_complex", "j0_matvec", "j0_outer"]

_SWITCH = 12.0


@nb.njit(cache=True, fastmath=False)
def _hankel_pq(z: complex) -> tuple[complex, complex]:
    """P(z) and Q(z) of Hankel's asymptotic expansion of J0 (mu = 4 nu^2 = 0) [-].

    b_k = prod_{j=1..k} (2j-1)^2 / (k! 8^k z^k): P = 1 - b_2 + b_4 - ..., Q = -b_1 + b_3 - ...; the series stop at
    the first term below 1e-17 or at the smallest term (optimal truncation).
    """
    iz8 = 1.0 / (8.0 * z)
    p = 1.0 + 0.0j
    qq = 0.0 + 0.0j
    a = 1.0 + 0.0j
    best = 1e300
    for k in range(1, 60):
        a = a * ((2 * k - 1) * (2 * k - 1)) / k * iz8
        mag = abs(a)
        if mag > best:
            break
        best = mag
        r = k % 4
        if r == 1:
            qq -= a
        elif r == 2:
            p -= a
        elif r == 3:
            qq += a
        else:
            p += a
        if mag < 1e-17:
            break
    return p, qq


@nb.njit(cache=True, fastmath=False)
def _j0_scalar(z: complex) -> complex:
    az = abs(z)
    if az < _SWITCH:
        q = -0.25 * z * z
        term = 1.0 + 0.0j
        s = term
        m = 1
        while m < 200:
            term = term * q / (m * m)
            s += term
            if abs(term) < 1e-17 * abs(s) and m > 2:
                break
            m += 1
        return s
    # Hankel asymptotic expansion, mu = 4 nu^2 = 0
    p, qq = _hankel_pq(z)
    phase = z - 0.25 * math.pi
    out: complex = np.sqrt(2.0 / (math.pi * z)) * (p * np.cos(phase) - qq * np.sin(phase))
    return out


@nb.njit(cache=True, parallel=True)
def _j0_outer_kernel(k: NDArray[np.complex128], r: NDArray[np.float64], out: NDArray[np.complex128]) -> None:
    nr = r.shape[0]
    nk = k.shape[0]
    for i in nb.prange(nr):
        for j in range(nk):
            out[i, j] = _j0_scalar(k[j] * r[i])


@nb.njit(cache=True, parallel=True)
def _j0_flat_kernel(z: NDArray[np.complex128], out: NDArray[np.complex128]) -> None:
    for i in nb.prange(z.shape[0]):
        out[i] = _j0_scalar(z[i])


@nb.njit(cache=True, fastmath=False)
def _j0_hankel(z: complex, amp: complex) -> complex:
    """Hankel's expansion of J0(z) for |z| >= _SWITCH, given amp = sqrt(2 / (pi z)) [-].

    cos and sin of z - pi/4 from one complex exponential; the series P, Q
    from :func:`_hankel_pq`, as in :func:`_j0_scalar`.
    """
    p, qq = _hankel_pq(z)
    e = np.exp(1j * (z - 0.25 * math.pi))
    ei = 1.0 / e
    cos = 0.5 * (e + ei)
    sin = -0.5j * (e - ei)
    out: complex = amp * (p * cos - qq * sin)
    return out


@nb.njit(cache=True, parallel=True)
def _j0_matvec_kernel(k: NDArray[np.complex128], amp_k: NDArray[np.complex128], r: NDArray[np.float64],
                      f: NDArray[np.complex128], out: NDArray[np.complex128]) -> None:
    nr = r.shape[0]
    nk = k.shape[0]
    for i in nb.prange(nr):
        ri = r[i]
        acc = 0.0 + 0.0j
        if ri > 0.0:
            amp_r = 1.0 / math.sqrt(ri)
            for j in range(nk):
                z = k[j] * ri
                if abs(z) < _SWITCH:
                    acc += _j0_scalar(z) * f[j]
                else:
                    acc += _j0_hankel(z, amp_k[j] * amp_r) * f[j]
        else:
            for j in range(nk):
                acc += f[j]
        out[i] = acc


def j0_complex(z: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """J0(z) for complex ``z`` with Re z >= 0 (any shape) [-]."""
    zz = np.ascontiguousarray(np.asarray(z, dtype=np.complex128).ravel())
    out = np.empty_like(zz)
    _j0_flat_kernel(zz, out)
    return out.reshape(np.shape(z))


def j0_outer(r: NDArray[np.float64], k: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """Matrix J0(k_j r_i) of shape (len(r), len(k)), for r >= 0 [m] and complex k [1/m]."""
    rr = np.ascontiguousarray(np.asarray(r, dtype=np.float64).ravel())
    kk = np.ascontiguousarray(np.asarray(k, dtype=np.complex128).ravel())
    out = np.empty((rr.shape[0], kk.shape[0]), dtype=np.complex128)
    _j0_outer_kernel(kk, rr, out)
    return out


def j0_matvec(r: NDArray[np.float64], k: NDArray[np.complex128], f: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """sum_j J0(k_j r_i) f_j for each r_i, shape (len(r),): ``j0_outer(r, k) @ f`` without the matrix.

    Parameters
    ----------
    r : array_like
        Radii >= 0 [m].
    k : array_like of complex
        Wavenumbers with Re k > 0 [1/m] (the contour of the wavenumber integral).
    f : array_like of complex
        Weights (quadrature weights times integrand), one per ``k``.
    """
    rr = np.ascontiguousarray(np.asarray(r, dtype=np.float64).ravel())
    kk = np.ascontiguousarray(np.asarray(k, dtype=np.complex128).ravel())
    ff = np.ascontiguousarray(np.asarray(f, dtype=np.complex128).ravel())
    if ff.shape != kk.shape:
        raise ValueError(f"j0_matvec: {ff.size} weights for {kk.size} wavenumbers")
    out = np.empty(rr.shape[0], dtype=np.complex128)
    amp = np.zeros_like(kk)  # sqrt(2 / (pi k)), used only where |k r| >= _SWITCH (so k != 0)
    nz = kk != 0
    amp[nz] = np.sqrt(2.0 / (math.pi * kk[nz]))
    _j0_matvec_kernel(kk, amp, rr, ff, out)
    return out
