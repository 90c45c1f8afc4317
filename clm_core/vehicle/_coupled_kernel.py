"""Compiled coupled vehicle–track steps (the fast path of :class:`clm_core.vehicle.coupled.CoupledSimulation`).

:func:`coupled_steps` runs many steps of the monolithic coupled scheme in one
call, for a stretch of steps with the track window in one position (the
Python side shifts the window between calls, :meth:`clm_core.solver.TrackSimulator.coupled_chunk`).
Per step it does what ``TrackSimulator.begin_step``,
``VehicleNewmark.step_with_contact`` and ``TrackSimulator.finish_step`` do
from Python, with the same arithmetic up to rounding:

1. track free response: x0 = K_eff^-1 (-2 K u + (4/dt) M v + f_n), the step
   increment with zero wheel forces at t + dt (one fused right-hand side,
   forward and back substitution, :func:`clm_core.solver._kernels.free_response`);
   rail deflection under the wheels w_free = N (u + x0);
2. wheel compliance G = N K_eff^-1 N^T from the columns K_eff^-1 e_d of the
   rail DOFs d the wheels load. These depend on the window's operator only,
   not on the step, so they are computed once per operator and DOF
   (:meth:`clm_core.solver.operators.Operator.columns`): on a uniform track the wheels revisit
   the same window DOFs after every shift and no solve is left per step;
3. vehicle Newmark predictor, Newton solution of the Hertz contact and
   vehicle update: the compiled
   :func:`clm_core.vehicle.contact.fused_vehicle_contact_step` itself
   (loops and its own small elimination, no LAPACK call; numba's on-disk
   cache of this module does not see a change of that function: this
   file must change with it, as this sentence did);
4. track update du = x0 + sum_j P_j K_eff^-1 n_j (16 axpys for 4 wheels),
   u += du, v = (2/dt) du - v; running peaks of the soil force and rail
   deflection; outputs.

N holds the Hermite weights of each wheel on its rail element (4 DOFs).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from clm_core.solver import free_response
from clm_core.vehicle.contact import fused_vehicle_contact_step


@njit(cache=True)
def coupled_steps(  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    # track operator, state, wheel weights and columns (the fields of TrackSimulator.coupled_chunk's CoupledTrack)
    op, state, ldofs, lw, cols, slot,
    # vehicle (VehicleNewmark) and contact
    Kinv, KinvB, H, Mv, Cv, Kv, grav, wdof, vu, vv, va, u_ref, dt,
    R, ch, delta, tol, maxit,
    # outputs, one row per step
    load, comp, zw, wr, energy, iters,
    # track snapshots
    n_start, snap_every, snap_force, snap_rail, snap_step, pk_snap,
):
    """Advance ``ldofs.shape[0]`` coupled steps in place.

    Parameters (all arrays contiguous)
    ----------------------------------
    op, state, ldofs, lw, cols, slot : the fields of the
        :class:`clm_core.solver._kernels.CoupledTrack` returned by
        ``TrackSimulator.coupled_chunk``: the window's operator
        (:class:`~clm_core.solver._kernels.StepOperator`), the track state
        (:class:`~clm_core.solver._kernels.StepState`, updated in place; its
        work array ``y`` holds the free response), the wheels' element DOFs
        and Hermite weights (S, 4 W) and the columns ``cols[slot[d]] = K_eff^-1 e_d``.
    Kinv, KinvB, H : the vehicle's K_hat^-1, K_hat^-1 B and B^T K_hat^-1 B.
    Mv, Cv, Kv, grav, wdof : vehicle mass, damping, stiffness matrices, gravity
        force and wheel DOFs.
    vu, vv, va : vehicle displacement, velocity, acceleration (updated).
    u_ref : static state of the vehicle (energy reference).
    dt : time step [s].
    R : (S, W) irregularity under the wheels at each step [m].
    ch : (W,) Hertz constants; delta : (W,) compressions at the start, updated.
    tol, maxit : Newton tolerance [m] and iteration limit.
    load, comp, zw, wr : (S, W) wheel loads, compressions, wheel displacements,
        rail deflection under the wheels; energy (S,), iters (S,) int.
    n_start : global step number of row 0; a step n with n % snap_every == 0
        writes a snapshot row (soil force, rail deflection above the sleepers),
        its step number in snap_step and the running soil-force peaks in pk_snap.

    Returns
    -------
    (steps done, snapshots written, status, residual): status 0, or 1 when
    the Newton iteration of step ``steps done`` did not converge (residual
    [m]; that step is not completed on the track, the vehicle state has been
    advanced).
    """
    a1, s_dof, a_dof, r_dof, kb, db = op.a1, op.s_dof, op.a_dof, op.r_dof, op.kb, op.db
    u, v, z, x0 = state.u, state.v, state.z, state.y
    prev_dofs, prev_vals, pk_force, pk_rail = state.prev_dofs, state.prev_vals, state.pk_force, state.pk_rail
    n = u.shape[0]
    S = ldofs.shape[0]
    W = ldofs.shape[1] // 4
    N = s_dof.shape[0]
    nv = vu.shape[0]
    w_free = np.empty(W)
    G = np.empty((W, W))
    coef = np.empty(4 * W)
    rows = np.empty(4 * W, dtype=np.int64)
    dv = np.empty(nv)
    nsnap = 0
    for s in range(S):
        # loads f_n into z (zero on entry)
        if s == 0:
            for q in range(prev_dofs.shape[0]):
                z[prev_dofs[q]] += prev_vals[q]
        else:
            for w in range(W):
                fw = load[s - 1, w]
                for c in range(4):
                    z[ldofs[s - 1, 4 * w + c]] += lw[s - 1, 4 * w + c] * fw
        free_response(op, u, v, z, x0)
        # free deflection and compliance under the wheels
        for q in range(4 * W):
            rows[q] = slot[ldofs[s, q]]
        for i in range(W):
            sw = 0.0
            for c in range(4):
                d = ldofs[s, 4 * i + c]
                sw += lw[s, 4 * i + c] * (u[d] + x0[d])
            w_free[i] = sw
            for j in range(W):
                g = 0.0
                for c in range(4):
                    d = ldofs[s, 4 * i + c]
                    h = lw[s, 4 * i + c]
                    for cc in range(4):
                        g += h * lw[s, 4 * j + cc] * cols[rows[4 * j + cc], d]
                G[i, j] = g
        # vehicle and contact
        d_new, P, it, rn = fused_vehicle_contact_step(
            Kinv, KinvB, H, Mv, Cv, grav, wdof, vu, vv, va, dt, w_free, G, R[s], ch, delta, tol, maxit
        )
        ok = rn <= tol
        for i in range(W):
            if not np.isfinite(P[i]):
                ok = False
        if not ok:
            return s, nsnap, 1, rn
        # track update with the contact forces
        for q in range(4 * W):
            coef[q] = lw[s, q] * P[q // 4]
        for q in range(4 * W):
            cq = coef[q]
            col = cols[rows[q]]
            for k in range(n):
                x0[k] += cq * col[k]
        for k in range(n):
            du = x0[k]
            u[k] += du
            v[k] = a1 * du - v[k]
        # outputs
        iters[s] = it
        for i in range(W):
            delta[i] = d_new[i]
            load[s, i] = P[i]
            comp[s, i] = d_new[i]
            zw[s, i] = vu[wdof[i]]
            acc = w_free[i]
            for j in range(W):
                acc += G[i, j] * P[j]
            wr[s, i] = acc
        for k in range(nv):
            dv[k] = vu[k] - u_ref[k]
        ek = 0.0
        ep = 0.0
        for k in range(nv):
            mk = 0.0
            kk = 0.0
            for m in range(nv):
                mk += vv[m] * Mv[m, k]
                kk += dv[m] * Kv[m, k]
            ek += mk * vv[k]
            ep += kk * dv[k]
        energy[s] = 0.5 * (ek + ep)
        record = (n_start + s) % snap_every == 0
        for i in range(N):
            sd = s_dof[i]
            ad = a_dof[i]
            if ad >= 0:
                fs = kb[i] * (u[sd] - u[ad]) + db[i] * (v[sd] - v[ad])
            else:
                fs = kb[i] * u[sd] + db[i] * v[sd]
            rw = u[r_dof[i]]
            if fs > pk_force[i]:
                pk_force[i] = fs
            if rw > pk_rail[i]:
                pk_rail[i] = rw
            if record:
                snap_force[nsnap, i] = fs
                snap_rail[nsnap, i] = rw
        if record:
            for i in range(N):
                pk_snap[i] = pk_force[i]
            snap_step[nsnap] = n_start + s
            nsnap += 1
    return S, nsnap, 0, 0.0
