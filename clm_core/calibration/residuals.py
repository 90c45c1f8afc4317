"""Residuals of transfer-function fits: error norms, layout, noise covariance.

Shared by the impact (:mod:`clm_core.calibration.impact`) and receptance
(:mod:`clm_core.calibration.receptance`) fits. A residual is formed per
frequency line and channel from the complex misfit e = H_model - H:

- ``weighted``: e / std(H) x sqrt(2) (each real component ~ N(0, 1));
- ``absolute``: e / max |H|;
- ``relative``: e / |H|;
- ``log``: log(H_model / H).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.spectra import TransferData

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

NORMS: tuple[str, ...] = ("weighted", "absolute", "relative", "log")


def stack_residual(e: CArray, de: CArray | None = None) -> tuple[Array, Array | None]:
    """Real residual vector and Jacobian from complex (n_f, n_ch) residuals and (n_p, n_f, n_ch) derivatives.

    Layout, channel by channel: the n_f real parts, then the n_f imaginary
    parts (what :func:`make_sandwich` expects).
    """
    r = np.concatenate([e.real.T, e.imag.T], axis=1).ravel()
    if de is None:
        return r, None
    k = de.shape[0]
    dT = np.transpose(de, (0, 2, 1))  # (k, n_ch, n_f)
    J = np.concatenate([dT.real, dT.imag], axis=2).reshape(k, -1).T
    return r, J


def make_sandwich(data: TransferData, cols: list[int], D: CArray) -> Callable[[Array], tuple[Array, float]] | None:
    """J -> (J^T Sigma J, trace Sigma) for residuals y = D (H_model - H) of the channels ``cols``.

    Sigma is the residual covariance that the measurement noise causes:
    each channel's sensor noise with the window's line correlation
    (:meth:`TransferData.h_cov`), plus the force-channel noise, which is
    common to all channels (``TransferData.force_cov``). For y = a + j b with
    complex covariance C (pseudo-covariance neglected),
    J^T Sigma J = 1/2 Re(Jc^H C Jc), Jc = J_re + j J_im. None when the data
    carry no noise model.
    """
    covs = [data.h_cov(j) for j in cols]
    if any(c is None for c in covs) or data.force_cov is None:
        return None
    n_f = data.frequency.size
    Cs = []
    for k, Cj in enumerate(covs):
        assert Cj is not None
        d = D[:, k]
        Cs.append(d[:, None] * Cj * np.conj(d)[None, :])
    Y = D * data.H[:, cols]  # (n_f, n_ch): the force noise moves y by -Y dF / F
    Gf = data.force_cov
    tr_f = float(np.sum(np.abs(Y) ** 2 * np.real(np.diag(Gf))[:, None]))

    def apply(J: Array) -> tuple[Array, float]:
        n_p = J.shape[1]
        B = np.zeros((n_p, n_p))
        tr = tr_f
        Ahat = np.zeros((n_f, n_p), dtype=complex)
        for k, C in enumerate(Cs):
            blk = J[2 * n_f * k : 2 * n_f * (k + 1)]
            Jc = blk[:n_f] + 1j * blk[n_f:]
            B += 0.5 * np.real(np.conj(Jc).T @ C @ Jc)
            tr += float(np.real(np.trace(C)))
            Ahat += Jc * np.conj(Y[:, k])[:, None]
        B += 0.5 * np.real(np.conj(Ahat).T @ Gf @ Ahat)
        return B, tr

    return apply


def norm_weights(data: TransferData, cols: list[int], norm: str) -> tuple[Array | None, str, list[str]]:
    """Real weights W of the residual W (H_model - H) for the channels ``cols``, per norm.

    Returns
    -------
    W : (n_f, n_cols) array or None
        None for the ``log`` norm (residual log(H_model / H)).
    norm : str
        The norm used (``weighted`` falls back to ``absolute`` without a noise estimate).
    warnings : list of str

    Raises
    ------
    CalibrationError
        Unknown norm.
    """
    H = data.H[:, cols]
    if norm == "weighted":
        if data.std is None:
            return np.ones(H.shape) / np.max(np.abs(H)), "absolute", [
                "norm 'weighted' needs a noise estimate (samples before the first hit): used 'absolute'"
            ]
        return np.sqrt(2.0) / data.std[:, cols], "weighted", []
    if norm == "absolute":
        return np.ones(H.shape) / np.max(np.abs(H)), "absolute", []
    if norm == "relative":
        return 1.0 / np.abs(H), "relative", []
    if norm == "log":
        return None, "log", []
    raise CalibrationError(f"norm = {norm!r}: must be one of {', '.join(NORMS)}")


def misfit(Hm: CArray, H: CArray, W: Array | None) -> float:
    """Relative misfit in the fit's norm: ||W (H_model - H)|| / ||W H|| (``log``: rms |log(H_model / H)|) [-]."""
    if W is None:
        return float(np.sqrt(np.mean(np.abs(np.log(Hm / H)) ** 2)))
    return float(np.linalg.norm(W * (Hm - H)) / np.linalg.norm(W * H))
