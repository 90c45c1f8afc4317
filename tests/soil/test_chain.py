"""The one CLM chain solver (clm_core.soil.chain): Jacobian, sum identities, independent solves."""

from __future__ import annotations

import re

import numpy as np
import pytest

from clm_core.errors import ParameterError
from clm_core.params import SoilParams, load_soil
from clm_core.soil.chain import (
    CHAIN_PARAMS,
    chain_damping_min_eigenvalue,
    chain_frequency_response,
    chain_impedance_sums,
    chain_matrices,
    chain_response,
    chain_sums,
    chain_time_response,
    laplace,
)
from clm_core.soil.formulas import sum_impedance_jacobian, sum_impedances

TABLE1 = {"mf": 380.0, "kf": 72e6, "df": 680e3, "kc": 160e6, "dc": -155e3}
F = np.array([0.0, 3.0, 17.0, 64.0, 150.0, 310.0])


def dense_solve(p: dict[str, float], n_areas: int, s: np.ndarray, loaded: int) -> np.ndarray:
    """Eq. (9)-(13) written out area by area (free ends), dense complex solve at each s."""
    X = np.zeros((s.size, n_areas), complex)
    for i, si in enumerate(s):
        zc = p["kc"] + si * p["dc"]
        D = np.zeros((n_areas, n_areas), complex)
        for a in range(n_areas):
            nb = (a > 0) + (a < n_areas - 1)
            D[a, a] = p["kf"] + si * p["df"] + si**2 * p["mf"] + nb * zc
            if a > 0:
                D[a, a - 1] = -zc
            if a < n_areas - 1:
                D[a, a + 1] = -zc
        e = np.zeros(n_areas, complex)
        e[loaded] = 1.0
        X[i] = np.linalg.solve(D, e)
    return X


