"""CLM fit to impedance sums (Eq. 16, 18): exact recovery, norms, constraints."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from clm_core.checks import chain_min_eigenvalue, clm_chain_admissible
from clm_core.errors import ParameterError, StabilityError
from clm_core.soil.chain import chain_frequency_response
from clm_core.soil.fit import fit_clm_sums, fit_lysmer

TABLE1 = {"mf": 380.0, "kf": 72e6, "df": 680e3, "kc": 160e6, "dc": -155e3}


def chain_sums(freqs: np.ndarray, p: dict[str, float], n_areas: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Independent tridiagonal solve of Eq. (9)-(13) for a free chain (force on the centre)."""
    N = n_areas
    S = np.zeros(freqs.size, complex)
    A = np.zeros(freqs.size, complex)
    X = np.zeros((freqs.size, N), complex)
    j = np.arange(N) - N // 2
    for i, f in enumerate(freqs):
        w = 2 * math.pi * f
        zc = p["kc"] + 1j * w * p["dc"]
        M = np.zeros((N, N), complex)
        for a in range(N):
            nb = (a > 0) + (a < N - 1)
            M[a, a] = p["kf"] - w**2 * p["mf"] + 1j * w * p["df"] + nb * zc
            if a > 0:
                M[a, a - 1] = -zc
            if a < N - 1:
                M[a, a + 1] = -zc
        F = np.zeros(N, complex)
        F[N // 2] = 1.0
        x = np.linalg.solve(M, F)
        X[i] = x
        S[i] = 1.0 / x.sum()
        A[i] = 1.0 / (x * (-1.0) ** j).sum()
    return S, A, X


@pytest.mark.parametrize("norm", ["ls", "relative"])
def test_recovers_clm_parameters_from_chain_sums(norm: str) -> None:
    f = np.arange(0.0, 101.0, 1.0)
    S, A, _ = chain_sums(f, TABLE1, 81)
    fit = fit_clm_sums(f, S, A, fmin=0.0, fmax=100.0, norm=norm)  # type: ignore[arg-type]
    # Eq. (16) is exact for any free chain
    for key in ("mf", "kf", "df"):
        assert getattr(fit, key) == pytest.approx(TABLE1[key], rel=1e-9)
    # Eq. (18) is exact for the infinite chain; 81 areas give it to ~1e-12
    for key in ("kc", "dc"):
        assert getattr(fit, key) == pytest.approx(TABLE1[key], rel=1e-8)
    assert fit.residual_total < 1e-12 and fit.residual_alternating < 1e-9
    assert fit.band == (0.0, 100.0) and fit.norm == norm and fit.n_points == 101
    assert fit.constrained == ()
    assert fit.damping_min_eigenvalue == pytest.approx(680e3 - 4 * 155e3)


def test_chain_response_helper_matches_independent_solve() -> None:
    f = np.array([0.0, 7.0, 55.0])
    _, _, X = chain_sums(f, TABLE1, 11)
    np.testing.assert_allclose(chain_frequency_response(TABLE1, 11, f), X, rtol=1e-12)


def test_band_selects_frequencies() -> None:
    f = np.arange(0.0, 151.0, 1.0)
    S, A, _ = chain_sums(f, TABLE1, 41)
    S = S.copy()
    S[f > 100] *= 3.0  # garbage outside the band must not matter
    # total-first: k_f comes from Eq. (16) alone, exact for the free 41-area chain
    fit = fit_clm_sums(f, S, A, fmin=10.0, fmax=100.0, route="total-first")
    assert fit.kf == pytest.approx(72e6, rel=1e-9)
    assert fit.n_points == 91
    # joint (default): Eq. (18) holds to ~1e-4 for 41 areas, which reaches k_f at ~1e-6
    fit = fit_clm_sums(f, S, A, fmin=10.0, fmax=100.0)
    assert fit.kf == pytest.approx(72e6, rel=1e-5)
    assert fit.n_points == 91


def test_negative_mass_is_constrained_or_refused() -> None:
    f = np.arange(0.0, 81.0, 2.0)
    p = dict(TABLE1, mf=-200.0)
    w = 2 * np.pi * f
    S = p["kf"] - w**2 * p["mf"] + 1j * w * p["df"]
    A = p["kf"] + 4 * p["kc"] - w**2 * p["mf"] + 1j * w * (p["df"] + 4 * p["dc"])
    fit = fit_clm_sums(f, S, A, fmin=0.0, fmax=80.0)
    assert fit.mf == 0.0 and "mf=0" in fit.constrained
    assert fit.kf == pytest.approx(np.mean(S.real))
    with pytest.raises(StabilityError, match="mf = -200"):
        fit_clm_sums(f, S, A, fmin=0.0, fmax=80.0, mass="free")


def test_unstable_coupling_damping_raises_or_clips() -> None:
    f = np.arange(0.0, 81.0, 2.0)
    p = dict(TABLE1, dc=-200e3)  # df + 4 dc = -120 kN s/m < 0
    w = 2 * np.pi * f
    S = p["kf"] - w**2 * p["mf"] + 1j * w * p["df"]
    A = p["kf"] + 4 * p["kc"] - w**2 * p["mf"] + 1j * w * (p["df"] + 4 * p["dc"])
    with pytest.raises(StabilityError, match=r"dc = -200000.*not positive definite"):
        fit_clm_sums(f, S, A, fmin=0.0, fmax=80.0)
    fit = fit_clm_sums(f, S, A, fmin=0.0, fmax=80.0, on_unstable="clip")
    assert "dc clipped" in fit.constrained
    assert fit.dc == pytest.approx(-0.95 * 680e3 / 4)
    assert fit.df + 4 * fit.dc > 0


@pytest.mark.parametrize("N", [1, 2, 3, 7, 41])
@pytest.mark.parametrize("dc", [-160e3, -100e3, 50e3])
def test_damping_matrix_eigenvalue_bound(N: int, dc: float) -> None:
    """Chain damping matrix: diagonal df + 2 dc (ends df + dc), off-diagonal -dc."""
    df = 680e3
    C = np.diag(np.full(N, df + 2 * dc))
    if N > 1:
        C[0, 0] = C[-1, -1] = df + dc
    else:
        C[0, 0] = df
    for a in range(N - 1):
        C[a, a + 1] = C[a + 1, a] = -dc
    lam = np.linalg.eigvalsh(C).min()
    assert chain_min_eigenvalue(df, dc, N) == pytest.approx(lam, rel=1e-9, abs=1e-6)
    # the length-independent bound df + 4 min(dc, 0) is never above the finite-chain value
    assert chain_min_eigenvalue(df, dc) <= lam + 1e-6


def test_check_positive_definite_messages() -> None:
    clm_chain_admissible(**{"df": 680e3, "dc": -155e3, "kf": 72e6, "kc": 160e6, "mf": 380.0})
    with pytest.raises(StabilityError, match="kc = -2e\\+07"):
        clm_chain_admissible(df=680e3, dc=-155e3, kf=72e6, kc=-20e6, mf=380.0)


def test_fit_lysmer_exact() -> None:
    f = np.linspace(0.0, 80.0, 41)
    w = 2 * np.pi * f
    K = 176e6 - w**2 * 250.0 + 1j * w * 480e3
    for norm in ("ls", "relative"):
        fit = fit_lysmer(f, K, fmin=0.0, fmax=80.0, norm=norm)  # type: ignore[arg-type]
        assert (fit.mf, fit.kf, fit.df) == pytest.approx((250.0, 176e6, 480e3), rel=1e-9)
        np.testing.assert_allclose(fit.impedance(f), K, rtol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"fmin": 50.0, "fmax": 10.0}, "band"),
        ({"fmin": 200.0, "fmax": 300.0}, "holds 0 distinct frequencies"),
        ({"fmin": 0.0, "fmax": 80.0, "norm": "l1"}, "norm"),
        ({"fmin": 0.0, "fmax": 80.0, "on_unstable": "ignore"}, "on_unstable"),
    ],
)
def test_bad_arguments(kwargs: dict[str, object], match: str) -> None:
    f = np.arange(0.0, 81.0, 10.0)
    S, A, _ = chain_sums(f, TABLE1, 5)
    with pytest.raises(ParameterError, match=match):
        fit_clm_sums(f, S, A, **kwargs)  # type: ignore[arg-type]


