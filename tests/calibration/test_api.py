"""Calibration from bags (issue 6): recovery of known parameters, intervals, stability, models.

Synthetic bags are written by :mod:`clm_core.synthetic` into
``tmp_path`` (time integration of the CLM chain / the track under a hammer
pulse, anti-alias decimation, 30 dB white noise on every channel) and fitted
by the frequency-domain models: two independent routes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clm_core.calibration import CalibrationOptions, calibrate, read_bag
from clm_core.calibration.channels import load_channel_map
from clm_core.calibration.impact import fit_impact, measured_sums
from clm_core.calibration.models import track_response
from clm_core.calibration.signals import SamplingRules, common_grid
from clm_core.calibration.spectra import WindowSpec, transfer_functions
from clm_core.frequency import dynamic_solve
from clm_core.params import SoilParams, load_model, load_soil
from clm_core.soil.chain import chain_damping_min_eigenvalue, chain_frequency_response, chain_response, laplace
from clm_core.synthetic import add_noise, simulate_impact, simulate_receptance, write_bag, write_simulated_bag
from clm_core.track import assemble

TRUTH = load_soil("mevergnies")
NAMES = ("mf", "kf", "df", "kc", "dc")


@pytest.fixture(scope="module")
def impact_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The shipped impact test, regenerated: 41 areas, geophones (velocity), 1 kHz, 1 s, 30 dB."""
    path = tmp_path_factory.mktemp("impact") / "impact_mevergnies"
    write_simulated_bag(simulate_impact, path, snr_db=30.0, seed=1, storage="mcap")
    return path


@pytest.fixture(scope="module")
def impact_result(impact_bag: Path):  # type: ignore[no-untyped-def]
    return calibrate(impact_bag, "impact", {})


def test_models_equal_the_project_solvers_on_the_real_axis() -> None:
    f = np.linspace(0.0, 200.0, 41)
    X, _ = chain_response(TRUTH, 41, laplace(f))
    np.testing.assert_allclose(X, chain_frequency_response(TRUTH, 41, f), rtol=1e-12, atol=0)
    params = load_model("mevergnies", "mevergnies", "clm")
    system = assemble(params, 21)
    c = 10
    F = np.zeros(system.n_dof)
    fd = int(system.rail_w[system.sleeper_node[c]])
    F[fd] = 1.0
    ref = dynamic_solve(system, f, F)[:, [fd, int(system.sleeper_dof[c])]]
    got = track_response(system, laplace(f), fd, [fd, int(system.sleeper_dof[c])])
    np.testing.assert_allclose(got, ref, rtol=1e-10)


def test_chain_jacobian_matches_finite_differences() -> None:
    s = laplace(np.linspace(1, 150, 30), sigma=4.0)
    X, dX = chain_response(TRUTH, 11, s, jacobian=True)
    assert dX is not None
    for k, name in enumerate(NAMES):
        h = abs(getattr(TRUTH, name)) * 1e-6
        Xp, _ = chain_response(SoilParams(**{**TRUTH.to_dict(), name: getattr(TRUTH, name) + h}), 11, s)
        np.testing.assert_allclose((Xp - X) / h, dX[k], rtol=2e-4, atol=1e-8 * np.abs(dX[k]).max())


def test_windowed_transfer_functions_are_the_model_at_complex_frequency() -> None:
    """Noise-free record: H from the exponentially windowed spectra equals H(sigma + j w) (Sec. 4, Eq. 9-13)."""
    rec = add_noise(simulate_impact(TRUTH, n_areas=11, duration=1.0), 200.0)
    r = common_grid(rec.force, list(rec.responses), SamplingRules())
    data, _ = transfer_functions(r, 2.0, 150.0, WindowSpec(exp_end=0.01))
    assert data.sigma > 0
    X, _ = chain_response(TRUTH, 11, data.s)
    H = X[:, [5 + c.index for c in data.channels]]
    near = [k for k, c in enumerate(data.channels) if abs(c.index) <= 2]
    err = np.abs(H[:, near] - data.H[:, near]) / np.abs(H[:, near])
    assert err.max() < 5e-3  # Newmark (dt = 1e-4 s) and anti-alias filter, not the window


