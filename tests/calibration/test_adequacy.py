"""Calibration that knows when its model or its timing is wrong (issue 24).

Noise-free bias of the impact fit (the force window must keep the anti-alias
filter's ringing), the noise spectrum from the record before the hit, the
force-to-response delay, and the model-adequacy check. Records from the
project's generator (:mod:`clm_core.synthetic`: Newmark, ``resample_poly``)
and from the independent one of ``benchmarks/calibration_truth.py``
(closed-form modal response, IIR or causal FIR anti-alias filter). The full
figures are printed by ``benchmarks/calibration_coverage.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clm_core.calibration.impact import fit_impact
from clm_core.calibration.signals import Recording, SamplingRules, common_grid
from clm_core.calibration.spectra import WindowSpec, force_window, transfer_functions
from clm_core.params import SoilParams
from clm_core.synthetic import add_noise, simulate_impact
from tests.calibration import load_benchmark

NAMES = ("mf", "kf", "df", "kc", "dc")
STIFF = SoilParams(model="clm", mf=600.0, kf=150e6, df=1.1e6, kc=300e6, dc=-250e3)  # the soil of issues 14, 24


truth = load_benchmark("calibration_truth")


def _rel_error(soil: SoilParams, fitted: SoilParams) -> np.ndarray:
    return np.array([getattr(fitted, k) / getattr(soil, k) - 1.0 for k in NAMES])


def _synthetic(fs: float, snr_db: float, seed: int = 1, **kw: object) -> Recording:
    rec = add_noise(simulate_impact(STIFF, n_areas=21, fs=fs, **kw), snr_db, seed)  # type: ignore[arg-type]
    return common_grid(rec.force, list(rec.responses), SamplingRules())


@pytest.mark.parametrize("fs", [1000.0, 2000.0])
@pytest.mark.parametrize("generator", ["synthetic", "exact-iir", "exact-fir"])
def test_noise_free_bias_is_below_two_in_ten_thousand(generator: str, fs: float) -> None:
    """Without noise (SNR 140 dB) every fitted parameter is within 0.02 % of the truth at 1 and 2 kHz.

    Before issue 24 the force window ended 4 ms (4 samples at 1 kHz) after the pulse and cut off the
    anti-alias filter's ringing that the responses keep: d_f -0.11 %, d_c -0.19 %, k_c -0.09 % on the
    independent record (IIR), m_f +0.19 % on the project's own (Newmark at 10 steps per sample).
    """
    if generator == "synthetic":
        rec = _synthetic(fs, 140.0)
    else:
        clean = truth.exact_impact(STIFF, list(range(-10, 11)), fs=fs, anti_alias=generator[6:])
        rec = truth.add_noise(clean, "proportional", 1e-7, 1)
    data, _ = transfer_functions(rec, 2.0, 150.0)
    fit = fit_impact(data, "clm")
    err = _rel_error(STIFF, fit.soil)
    assert np.all(np.abs(err) <= 2e-4), dict(zip(NAMES, np.round(100 * err, 4)))


def test_force_window_ends_after_the_ringing_has_decayed() -> None:
    """The window keeps >= 20 samples after the pulse, and longer while the force rings above its noise."""
    L = 400
    f = np.zeros(L)
    f[20:23] = [0.5, 1.0, 0.5]
    n = np.arange(L - 23)
    f[23:] = 0.3 * np.exp(-n / 15.0) * np.cos(2.5 * n)  # ringing, decaying over 15 samples
    wf, tail, settled = force_window(f, margin=4, min_tail=20, noise=1e-3)
    assert settled
    ring_end = 23 + int(np.ceil(15.0 * np.log(0.3 / 3e-3)))  # |ringing| < 3 x noise from here
    assert tail >= 20 and 23 + tail >= ring_end - 3
    assert np.all(wf[: 23 + tail] == 1.0) and wf[-1] == 0.0
    quiet = np.zeros(L)
    quiet[20:23] = [0.5, 1.0, 0.5]
    _, tail_q, _ = force_window(quiet, margin=4, min_tail=20, noise=1e-3)
    assert tail_q == 20
    drifting = quiet + 0.01  # an offset above the noise: never settles
    _, tail_d, settled_d = force_window(drifting, margin=4, min_tail=20, noise=1e-3)
    assert not settled_d and tail_d > 20


def test_force_window_tail_is_reported() -> None:
    """TransferData.force_tail says how long the force was kept after the pulse [s]."""
    rec = _synthetic(1000.0, 40.0)
    data, _ = transfer_functions(rec, 2.0, 150.0, WindowSpec(force_margin=0.004))
    assert 0.0199 <= data.force_tail < 0.2


def test_noise_model_of_a_white_and_an_ar1_record() -> None:
    """BIC keeps white noise white (in >= 17 of 20 records); an AR(1) record gives its coefficient and spectrum."""
    from scipy.signal import lfilter

    from clm_core.calibration.noise import fit_noise

    rng = np.random.default_rng(0)
    orders = [fit_noise(rng.normal(0.0, 2.0, 200)).order for _ in range(20)]
    assert sum(o == 0 for o in orders) >= 17, orders
    x = lfilter([1.0], [1.0, -0.8], rng.normal(0.0, 1.0, 4200))[200:]
    m = fit_noise(x)
    assert m.order >= 1 and abs(m.ar[0] - 0.8) < 0.05
    f = np.array([1.0, 100.0, 450.0])
    expected = (1 - 0.8**2) / np.abs(1 - 0.8 * np.exp(-2j * np.pi * f / 1000.0)) ** 2
    assert np.allclose(m.shape(f, 1000.0), expected, rtol=0.25)
    c = m.autocovariance(4)
    assert np.allclose(c / c[0], 0.8 ** np.arange(4), atol=0.05)


def test_windowed_force_noise_covariance_of_white_noise_is_the_window_correlation() -> None:
    """For white noise the exact windowed covariance is sigma^2 R(k - l), R the DFT of w^2 (the issue-14 form)."""
    from clm_core.calibration.noise import NoiseSpectrum, windowed_cov

    L = 256
    w = np.zeros(L)
    w[:40] = np.exp(-0.01 * np.arange(40))
    lines = np.arange(3, 30)
    C, P = windowed_cov(NoiseSpectrum(4.0, np.zeros(0), 4.0, 100), w, lines, L)
    R = np.fft.fft(w**2)
    assert np.allclose(C, 4.0 * R[(lines[:, None] - lines[None, :]) % L])
    assert np.allclose(P, 4.0 * R[(lines[:, None] + lines[None, :]) % L])


def test_coloured_noise_spectrum_predicts_the_scatter_of_the_receptance() -> None:
    """AR(1) noise (coefficient 0.8, the benchmark's 'coloured' model): the predicted std of H matches 40 draws.

    The noise spectrum from the record before the hit gives the per-line standard deviation within 25 %
    (in the band's lower and upper thirds); a white model is off by a factor > 2 at one end.
    """
    clean = truth.exact_impact(STIFF, [0, 1], fs=1000.0)
    from scipy.signal import lfilter

    rng = np.random.default_rng(3)
    act = (clean.t >= 0.2) & (clean.t < 0.3)
    rms = np.sqrt(np.mean(clean.responses[act] ** 2, axis=0))
    Hs = []
    pred: dict[int, list[np.ndarray]] = {0: [], 8: []}
    for _ in range(40):
        e = lfilter([1.0], [1.0, -0.8], rng.normal(size=(clean.t.size + 200, 2)), axis=0)[200:] * 0.6
        rec = Recording(t=clean.t, fs=clean.fs, force=clean.force.copy(), responses=clean.responses + 0.02 * rms * e,
                        channels=clean.channels)
        for order in (0, 8):
            data, _ = transfer_functions(rec, 2.0, 150.0, WindowSpec(noise_order=order))
            assert data.std is not None
            pred[order].append(data.std[:, 0] ** 2)
        Hs.append(data.H[:, 0])
    emp = np.var(np.array(Hs), axis=0)
    n = emp.size
    thirds = (slice(0, n // 3), slice(2 * n // 3, n))
    # the level of coloured noise from ~190 samples scatters by ~30 % per record: compare the mean prediction
    ratio_ar = [np.sqrt(np.mean(emp[p]) / np.mean(np.array(pred[8])[:, p])) for p in thirds]
    assert all(0.8 < r < 1.25 for r in ratio_ar), ratio_ar
    ratio_white = [np.sqrt(np.mean(emp[p]) / np.mean(np.array(pred[0])[:, p])) for p in thirds]
    assert max(ratio_white) > 2.0 or min(ratio_white) < 0.5, ratio_white


def _fit(rec: Recording, **kw: object) -> object:
    data, _ = transfer_functions(rec, 2.0, 150.0)
    return fit_impact(data, "clm", **kw)  # type: ignore[arg-type]


def test_coupling_columns_are_the_derivative_of_the_extended_chain() -> None:
    """d H / d k_c2 of the dense route equals a finite difference of a chain with second-neighbour springs."""
    from clm_core.calibration.adequacy import coupling2_columns
    from clm_core.soil.chain import chain_response

    n, s = 11, np.array([5.0 + 2j * np.pi * 30.0, 5.0 + 2j * np.pi * 120.0])
    p = [getattr(STIFF, k) for k in NAMES]
    cols = [5, 6, 8]
    dk, dd = coupling2_columns(*p, n, s, cols)  # type: ignore[arg-type]
    X, _ = chain_response(STIFF, n, s)
    L1 = np.diag(np.r_[1.0, 2.0 * np.ones(n - 2), 1.0]) - np.eye(n, k=1) - np.eye(n, k=-1)
    deg = np.full(n, 2.0)
    deg[[0, 1, -2, -1]] = 1.0
    L2 = np.diag(deg) - np.eye(n, k=2) - np.eye(n, k=-2)
    e = np.eye(n)[5]
    h = 1e-4 * STIFF.kc
    for i, si in enumerate(s):
        Z = (STIFF.mf * si**2 + STIFF.kf + STIFF.df * si) * np.eye(n) + (STIFF.kc + STIFF.dc * si) * L1
        assert np.allclose(np.linalg.solve(Z, e)[cols], X[i, cols], rtol=1e-9)
        fd = (np.linalg.solve(Z + h * L2, e) - np.linalg.solve(Z - h * L2, e))[cols] / (2 * h)
        assert np.allclose(dk[i], fd, rtol=1e-5)
        assert np.allclose(dd[i], si * fd, rtol=1e-5)


def test_a_skew_of_10_us_at_1_khz_is_estimated_warned_and_fitted() -> None:
    """Responses 10 us late (0.5 % noise, 1 kHz): the check estimates the delay within 3 sigma and warns;
    ``delay: fit`` removes it (m_f within its interval and within 0.3 %); simultaneous channels: no warning."""
    skewed = _synthetic(1000.0, 46.0, seed=2, skew=1e-5)
    fit = _fit(skewed)
    assert fit.delay is not None  # type: ignore[attr-defined]
    tau, sd = float(fit.delay.estimate[0]), float(fit.delay.std[0])  # type: ignore[attr-defined]
    assert abs(tau - 1e-5) < 3 * sd and sd < 3e-6, (tau, sd)
    assert any("force-to-response delay" in w for w in fit.warnings)  # type: ignore[attr-defined]
    fitted = _fit(skewed, delay="fit")
    assert abs(fitted.delay_applied - 1e-5) < 3 * sd and fitted.delay.rejects()  # type: ignore[attr-defined]
    mf = fitted.parameters[0]  # type: ignore[attr-defined]
    assert mf.contains(STIFF.mf) and abs(mf.value / STIFF.mf - 1) < 3e-3, mf
    plain = _fit(_synthetic(1000.0, 46.0, seed=2))
    assert not any("force-to-response delay" in w for w in plain.warnings)  # type: ignore[attr-defined]
    wide = _fit(skewed, timing_accuracy=2e-5)
    assert wide.parameters[0].std > 1.5 * fit.parameters[0].std  # type: ignore[attr-defined]


def test_second_neighbour_coupling_is_warned_in_nine_of_ten_seeds() -> None:
    """A truth outside the CLM family (1 % second-neighbour coupling, 2 % noise, 1 kHz): warned in >= 18 of
    20 seeds; the CLM truth itself in at most 2 of 10. (The benchmark gives the rate over >= 100 seeds.)"""
    clean = simulate_impact(STIFF, n_areas=21, fs=1000.0, coupling2=0.01)
    warned = 0
    for seed in range(20):
        r = add_noise(clean, 34.0, seed)
        fit = _fit(common_grid(r.force, list(r.responses), SamplingRules()))
        warned += any("outside the CLM model" in w for w in fit.warnings)  # type: ignore[attr-defined]
    assert warned >= 18, warned
    clm = simulate_impact(STIFF, n_areas=21, fs=1000.0)
    false = 0
    for seed in range(10):
        r = add_noise(clm, 34.0, 100 + seed)
        fit = _fit(common_grid(r.force, list(r.responses), SamplingRules()))
        false += any("outside the CLM model" in w for w in fit.warnings)  # type: ignore[attr-defined]
    assert false <= 2, false


def test_timing_and_noise_options_are_checked() -> None:
    """delay, timing_accuracy and the window's force_tail / noise_order reach the fit; bad values are refused."""
    from clm_core.calibration import CalibrationOptions
    from clm_core.calibration.errors import CalibrationError

    o = CalibrationOptions.from_yaml("delay: fit\ntiming_accuracy: 2.0e-6\nwindow: {force_tail: 30, noise_order: 0}")
    assert (o.delay, o.timing_accuracy, o.window.force_tail, o.window.noise_order) == ("fit", 2e-6, 30, 0)
    with pytest.raises(CalibrationError, match="delay = 'guess': must be check or fit"):
        CalibrationOptions.from_mapping({"delay": "guess"})
    with pytest.raises(CalibrationError, match="timing_accuracy"):
        CalibrationOptions.from_mapping({"timing_accuracy": -1.0})
    data, _ = transfer_functions(_synthetic(1000.0, 40.0), 2.0, 150.0)
    with pytest.raises(CalibrationError, match="delay = 'x'"):
        fit_impact(data, "clm", delay="x")
    with pytest.raises(CalibrationError, match="window: noise_order = -1: must be an integer >= 0"):
        transfer_functions(_synthetic(1000.0, 40.0), 2.0, 150.0, WindowSpec(noise_order=-1))


def test_calibrate_reports_the_checks_in_summary_json(tmp_path: Path) -> None:
    """A bag whose responses lag the force by 20 us (40 dB): calibrate(..., delay: fit) states the delay it removed
    and the model tests in summary.json (fit.adequacy)."""
    import json

    from clm_core.calibration import calibrate
    from clm_core.synthetic import write_bag

    rec = add_noise(simulate_impact(STIFF, n_areas=11, fs=1000.0, skew=2e-5), 46.0, 4)
    path = tmp_path / "skewed"
    write_bag(rec, path)
    res = calibrate(path, "impact", {"delay": "fit", "compare": False})
    adq = json.loads(res.summary_json())["fit"]["adequacy"]
    assert abs(adq["delay_applied_s"] - 2e-5) < 3 * adq["delay"]["std"][0], adq
    assert adq["delay"]["warned"] and adq["delay"]["p_value"] < 2.7e-3
    assert set(adq["second_neighbour_coupling"]) >= {"estimate", "std", "chi2", "dof", "p_value", "warned"}
    assert set(adq["first_vs_refined"]["z"]) == set(NAMES)
    assert any("delay fitted" in w for w in res.warnings)