def test_degenerate_data_is_refused_not_fitted() -> None:
    """Three copies of one frequency fit anything, and zero data give zeros with a NaN residual: both refused."""
    K = np.array([1e8 + 1e6j, 1.1e8 + 1e6j, 1.2e8 + 1e6j])
    with pytest.raises(ParameterError, match=r"holds 1 distinct frequencies of the data, need >= 3"):
        fit_lysmer([10.0, 10.0, 10.0], K, fmin=0.0, fmax=100.0)
    with pytest.raises(ParameterError, match=r"^impedance\[0\]: zero at every frequency of the band"):
        fit_lysmer([10.0, 20.0, 30.0], np.zeros(3), fmin=0.0, fmax=100.0)
    with pytest.raises(ParameterError, match=r"^sums\[1\]: zero at every frequency of the band"):
        fit_clm_sums([10.0, 20.0, 30.0], K, np.zeros(3), fmin=0.0, fmax=100.0)


def test_shape_mismatch() -> None:
    with pytest.raises(ParameterError, match="shape"):
        fit_clm_sums(np.arange(5.0), np.ones(4), np.ones(5), fmin=0.0, fmax=4.0)


# ----------------------------------------------------------------------------- joint fit of both sums (issue 14)


@pytest.mark.parametrize("norm", ["ls", "relative"])
def test_joint_fit_recovers_all_five_parameters(norm: str) -> None:
    """Sums of a known 81-area chain (Eq. 18 exact to ~1e-11 there): the joint fit returns the chain."""
    f = np.arange(0.0, 121.0, 1.0)
    S, A, _ = chain_sums(f, TABLE1, 81)
    fit = fit_clm_sums(f, S, A, fmin=0.0, fmax=120.0, norm=norm, n_areas=81)  # type: ignore[arg-type]
    assert fit.route == "joint" and fit.constrained == ()
    for key, value in TABLE1.items():
        assert getattr(fit, key) == pytest.approx(value, rel=1e-8), key
    assert fit.mf_unconstrained == fit.mf
    q = fit.quality()
    assert q["total"]["residual"] < 1e-9 and q["alternating"]["residual"] < 1e-9


