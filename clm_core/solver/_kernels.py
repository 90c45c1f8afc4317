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
  increment form (see :mod:`clm_core.solver`)::

      K_eff du = f_{n+1} + f_n - 2 K u_n + (4/dt) M v_n,
      u_{n+1} = u_n + du,   v_{n+1} = (2/dt) du - v_n,

  with K_eff = K + (2/dt) C + (4/dt^2) M; the right-hand side is one sparse
  (CSR) pass over the union pattern of K and M.

The inputs of :func:`run_steps` travel in one typed structure,
:class:`StepArgs`, made of named tuples of arrays (numba types them as
named tuples; attribute access compiles to a field load): the operator of
the window (:class:`StepOperator`, built once per operator), the state
(:class:`StepState`, arrays updated in place), the loads of the steps
(:class:`StepLoads`) and the output buffers (:class:`StepOutputs`). All
arrays are C-contiguous, float64 or int64.

The kernels are compiled with ``cache=True`` (the first call in a fresh
environment compiles, later processes load the cache).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from clm_core.arrays import Array, IntArray


class StepOperator(NamedTuple):
    """Position-independent operator of one window configuration (n DOFs, N sleepers).

    Attributes
    ----------
    indptr, indices : (n + 1,), (nnz,) int arrays
        CSR pattern of the union of the patterns of K and M.
    Ka, Mb : (nnz,) arrays
        -2 K [N/m] and (4/dt) M [kg/s] on that pattern.
    first, ptr, L, D : int, int, float, float arrays
        Envelope LDL^T factor of K_eff = K + (2/dt) C + (4/dt^2) M
        (:func:`ldlt_envelope`); D the pivots [N/m].
    Dinv : (n,) array
        1 / D [m/N].
    a1 : float
        2 / dt [1/s].
    s_dof, a_dof, r_dof : (N,) int arrays
        Sleeper, contact-area (-1: rigid soil) and rail-above-sleeper DOFs.
    kb, db : (N,) arrays
        Ballast stiffness [N/m] and damping [N s/m] under each sleeper.
    """

    indptr: IntArray
    indices: IntArray
    Ka: Array
    Mb: Array
    first: IntArray
    ptr: IntArray
    L: Array
    D: Array
    Dinv: Array
    a1: float
    s_dof: IntArray
    a_dof: IntArray
    r_dof: IntArray
    kb: Array
    db: Array


class StepState(NamedTuple):
    """State of the window and work arrays, updated in place (n DOFs, N sleepers).

    Attributes
    ----------
    u, v : (n,) arrays
        Displacement [m] and velocity [m/s].
    z, y : (n,) arrays
        Work arrays; ``z`` is zero on entry and on exit of every kernel.
    prev_dofs, prev_vals : (q,) int array, (q,) array
        The load vector f_n at the start, as (DOF, value [N]) pairs.
    pk_force, pk_rail : (N,) arrays
        Running maxima of the soil force [N] and of the rail deflection above
        the sleepers [m], updated every step.
    """

    u: Array
    v: Array
    z: Array
    y: Array
    prev_dofs: IntArray
    prev_vals: Array
    pk_force: Array
    pk_rail: Array


class StepLoads(NamedTuple):
    """Wheel loads of S consecutive steps (W wheels).

    Attributes
    ----------
    ldofs : (S, 4 W) int array
        DOFs of each wheel's rail element at every step (0 for an absent wheel).
    lw : (S, 4 W) array
        Hermite weights (0 for an absent wheel).
    F : (S, W) array
        Wheel forces [N] at t_{n+1} of each step (0 for an absent wheel).
    """

    ldofs: IntArray
    lw: Array
    F: Array


class StepOutputs(NamedTuple):
    """Output buffers of S steps (W wheels, N sleepers, K output steps).

    Attributes
    ----------
    wdefl, wvel : (S, W) arrays
        Rail deflection [m] and velocity [m/s] under each wheel, every step.
    steps : (K,) int array
        Increasing step indices (0 .. S - 1) at which the sleeper fields are
        recorded (empty: none).
    force, rail, sleeper, area : (K, N) arrays
        Soil force [N], rail deflection above the sleeper, sleeper and
        contact-area displacement [m] at the output steps.
    """

    wdefl: Array
    wvel: Array
    steps: IntArray
    force: Array
    rail: Array
    sleeper: Array
    area: Array


class StepArgs(NamedTuple):
    """Everything :func:`run_steps` reads and writes, in one typed structure."""

    op: StepOperator
    state: StepState
    loads: StepLoads
    out: StepOutputs


