"""Model transfer functions at complex frequency, for fitting windowed records.

An exponential window exp(-sigma t) applied to both the force and the
response of a linear system from rest turns the ratio of their spectra into
the transfer function at the complex Laplace variable s = sigma + j w:

    X_w(w) / F_w(w) = H(s),  H(s) = [K + s C + s^2 M]^-1,  s = sigma + j 2 pi f

(the exp(+j w t) convention of :mod:`clm_core.frequency`). Evaluating the
model at s instead of j w makes the fit exact for any window decay, with no
"added damping" correction. For sigma = 0 these functions equal
:func:`clm_core.soil.chain.chain_frequency_response` and
:func:`clm_core.frequency.dynamic_solve` (tested).

The matrices come from the project's own assembly:
:func:`clm_core.soil.chain.chain_matrices` for the CLM chain (Eq. 7–8) and
:func:`clm_core.track.assemble` for the track (paper Sec. 5, Fig. 6).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from numpy.typing import ArrayLike, NDArray

from clm_core.calibration.errors import CalibrationError
from clm_core.params import SoilParams
from clm_core.soil.chain import chain_matrices
from clm_core.track import TrackSystem

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

#: Soil parameter order used by the chain Jacobian.
CHAIN_PARAMS: tuple[str, ...] = ("mf", "kf", "df", "kc", "dc")


def laplace(f: ArrayLike, sigma: float = 0.0) -> CArray:
    """Complex frequency s = sigma + j 2 pi f [1/s] for frequencies ``f`` [Hz]."""
    return sigma + 2j * np.pi * np.asarray(f, dtype=float)


def chain_response(
    soil: SoilParams, n_areas: int, s: ArrayLike, jacobian: bool = False
) -> tuple[CArray, CArray | None]:
    """Area displacements per unit force on the centre area, at complex frequency s.

    Solves (K + s C + s^2 M) X = e_c for the free-ended chain of Eq. (7)–(8)
    (matrices of :func:`clm_core.soil.chain.chain_matrices`), by banded LU
    with partial pivoting at each frequency.

    Parameters
    ----------
    soil : SoilParams
        Winkler, Lysmer or CLM soil.
    n_areas : int
        Number of areas 2n + 1 (odd); the loaded area is column ``n_areas // 2``.
    s : (n_f,) complex array_like
        Laplace variable [1/s] (``laplace(f, sigma)``).
    jacobian : bool
        Also return dX/dp for p = (m_f, k_f, d_f, k_c, d_c).

    Returns
    -------
    X : (n_f, n_areas) complex array
        Receptances X_j / F [m/N].
    dX : (5, n_f, n_areas) complex array or None
        Derivatives with respect to ``CHAIN_PARAMS`` [m/N per unit of the
        parameter]: dX/dp = -D^-1 (dD/dp) X.
    """
    s = np.atleast_1d(np.asarray(s, dtype=complex))
    M, C, K = chain_matrices(soil, n_areas)
    n = n_areas
    kd, ko = K.diagonal(), K.diagonal(1)
    cd, co = C.diagonal(), C.diagonal(1)
    md = M.diagonal()
    nb = np.full(n, 2.0)  # number of neighbours of each area
    nb[0] = nb[-1] = 1.0
    if n == 1:
        nb[:] = 0.0
    rhs = np.zeros((n, 6 if jacobian else 1), dtype=complex)
    X = np.empty((s.size, n), dtype=complex)
    dX = np.empty((5, s.size, n), dtype=complex) if jacobian else None
    e_c = np.zeros(n, dtype=complex)
    e_c[n // 2] = 1.0
    ab = np.zeros((3, n), dtype=complex)
    for i, si in enumerate(s):
        ab[1] = kd + si * cd + si * si * md
        if n > 1:
            ab[0, 1:] = ko + si * co
            ab[2, :-1] = ko + si * co
        x = sla.solve_banded((1, 1), ab, e_c, check_finite=False)
        X[i] = x
        if jacobian and dX is not None:
            lap = nb * x
            if n > 1:
                lap[:-1] -= x[1:]
                lap[1:] -= x[:-1]
            rhs[:, 0] = si * si * x  # d/dmf
            rhs[:, 1] = x  # d/dkf
            rhs[:, 2] = si * x  # d/ddf
            rhs[:, 3] = lap  # d/dkc
            rhs[:, 4] = si * lap  # d/ddc
            sol = sla.solve_banded((1, 1), ab, rhs[:, :5], check_finite=False)
            dX[:, i, :] = -sol.T
    return X, dX


def track_response(system: TrackSystem, s: ArrayLike, force_dof: int, out_dofs: ArrayLike) -> CArray:
    """Responses at ``out_dofs`` per unit force at ``force_dof``, at complex frequency s.

    Solves (K + s C + s^2 M) X = e_force with the banded matrices of an
    assembled track (:func:`clm_core.track.assemble`), as
    :func:`clm_core.frequency.dynamic_solve` does for s = j w.

    Parameters
    ----------
    system : TrackSystem
        Assembled track–soil model.
    s : (n_f,) complex array_like
        Laplace variable [1/s].
    force_dof : int
        DOF of the unit force (e.g. ``system.rail_w[system.sleeper_node[c]]``).
    out_dofs : (n_out,) int array_like
        DOFs whose displacement is returned.

    Returns
    -------
    (n_f, n_out) complex array [m/N]
    """
    s = np.atleast_1d(np.asarray(s, dtype=complex))
    out = np.asarray(out_dofs, dtype=np.int64)
    if force_dof < 0 or force_dof >= system.n_dof or np.any(out < 0) or np.any(out >= system.n_dof):
        raise CalibrationError(f"track_response: DOF out of range (force {force_dof}, outputs {out.tolist()})")
    b = system.half_bandwidth
    Kb, Mb, Cb = (system.banded(A).astype(float) for A in (system.K, system.M, system.C))
    F = np.zeros(system.n_dof, dtype=complex)
    F[force_dof] = 1.0
    H = np.empty((s.size, out.size), dtype=complex)
    for k, sk in enumerate(s):
        ab = Kb + sk * Cb + sk * sk * Mb
        H[k] = sla.solve_banded((b, b), ab, F, overwrite_ab=True, check_finite=False)[out]
    return H