def test_impact_recovers_the_mevergnies_clm_parameters(impact_result) -> None:  # type: ignore[no-untyped-def]
    """Table 1 truth, 30 dB SNR: every parameter within 5 % and inside its 95 % interval."""
    res = impact_result
    assert res.model == "clm" and res.norm == "weighted" and res.band == (2.0, 150.0)
    for p in res.parameters:
        true = getattr(TRUTH, p.name)
        assert abs(p.value / true - 1) < 0.05, (p.name, p.value, true)
        assert p.contains(true), (p.name, p.ci_low, p.value, p.ci_high, true)
        assert p.identifiable and 0 < p.rel_halfwidth < 0.05
    assert 0.8 < res.stats.rms < 1.2  # residuals at the noise level
    assert res.stats.covariance == "sandwich"
    assert "Eq. (16)/(18)" in res.first_estimate_method
    assert res.elapsed_s < 30


def test_impact_comparison_models_run_and_fit_worse(impact_result) -> None:  # type: ignore[no-untyped-def]
    res = impact_result
    comps = {c.model: c for c in res.comparisons}
    assert set(comps) == {"lysmer", "winkler"}
    assert comps["winkler"].soil.mf == 0.0 and comps["winkler"].soil.kc == 0.0
    assert comps["lysmer"].soil.model == "lysmer"
    main = res.main_fit
    for c in comps.values():
        assert c.channels_used == ("/soil/area_p00",)  # uncoupled models predict the loaded area only
        assert c.misfit_loaded > 1.5 * main.misfit_loaded  # coupling matters on the loaded area too


def test_lysmer_and_winkler_fits_recover_their_own_models(tmp_path: Path) -> None:
    lys = SoilParams(model="lysmer", mf=380.0, kf=72e6, df=680e3)
    rec = add_noise(simulate_impact(lys, n_areas=3, measured=[0], duration=0.6), 40.0, seed=3)
    r = common_grid(rec.force, list(rec.responses), SamplingRules())
    data, _ = transfer_functions(r, 2.0, 150.0)
    fit = fit_impact(data, "lysmer")
    for p in fit.parameters:
        assert abs(p.value / getattr(lys, p.name) - 1) < 0.03, p
    w = fit_impact(data, "winkler")
    assert w.soil.model == "winkler" and {p.name for p in w.parameters} == {"kf", "df"}


def test_sqlite3_and_mcap_bags_hold_the_same_record(tmp_path: Path) -> None:
    rec = add_noise(simulate_impact(TRUTH, n_areas=5, duration=0.5, hit_times=(0.1,)), 30.0, seed=2)
    a = write_bag(rec, tmp_path / "a", storage="mcap")
    b = write_bag(rec, tmp_path / "b", storage="sqlite3")
    assert list(b.path.glob("*.db3"))
    ra = read_bag(a.path, load_channel_map(a.channels))
    rb = read_bag(b.path, load_channel_map(b.channels))
    assert (ra.storage, rb.storage) == ("mcap", "sqlite3")
    np.testing.assert_array_equal(ra.recording.responses, rb.recording.responses)
    np.testing.assert_array_equal(ra.recording.force, rb.recording.force)
    res = calibrate(b.path, "impact", {"compare": False})
    assert res.storage == "sqlite3" and all(np.isfinite(p.value) for p in res.parameters)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_fit_never_returns_an_unstable_set(seed: int) -> None:
    """Truth on the stability limit d_f + 4 d_c = 0 (Sec. 4.2): noise pushes the optimum beyond it; refused."""
    edge = SoilParams(model="clm", mf=380.0, kf=72e6, df=680e3, kc=160e6, dc=-170e3)
    rec = add_noise(simulate_impact(edge, n_areas=11, duration=0.8), 25.0, seed=seed)
    r = common_grid(rec.force, list(rec.responses), SamplingRules())
    data, _ = transfer_functions(r, 2.0, 150.0)
    fit = fit_impact(data, "clm", initial={"mf": 300.0, "kf": 60e6, "df": 500e3, "kc": 100e6, "dc": -100e3})
    s = fit.soil
    assert s.df + 4 * s.dc >= -1e-9 * s.df
    assert chain_damping_min_eigenvalue(s, 11) >= -1e-9 * s.df
    assert s.kc >= 0 and s.kf > 0 and s.mf > 0
    dc = next(p for p in fit.parameters if p.name == "dc")
    if s.df + 4 * s.dc < 1e-6 * s.df:
        assert dc.at_bound and any("constraint" in w for w in fit.warnings)