@pytest.mark.parametrize("sigma", [0.0, 6.0])
@pytest.mark.parametrize(("n_areas", "loaded"), [(1, None), (3, None), (11, None), (11, 2), (41, 40)])
def test_matches_independent_dense_solve(sigma: float, n_areas: int, loaded: int | None) -> None:
    s = laplace(F, sigma)
    X, _ = chain_response(TABLE1, n_areas, s, loaded=loaded)
    ref = dense_solve(TABLE1, n_areas, s, n_areas // 2 if loaded is None else loaded)
    np.testing.assert_allclose(X, ref, rtol=1e-11, atol=1e-11 * np.abs(ref).max())


def test_matches_assembled_matrices() -> None:
    """The solver and the time-domain matrices describe the same chain: X = (K + s C + s^2 M)^-1 e."""
    soil = load_soil("haren")
    M, C, K = (A.toarray() for A in chain_matrices(soil, 9))
    s = laplace(F, 2.0)
    X, _ = chain_response(soil, 9, s)
    for i, si in enumerate(s):
        np.testing.assert_allclose((K + si * C + si**2 * M) @ X[i], np.eye(9)[4], atol=1e-12)


def test_reciprocity() -> None:
    """Maxwell-Betti: X_j for a force on area i equals X_i for a force on area j (D is symmetric)."""
    s = laplace(F, 1.0)
    X2, _ = chain_response(TABLE1, 9, s, loaded=2)
    X7, _ = chain_response(TABLE1, 9, s, loaded=7)
    np.testing.assert_allclose(X2[:, 7], X7[:, 2], rtol=1e-12)


@pytest.mark.parametrize("sigma", [0.0, 5.0])
@pytest.mark.parametrize("n_areas", [1, 5, 21])
def test_jacobian_against_finite_differences(sigma: float, n_areas: int) -> None:
    s = laplace(np.linspace(0.5, 200.0, 23), sigma)
    X, dX = chain_response(TABLE1, n_areas, s, jacobian=True)
    assert dX.shape == (5, s.size, n_areas)
    for k, name in enumerate(CHAIN_PARAMS):
        h = 1e-6 * max(abs(TABLE1[name]), 1.0)
        up, _ = chain_response({**TABLE1, name: TABLE1[name] + h}, n_areas, s)
        dn, _ = chain_response({**TABLE1, name: TABLE1[name] - h}, n_areas, s)
        fd = (up - dn) / (2 * h)
        np.testing.assert_allclose(dX[k], fd, rtol=1e-6, atol=1e-7 * np.abs(fd).max(), err_msg=name)


def test_sum_jacobian_against_finite_differences() -> None:
    f = np.linspace(1.0, 150.0, 16)
    sums = chain_impedance_sums(TABLE1, 7, f, sigma=3.0, jacobian=True)
    assert sums.d_total is not None and sums.d_alternating is not None
    for k, name in enumerate(CHAIN_PARAMS):
        h = 1e-6 * abs(TABLE1[name])
        up = chain_impedance_sums({**TABLE1, name: TABLE1[name] + h}, 7, f, sigma=3.0)
        dn = chain_impedance_sums({**TABLE1, name: TABLE1[name] - h}, 7, f, sigma=3.0)
        pairs = ((sums.d_total[k], up.total, dn.total), (sums.d_alternating[k], up.alternating, dn.alternating))
        for got, a, b in pairs:
            fd = (a - b) / (2 * h)  # dS/dkc and dS/ddc vanish (Eq. 16): compare on the scale Z / p
            atol = 1e-6 * np.abs(a).max() / abs(TABLE1[name])
            np.testing.assert_allclose(got, fd, rtol=1e-6, atol=atol, err_msg=name)


@pytest.mark.parametrize("name", ["mevergnies", "soft", "stiff", "haren"])
@pytest.mark.parametrize("n_areas", [1, 3, 7, 41, 101])
@pytest.mark.parametrize("sigma", [0.0, 8.0])
def test_eq16_identity_exact_for_any_length(name: str, n_areas: int, sigma: float) -> None:
    """Free ends: F / sum X_j = k_f + s d_f + s^2 m_f (Eq. 16) and dS/dp = (s^2, 1, s, 0, 0), any n, any s."""
    soil = load_soil(name)
    sums = chain_impedance_sums(soil, n_areas, F, sigma=sigma, jacobian=True)
    s = laplace(F, sigma)
    S, _ = sum_impedances(s, soil)
    dS, _ = sum_impedance_jacobian(s)
    np.testing.assert_allclose(sums.total, S, rtol=1e-10)
    assert sums.d_total is not None
    scale = np.abs(sum_impedance_jacobian(s)[1]).max(axis=1, keepdims=True)  # nonzero for every parameter
    np.testing.assert_allclose(sums.d_total / scale, dS / scale, atol=1e-9)


@pytest.mark.parametrize("name", ["mevergnies", "medium", "haren"])
def test_eq18_and_its_jacobian_converge_with_n(name: str) -> None:
    """The alternating sum and its Jacobian tend to Eq. (18) and (s^2, 1, s, 4, 4 s) as n grows."""
    soil = load_soil(name)
    s = laplace(F)
    _, A = sum_impedances(s, soil)
    _, dA = sum_impedance_jacobian(s)
    scale = np.abs(dA).max(axis=1, keepdims=True)
    err, derr = [], []
    for n in (3, 5, 11, 21, 41, 81):
        sums = chain_impedance_sums(soil, n, F, jacobian=True)
        assert sums.d_alternating is not None
        err.append(np.max(np.abs(sums.alternating / A - 1)))
        derr.append(np.max(np.abs(sums.d_alternating - dA) / scale))
    assert all(b <= a * 1.0001 for a, b in zip(err, err[1:], strict=False))
    assert all(b <= a * 1.0001 for a, b in zip(derr[2:], derr[3:], strict=False))  # from 11 areas on
    assert err[-1] < 1e-6 and derr[-1] < 1e-5
    assert err[0] > 1e3 * err[-1]  # it does converge from a visible error


def test_soil_params_and_plain_values_agree() -> None:
    soil = load_soil("medium")
    f = np.array([0.0, 40.0, 120.0])
    plain = {k: getattr(soil, k) for k in CHAIN_PARAMS}
    np.testing.assert_array_equal(chain_frequency_response(soil, 5, f), chain_frequency_response(plain, 5, f))
    # a fitted set with m_f = 0 (not a valid SoilParams) is a valid chain
    X = chain_frequency_response({**TABLE1, "mf": 0.0}, 5, f)
    assert np.all(np.isfinite(X))
    # a Winkler soil has no coupling: only the loaded area moves
    w = SoilParams(model="winkler", kf=72e6, df=680e3)
    Xw = chain_frequency_response(w, 5, f)
    np.testing.assert_allclose(Xw[:, 2], 1.0 / (72e6 + 2j * np.pi * f * 680e3))
    assert np.all(Xw[:, [0, 1, 3, 4]] == 0)


def test_damping_eigenvalue_closed_form() -> None:
    soil = load_soil("mevergnies")
    for n in (1, 3, 11):
        _, C, _ = chain_matrices(soil, n)
        assert chain_damping_min_eigenvalue(soil, n) == pytest.approx(np.linalg.eigvalsh(C.toarray())[0], rel=1e-10)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: chain_response(TABLE1, 4, [1j]), "n_areas = 4: must be odd"),
        (lambda: chain_response(TABLE1, 5, [1j], loaded=5), "loaded = 5"),
        (lambda: chain_response({"kz": 1.0}, 5, [1j]), "unknown name"),
        (lambda: chain_response({**TABLE1, "kf": np.nan}, 5, [1j]), "kf = nan"),
        (lambda: chain_response(SoilParams(model="rigid"), 5, [1j]), "winkler, lysmer or clm"),
        (lambda: chain_response({"kf": 0.0}, 3, [0.0]), "singular at s = 0"),
    ],
)
def test_errors(call: object, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        call()  # type: ignore[operator]


# ---------------------------------------------------------------- bad input


_SOIL = {"mf": 380.0, "kf": 7.2e7, "df": 6.8e5, "kc": 1.6e8, "dc": -1.2e5}


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"loaded": float("nan")}, "loaded = nan: must be an integer"),
        ({"loaded": "x"}, "loaded = 'x': must be an integer"),
        ({"loaded": 1.5}, "loaded = 1.5: must be an integer"),
        ({"loaded": 5}, "loaded = 5: must be an integer in 0..4 (an area index)"),
        ({"n_areas": 10**9 + 1}, "n_areas = 1000000001: must be an integer <= 100001 (a chain of 2n + 1 areas)"),
        ({"s": [np.nan]}, "must be finite"),
        ({"s": [np.inf]}, "must be finite"),
        ({"s": []}, "s: must be a non-empty 1-D array"),
        ({"s": [[1j, 2j]]}, "s: must be a non-empty 1-D array"),
        ({"s": "abc"}, "s = 'abc': must be complex numbers"),
    ],
)
def test_chain_response_refuses_bad_input(kwargs: dict[str, object], fragment: str) -> None:
    args: dict[str, object] = {"s": [2j * np.pi]} | kwargs
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        chain_response(_SOIL, args.pop("n_areas", 5), args.pop("s"), **args)  # type: ignore[arg-type]


