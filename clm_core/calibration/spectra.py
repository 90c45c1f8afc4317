"""Transfer functions from impact records: hits, windows, H1 estimator, noise.

Route (standard impact-testing practice, e.g. Ewins, *Modal Testing*, 2000,
Sec. 3.9–3.10):

1. Hits are found on the force channel (threshold ``hit_threshold`` x peak,
   hits closer than ``hit_separation`` are one hit); each hit gives a
   segment that starts ``pretrigger`` seconds before the threshold crossing.
   All segments have the length of the shortest.
2. Force window: the force is kept from the segment start to the end of the
   pulse plus a margin (half-cosine taper) and zeroed after it, which
   removes the force-channel noise of the free-decay part.
3. Exponential window exp(-sigma t) on force and responses, decaying to
   ``exp_end`` at the segment end (``exp_end = 1``: none). The ratio of the
   windowed spectra is then the transfer function at the complex frequency
   s = sigma + j w, exactly (no added-damping correction), and the fit
   evaluates the model there (:mod:`clm_core.calibration.models`).
4. H1 = sum_k X_k F_k* / sum_k |F_k|^2 over the hits; velocity and
   acceleration become displacement receptances by dividing by s and s^2
   (from rest: V(s) = s X(s)).
5. Noise: the record of each channel before the first hit gives its noise
   spectrum (an autoregressive model, :mod:`clm_core.calibration.noise`;
   white noise stays white) and so the variance of every spectral line,
   var H = (var X(f) + |H|^2 var F(f)) / sum |F|^2, which weights the
   statistical (``weighted``) norm and gives the intervals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clm_core.arrays import Array, CArray
from clm_core.calibration.channels import ChannelSpec
from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.noise import NoiseSpectrum, fit_noise, windowed_cov
from clm_core.calibration.signals import Recording


@dataclass(frozen=True)
class WindowSpec:
    """Segmentation and windows of impact records.

    Attributes
    ----------
    pretrigger : float
        Segment start before the force crosses the hit threshold [s].
    exp_end : float
        Value of the exponential window at the segment end, in (0, 1];
        1 means no exponential window.
    hit_threshold : float
        Hit detection threshold, fraction of the largest |force|.
    hit_separation : float
        Threshold crossings closer than this are one hit [s].
    force_margin : float
        Least force window kept after the end of the pulse (|f| < 2 % of the
        hit's peak) [s]; the window is extended from the data
        (:func:`force_window`): at least ``force_tail`` samples, and until the
        force has settled below its noise. A cosine taper of half this margin
        (at least ``force_tail // 2`` samples) follows.
    force_tail : int
        Least number of samples kept after the end of the pulse, whatever
        ``force_margin`` says: the anti-alias filter's ringing (the responses
        keep theirs) must be inside the window. 4 ms at 1 kHz (4 samples)
        cut it off and biased the damping by -0.1 to -0.2 % (issue 24).
    noise_order : int
        Highest order of the autoregressive noise model fitted to the record
        before the hit (:mod:`clm_core.calibration.noise`; BIC chooses the
        order, white noise keeps 0); 0: white noise, as before issue 24.
    max_segment : float or None
        Upper bound of the segment length [s] (None: up to the next hit or
        the record end).
    snr_window : float
        Window after the hit over which the signal power of the reported
        SNR is taken [s] (the definition of the synthetic bags).
    """

    pretrigger: float = 0.01
    exp_end: float = 0.01
    hit_threshold: float = 0.2
    hit_separation: float = 0.05
    force_margin: float = 0.004
    force_tail: int = 20
    noise_order: int = 8
    max_segment: float | None = None
    snr_window: float = 0.1


@dataclass(frozen=True)
class TransferData:
    """Measured transfer functions of one test.

    Attributes
    ----------
    frequency : (n_f,) array
        Frequency lines in the band [Hz].
    sigma : float
        Decay rate of the exponential window [1/s]; the data are H(s) at
        s = sigma + j 2 pi f.
    H : (n_f, n_ch) complex array
        Displacement receptances X / F [m/N], one column per channel.
    std : (n_f, n_ch) array or None
        Standard deviation of each complex H value [m/N] (None if no noise
        estimate was possible).
    coherence : (n_f, n_ch) array or None
        Ordinary coherence over the hits (None for one hit).
    channels : tuple of ChannelSpec
        Response channels, in column order.
    n_hits : int
        Number of hits averaged.
    hit_times : tuple of float
        Threshold crossing of each hit [s].
    segment : float
        Segment length [s].
    corr_factor : float
        Correlation of neighbouring lines caused by the window,
        L sum w^4 / (sum w^2)^2 (1 for no exponential window); inflates the
        covariance of fitted parameters.
    snr_db : (n_ch,) array
        Estimated signal-to-noise ratio of each response channel, rms signal
        over ``snr_window`` from the hit / rms noise before the first hit [dB];
        NaN if unknown.
    force_snr_db : float
        The same for the force channel.
    fs : float
        Sample rate [Hz].
    band : tuple of float
        The requested band (fmin, fmax) [Hz]; ``frequency`` holds the lines inside it.
    noise_var : (n_ch,) array or None
        Noise variance of each response channel before the hit [SI unit^2].
    line_cov : (n_f, n_f) complex array or None
        Noise covariance kernel of the H1 estimate between frequency lines
        for unit noise variance, R(k - l) sum_h conj(F_hk) F_hl / (S_k S_l)
        with R(d) = sum_n w_n^2 exp(-2 pi j d n / L) (window correlation),
        in the recorded quantity's units (before conversion to displacement).
    force_cov : (n_f, n_f) complex array or None
        Relative covariance of the H1 estimate caused by the force-channel
        noise, shared by every channel: Cov(dH_jk, dH_il) = H_jk conj(H_il)
        force_cov[k, l] (the same force record divides every response).
    line_pcov, force_pcov : (n_f, n_f) complex arrays or None
        The matching pseudo-covariances E[dH_k dH_l] (no conjugate), with
        R(k + l) in place of R(k - l). The noise is real, so its spectrum at
        line k and at line -k are conjugate: for a short window (the force
        window lasts a few milliseconds) E[N_k N_l] is as large as
        E[N_k conj(N_l)] and the real and imaginary parts of the residuals
        do not have equal, uncorrelated variances. Neglecting it
        underestimated the force-noise part of the parameter covariance by up
        to a factor 1.4 in standard deviation (issue 14).
    force_tail : float
        Force window kept after the end of the pulse, mean over the hits
        [s] (:func:`force_window`; the taper follows it).
    noise_shape : (n_f, n_ch) array or None
        Each response channel's noise spectrum over its variance at the
        lines, P(f) / r(0) (:mod:`clm_core.calibration.noise`, fitted to the
        record before the hit); None when every channel's noise is white.
        Scales the sensor-noise variance of each line (and the covariance of
        lines k, l by the square root of the product).
    noise_models, force_noise_model : NoiseSpectrum
        The fitted noise models (response channels in column order; force);
        the force's enters ``force_cov`` exactly (:func:`~clm_core.calibration.noise.windowed_cov`).
    """

    frequency: Array
    sigma: float
    H: CArray
    std: Array | None
    coherence: Array | None
    channels: tuple[ChannelSpec, ...]
    n_hits: int
    hit_times: tuple[float, ...]
    segment: float
    corr_factor: float
    snr_db: Array
    force_snr_db: float
    fs: float
    band: tuple[float, float] = (0.0, 0.0)
    noise_var: Array | None = None
    line_cov: CArray | None = None
    force_cov: CArray | None = None
    line_pcov: CArray | None = None
    force_pcov: CArray | None = None
    force_tail: float = math.nan
    noise_shape: Array | None = None
    noise_models: tuple[NoiseSpectrum, ...] = ()
    force_noise_model: NoiseSpectrum | None = None

    @property
    def s(self) -> CArray:
        """Laplace variable sigma + j 2 pi f [1/s]."""
        return np.asarray(self.sigma + 2j * np.pi * self.frequency, dtype=np.complex128)

    def h_cov(self, j: int) -> CArray | None:
        """Covariance of the displacement receptance H[:, j] between lines due to its own sensor noise.

        (n_f, n_f) complex [(m/N)^2], with the window's line correlation;
        None without a noise estimate. The force noise adds
        ``H[:, j] conj(H[:, i]) force_cov`` (common to all channels).
        """
        if self.noise_var is None or self.line_cov is None:
            return None
        p = {"displacement": 0, "velocity": 1, "acceleration": 2}[self.channels[j].quantity]
        conv = self.s**p
        cov = self.noise_var[j] * self.line_cov / np.outer(conv, np.conj(conv))
        if self.noise_shape is not None:
            g = np.sqrt(self.noise_shape[:, j])
            cov = cov * np.outer(g, g)
        return np.asarray(cov)

    def h_pcov(self, j: int) -> CArray | None:
        """Pseudo-covariance E[dH_k dH_l] of H[:, j] due to its own sensor noise [(m/N)^2].

        (n_f, n_f) complex, the companion of :meth:`h_cov`; None without a
        noise estimate.
        """
        if self.noise_var is None or self.line_pcov is None:
            return None
        p = {"displacement": 0, "velocity": 1, "acceleration": 2}[self.channels[j].quantity]
        conv = self.s**p
        pcov = self.noise_var[j] * self.line_pcov / np.outer(conv, conv)
        if self.noise_shape is not None:
            g = np.sqrt(self.noise_shape[:, j])
            pcov = pcov * np.outer(g, g)
        return np.asarray(pcov)


def force_window(
    seg_f: Array, margin: int, min_tail: int = 20, noise: float | None = None, run: int = 10, floor: float = 1e-6
) -> tuple[Array, int, bool]:
    """Force window of one hit segment, its end found in the data (issue 24).

    The window is 1 from the segment start to the end of the pulse (the
    first sample after the peak below 2 % of it) plus a tail, then a cosine
    taper, then 0. The tail is the longest of ``margin // 2`` samples,
    ``min_tail`` samples, and the time the force takes to settle: the
    first run of ``run`` samples all below ``3 noise`` (or ``floor`` x the
    peak for a noise-free record). A sampled hammer force rings after the
    pulse (the data logger's anti-alias filter); the responses keep that
    ringing, so cutting it off the force biases the receptances (4 ms at
    1 kHz gave d_f -0.11 %, d_c -0.19 %; issue 24).

    Parameters
    ----------
    seg_f : (L,) array
        Force of the segment, positive pulse, resting level removed [N].
    margin : int
        Least kept length after the pulse [samples] (``force_margin`` x fs);
        the taper lasts ``max(margin - margin // 2, min_tail // 2)`` samples.
    min_tail : int
        Least tail [samples].
    noise : float, optional
        Standard deviation of the force noise [N].
    run, floor : int, float
        Settling rule (above).

    Returns
    -------
    wf : (L,) array
        The window.
    tail : int
        Tail kept at full weight after the pulse [samples].
    settled : bool
        Whether the force settled within the segment (else the tail is the
        whole segment after the pulse, capped at a quarter of it).
    """
    L = seg_f.size
    pk = int(np.argmax(seg_f))
    below = np.nonzero(seg_f[pk:] < 0.02 * seg_f[pk])[0]
    end = pk + (int(below[0]) if below.size else L - pk)
    thr = max(3.0 * (noise or 0.0), floor * float(seg_f[pk]))
    quiet = (np.abs(seg_f[end:]) < thr).astype(np.int64)
    settled = False
    decay = max(0, (L - end) // 4)
    if quiet.size >= run:
        runs = np.convolve(quiet, np.ones(run, dtype=np.int64), mode="valid")
        ok = np.nonzero(runs == run)[0]
        if ok.size:
            settled, decay = True, int(ok[0])
    tail = max(margin // 2, min_tail, decay)
    wf = np.zeros(L)
    flat = min(L, end + tail)
    stop = min(L, flat + max(margin - margin // 2, min_tail // 2, 2))
    wf[:flat] = 1.0
    if stop > flat:
        wf[flat:stop] = 0.5 * (1 + np.cos(np.pi * (np.arange(stop - flat) + 1) / (stop - flat + 1)))
    return wf, tail, settled


def find_hits(force: Array, fs: float, spec: WindowSpec) -> tuple[list[int], int]:
    """Threshold crossings of the hits and the polarity of the force (+1 / -1).

    Raises
    ------
    CalibrationError
        A force record with no excursion above its noise.
    """
    a = np.abs(force)
    peak_i = int(np.argmax(a))
    peak = float(a[peak_i])
    if peak == 0.0:
        raise CalibrationError("force record is all zeros: no hit")
    pol = 1 if force[peak_i] > 0 else -1
    x = pol * force
    above = x >= spec.hit_threshold * peak
    cross = np.nonzero(above[1:] & ~above[:-1])[0] + 1
    if above[0]:
        cross = np.concatenate([[0], cross])
    sep = max(1, int(round(spec.hit_separation * fs)))
    hits: list[int] = []
    for c in cross:
        if not hits or c - hits[-1] > sep:
            hits.append(int(c))
    return hits, pol


def transfer_functions(
    rec: Recording,
    fmin: float,
    fmax: float,
    spec: WindowSpec | None = None,
    min_lines: int = 16,
) -> tuple[TransferData, list[str]]:
    """Estimate displacement receptances of every response channel from an impact record.

    Parameters
    ----------
    rec : Recording
        Force [N] and responses (displacement [m], velocity [m/s] or
        acceleration [m/s^2]) on one time grid.
    fmin, fmax : float
        Band [Hz]; lines outside are dropped.
    spec : WindowSpec, optional
        Segmentation and windows.
    min_lines : int
        Least number of frequency lines in the band (a shorter segment is
        "too short a record").

    Returns
    -------
    TransferData
        See its attributes.
    list of str
        Warnings (response not decayed at the segment end, weak force in
        part of the band, no noise estimate).

    Raises
    ------
    CalibrationError
        No force, no hit, a band outside (0, 0.45 fs], a segment too short
        for ``min_lines`` lines in the band.
    """
    spec = spec or WindowSpec()
    if rec.force is None:
        raise CalibrationError("an impact or receptance test needs a force channel")
    if not 0.0 <= fmin < fmax:
        raise CalibrationError(f"band fmin = {fmin:g} Hz, fmax = {fmax:g} Hz: need 0 <= fmin < fmax")
    fs = rec.fs
    if fmax > 0.45 * fs:
        raise CalibrationError(
            f"fmax = {fmax:g} Hz: above 0.45 x the sample rate {fs:g} Hz (anti-alias filter region); "
            f"use fmax <= {0.45 * fs:g} Hz"
        )
    if not 0.0 < spec.exp_end <= 1.0:
        raise CalibrationError(f"exp_end = {spec.exp_end:g}: must lie in (0, 1]")
    for key in ("force_tail", "noise_order"):
        v = getattr(spec, key)
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise CalibrationError(f"window: {key} = {v!r}: must be an integer >= 0")
    warnings: list[str] = []
    f = rec.force
    hits, pol = find_hits(f, fs, spec)
    pre = int(round(spec.pretrigger * fs))
    starts = [h - pre for h in hits]
    if starts[0] < 0:
        raise CalibrationError(
            f"the first hit at t = {rec.t[hits[0]]:.4f} s is closer to the record start than the pretrigger "
            f"{spec.pretrigger:g} s; record longer before the hit or lower pretrigger"
        )
    n = f.size
    ends = [*starts[1:], n]
    L = min(e - s0 for s0, e in zip(starts, ends))
    if spec.max_segment is not None:
        L = min(L, int(round(spec.max_segment * fs)))
    T = L / fs
    lines = np.arange(L // 2 + 1) * fs / L
    band = (lines >= max(fmin, 1e-12)) & (lines <= fmax)
    if int(band.sum()) < min_lines:
        raise CalibrationError(
            f"too short a record: segments of {T:.4g} s after each hit give {int(band.sum())} frequency lines in "
            f"{fmin:g}-{fmax:g} Hz (rule: at least {min_lines}, line spacing 1/T = {1 / T:.3g} Hz); record at least "
            f"{min_lines / (fmax - fmin):.3g} s after each hit or widen the band"
        )
    sigma = -math.log(spec.exp_end) / T if spec.exp_end < 1.0 else 0.0
    tt = np.arange(L) / fs
    w_exp = np.exp(-sigma * tt)
    # noise before the first hit
    noise_x: Array | None = None
    noise_f: float | None = None
    f_model: NoiseSpectrum | None = None
    x_models: list[NoiseSpectrum] = []
    if starts[0] >= 32:
        pre_x = rec.responses[: starts[0]]
        noise_x = np.std(pre_x - pre_x.mean(axis=0), axis=0)
        noise_f = float(np.std(f[: starts[0]] - f[: starts[0]].mean()))
        f_model = fit_noise(f[: starts[0]], spec.noise_order)
        x_models = [fit_noise(pre_x[:, j], spec.noise_order) for j in range(pre_x.shape[1])]
    else:
        warnings.append(
            f"no noise estimate: only {starts[0]} samples before the first hit (rule: >= 32); the 'weighted' norm "
            "falls back to 'absolute'"
        )
    Sxf = np.zeros((band.sum(), rec.responses.shape[1]), dtype=complex)
    Sff = np.zeros(band.sum())
    Sxx = np.zeros((band.sum(), rec.responses.shape[1]))
    sum_w2_f = 0.0
    F_hits: list[CArray] = []
    wf_hits: list[Array] = []
    sig_pow = np.zeros(rec.responses.shape[1])
    force_pow = 0.0
    margin = max(3, int(round(spec.force_margin * fs)))
    f_rest = float(np.mean(f[: starts[0]])) if starts[0] >= 32 else 0.0
    tails: list[int] = []
    unsettled = 0
    for s0 in starts:
        seg_f = f[s0 : s0 + L] * pol
        seg_x = rec.responses[s0 : s0 + L] * pol
        wf, tail_n, settled = force_window(seg_f - f_rest * pol, margin, spec.force_tail, noise_f)
        tails.append(tail_n)
        if not settled:
            unsettled += 1
        Fk = np.fft.rfft(seg_f * wf * w_exp)[band]
        F_hits.append(Fk)
        wf_hits.append(wf * w_exp)
        Xk = np.fft.rfft(seg_x * w_exp[:, None], axis=0)[band]
        Sxf += Xk * np.conj(Fk)[:, None]
        Sff += np.abs(Fk) ** 2
        Sxx += np.abs(Xk) ** 2
        sum_w2_f += float(np.sum((wf * w_exp) ** 2))
        act = slice(pre, min(L, pre + max(1, int(round(spec.snr_window * fs)))))
        sig_pow += np.mean((seg_x[act] - (seg_x[:pre].mean(axis=0) if pre else 0.0)) ** 2, axis=0)
        force_pow += float(np.mean(seg_f[act] ** 2))
        tail = max(1, L // 10)
        peak_x = np.max(np.abs(seg_x), axis=0)
        tail_x = np.max(np.abs(seg_x[-tail:] * w_exp[-tail:, None]), axis=0)
        if noise_x is not None:
            undecayed = (tail_x > 0.05 * peak_x) & (tail_x > 5 * noise_x)
        else:
            undecayed = tail_x > 0.05 * peak_x
        if np.any(undecayed):
            names = [rec.channels[i].name for i in np.nonzero(undecayed)[0][:3]]
            warnings.append(
                f"response not decayed at the end of the {T:.3g} s segment ({', '.join(names)}...): leakage; "
                "lower exp_end or record longer after each hit"
            )
    K = len(starts)
    if unsettled:
        warnings.append(
            f"the force does not settle below its noise after the pulse ({unsettled} of {K} hit(s)): the force "
            f"window ends {max(tails) / fs:.3g} s after the pulse; a drifting or ringing force channel (check the "
            "hammer's cable and conditioning)"
        )
    H = Sxf / Sff[:, None]
    fr = lines[band]
    s = sigma + 2j * np.pi * fr
    power = {"displacement": 0, "velocity": 1, "acceleration": 2}
    conv = np.column_stack([s ** power[c.quantity] for c in rec.channels])
    std = None
    snr = np.full(len(rec.channels), np.nan)
    fsnr = float("nan")
    sum_w2 = float(np.sum(w_exp**2))
    line_cov = None
    shape: Array | None = None
    coloured = False
    fcov = None
    line_pcov = None
    fpcov = None
    if noise_x is not None and noise_f is not None:
        kb = np.nonzero(band)[0]
        dk = (kb[:, None] - kb[None, :]) % L
        sk = (kb[:, None] + kb[None, :]) % L
        R2 = np.fft.fft(w_exp**2)  # R(d) = sum w^2 exp(-2 pi j d n / L), d taken modulo L
        Fh = np.array(F_hits)  # (K, n_f)
        SS = np.outer(Sff, Sff)
        line_cov = R2[dk] * (np.conj(Fh).T @ Fh) / SS  # sum_h conj(F_hk) F_hl R(k - l) / (S_k S_l)
        line_pcov = R2[sk] * (np.conj(Fh).T @ np.conj(Fh)) / SS  # sum_h conj(F_hk) conj(F_hl) R(k + l) / (S_k S_l)
        fcov = np.zeros((kb.size, kb.size), dtype=complex)
        fpcov = np.zeros((kb.size, kb.size), dtype=complex)
        for Fk, wk in zip(F_hits, wf_hits):
            assert f_model is not None
            Gc, Gp = windowed_cov(f_model, wk, kb, L)  # E[N_k conj N_l], E[N_k N_l] of the windowed force noise
            fcov += Gc * np.outer(np.conj(Fk), Fk)
            fpcov += Gp * np.outer(np.conj(Fk), np.conj(Fk))
        fcov /= SS
        fpcov /= SS
        shape = np.column_stack([m.shape(fr, fs) for m in x_models])
        coloured = any(m.order > 0 for m in x_models)
        var_h = noise_x[None, :] ** 2 * np.real(np.diag(line_cov))[:, None] * shape + np.abs(H) ** 2 * np.real(
            np.diag(fcov)
        )[:, None]
        std = np.sqrt(var_h) / np.abs(conv)
        with np.errstate(divide="ignore"):
            snr = 10 * np.log10((sig_pow / K) / np.maximum(noise_x**2, 1e-300))
            fsnr = 10 * math.log10(max(force_pow / K, 1e-300) / max(noise_f**2, 1e-300))
    coh = None
    if K >= 2:
        coh = np.abs(Sxf) ** 2 / (Sff[:, None] * Sxx)
    Hd = np.asarray(H / conv, dtype=np.complex128)
    weak = np.sqrt(Sff / K) < 0.01 * np.max(np.sqrt(Sff / K))
    if np.any(weak):
        warnings.append(
            f"force spectrum more than 40 dB below its maximum above {fr[np.argmax(weak)]:.4g} Hz: the hammer "
            "does not excite the top of the band (harder tip or lower fmax)"
        )
    corr = float(L * np.sum(w_exp**4) / sum_w2**2)
    return (
        TransferData(
            frequency=fr,
            sigma=sigma,
            H=Hd,
            std=std,
            coherence=coh,
            channels=rec.channels,
            n_hits=K,
            hit_times=tuple(float(rec.t[h]) for h in hits),
            segment=T,
            corr_factor=corr,
            snr_db=snr,
            force_snr_db=fsnr,
            fs=fs,
            band=(float(fmin), float(fmax)),
            noise_var=None if noise_x is None else noise_x**2,
            line_cov=line_cov,
            force_cov=fcov,
            line_pcov=line_pcov,
            force_pcov=fpcov,
            force_tail=float(np.mean(tails)) / fs,
            noise_shape=shape if coloured else None,
            noise_models=tuple(x_models),
            force_noise_model=f_model,
        ),
        warnings,
    )