def test_single_area_record_warns_that_coupling_is_not_identifiable() -> None:
    """Only the loaded area measured: k_c, d_c cannot be told apart from the other parameters."""
    rec = add_noise(simulate_impact(TRUTH, n_areas=41, measured=[0], duration=1.0), 30.0, seed=4)
    r = common_grid(rec.force, list(rec.responses), SamplingRules())
    data, w = transfer_functions(r, 2.0, 150.0)
    fit = fit_impact(data, "clm", n_areas=41)
    bad = {p.name for p in fit.parameters if not p.identifiable}
    assert bad & {"kc", "dc"}, [(p.name, p.rel_halfwidth) for p in fit.parameters]
    assert any("not identifiable" in x for x in fit.warnings)
    assert any("Eq. (16)/(18) sums cannot be formed" in x for x in fit.warnings)


def test_one_sided_record_uses_the_symmetric_sums() -> None:
    rec = add_noise(simulate_impact(TRUTH, n_areas=21, measured=range(0, 11), duration=0.8), 30.0, seed=5)
    r = common_grid(rec.force, list(rec.responses), SamplingRules())
    data, _ = transfer_functions(r, 2.0, 150.0)
    sums = measured_sums(data)
    assert sums is not None and "symmetry" in sums[3]
    fit = fit_impact(data, "clm", n_areas=21)
    assert "Eq. 19-20" in fit.first_estimate_method
    for p in fit.parameters:
        assert abs(p.value / getattr(TRUTH, p.name) - 1) < 0.08, p


@pytest.fixture(scope="module")
def receptance_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("receptance") / "receptance_mevergnies"
    write_simulated_bag(simulate_receptance, path, snr_db=30.0, seed=1)
    return path


def test_receptance_recovers_track_parameters(receptance_bag: Path) -> None:
    """Start from the soil-study track values (Sec. 5.2); Table 2 truth comes back within 5 %."""
    truth = load_model("mevergnies", "mevergnies", "clm")
    opts = CalibrationOptions.from_mapping(
        {"fit": ["kp", "dp", "ms", "kb", "db"], "initial": {"kp": 90e6, "dp": 30e3, "kb": 120e6, "db": 40e3, "ms": 200}}
    )
    res = calibrate(receptance_bag, "receptance", opts)
    assert res.band == (10.0, 500.0) and res.norm == "weighted"
    for p in res.parameters:
        true = getattr(truth.track, p.name)
        assert abs(p.value / true - 1) < 0.05, (p.name, p.value, true)
        assert p.contains(true), (p.name, p.ci_low, p.value, p.ci_high, true)
    assert res.params.soil == truth.soil  # soil fixed
    assert 0.8 < res.stats.rms < 1.2


def test_receptance_joint_soil_fit_is_admissible_and_flags_weak_parameters(receptance_bag: Path) -> None:
    res = calibrate(receptance_bag, "receptance", {"fit": ["kp", "kb"], "soil": "joint", "max_nfev": 12})
    names = [p.name for p in res.parameters]
    assert names == ["kp", "kb", "mf", "kf", "df", "kc", "dc"]
    s = res.params.soil
    assert s.df + 4 * s.dc >= 0 and s.kc >= 0
    # a rail hammer test hardly sees the coupling of the soil under 41 sleepers
    assert any(not p.identifiable for p in res.parameters)


