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
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array, CArray
from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.spectra import TransferData

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

    Sigma is the covariance of the stacked real residuals (real parts, then
    imaginary parts, channel by channel; :func:`stack_residual`) that the
    measurement noise causes: each channel's sensor noise with the window's
    line correlation (:meth:`TransferData.h_cov`, :meth:`TransferData.h_pcov`),
    plus the force-channel noise, which is common to all channels
    (``TransferData.force_cov``, ``force_pcov``). The parameter score is
    s = J^T r = Re(u^T y) with u = conj(J_re + j J_im) per line, so for a
    complex residual y with covariance C = E[y y^H] and pseudo-covariance
    P = E[y y^T]

        J^T Sigma J = 1/2 Re(Jc^H C Jc + Jc^H P conj(Jc)),   Jc = J_re + j J_im.

    The pseudo-covariance matters for the force noise: it lives in a window
    of a few milliseconds, so its spectrum is nearly real and fully
    correlated over the band (issue 14). None when the data carry no noise
    model.
    """
    covs = [data.h_cov(j) for j in cols]
    pcovs = [data.h_pcov(j) for j in cols]
    if any(c is None for c in covs) or data.force_cov is None:
        return None
    n_f = data.frequency.size
    Cs: list[CArray] = []
    Ps: list[CArray | None] = []
    for k, (Cj, Pj) in enumerate(zip(covs, pcovs)):
        assert Cj is not None
        d = D[:, k]
        Cs.append(d[:, None] * Cj * np.conj(d)[None, :])
        Ps.append(None if Pj is None else d[:, None] * Pj * d[None, :])
    Y = D * data.H[:, cols]  # (n_f, n_ch): the force noise moves y by -Y dF / F
    Gf = data.force_cov
    Pf = data.force_pcov
    tr_f = float(np.sum(np.abs(Y) ** 2 * np.real(np.diag(Gf))[:, None]))

    def apply(J: Array) -> tuple[Array, float]:
        n_p = J.shape[1]
        B = np.zeros((n_p, n_p))
        tr = tr_f
        Ahat = np.zeros((n_f, n_p), dtype=complex)
        for k, (C, P) in enumerate(zip(Cs, Ps)):
            blk = J[2 * n_f * k : 2 * n_f * (k + 1)]
            Jc = blk[:n_f] + 1j * blk[n_f:]
            B += 0.5 * np.real(np.conj(Jc).T @ C @ Jc)
            if P is not None:
                B += 0.5 * np.real(np.conj(Jc).T @ P @ np.conj(Jc))
            tr += float(np.real(np.trace(C)))
            Ahat += Jc * np.conj(Y[:, k])[:, None]
        B += 0.5 * np.real(np.conj(Ahat).T @ Gf @ Ahat)
        if Pf is not None:
            B += 0.5 * np.real(np.conj(Ahat).T @ Pf @ np.conj(Ahat))
        return B, tr

    return apply


def channel_noise_power(data: TransferData, cols: list[int], D: CArray) -> Array | None:
    """E[sum r_i^2] of each channel's residuals y = D (H_model - H) under the noise model.

    The trace of the channel's block of the residual covariance of
    :func:`make_sandwich`: its sensor noise plus its share of the force
    noise, sum_k |D_k|^2 (var_sensor(H_k) + |H_k|^2 force_cov[k, k]).

    Returns
    -------
    (n_cols,) array or None
        None without a noise model.
    """
    if data.force_cov is None:
        return None
    out = np.zeros(len(cols))
    fdiag = np.real(np.diag(data.force_cov))
    for k, j in enumerate(cols):
        Cj = data.h_cov(j)
        if Cj is None:
            return None
        d2 = np.abs(D[:, k]) ** 2
        out[k] = float(np.sum(d2 * (np.real(np.diag(Cj)) + np.abs(data.H[:, j]) ** 2 * fdiag)))
    return out


def residual_layout(n_f: int, n_ch: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Frequency line and channel of every real residual in the layout of :func:`stack_residual`.

    Returns
    -------
    lines, channels : (2 n_f n_ch,) int arrays
    """
    lines = np.tile(np.concatenate([np.arange(n_f), np.arange(n_f)]), n_ch).astype(np.int64)
    chans = np.repeat(np.arange(n_ch), 2 * n_f).astype(np.int64)
    return lines, chans


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


def corr_factor(data: TransferData, norm: str) -> float:
    """kappa of a fit in ``norm`` (:func:`clm_core.calibration.lsq.fit_bounded`) [-].

    The window's correlation of neighbouring lines (:attr:`TransferData.corr_factor`)
    for the ``weighted`` norm, 1 for the others.
    """
    return data.corr_factor if norm == "weighted" else 1.0


def misfit(Hm: CArray, H: CArray, W: Array | None) -> float:
    """Relative misfit in the fit's norm: ||W (H_model - H)|| / ||W H|| (``log``: rms |log(H_model / H)|) [-]."""
    if W is None:
        return float(np.sqrt(np.mean(np.abs(np.log(Hm / H)) ** 2)))
    return float(np.linalg.norm(W * (Hm - H)) / np.linalg.norm(W * H))


