"""Track assembly and receptances: closed-form limits, convergence, two routes."""

import re

import numpy as np
import pytest

from clm_core.errors import ParameterError
from clm_core.frequency import dynamic_solve, receptance, receptance_from_pulse
from clm_core.params import ModelParams, load_model
from clm_core.track import assemble, beam_element, hermite


def _boef(p: ModelParams) -> tuple[float, float]:
    """Equivalent continuous beam on elastic foundation: (k per metre, beta)."""
    t = p.track
    soil = 1 / p.soil.kf if p.soil.model != "rigid" else 0.0
    ks = 1 / (1 / t.kp + 1 / t.kb + soil)
    k = ks / t.spacing
    return k, (k / (4 * p.rail.EI)) ** 0.25


@pytest.mark.parametrize(
    ("track", "soil", "model"),
    [
        ("mevergnies", "mevergnies", "rigid"),
        ("mevergnies", "mevergnies", "winkler"),
        ("soil-study", "soft", "winkler"),
        ("soil-study", "medium", "winkler"),
    ],
)
def test_static_limit_beam_on_elastic_foundation(track: str, soil: str, model: str) -> None:
    p = load_model(track, soil, model)
    s = assemble(p, 201, elements_per_bay=2)
    k, beta = _boef(p)
    # receptance at 0.01 Hz (quasi-static) against w(0) = beta / (2k)
    rec = receptance(s, [0.01], n_out=5)
    assert abs(rec.H[0, 0]) == pytest.approx(beta / (2 * k), rel=0.01)
    # and the deflected shape w(x) = beta/(2k) e^{-bx} (cos bx + sin bx) above the next sleepers
    x = np.arange(5) * p.track.spacing
    shape = beta / (2 * k) * np.exp(-beta * x) * (np.cos(beta * x) + np.sin(beta * x))
    np.testing.assert_allclose(rec.H[0].real, shape, atol=0.01 * shape[0])


def test_static_sum_of_ballast_forces_equals_load() -> None:
    p = load_model("mevergnies", "mevergnies", "clm")
    s = assemble(p, 61)
    F = np.zeros(s.n_dof)
    dofs, w = s.point_load(s.sleeper_x[30] + 0.17)  # between nodes
    F[dofs] += 100e3 * w
    X = dynamic_solve(s, [0.0], F)[0].real
    fb = s.ballast_force(X, 0 * X)
    assert fb.sum() == pytest.approx(100e3, rel=1e-9)


def test_convergence_with_elements_per_bay() -> None:
    p = load_model("mevergnies", "mevergnies", "clm")
    f = np.array([10.0, 100.0, 300.0, 400.0])
    H = {ne: receptance(assemble(p, 41, elements_per_bay=ne), f).H for ne in (1, 2, 4, 8)}
    err = {ne: np.max(np.abs(H[ne] / H[8] - 1)) for ne in (1, 2, 4)}
    assert err[4] < err[2] < err[1]
    assert err[2] < 0.02  # two elements per bay: within 2 % up to 400 Hz (paper's ref. [23])
    assert err[4] < 0.002


def test_convergence_with_sleeper_count_and_end_conditions() -> None:
    p = load_model("mevergnies", "mevergnies", "clm")
    f = np.arange(1.0, 300.0, 1.0)
    ref = receptance(assemble(p, 121), f).H
    for n in (41, 61, 81):
        for ends in ("free", "pinned", "clamped"):
            H = receptance(assemble(p, n, rail_ends=ends), f).H
            err = np.max(np.abs(H[:, :3] - ref[:, :3]) / np.abs(ref[:, [0]]))
            assert err < 0.01, (n, ends, err)
    # too short a track is visibly affected by its ends (the check can fail)
    short = receptance(assemble(p, 7, rail_ends="clamped"), f, n_out=3).H
    assert np.max(np.abs(short[:, 0] - ref[:, 0]) / np.abs(ref[:, 0])) > 0.05