def test_every_model_evaluation_reports_and_a_raising_report_stops_the_fit(receptance_bag: Path) -> None:
    """Progress comes after each model evaluation of the fit (finite differences too), never decreasing, and an
    exception raised by the callback (the calibration node's cancel) stops the fit at that evaluation."""
    seen: list[tuple[str, float]] = []
    res = calibrate(receptance_bag, "receptance", {"fit": ["kp", "kb"]}, progress=lambda s, f: seen.append((s, f)))
    fit = [f for s, f in seen if s == "track fit"]
    # least_squares' evaluations (nfev) plus its 2-point Jacobians (2 per iteration), the last one at 0.9
    assert len(fit) > res.stats.nfev >= 2
    assert all(0.25 < f <= 0.9 for f in fit) and fit[-1] == 0.9
    assert [f for _, f in seen] == sorted(f for _, f in seen)

    class Stop(Exception):
        pass

    reports: list[str] = []

    def stop_at_the_third_evaluation(stage: str, frac: float) -> None:
        reports.append(stage)
        if reports.count("track fit") == 3:
            raise Stop

    with pytest.raises(Stop):
        calibrate(receptance_bag, "receptance", {"fit": ["kp", "kb"]}, progress=stop_at_the_third_evaluation)
    assert reports[-1] == "track fit" and reports.count("track fit") == 3 and "done" not in reports


def test_options_refuse_unknown_keys_and_bad_values() -> None:
    from clm_core.calibration import CalibrationError

    with pytest.raises(CalibrationError, match=r"unknown key\(s\) \['fmaxx'\]"):
        CalibrationOptions.from_mapping({"fmaxx": 100})
    with pytest.raises(CalibrationError, match="norm = 'l2'"):
        CalibrationOptions.from_mapping({"norm": "l2"})
    with pytest.raises(CalibrationError, match="fmin = 50 Hz, fmax = 10 Hz"):
        CalibrationOptions.from_mapping({"fmin": 50, "fmax": 10})
    with pytest.raises(CalibrationError, match=r"window: unknown key\(s\) \['decay'\]"):
        CalibrationOptions.from_yaml("window: {decay: 3}")
    o = CalibrationOptions.from_yaml("fmax: 100\nwindow: {exp_end: 0.05}\nfit: kp, kb\n")
    assert o.fmax == 100.0 and o.window.exp_end == 0.05 and o.fit == ("kp", "kb")
    assert CalibrationOptions.from_mapping(o.to_dict()) == o


def test_options_give_the_fit_controls_with_the_method_budget() -> None:
    """FitControls holds the rules of max_nfev, ident_rel and cond_max; the options fill in the method's budget."""
    from clm_core.calibration import CalibrationError
    from clm_core.calibration.lsq import FitControls

    assert CalibrationOptions().controls(60) == FitControls(max_nfev=60)
    assert CalibrationOptions(max_nfev=7, ident_rel=0.5).controls(60) == FitControls(7, 0.5, 1e6)
    for bad, match in (({"max_nfev": 0}, "max_nfev = 0: must be >= 1"), ({"ident_rel": 0.0}, "ident_rel = 0.0"),
                       ({"cond_max": 1.0}, "cond_max = 1.0: must be > 1")):
        with pytest.raises(CalibrationError, match=match):
            CalibrationOptions.from_mapping(bad)


def test_public_functions_document_every_argument() -> None:
    """numpydoc: each public function of clm_core.calibration names all its parameters in its docstring."""
    import inspect

    import clm_core.calibration as cal

    for name in cal.__all__:
        obj = getattr(cal, name)
        if not inspect.isfunction(obj):
            continue
        doc = inspect.getdoc(obj) or ""
        assert "Parameters" in doc and "Returns" in doc, name
        for arg in inspect.signature(obj).parameters:
            assert arg in doc, f"{name}: argument {arg!r} not documented"
