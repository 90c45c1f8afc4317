"""Model transfer functions at complex frequency, for fitting windowed records.

An exponential window exp(-sigma t) applied to both the force and the
response of a linear system from rest turns the ratio of their spectra into
the transfer function at the complex Laplace variable s = sigma + j w:

    X_w(w) / F_w(w) = H(s),  H(s) = [K + s C + s^2 M]^-1,  s = sigma + j 2 pi f

(the exp(+j w t) convention of :mod:`clm_core.frequency`). Evaluating the
model at s instead of j w makes the fit exact for any window decay, with no
"added damping" correction.

- the CLM chain (Eq. 7-8): :func:`clm_core.soil.chain.chain_response`, the
  project's one chain solver, with its Jacobian (``laplace`` and
  ``CHAIN_PARAMS`` live there too);
- the track (paper Sec. 5, Fig. 6): :func:`track_response` with the matrices of
  :func:`clm_core.track.assemble`; for sigma = 0 it equals
  :func:`clm_core.frequency.dynamic_solve` (tested).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from numpy.typing import ArrayLike

from clm_core.arrays import CArray
from clm_core.calibration.errors import CalibrationError
from clm_core.track import TrackSystem


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
