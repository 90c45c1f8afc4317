"""The CLM chain of 2n + 1 soil contact areas alone (paper Sec. 4, Eq. 7–20).

Area 0 is loaded; the chain has free ends (each end area has one neighbour).
Equations of motion, Eq. (7)–(8):

    m_f x_i'' + d_f x_i' + k_f x_i + sum_{j = i +- 1} [d_c (x_i' - x_j') + k_c (x_i - x_j)] = f_i(t)

In the frequency domain (exp(+j w t)) the impedance over the total sum
F / sum_j X_j equals k_f - w^2 m_f + j w d_f exactly for free ends (Eq. 15–16;
the coupling terms cancel in the sum), and the impedance over the
alternating sum tends to (k_f + 4 k_c) - w^2 m_f + j w (d_f + 4 d_c) as n grows
(Eq. 18; the end areas make it approximate for finite n).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from clm_core.errors import ParameterError
from clm_core.excitation import decay_pulse
from clm_core.newmark import NewmarkLinear
from clm_core.params import SoilParams

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]


def _check(soil: SoilParams, n_areas: int) -> None:
    if soil.model not in ("lysmer", "clm", "winkler"):
        raise ParameterError(f"soil.model = {soil.model!r}: the chain needs winkler, lysmer or clm")
    if n_areas < 1 or n_areas % 2 == 0:
        raise ParameterError(f"n_areas = {n_areas}: must be odd (2n + 1 areas, loaded one at the centre)")


def chain_matrices(soil: SoilParams, n_areas: int) -> tuple[sp.csr_matrix, sp.csr_matrix, sp.csr_matrix]:
    """Mass, damping and stiffness matrices of a free-ended chain of ``n_areas`` areas.

    Returns
    -------
    M, C, K : scipy.sparse.csr_matrix, shape (n_areas, n_areas)
        [kg], [N s/m], [N/m].
    """
    _check(soil, n_areas)
    n = n_areas
    links = np.zeros(n)
    links[:-1] += 1
    links[1:] += 1  # number of neighbours of each area
    K = sp.diags([soil.kf + soil.kc * links, -soil.kc * np.ones(n - 1), -soil.kc * np.ones(n - 1)], [0, -1, 1])
    C = sp.diags([soil.df + soil.dc * links, -soil.dc * np.ones(n - 1), -soil.dc * np.ones(n - 1)], [0, -1, 1])
    M = sp.diags([soil.mf * np.ones(n)], [0])
    return M.tocsr(), C.tocsr(), K.tocsr()


def chain_frequency_response(soil: SoilParams, n_areas: int, f: ArrayLike) -> CArray:
    """Displacements X_j / F of all areas for a unit force on the centre area [m/N].

    Returns
    -------
    (n_f, n_areas) complex array; column ``n_areas // 2`` is the loaded area.
    """
    f = np.asarray(f, dtype=float)
    M, C, K = chain_matrices(soil, n_areas)
    n = n_areas
    diag_k, off_k = K.diagonal(), K.diagonal(1)
    diag_c, off_c = C.diagonal(), C.diagonal(1)
    F = np.zeros(n, dtype=complex)
    F[n // 2] = 1.0
    out = np.empty((f.size, n), dtype=complex)
    for i, fi in enumerate(f):
        w = 2 * np.pi * fi
        ab = np.zeros((3, n), dtype=complex)
        ab[1] = diag_k - w**2 * soil.mf + 1j * w * diag_c
        ab[0, 1:] = off_k + 1j * w * off_c
        ab[2, :-1] = off_k + 1j * w * off_c
        out[i] = sla.solve_banded((1, 1), ab, F)
    return out


@dataclass(frozen=True)
class ChainSums:
    """Impedances over the two sums of a chain response (Eq. 16 and 18) [N/m]."""

    frequency: Array
    total: CArray  # F / sum_j X_j
    alternating: CArray  # F / sum_j (-1)^j X_j


def chain_sums(frequency: ArrayLike, X: CArray, force: ArrayLike = 1.0) -> ChainSums:
    """Form F / sum_j X_j and F / sum_j (-1)^j X_j from area responses.

    Parameters
    ----------
    frequency : (n_f,) array [Hz]
    X : (n_f, 2n + 1) complex array
        Area displacements, the loaded area at the centre column.
    force : scalar or (n_f,) array
        Force spectrum F [N] (1 for receptances).
    """
    X = np.asarray(X)
    n = X.shape[1]
    if n % 2 == 0:
        raise ParameterError(f"X has {n} areas: need 2n + 1 with the loaded area at the centre")
    j = np.arange(n) - n // 2
    sign = np.where(j % 2 == 0, 1.0, -1.0)
    F = np.asarray(force)
    return ChainSums(np.asarray(frequency, dtype=float), F / X.sum(axis=1), F / (X * sign).sum(axis=1))


@dataclass(frozen=True)
class ChainTimeResponse:
    """Time response of a chain to a force on the centre area.

    Attributes
    ----------
    t : (n_t,) array [s]
    force : (n_t,) array [N]
    x, v : (n_t, n_areas) arrays [m], [m/s]
    """

    t: Array
    force: Array
    x: Array
    v: Array

    def peaks(self, n_neighbours: int = 2) -> tuple[list[float], list[float]]:
        """Peak displacement [m] and its time [s] for the loaded area and its neighbours."""
        c = self.x.shape[1] // 2
        amps, times = [], []
        for k in range(n_neighbours + 1):
            col = self.x[:, c + k]
            i = int(np.argmax(np.abs(col)))
            amps.append(float(col[i]))
            times.append(float(self.t[i]))
        return amps, times


def chain_time_response(
    soil: SoilParams,
    n_areas: int = 41,
    dt: float = 1.0e-5,
    duration: float = 0.15,
    A: float = 1.0,
    t0: float = 0.05,
    td: float = 0.001,
) -> ChainTimeResponse:
    """Response of the chain to the Eq. (1) pulse on the centre area (Newmark, from rest)."""
    M, C, K = chain_matrices(soil, n_areas)
    n_steps = int(round(duration / dt))
    t = np.arange(n_steps + 1) * dt
    p = decay_pulse(t, A, t0, td)
    F = np.zeros((n_steps + 1, n_areas))
    F[:, n_areas // 2] = p
    _, x, v = NewmarkLinear(M, C, K, dt).run(F, n_steps)
    return ChainTimeResponse(np.asarray(t, dtype=np.float64), p, x, v)


def chain_damping_min_eigenvalue(soil: SoilParams, n_areas: int) -> float:
    """Smallest eigenvalue of the chain damping matrix [N s/m] (stability, Sec. 4.2)."""
    _, C, _ = chain_matrices(soil, n_areas)
    return float(np.linalg.eigvalsh(C.toarray())[0])
