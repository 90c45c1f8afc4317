"""Recorded signals: checks (length, clipping, sampling) and a common time grid.

A :class:`Signal` is one channel as read from a bag: sample times and values
in SI units (positive downwards). :func:`check_signal` refuses records that
cannot be fitted reliably, and :func:`common_grid` puts the force and the
responses on one uniform time grid (:class:`Recording`).

Rules (defaults of :class:`SamplingRules`, all adjustable in the options):

- too short: fewer than ``min_samples`` samples;
- clipped: ``clip_run`` or more consecutive samples (or ``2 clip_run`` in
  all) at the record's maximum (or minimum) value, unless that value is the
  record's median (a noise-free resting level, not a flat top), or any sample at or beyond the sensor's ``full_scale``;
- duplicated stamps (messages are sorted by stamp first, so reordered
  messages are accepted);
- gappy: an interval longer than ``(1 + gap_tol)`` times the median interval,
  the stamps being otherwise on a uniform grid (missing samples);
- jittered: a stamp further than ``jitter_tol`` median intervals from the
  uniform grid fitted to all stamps (missing samples accounted for).

Stamps within the jitter tolerance are replaced by that fitted uniform grid
(the sensor clock is taken as uniform; the stamps only place it in time).
Channels with another rate are brought to the reference rate by polyphase
resampling, and sub-sample offsets between channels are removed by a
band-limited (FFT) delay.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.calibration.channels import ChannelSpec
from clm_core.calibration.errors import BagError


@dataclass(frozen=True)
class SamplingRules:
    """Tolerances of the record checks.

    Attributes
    ----------
    min_samples : int
        Least number of samples per channel.
    gap_tol : float
        An interval longer than (1 + gap_tol) x the median interval is a gap.
    jitter_tol : float
        Largest allowed distance of a stamp from the fitted uniform grid, in
        median intervals.
    clip_run : int
        Consecutive samples at the record's extreme that mean a flat top
        (clipping; twice as many in all, not consecutive, too); 0 disables
        the check (``full_scale`` still applies).
    """

    min_samples: int = 64
    gap_tol: float = 0.5
    jitter_tol: float = 0.25
    clip_run: int = 3


@dataclass(frozen=True)
class Signal:
    """One channel: sample times and values.

    Attributes
    ----------
    spec : ChannelSpec
        What the channel measures.
    t : (n,) array
        Sample times [s] from the recording's time origin.
    values : (n,) array
        Samples in SI units (N, m, m/s, m/s^2), positive downwards.
    """

    spec: ChannelSpec
    t: Array
    values: Array


@dataclass(frozen=True)
class Recording:
    """Force and responses on one uniform time grid.

    Attributes
    ----------
    t : (n,) array
        Times [s] (uniform, step ``1 / fs``).
    fs : float
        Sample rate [Hz].
    force : (n,) array or None
        Hammer force [N] (None for a pass-by).
    responses : (n, n_ch) array
        Responses in SI units, one column per channel.
    channels : tuple of ChannelSpec
        The response channels, in column order.
    force_spec : ChannelSpec or None
        The force channel.
    t_origin_ns : int
        Bag time [ns] of t = 0.
    notes : tuple of str
        What was done to the records (resampling, alignment).
    """

    t: Array
    fs: float
    force: Array | None
    responses: Array
    channels: tuple[ChannelSpec, ...]
    force_spec: ChannelSpec | None = None
    t_origin_ns: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def duration(self) -> float:
        """Record length n / fs [s]."""
        return self.t.size / self.fs


def _fmt_t(t: float) -> str:
    return f"{t:.6f} s"


def check_signal(sig: Signal, rules: SamplingRules) -> tuple[float, float]:
    """Check one channel; return its uniform grid (t0 [s], dt [s]).

    Raises
    ------
    BagError
        Too short, non-finite values, clipped, stamps not increasing, gappy
        or jittered stamps; the message names the topic and the values.
    """
    name = f"topic {sig.spec.topic}" + (f" (field {sig.spec.field})" if sig.spec.field else "")
    n = sig.t.size
    if n < rules.min_samples:
        raise BagError(
            f"{name}: too short a record: {n} samples (rule: at least {rules.min_samples}); "
            "was the recording stopped early or the topic published rarely?"
        )
    bad = np.nonzero(~np.isfinite(sig.values))[0]
    if bad.size:
        raise BagError(
            f"{name}: {bad.size} non-finite sample(s) (NaN or infinity), first at t = {_fmt_t(sig.t[bad[0]])}"
        )
    d = np.diff(sig.t)
    nonpos = np.nonzero(d <= 0)[0]
    if nonpos.size:
        i = int(nonpos[0])
        raise BagError(
            f"{name}: duplicated stamps: sample {i + 1} has the stamp t = {_fmt_t(sig.t[i + 1])} of the sample "
            f"before ({nonpos.size} such place(s)); a logger that repeats stamps cannot be resampled"
        )
    dt = float(np.median(d))

    def grid(k: Array) -> tuple[float, float, Array]:
        coef = np.linalg.lstsq(np.column_stack([np.ones(n), k]), sig.t, rcond=None)[0]
        return float(coef[0]), float(coef[1]), sig.t - (float(coef[0]) + float(coef[1]) * k)

    t0, dt_fit, dev = grid(np.arange(n, dtype=float))
    if np.max(np.abs(dev)) <= rules.jitter_tol * dt_fit:
        _check_clipping(sig, rules, name)
        return t0, dt_fit
    gaps = np.nonzero(d > (1.0 + rules.gap_tol) * dt)[0]
    if gaps.size:
        steps = np.maximum(1, np.round(d / dt)).astype(np.int64)
        _, dt2, dev2 = grid(np.concatenate([[0], np.cumsum(steps)]).astype(float))
        if np.max(np.abs(dev2)) <= rules.jitter_tol * dt2:
            i = int(gaps[0])
            missing = int(np.sum(steps[gaps] - 1))
            raise BagError(
                f"{name}: gappy stamps: {gaps.size} gap(s), the first of {d[i]:.6g} s after t = {_fmt_t(sig.t[i])} "
                f"(nominal interval {dt:.6g} s, about {missing} sample(s) missing in all; rule: no interval longer "
                f"than {1 + rules.gap_tol:g} x nominal). Dropped messages cannot be fitted: record again or cut the "
                "bag"
            )
    worst = int(np.argmax(np.abs(dev)))
    raise BagError(
        f"{name}: jittered stamps: sample {worst} at t = {_fmt_t(sig.t[worst])} is {dev[worst]:+.3g} s "
        f"({dev[worst] / dt_fit:+.2f} intervals) from the uniform grid of {dt_fit:.6g} s "
        f"(rule: within {rules.jitter_tol:g} intervals). Stamp samples at acquisition (header.stamp), "
        "not at reception"
    )


def _check_clipping(sig: Signal, rules: SamplingRules, name: str) -> None:
    v = sig.values
    fs_lim = sig.spec.full_scale
    if fs_lim is not None:
        over = np.nonzero(np.abs(v) >= fs_lim * (1 - 1e-9))[0]
        if over.size:
            raise BagError(
                f"{name}: clipped record: {over.size} sample(s) at or beyond the sensor full scale "
                f"{fs_lim:g} (SI), first at t = {_fmt_t(sig.t[over[0]])}; the sensor saturated, lower the "
                "excitation or use a larger range"
            )
    if rules.clip_run <= 0:
        return
    span = float(np.max(v) - np.min(v))
    if span == 0.0:
        raise BagError(f"{name}: constant record (every sample = {v[0]:g}): no signal (sensor off or stuck?)")
    med = float(np.median(v))
    for label, ext in (("maximum", float(np.max(v))), ("minimum", float(np.min(v)))):
        if abs(ext - med) <= 1e-12 * span:
            continue  # the record rests at this value (a noise-free force before the hit): not a flat top
        at = np.abs(v - ext) <= 1e-12 * span
        run = _longest_run(at)
        n_at = int(at.sum())
        if run[0] >= rules.clip_run or n_at >= 2 * rules.clip_run:
            i = run[1] if run[0] >= rules.clip_run else int(np.argmax(at))
            raise BagError(
                f"{name}: clipped record (flat top): {n_at} samples at the {label} {ext:g} (SI), {run[0]} of them "
                f"consecutive, from t = {_fmt_t(sig.t[i])} (rule: fewer than {rules.clip_run} consecutive and "
                f"{2 * rules.clip_run} in all); the sensor or the acquisition saturated"
            )


def _longest_run(mask: NDArray[np.bool_]) -> tuple[int, int]:
    """Length and start of the longest run of True."""
    if not mask.any():
        return 0, 0
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    dm = np.diff(m)
    starts = np.nonzero(dm == 1)[0]
    ends = np.nonzero(dm == -1)[0]
    lengths = ends - starts
    j = int(np.argmax(lengths))
    return int(lengths[j]), int(starts[j])


def fractional_delay(x: Array, shift: float) -> Array:
    """Delay ``x`` by ``shift`` samples (band-limited, FFT with zero padding): y[k] = x(k - shift)."""
    if abs(shift) < 1e-9:
        return x
    n = x.shape[0]
    nfft = int(2 ** math.ceil(math.log2(2 * n)))
    X = np.fft.rfft(x, nfft, axis=0)
    f = np.fft.rfftfreq(nfft)
    ph = np.exp(-2j * np.pi * f * shift)
    y = np.fft.irfft(X * ph.reshape((-1,) + (1,) * (x.ndim - 1)), nfft, axis=0)
    return np.asarray(y[:n], dtype=float)


def common_grid(
    force: Signal | None,
    responses: list[Signal],
    rules: SamplingRules,
    t_origin_ns: int = 0,
) -> Recording:
    """Check every channel and put them on the reference channel's uniform grid.

    The reference is the force channel if given, else the first response.
    Channels at another rate are resampled (polyphase, rational ratio with
    denominator <= 1000); channels offset by a fraction of a sample are
    shifted (band-limited); all are cut to the time span they share.

    Raises
    ------
    BagError
        A channel fails :func:`check_signal`, the rates have no simple ratio,
        or the shared span is shorter than ``rules.min_samples`` samples.
    """
    sigs = ([force] if force is not None else []) + list(responses)
    if not sigs:
        raise BagError("no channels to read")
    grids = [check_signal(s, rules) for s in sigs]
    t0_ref, dt_ref = grids[0]
    fs = 1.0 / dt_ref
    notes: list[str] = []
    series: list[tuple[float, Array]] = []  # (start time, samples at dt_ref)
    for s, (t0, dt) in zip(sigs, grids):
        x = s.values.astype(float)
        if abs(dt / dt_ref - 1.0) > 1e-4:
            ratio = Fraction(dt / dt_ref).limit_denominator(1000)  # up / down
            if abs(float(ratio) - dt / dt_ref) > 1e-4 * dt / dt_ref:
                raise BagError(
                    f"topic {s.spec.topic}: sample rate {1 / dt:.6g} Hz has no simple ratio to the reference "
                    f"rate {fs:.6g} Hz ({sigs[0].spec.topic}); resample the record first"
                )
            from scipy.signal import resample_poly  # here: importing this module stays light (clm --help)

            x = resample_poly(x, ratio.numerator, ratio.denominator)
            notes.append(f"{s.spec.topic}: resampled from {1 / dt:.6g} Hz to {fs:.6g} Hz")
        series.append((t0, x))
    start = max(t0 for t0, _ in series)
    end = min(t0 + (x.size - 1) * dt_ref for t0, x in series)
    n = int(math.floor((end - start) / dt_ref + 1e-6)) + 1
    if n < rules.min_samples:
        raise BagError(
            f"the channels overlap in time for only {max(end - start, 0.0):.4g} s ({max(n, 0)} samples; rule: at "
            f"least {rules.min_samples}); were they recorded at the same time?"
        )
    out = []
    for (t0, x), s in zip(series, sigs):
        pos = (start - t0) / dt_ref  # index of `start` in this series
        i0 = int(math.floor(pos + 1e-9))
        frac = pos - i0
        seg = x[i0 : i0 + n + 1]
        if frac > 1e-6:
            seg = fractional_delay(seg, -frac)
            if frac > 1e-3:
                notes.append(f"{s.spec.topic}: shifted by {frac * dt_ref:.3g} s to the common grid")
        if seg.size < n:
            seg = np.concatenate([seg, np.full(n - seg.size, seg[-1])])
        out.append(seg[:n])
    t = (np.arange(n) * dt_ref).astype(float)
    origin = t_origin_ns + int(round(start * 1e9))
    f_arr = out[0] if force is not None else None
    resp = np.column_stack(out[1:] if force is not None else out) if responses else np.zeros((n, 0))
    return Recording(
        t=t,
        fs=fs,
        force=f_arr,
        responses=resp,
        channels=tuple(s.spec for s in responses),
        force_spec=force.spec if force is not None else None,
        t_origin_ns=origin,
        notes=tuple(notes),
    )
