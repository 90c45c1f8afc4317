"""Compiled kernels (numba) of the streaming time integrator.

The pieces, all O(n) per call for a banded system of n DOFs:

- :func:`ldlt_envelope`: LDL^T factorisation of a symmetric positive definite
  matrix in envelope (profile, "skyline") storage, done once per window
  configuration. Row ``i`` of the strict lower triangle is stored from its
  first non-zero column ``first[i]`` to ``i - 1`` at ``L[ptr[i]:ptr[i+1]]``;
  there is no fill outside the envelope.
- :func:`solve_envelope`: forward and back substitution with that factor.
- :func:`unit_columns`, :func:`free_response`: columns of the inverse and
  the load-free step increment, the pieces of the compiled vehicle coupling
  (:mod:`clm_core.vehicle._coupled_kernel`).
- :func:`run_steps`: many steps of Newmark average acceleration in the
  increment form (see :mod:`clm_core.stepper`)::

      K_eff du = f_{n+1} + f_n - 2 K u_n + (4/dt) M v_n,
      u_{n+1} = u_n + du,   v_{n+1} = (2/dt) du - v_n,

  with K_eff = K + (2/dt) C + (4/dt^2) M; the right-hand side is one sparse
  (CSR) pass over the union pattern of K and M.

The kernels are compiled with ``cache=True`` (the first call in a fresh
environment compiles, later processes load the cache).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def ldlt_envelope(first, ptr, L, D):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Factorise A = L D L^T in place (envelope storage); return the first failing row or -1.

    On entry ``L`` holds the strict lower envelope of A and ``D`` its
    diagonal; on exit the unit lower factor and the pivots. A pivot
    <= 0 (matrix not positive definite) stops the factorisation and its row
    is returned.
    """
    n = D.shape[0]
    for i in range(n):
        fi = first[i]
        pi = ptr[i]
        for j in range(fi, i):
            fj = first[j]
            pj = ptr[j]
            k0 = fi if fi > fj else fj
            s = L[pi + j - fi]
            for k in range(k0, j):
                s -= L[pi + k - fi] * L[pj + k - fj] * D[k]
            L[pi + j - fi] = s / D[j]
        d = D[i]
        for k in range(fi, i):
            lik = L[pi + k - fi]
            d -= lik * lik * D[k]
        if not d > 0.0:
            return i
        D[i] = d
    return -1