@dataclass(frozen=True)
class WhitenessCheck:
    """Are the residuals of a fit the measurement noise alone? (issue 14).

    The residuals of each channel (real parts, then imaginary parts, over
    the band) are whitened with the Cholesky factor of their covariance
    under the noise model (sensor noise with the window's line correlation,
    and the force noise; :func:`make_sandwich` describes both). If the model
    explains the data down to the noise the whitened residuals z are
    independent with unit variance; a model error (a chain too short, a soil
    that is no CLM chain, a noise model that is wrong) leaves them too large
    and correlated from one frequency line to the next, because a model
    error is smooth in frequency.

    Attributes
    ----------
    rms : float
        sqrt(mean z^2) over every channel [-] (1 under the noise model).
    lag1 : float
        Lag-1 autocorrelation of z along frequency, pooled over channels [-]
        (0 under the noise model, standard error about 1 / sqrt(n)).
    ljung_box : float
        Ljung–Box statistic Q = sum_channels n (n + 2) sum_{l <= h} rho_l^2 / (n - l)
        over ``lags`` lags [-].
    p_value : float
        P(chi^2 with ``lags`` x n_channels degrees of freedom > Q) [-].
    lags : int
        h.
    channel_rms : tuple of float
        rms of z per channel (the order of the fitted channels) [-].
    channel_lag1 : tuple of float
        Lag-1 autocorrelation of z per channel [-].
    """

    rms: float
    lag1: float
    ljung_box: float
    p_value: float
    lags: int
    channel_rms: tuple[float, ...]
    channel_lag1: tuple[float, ...]

    def white(self, lag1_max: float = 0.05, p_min: float = 1e-3) -> bool:
        """Whether the residuals pass as white: lag-1 autocorrelation <= ``lag1_max`` or p >= ``p_min``.

        The whitened rms is reported but not used: where the noise model
        predicts almost no noise (the force noise spans only a few dozen
        directions of the band), a tiny model error, invisible in the plain
        rms, inflates it on one or two channels.
        """
        return bool(self.lag1 <= lag1_max or self.p_value >= p_min)


def _real_cov(C: CArray, P: CArray | None) -> Array:
    """Covariance of [Re y; Im y] from C = E[y y^H] and P = E[y y^T]."""
    Pm = np.zeros_like(C) if P is None else P
    top = np.concatenate([0.5 * np.real(C + Pm), 0.5 * (np.imag(Pm) - np.imag(C))], axis=1)
    bot = np.concatenate([0.5 * (np.imag(Pm) + np.imag(C)), 0.5 * np.real(C - Pm)], axis=1)
    return np.asarray(np.concatenate([top, bot], axis=0))


def residual_whiteness(
    data: TransferData, cols: list[int], D: CArray, r: Array, lags: int = 5
) -> WhitenessCheck | None:
    """Whiten the residuals r = stack(D (H_model - H)) of the channels ``cols`` and test them (:class:`WhitenessCheck`).

    Parameters
    ----------
    data : TransferData
        Measured receptances with their noise model.
    cols : list of int
        Fitted channels (columns of ``data.H``), in residual order.
    D : (n_f, n_cols) complex array
        Residual weights (``weighted`` norm: sqrt(2) / std(H)).
    r : (2 n_f n_cols,) array
        Residuals at the optimum, layout of :func:`stack_residual`.
    lags : int
        Lags h of the Ljung–Box statistic.

    Returns
    -------
    WhitenessCheck or None
        None without a noise model.
    """
    from scipy.stats import chi2

    if data.force_cov is None:
        return None
    n_f = data.frequency.size
    Y = D * data.H[:, cols]
    Gf = data.force_cov
    Pf = data.force_pcov
    zs: list[Array] = []
    for k, j in enumerate(cols):
        Cj, Pj = data.h_cov(j), data.h_pcov(j)
        if Cj is None:
            return None
        d, y = D[:, k], Y[:, k]
        C = d[:, None] * Cj * np.conj(d)[None, :] + y[:, None] * Gf * np.conj(y)[None, :]
        P = None if Pj is None else d[:, None] * Pj * d[None, :]
        if Pf is not None:
            P = (P if P is not None else 0) + y[:, None] * Pf * y[None, :]
        S = _real_cov(C, P)
        try:
            Lc = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            return None
        zs.append(np.asarray(np.linalg.solve(Lc, r[2 * n_f * k : 2 * n_f * (k + 1)]), dtype=np.float64))
    Z = np.array(zs)  # (n_ch, 2 n_f)
    halves = [Z[:, :n_f], Z[:, n_f:]]  # real and imaginary sequences along frequency
    ms = float(np.mean(Z**2))
    num1 = sum(float(np.sum(h[:, 1:] * h[:, :-1])) for h in halves)
    den = sum(float(np.sum(h**2)) for h in halves)
    lag1 = num1 / den if den > 0 else 0.0
    Q = 0.0
    n = n_f
    for h in halves:
        c0 = np.sum(h**2, axis=1)
        c0 = np.where(c0 > 0, c0, 1.0)
        for lag in range(1, lags + 1):
            rho = np.sum(h[:, lag:] * h[:, :-lag], axis=1) / c0
            Q += float(np.sum(n * (n + 2) * rho**2 / (n - lag)))
    dof = lags * 2 * len(cols)
    ch_rms = tuple(float(x) for x in np.sqrt(np.mean(Z**2, axis=1)))
    ch_l1 = tuple(
        float(
            (np.sum(Z[c, 1:n_f] * Z[c, : n_f - 1]) + np.sum(Z[c, n_f + 1 :] * Z[c, n_f:-1]))
            / max(float(np.sum(Z[c] ** 2)), 1e-300)
        )
        for c in range(Z.shape[0])
    )
    return WhitenessCheck(
        rms=float(np.sqrt(ms)),
        lag1=float(lag1),
        ljung_box=Q,
        p_value=float(chi2.sf(Q, dof)),
        lags=lags,
        channel_rms=ch_rms,
        channel_lag1=ch_l1,
    )