def test_laplace_refuses_nonfinite_sigma() -> None:
    with pytest.raises(ParameterError, match=re.escape("sigma = nan: must be finite")):
        laplace([1.0], float("nan"))


@pytest.mark.parametrize(
    ("frequency", "X", "force", "loaded", "fragment"),
    [
        ([1.0, 2.0], np.ones(5), 1.0, None, "X: shape (5,): must be (n_f, 2n + 1)"),
        ([], np.zeros((0, 5)), 1.0, None, "X: shape (0, 5): must be (n_f, 2n + 1) with n_f >= 1"),
        ([1.0, 2.0, 3.0], np.ones((2, 5)), 1.0, None, "frequency: shape (3,): must be (2,)"),
        ([1.0, 2.0], np.ones((2, 5)), [1.0, 2.0, 3.0], None, "force: shape (3,): must be a scalar or (2,)"),
        ([1.0, 2.0], np.ones((2, 5)), 1.0, 7, "loaded = 7: must be an integer in 0..4 (an area index)"),
        ([1.0, 2.0], np.ones((2, 5)), 1.0, -1, "loaded = -1: must be an integer in 0..4 (an area index)"),
        ([1.0], "abc", 1.0, None, "must be numbers"),
    ],
)
def test_chain_sums_refuses_bad_input(
    frequency: object, X: object, force: object, loaded: int | None, fragment: str
) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        chain_sums(frequency, X, force, loaded=loaded)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"dt": 0.0}, "dt = 0 s: must be > 0"),
        ({"dt": -1e-5}, "dt = -1e-05 s: must be > 0"),
        ({"dt": float("nan")}, "dt = nan: must be finite"),
        ({"duration": -0.1}, "duration = -0.1 s: must be > 0"),
        ({"duration": 0.0}, "duration = 0 s: must be > 0"),
        ({"duration": float("inf")}, "duration = inf: must be finite"),
        ({"duration": 5e-5}, "duration = 5e-05 s: must be >= dt"),
        ({"A": float("nan")}, "A = nan: must be finite"),
        ({"t0": float("nan")}, "t0 = nan: must be finite"),
        ({"td": 0.0}, "td = 0 s: must be > 0"),
        ({"n_areas": 4}, "n_areas = 4: must be odd"),
    ],
)
def test_chain_time_response_refuses_bad_settings(kwargs: dict[str, float], fragment: str) -> None:
    soil = load_soil("mevergnies", "clm")
    args = {"n_areas": 5, "dt": 1e-4, "duration": 0.01} | kwargs
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        chain_time_response(soil, **args)  # type: ignore[arg-type]


@pytest.mark.parametrize("n_neighbours", [3, -1, 1.5])
def test_time_response_peaks_refuses_neighbours_outside_the_chain(n_neighbours: int) -> None:
    resp = chain_time_response(load_soil("mevergnies", "clm"), 5, 1e-4, 0.01)
    with pytest.raises(ParameterError, match=re.escape(f"n_neighbours = {n_neighbours!r}: must be an integer in 0..2")):
        resp.peaks(n_neighbours)