class CoupledTrack(NamedTuple):
    """Track inputs of the compiled coupled steps for m steps (W wheels, n DOFs).

    Returned by :meth:`clm_core.solver.TrackSimulator.coupled_chunk`; its
    fields are the leading arguments of
    :func:`clm_core.vehicle._coupled_kernel.coupled_steps`.

    Attributes
    ----------
    op : StepOperator
        The window's operator.
    state : StepState
        The track state (updated in place; ``y`` is the work array of the
        free response).
    ldofs, lw : (m, 4 W) int array, (m, 4 W) array
        DOFs and Hermite weights of the wheels at every step.
    cols, slot : (capacity, n) array, (n,) int array
        Columns ``cols[slot[d]] = K_eff^-1 e_d`` [m/N] of every DOF in ``ldofs``.
    """

    op: StepOperator
    state: StepState
    ldofs: IntArray
    lw: Array
    cols: Array
    slot: IntArray


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


@njit(cache=True, inline="always")
def _rhs_forward(op, u, v, z, y):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Fused right-hand side and forward substitution of a step, in place (inlined into its callers).

    Row by row: ``z[i] <- z[i] - 2 (K u)_i + (4/dt) (M v)_i - sum_k L_ik z[k]``
    (``z`` holds the loads on entry, ``L`` the unit lower factor of K_eff),
    then ``y[i] = z[i] / D_i``: after it only the back substitution of ``y``
    is left (``op`` a :class:`StepOperator`).
    """
    indptr, indices, Ka, Mb = op.indptr, op.indices, op.Ka, op.Mb
    first, ptr, L, Dinv = op.first, op.ptr, op.L, op.Dinv
    for i in range(u.shape[0]):
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


@njit(cache=True, inline="always")
def _back_update(op, u, v, z, y):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Fused back substitution (column sweep of ``y``) and Newmark state update, in place; ``z`` left zero.

    ``u += du``, ``v = (2/dt) du - v`` with ``du = L^-T y`` (``op`` a :class:`StepOperator`).
    """
    first, ptr, L, a1 = op.first, op.ptr, op.L, op.a1
    for i in range(u.shape[0] - 1, -1, -1):
        du = y[i]
        z[i] = 0.0
        u[i] += du
        v[i] = a1 * du - v[i]
        fi = first[i]
        pi = ptr[i] - fi
        for k in range(fi, i):
            y[k] -= L[pi + k] * du


@njit(cache=True, inline="always")
def _under_wheel(dofs, wts, k, u, v):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Rail deflection [m] and velocity [m/s] under the wheel whose 4 DOFs and weights start at ``k``."""
    sw = 0.0
    sv = 0.0
    for c in range(4):
        dof = dofs[k + c]
        wt = wts[k + c]
        sw += wt * u[dof]
        sv += wt * v[dof]
    return sw, sv


@njit(cache=True, inline="always")
def _sleeper_step(op, u, v, pk_force, pk_rail, force, rail, sleeper, area, row):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Update the running peaks of soil force and rail deflection; record the sleeper fields in ``row`` (>= 0)."""
    s_dof, a_dof, r_dof, kb, db = op.s_dof, op.a_dof, op.r_dof, op.kb, op.db
    for i in range(s_dof.shape[0]):
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
        if row >= 0:
            force[row, i] = fs
            rail[row, i] = rw
            sleeper[row, i] = u[sd]
            area[row, i] = xa