@njit(cache=True)
def solve_envelope(first, ptr, L, D, x):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Solve (L D L^T) y = x in place."""
    n = D.shape[0]
    for i in range(n):
        fi = first[i]
        pi = ptr[i]
        s = x[i]
        for k in range(fi, i):
            s -= L[pi + k - fi] * x[k]
        x[i] = s
    for i in range(n):
        x[i] /= D[i]
    for i in range(n - 1, -1, -1):
        fi = first[i]
        pi = ptr[i]
        xi = x[i]
        for k in range(fi, i):
            x[k] -= L[pi + k - fi] * xi


@njit(cache=True)
def free_rhs(indptr, indices, Ka, Mb, u, v, prev_dofs, prev_vals, rhs):  # type: ignore[no-untyped-def]  # pragma: no cover
    """rhs = Ka u + Mb v + f_n (the part of the step right-hand side known at t_n)."""
    n = u.shape[0]
    for i in range(n):
        s = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            s += Ka[p] * u[j] + Mb[p] * v[j]
        rhs[i] = s
    for q in range(prev_dofs.shape[0]):
        rhs[prev_dofs[q]] += prev_vals[q]


@njit(cache=True)
def run_steps(  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    indptr, indices, Ka, Mb, first, ptr, L, Dinv, a1,
    u, v, z, y, prev_dofs, prev_vals,
    ldofs, lw, F,
    s_dof, a_dof, r_dof, kb, db,
    wdefl, wvel,
    out_every, out_phase, out_force, out_rail, out_sleeper, out_area,
    pk_force, pk_rail,
):
    """Advance ``F.shape[0]`` steps in place.

    Parameters (all arrays contiguous)
    ----------------------------------
    indptr, indices, Ka, Mb : CSR of -2 K and (4/dt) M on the union pattern.
    first, ptr, L, Dinv : envelope LDL^T factor of K_eff (Dinv = 1 / D).
    a1 : 2 / dt [1/s].
    u, v : state [m], [m/s] (n,), updated.
    z, y : work arrays (n,); z must be zero on entry and is zero on exit.
    prev_dofs, prev_vals : load vector f_n at the start, as (DOF, value [N]) pairs.
    ldofs : (S, 4 W) int DOFs of each wheel's element at every step.
    lw : (S, 4 W) Hermite weights (0 for an absent wheel).
    F : (S, W) wheel forces [N] at t_{n+1} of each step (0 for an absent wheel).
    s_dof, a_dof, r_dof : (N,) sleeper, contact-area (-1: rigid) and rail-above-sleeper DOFs.
    kb, db : (N,) ballast stiffness [N/m] and damping [N s/m].
    wdefl, wvel : (S, W) outputs: rail deflection [m] and velocity [m/s] under each wheel.
    out_every, out_phase : step s is an output step when (s + out_phase) % out_every == 0
        (out_every = 0: no sleeper outputs).
    out_force, out_rail, out_sleeper, out_area : (K, N) sleeper outputs at output steps.
    pk_force, pk_rail : (N,) running maxima of the soil force [N] and rail
        deflection above the sleepers [m], updated every step.
    """
    n = u.shape[0]
    S = F.shape[0]
    W = F.shape[1]
    N = s_dof.shape[0]
    kout = 0
    for s in range(S):
        # loads f_n + f_{n+1} scattered into z (zero on entry)
        if s == 0:
            for q in range(prev_dofs.shape[0]):
                z[prev_dofs[q]] += prev_vals[q]
        else:
            for w in range(W):
                fw = F[s - 1, w]
                for c in range(4):
                    z[ldofs[s - 1, 4 * w + c]] += lw[s - 1, 4 * w + c] * fw
        for w in range(W):
            fw = F[s, w]
            for c in range(4):
                z[ldofs[s, 4 * w + c]] += lw[s, 4 * w + c] * fw
        # fused: right-hand side row i (-2 K u + (4/dt) M v + loads), forward substitution
        for i in range(n):
            acc = z[i]
            for p in range(indptr[i], indptr[i + 1]):
                j = indices[p]
                acc += Ka[p] * u[j] + Mb[p] * v[j]
            fi = first[i]
            pi = ptr[i] - fi
            for k in range(fi, i):
                acc -= L[pi + k] * z[k]
            z[i] = acc
            y[i] = acc * Dinv[i]
        # fused: back substitution (column sweep) and state update
        for i in range(n - 1, -1, -1):
            du = y[i]
            z[i] = 0.0
            u[i] += du
            v[i] = a1 * du - v[i]
            fi = first[i]
            pi = ptr[i] - fi
            for k in range(fi, i):
                y[k] -= L[pi + k] * du
        # wheel outputs
        for w in range(W):
            sw = 0.0
            sv = 0.0
            for c in range(4):
                dof = ldofs[s, 4 * w + c]
                wt = lw[s, 4 * w + c]
                sw += wt * u[dof]
                sv += wt * v[dof]
            wdefl[s, w] = sw
            wvel[s, w] = sv
        # sleeper peaks every step, fields at output steps
        record = out_every > 0 and (s + out_phase) % out_every == 0
        for i in range(N):
            sd = s_dof[i]
            ad = a_dof[i]
            if ad >= 0:
                dz = u[sd] - u[ad]
                dv = v[sd] - v[ad]
                xa = u[ad]
            else:
                dz = u[sd]
                dv = v[sd]
                xa = 0.0
            fs = kb[i] * dz + db[i] * dv
            rw = u[r_dof[i]]
            if fs > pk_force[i]:
                pk_force[i] = fs
            if rw > pk_rail[i]:
                pk_rail[i] = rw
            if record:
                out_force[kout, i] = fs
                out_rail[kout, i] = rw
                out_sleeper[kout, i] = u[sd]
                out_area[kout, i] = xa
        if record:
            kout += 1
    return kout


@njit(cache=True)
def unit_columns(first, ptr, L, D, dofs, cols, rows):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """cols[rows[q]] = A^-1 e_{dofs[q]} for the factor (first, ptr, L, D) of A: columns of the inverse."""
    n = D.shape[0]
    for q in range(dofs.shape[0]):
        x = cols[rows[q]]
        for i in range(n):
            x[i] = 0.0
        x[dofs[q]] = 1.0
        solve_envelope(first, ptr, L, D, x)


@njit(cache=True)
def free_response(indptr, indices, Ka, Mb, first, ptr, L, Dinv, u, v, z, x):  # type: ignore[no-untyped-def]  # pragma: no cover
    """x = K_eff^-1 (-2 K u + (4/dt) M v + z): the step increment with no new load (f_{n+1} = 0).

    ``z`` holds the loads f_n scattered on the DOFs on entry and is zero on
    exit (the fused right-hand side / forward substitution of
    :func:`run_steps`).
    """
    n = u.shape[0]
    for i in range(n):
        acc = z[i]
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            acc += Ka[p] * u[j] + Mb[p] * v[j]
        fi = first[i]
        pi = ptr[i] - fi
        for k in range(fi, i):
            acc -= L[pi + k] * z[k]
        z[i] = acc
        x[i] = acc * Dinv[i]
    for i in range(n - 1, -1, -1):
        xi = x[i]
        z[i] = 0.0
        fi = first[i]
        pi = ptr[i] - fi
        for k in range(fi, i):
            x[k] -= L[pi + k] * xi


def warm_up() -> None:
    """Compile (or load from the cache) every kernel on a tiny system."""
    hermite_weights(np.array([[0.3, np.nan]]), 0.0, 1.0, 2, np.array([0, 2, 4], dtype=np.int64),
                    np.array([1, 3, 5], dtype=np.int64))
    first = np.array([0, 0], dtype=np.int64)
    ptr = np.array([0, 0, 1], dtype=np.int64)
    L = np.array([0.5])
    D = np.array([2.0, 2.0])
    ldlt_envelope(first, ptr, L, D)
    x = np.ones(2)
    solve_envelope(first, ptr, L, D, x)
    indptr = np.array([0, 1, 2], dtype=np.int64)
    indices = np.array([0, 1], dtype=np.int64)
    Ka = np.array([-1.0, -1.0])
    Mb = np.array([1.0, 1.0])
    u = np.zeros(2)
    v = np.zeros(2)
    rhs = np.zeros(2)
    pd = np.zeros(4, dtype=np.int64)
    pv = np.zeros(4)
    free_rhs(indptr, indices, Ka, Mb, u, v, pd, pv, rhs)
    ld = np.zeros((1, 4), dtype=np.int64)
    lw = np.zeros((1, 4))
    F = np.zeros((1, 1))
    sd = np.array([0], dtype=np.int64)
    ad = np.array([-1], dtype=np.int64)
    kb = np.ones(1)
    o = np.zeros((1, 1))
    run_steps(indptr, indices, Ka, Mb, first, ptr, L, 1.0 / D, 1.0, u, v, np.zeros(2), rhs, pd, pv, ld, lw, F,
              sd, ad, sd, kb, kb, o.copy(), o.copy(), 1, 0, o.copy(), o.copy(), o.copy(), o.copy(),
              np.zeros(1), np.zeros(1))
    unit_columns(first, ptr, L, D, np.array([1], dtype=np.int64), np.zeros((1, 2)), np.zeros(1, dtype=np.int64))
    free_response(indptr, indices, Ka, Mb, first, ptr, L, 1.0 / D, u, v, np.zeros(2), rhs)


@njit(cache=True)
def hermite_weights(
    P: np.ndarray, x0: float, Le: float, n_el: int, rail_w: np.ndarray, rail_th: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """DOFs and cubic Hermite weights (S, 4 W) of wheels at positions P (S, W) on a rail
    whose node 0 is at x0 with elements of length Le (NaN position: weight 0, DOF 0)."""
    S, W = P.shape
    dofs = np.zeros((S, 4 * W), dtype=np.int64)
    w = np.zeros((S, 4 * W))
    for s in range(S):
        for j in range(W):
            p = P[s, j]
            if not np.isfinite(p):
                continue
            xr = (p - x0) / Le
            e = int(math.floor(xr))
            e = min(max(e, 0), n_el - 1)
            xi = min(max(xr - e, 0.0), 1.0)
            xi2 = xi * xi
            xi3 = xi2 * xi
            k = 4 * j
            dofs[s, k] = rail_w[e]
            dofs[s, k + 1] = rail_th[e]
            dofs[s, k + 2] = rail_w[e + 1]
            dofs[s, k + 3] = rail_th[e + 1]
            w[s, k] = 1.0 - 3.0 * xi2 + 2.0 * xi3
            w[s, k + 1] = Le * (xi - 2.0 * xi2 + xi3)
            w[s, k + 2] = 3.0 * xi2 - 2.0 * xi3
            w[s, k + 3] = Le * (-xi2 + xi3)
    return dofs, w