@pytest.mark.parametrize("model", ["rigid", "winkler", "lysmer", "clm"])
def test_time_domain_pulse_route_matches_direct(model: str) -> None:
    p = load_model("mevergnies", "mevergnies", model)
    s = assemble(p, 31)
    rp = receptance_from_pulse(s, fmax=400.0, dt=2e-5, duration=0.6, td=1e-4, n_out=3)
    keep = rp.frequency > 0
    rd = receptance(s, rp.frequency[keep], n_out=3)
    err = np.abs(rp.H[keep] - rd.H) / np.abs(rd.H[:, [0]])
    assert np.max(err) < 0.01, np.max(err)


def test_models_ordering_at_low_frequency() -> None:
    # softer foundations give larger static receptance; the CLM chain spreads the load (between rigid and Lysmer)
    f = [0.5]
    H = {
        m: abs(receptance(assemble(load_model("mevergnies", "mevergnies", m), 41), f).H[0, 0])
        for m in ("rigid", "winkler", "lysmer", "clm")
    }
    assert H["rigid"] < H["clm"] < H["lysmer"]
    assert H["winkler"] == pytest.approx(H["lysmer"], rel=1e-4)


def test_point_load_outside_rail_refused() -> None:
    s = assemble(load_model("mevergnies", "mevergnies", "clm"), 11)
    from clm_core.errors import InputError

    with pytest.raises(InputError, match="outside the rail"):
        s.point_load(100.0)
    with pytest.raises(InputError, match=r"^load position x = nan: must be finite"):
        s.point_load(float("nan"))
    with pytest.raises(InputError, match=r"^load position x = 'x': must be a real number$"):
        s.point_load("x")  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match=r"^element length L = 0 m: must be > 0$"):
        hermite(np.array([0.5]), 0.0)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"n_sleepers": 2.5}, "n_sleepers = 2.5: must be an integer"),
        ({"n_sleepers": float("nan")}, "n_sleepers = nan: must be an integer"),
        ({"n_sleepers": "x"}, "n_sleepers = 'x': must be an integer"),
        ({"elements_per_bay": 1.5}, "elements_per_bay = 1.5: must be an integer"),
        ({"elements_per_bay": float("nan")}, "elements_per_bay = nan: must be an integer"),
        ({"first_sleeper": 1.5}, "first_sleeper = 1.5: must be an integer"),
        ({"first_sleeper": "x"}, "first_sleeper = 'x': must be an integer"),
        ({"overhang_elements": 1.5}, "overhang_elements = 1.5: must be an integer"),
        ({"overhang_elements": float("nan")}, "overhang_elements = nan: must be an integer"),
        ({"n_sleepers": 1}, "n_sleepers = 1: need at least 2"),
        # absurd sizes are refused at once, before anything is allocated (10**9 sleepers ran for minutes)
        ({"n_sleepers": 10**9}, "n_sleepers = 1000000000, elements_per_bay = 2: about 6000000002 degrees of freedom, "
                                "more than 2000000"),
        ({"n_sleepers": 1001, "elements_per_bay": 10**6}, "more than 2000000"),
    ],
)
def test_assemble_refuses_bad_counts(kwargs: dict[str, object], fragment: str) -> None:
    args: dict[str, object] = {"n_sleepers": 11} | kwargs
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        assemble(load_model(), **args)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        ((1.0, 1.0, 0.0), "L = 0 m: must be > 0"),
        ((1.0, 1.0, float("nan")), "L = nan: must be finite"),
        ((float("nan"), 1.0, 0.3), "EI = nan: must be finite"),
        ((-1.0, 1.0, 0.3), "EI = -1 N m^2: must be > 0"),
        ((1.0, -1.0, 0.3), "m = -1 kg/m: must be > 0"),
    ],
)
def test_beam_element_refuses_bad_values(args: tuple[float, float, float], fragment: str) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        beam_element(*args)
