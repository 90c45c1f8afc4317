"""Operator cache (clm_core.solver.operators) and the compiled step on its typed inputs."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from clm_core.params import ModelParams, SleeperOverride, load_model
from clm_core.solver import _kernels as kern
from clm_core.solver.operators import OperatorCache
from clm_core.solver.window import Placement, Window
from clm_core.track import SleeperValues

DT = 2e-4


@pytest.fixture(scope="module")
def mev() -> ModelParams:
    return load_model("mevergnies", "mevergnies", "clm")


def _cache(params: ModelParams, n: int = 21, size: int = 64, follow: bool = True) -> OperatorCache:
    w = Window.create(n, params.track.spacing, follow=follow)
    return OperatorCache(params, DT, w, 2, SleeperValues(params), size)


def test_uniform_track_shares_one_factorisation(mev: ModelParams) -> None:
    c = _cache(mev)
    ops = [c.get(Placement(g, "forward")) for g in (-10, 0, 7, 5000, -123456)]
    assert all(op is ops[0] for op in ops)
    assert c.n_factorisations == 1 and len(c) == 1
    back = c.get(Placement(3, "backward"))  # the mirrored ghost bay is another operator
    assert back is not ops[0] and c.n_factorisations == 2
    assert c.get(Placement(-99, "backward")) is back


def test_override_window_gets_its_own_operator(mev: ModelParams) -> None:
    kb_soft = 0.5 * mev.track.kb
    p = replace(mev, overrides=(SleeperOverride((200,), {"kb": kb_soft}),))
    c = _cache(p)
    uniform = c.get(Placement(0, "forward"))
    over = c.get(Placement(190, "forward"))  # sleepers 190 .. 210 (+ ghost 211)
    assert over is not uniform and c.n_factorisations == 2
    kb = over.kernel.kb
    assert kb[10] == kb_soft and np.all(np.delete(kb, 10) == mev.track.kb)
    other = c.get(Placement(195, "forward"))  # the same override at another place in the window
    assert other is not over and other.kernel.kb[5] == kb_soft and c.n_factorisations == 3
    assert c.get(Placement(190, "forward")) is over  # met again: from the cache
    assert c.get(Placement(1000, "forward")) is uniform and c.n_factorisations == 3
    # the key covers the span assembled: an override in the clamped ghost bay makes another operator
    assert c.key(Placement(179, "forward")) != c.key(Placement(178, "forward"))
    assert c.key(Placement(178, "forward")) == c.key(Placement(0, "forward"))


def test_identical_override_stretches_share_a_factorisation(mev: ModelParams) -> None:
    """The key is the values, not the place: two identical patches seen at the same offset share one operator."""
    p = replace(mev, overrides=(SleeperOverride((100, 101), {"kf": 20e6}), SleeperOverride((500, 501), {"kf": 20e6})))
    c = _cache(p)
    a = c.get(Placement(95, "forward"))
    b = c.get(Placement(495, "forward"))
    assert a is b and c.n_factorisations == 1


def test_least_recently_used_operator_is_dropped(mev: ModelParams) -> None:
    p = replace(mev, overrides=tuple(SleeperOverride((g,), {"kb": 40e6 + g}) for g in (100, 300, 500)))
    c = _cache(p, size=2)
    a = c.get(Placement(95, "forward"))
    c.get(Placement(295, "forward"))
    assert c.get(Placement(95, "forward")) is a  # refreshed: now the most recent
    c.get(Placement(495, "forward"))  # drops 295, the least recently used
    assert len(c) == 2 and c.n_factorisations == 3
    assert c.get(Placement(95, "forward")) is a and c.n_factorisations == 3
    c.get(Placement(295, "forward"))
    assert c.n_factorisations == 4


def test_factors_solve_the_assembled_matrices(mev: ModelParams) -> None:
    c = _cache(mev, follow=False)
    op = c.get(Placement(0, "free"))
    s = op.system
    Keff = (s.K + (2 / DT) * s.C + (4 / DT**2) * s.M).tocsc()
    b = np.random.default_rng(1).standard_normal(s.n_dof)
    x = b.copy()
    kern.solve_envelope(*op.env, x)
    ref = spla.spsolve(Keff, b)
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    xs = b.copy()
    kern.solve_envelope(*op.static_factor(), xs)
    ref = spla.spsolve(sp.csc_matrix(s.K), b)
    np.testing.assert_allclose(xs, ref, rtol=0, atol=1e-8 * np.abs(ref).max())
    dofs = np.array([s.rail_w[7], s.rail_th[7], s.rail_w[7]], dtype=np.int64)
    cols, slot = op.columns(dofs)
    e = np.zeros(s.n_dof)
    e[s.rail_th[7]] = 1.0
    ref = spla.spsolve(Keff, e)
    np.testing.assert_allclose(cols[slot[s.rail_th[7]]], ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    assert np.count_nonzero(slot >= 0) == 2  # one column per distinct DOF


def test_run_steps_is_one_newmark_step_and_writes_the_output_rows(mev: ModelParams) -> None:
    """The compiled kernel on its typed inputs: K_eff du = f_{n+1} + f_n - 2 K u + (4/dt) M v (increment form)."""
    c = _cache(mev, follow=False)
    op = c.get(Placement(0, "free"))
    s = op.system
    lay = c.layout
    rng = np.random.default_rng(2)
    n, N = s.n_dof, s.n_sleepers
    u, v = 1e-4 * rng.standard_normal(n), 1e-3 * rng.standard_normal(n)
    u0, v0 = u.copy(), v.copy()
    f_n = np.zeros(n)
    prev_dofs = np.array([s.rail_w[20], s.rail_th[20]], dtype=np.int64)
    prev_vals = np.array([50e3, 3e3])
    f_n[prev_dofs] = prev_vals
    S = 3
    ldofs = np.tile(np.array([s.rail_w[21], s.rail_th[21], s.rail_w[22], s.rail_th[22]], dtype=np.int64), (S, 1))
    lw = np.tile(np.array([0.5, 0.05, 0.5, -0.05]), (S, 1))
    F = np.array([[80e3], [90e3], [100e3]])
    steps = np.array([0, 2], dtype=np.int64)
    out = kern.StepOutputs(np.empty((S, 1)), np.empty((S, 1)), steps, *(np.full((2, N), np.nan) for _ in range(4)))
    state = kern.StepState(u, v, np.zeros(n), np.zeros(n), prev_dofs, prev_vals, np.full(N, -np.inf),
                           np.full(N, -np.inf))
    k = kern.run_steps(kern.StepArgs(op.kernel, state, kern.StepLoads(ldofs, lw, F), out))
    assert k == 2
    assert not state.z.any()  # the work array is zero on exit
    Keff = (s.K + (2 / DT) * s.C + (4 / DT**2) * s.M).tocsc()
    uu, vv = u0, v0
    for i in range(S):
        f1 = np.zeros(n)
        np.add.at(f1, ldofs[i], lw[i] * F[i, 0])
        du = spla.spsolve(Keff, f1 + f_n - 2 * (s.K @ uu) + (4 / DT) * (s.M @ vv))
        uu, vv = uu + du, (2 / DT) * du - vv
        f_n = f1
        assert out.wdefl[i, 0] == pytest.approx(lw[i] @ uu[ldofs[i]], rel=1e-9)
        if i == 0:
            row0 = uu[lay.r_dof].copy()
    np.testing.assert_allclose(u, uu, rtol=0, atol=1e-9 * np.abs(uu).max())
    np.testing.assert_allclose(v, vv, rtol=0, atol=1e-9 * np.abs(vv).max())
    np.testing.assert_allclose(out.rail[0], row0, rtol=1e-9)  # output rows at steps 0 and 2 only
    np.testing.assert_allclose(out.rail[1], uu[lay.r_dof], rtol=1e-9)
    fs = s.ballast_force(uu, vv)
    np.testing.assert_allclose(out.force[1], fs, rtol=1e-9, atol=1e-6)
    assert np.all(state.pk_force >= fs - 1e-6)