def _stacked(f: np.ndarray, S: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joint least-squares system written out by hand: unknowns (mf, kf, df, kc, dc), real rows."""
    w = 2 * np.pi * f
    z, o = np.zeros_like(w), np.ones_like(w)
    re_S = np.stack([-(w**2), o, z, z, z], 1)
    im_S = np.stack([z, z, w, z, z], 1)
    re_A = np.stack([-(w**2), o, z, 4 * o, z], 1)
    im_A = np.stack([z, z, w, z, 4 * w], 1)
    return np.vstack([re_S, im_S, re_A, im_A]), np.concatenate([S.real, S.imag, A.real, A.imag])


@pytest.mark.parametrize(("curv_S", "curv_A"), [(150.0, -75.0), (-400.0, 200.0), (600.0, 600.0)])
def test_joint_fit_is_the_bounded_least_squares_optimum(curv_S: float, curv_A: float) -> None:
    """Against scipy's bounded linear least squares (m_f >= 0) on non-CLM data; joint beats total-first."""
    from scipy.optimize import lsq_linear

    f = np.arange(0.0, 81.0, 1.0)
    w = 2 * np.pi * f
    rng = np.random.default_rng(3)
    S0, A0, _ = chain_sums(f, TABLE1, 41)
    # sums that no CLM matches: extra curvature (of either sign) and noise
    S = S0 + curv_S * w**2 + 2e6 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    A = A0 + curv_A * w**2 + 5e6 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    G, y = _stacked(f, S, A)
    scale = np.linalg.norm(G, axis=0)
    ref = lsq_linear(G / scale, y, bounds=([0, -np.inf, -np.inf, -np.inf, -np.inf], np.inf), tol=1e-14).x / scale
    fit = fit_clm_sums(f, S, A, fmin=0.0, fmax=80.0)
    got = np.array([fit.mf, fit.kf, fit.df, fit.kc, fit.dc])
    np.testing.assert_allclose(got, ref, rtol=1e-7, atol=1e-6)
    assert ("mf=0" in fit.constrained) == (fit.mf_unconstrained < 0) == (curv_A > 500)  # the bound is exercised
    seq = fit_clm_sums(f, S, A, fmin=0.0, fmax=80.0, route="total-first")
    cost = {r.route: float(np.sum((G @ [r.mf, r.kf, r.df, r.kc, r.dc] - y) ** 2)) for r in (fit, seq)}
    assert cost["joint"] <= cost["total-first"] * (1 + 1e-12)


def test_total_first_route_is_the_sequential_fit() -> None:
    """total-first: a parabola in w through Re S, a line through Im S, then offsets of A (Sec. 4.1)."""
    f = np.arange(0.0, 81.0, 2.0)
    w = 2 * np.pi * f
    rng = np.random.default_rng(5)
    S0, A0, _ = chain_sums(f, TABLE1, 21)
    S = S0 * (1 + 0.03 * rng.standard_normal(f.size))
    A = A0 * (1 + 0.03 * rng.standard_normal(f.size))
    V = np.stack([np.ones_like(w), -(w**2)], 1)
    kf, mf = np.linalg.lstsq(V, S.real, rcond=None)[0]
    df = float(w @ S.imag / (w @ w))
    kc = float(np.mean(A.real - kf + w**2 * mf)) / 4
    dc = (float(w @ A.imag / (w @ w)) - df) / 4
    fit = fit_clm_sums(f, S, A, fmin=0.0, fmax=80.0, route="total-first", mass="free")
    assert (fit.mf, fit.kf, fit.df, fit.kc, fit.dc) == pytest.approx((mf, kf, df, kc, dc), rel=1e-9)
    assert fit.route == "total-first"


def test_route_is_checked() -> None:
    f = np.arange(0.0, 81.0, 10.0)
    S, A, _ = chain_sums(f, TABLE1, 5)
    with pytest.raises(ParameterError, match="route = 'both'"):
        fit_clm_sums(f, S, A, fmin=0.0, fmax=80.0, route="both")  # type: ignore[arg-type]


# ---------------------------------------------------------------- bad input


def _sums() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from clm_core.soil.chain import chain_impedance_sums

    f = np.linspace(1.0, 50.0, 20)
    S = chain_impedance_sums({"mf": 380.0, "kf": 7.2e7, "df": 6.8e5, "kc": 1.6e8, "dc": -1.2e5}, 41, f)
    return f, S.total, S.alternating


@pytest.mark.parametrize(
    ("change", "fragment"),
    [
        ({"fmin": "x"}, "fmin = 'x': must be a real number"),
        ({"n_areas": 4}, "n_areas = 4: must be odd"),
        ({"n_areas": float("nan")}, "n_areas = nan: must be an integer"),
        ({"n_areas": "x"}, "n_areas = 'x': must be an integer"),
        ({"freqs": "nan"}, "freqs = nan Hz: must be finite"),
        ({"total": "abc"}, "sums[0] = 'abc': must be complex numbers"),
    ],
)
def test_fit_clm_sums_refuses_bad_input(change: dict[str, object], fragment: str) -> None:
    f, total, alternating = _sums()
    args: dict[str, object] = {"freqs": f, "total": total, "alternating": alternating, "fmin": 1.0, "fmax": 50.0}
    args |= change
    if isinstance(args["freqs"], str):
        args["freqs"] = np.r_[np.nan, f[1:]]
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        fit_clm_sums(**args)  # type: ignore[arg-type]


def test_fit_lysmer_refuses_text_frequencies() -> None:
    with pytest.raises(ParameterError, match=re.escape("freqs = 'abc': must be real numbers")):
        fit_lysmer("abc", [1.0], fmin=1.0, fmax=50.0)