@njit(cache=True)
def run_steps(a):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Advance ``a.loads.F.shape[0]`` steps in place; return the number of output rows written.

    Parameters
    ----------
    a : StepArgs
        Operator, state (updated), loads and output buffers (filled); see
        :class:`StepOperator`, :class:`StepState`, :class:`StepLoads`,
        :class:`StepOutputs`.
    """
    op, st, ld, out = a.op, a.state, a.loads, a.out
    u, v, z, y = st.u, st.v, st.z, st.y
    pk_force, pk_rail = st.pk_force, st.pk_rail
    ldofs, lw, F = ld.ldofs, ld.lw, ld.F
    out_steps = out.steps
    S = F.shape[0]
    W = F.shape[1]
    n_out = out_steps.shape[0]
    kout = 0
    for s in range(S):
        # loads f_n + f_{n+1} scattered into z (zero on entry)
        if s == 0:
            for q in range(st.prev_dofs.shape[0]):
                z[st.prev_dofs[q]] += st.prev_vals[q]
        else:
            for w in range(W):
                fw = F[s - 1, w]
                for c in range(4):
                    z[ldofs[s - 1, 4 * w + c]] += lw[s - 1, 4 * w + c] * fw
        for w in range(W):
            fw = F[s, w]
            for c in range(4):
                z[ldofs[s, 4 * w + c]] += lw[s, 4 * w + c] * fw
        _rhs_forward(op, u, v, z, y)
        _back_update(op, u, v, z, y)
        # wheel outputs
        for w in range(W):
            out.wdefl[s, w], out.wvel[s, w] = _under_wheel(ldofs[s], lw[s], 4 * w, u, v)
        # sleeper peaks every step, fields at output steps
        record = kout < n_out and out_steps[kout] == s
        _sleeper_step(op, u, v, pk_force, pk_rail, out.force, out.rail, out.sleeper, out.area, kout if record else -1)
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
def free_response(op, u, v, z, x):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """x = K_eff^-1 (-2 K u + (4/dt) M v + z): the step increment with no new load (f_{n+1} = 0).

    ``op`` is the window's :class:`StepOperator`; ``z`` holds the loads f_n
    scattered on the DOFs on entry and is zero on exit (the fused right-hand
    side / forward substitution of :func:`run_steps`).
    """
    first, ptr, L = op.first, op.ptr, op.L
    n = u.shape[0]
    _rhs_forward(op, u, v, z, x)
    for i in range(n - 1, -1, -1):
        xi = x[i]
        z[i] = 0.0
        fi = first[i]
        pi = ptr[i] - fi
        for k in range(fi, i):
            x[k] -= L[pi + k] * xi


def warm_up() -> None:
    """Compile (or load from the cache) every kernel on a tiny system."""
    i64 = np.int64
    hermite_weights(np.array([[0.3, np.nan]]), 0.0, 1.0, 2, np.array([0, 2, 4], dtype=i64),
                    np.array([1, 3, 5], dtype=i64))
    first = np.array([0, 0], dtype=i64)
    ptr = np.array([0, 0, 1], dtype=i64)
    L = np.array([0.5])
    D = np.array([2.0, 2.0])
    ldlt_envelope(first, ptr, L, D)
    x = np.ones(2)
    solve_envelope(first, ptr, L, D, x)
    indptr = np.array([0, 1, 2], dtype=i64)
    indices = np.array([0, 1], dtype=i64)
    Ka = np.array([-1.0, -1.0])
    Mb = np.array([1.0, 1.0])
    u = np.zeros(2)
    v = np.zeros(2)
    rhs = np.zeros(2)
    pd = np.zeros(4, dtype=i64)
    pv = np.zeros(4)
    free_rhs(indptr, indices, Ka, Mb, u, v, pd, pv, rhs)
    sd = np.array([0], dtype=i64)
    ad = np.array([-1], dtype=i64)
    kb = np.ones(1)
    op = StepOperator(indptr, indices, Ka, Mb, first, ptr, L, D, 1.0 / D, 1.0, sd, ad, sd, kb, kb.copy())
    state = StepState(u, v, np.zeros(2), rhs, pd, pv, np.zeros(1), np.zeros(1))
    loads = StepLoads(np.zeros((1, 4), dtype=i64), np.zeros((1, 4)), np.zeros((1, 1)))
    o = np.zeros((1, 1))
    out = StepOutputs(o.copy(), o.copy(), np.zeros(1, dtype=i64), o.copy(), o.copy(), o.copy(), o.copy())
    run_steps(StepArgs(op, state, loads, out))
    unit_columns(first, ptr, L, D, np.array([1], dtype=i64), np.zeros((1, 2)), np.zeros(1, dtype=i64))
    free_response(op, u, v, np.zeros(2), rhs)


@njit(cache=True, inline="always")
def hermite_wheel(p, x0, Le, n_el, rail_w, rail_th, dofs, w, k):  # type: ignore[no-untyped-def]  # pragma: no cover
    """DOFs and cubic Hermite weights of one wheel at position ``p`` [m] into ``dofs[k:k+4]``, ``w[k:k+4]``.

    The rail's node 0 is at ``x0`` [m], its ``n_el`` elements of length
    ``Le`` [m]; a position beyond the rail is clamped to its end element.
    """
    xr = (p - x0) / Le
    e = int(math.floor(xr))
    e = min(max(e, 0), n_el - 1)
    xi = min(max(xr - e, 0.0), 1.0)
    xi2 = xi * xi
    xi3 = xi2 * xi
    dofs[k] = rail_w[e]
    dofs[k + 1] = rail_th[e]
    dofs[k + 2] = rail_w[e + 1]
    dofs[k + 3] = rail_th[e + 1]
    w[k] = 1.0 - 3.0 * xi2 + 2.0 * xi3
    w[k + 1] = Le * (xi - 2.0 * xi2 + xi3)
    w[k + 2] = 3.0 * xi2 - 2.0 * xi3
    w[k + 3] = Le * (-xi2 + xi3)


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
            if np.isfinite(p):
                hermite_wheel(p, x0, Le, n_el, rail_w, rail_th, dofs[s], w[s], 4 * j)
    return dofs, w
