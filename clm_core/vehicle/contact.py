"""Nonlinear Hertzian wheel–rail contact and its per-step Newton solution.

Contact law (Hertz; Johnson 1985, "Contact Mechanics", Ch. 4):

    P = C_H * max(delta, 0)^(3/2)

with P the wheel load on the rail [N] (positive downwards on the rail) and
delta the contact compression [m] (positive = wheel and rail pressed
together). Loss of contact (delta <= 0) gives P = 0: the wheel may leave
the rail; the coupled simulation counts these events.

Compression, with every displacement positive downwards::

    delta = z_wheel - w_rail - r

z_wheel: wheel (axle centre) displacement; w_rail: rail deflection under the
wheel; r: the *rail surface irregularity* measured downwards (a dip of the
rail surface, e.g. a dipped joint, is r > 0 and reduces the compression; a
raised spot is r < 0), plus the wheel out-of-roundness of that wheel (a wheel
flat lowers the axle centre when it is in contact: r_flat > 0).

Per time step the vehicle gives z_wheel = z_free - H P and the track
w_rail = w_free + G P (both affine, both from implicit Newmark steps), so the
compressions solve the small nonlinear system

    R(delta) = delta - d0 + A p(delta) = 0,   A = H + G,   d0 = z_free - w_free - r,

solved here by Newton's method in delta (Jacobian I + A diag(p'(delta)),
non-singular because A is a compliance matrix), with a backtracking line
search. p is C^1 (p'(0) = 0), so the contact/no-contact switch does not
break the quadratic convergence.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.checks import positive
from clm_core.errors import InputError, ParameterError


def hertz_constant(
    wheel_radius: float,
    rail_head_radius: float = 0.30,
    E: float = 210.0e9,
    nu: float = 0.3,
    method: str = "hertz",
) -> float:
    """Hertz contact constant C_H [N/m^1.5] of a wheel on a rail.

    Parameters
    ----------
    wheel_radius : float
        Wheel rolling radius R_w [m] (curvature along the rail).
    rail_head_radius : float
        Transverse radius of the rail head crown R_r [m] (0.30 m for UIC60;
        curvature across the rail). Used by ``method='hertz'``.
    E, nu : float
        Young's modulus [Pa] and Poisson's ratio of wheel and rail steel.
    method : {'hertz', 'zhai'}
        ``'hertz'``: circular-contact equivalent of the elliptical Hertz
        contact of two crossed cylinders, C_H = (4/3) E* sqrt(R_e) with
        1/E* = 2 (1 - nu^2) / E and R_e = sqrt(R_w R_r) (Johnson 1985,
        Sec. 4.2, Eq. 4.33 with the equivalent radius of Eq. 4.36; the
        ellipticity correction is within a few per cent for R_w/R_r < 2).
        ``'zhai'``: the empirical constant for a worn (LM) tread of Zhai
        (Zhai, Wang & Cai 2009, Vehicle Syst. Dyn. 47(11), Eq. for the
        contact constant G = 3.86 R^-0.115 x 1e-8 m/N^(2/3)),
        C_H = G^(-3/2).

    Returns
    -------
    float
        C_H [N/m^1.5]; about 0.9e11 for R_w = 0.46 m on a UIC60 rail.
    """
    Rw = positive("wheel_radius", wheel_radius, unit="m")
    if method == "hertz":
        Rr = positive("rail_head_radius", rail_head_radius, unit="m")
        Ee = positive("E", E, unit="Pa")
        if not (-1.0 < nu < 0.5):
            raise ParameterError(f"nu = {nu}: Poisson's ratio must lie in (-1, 0.5)")
        Estar = Ee / (2.0 * (1.0 - nu**2))
        return float(4.0 / 3.0 * Estar * math.sqrt(math.sqrt(Rw * Rr)))
    if method == "zhai":
        G = 3.86e-8 * Rw ** (-0.115)
        return float(G ** (-1.5))
    raise ParameterError(f"method = {method!r}: one of 'hertz', 'zhai'")


def hertz_force(delta: Array, ch: Array | float) -> Array:
    """P = C_H max(delta, 0)^1.5 [N] for compressions ``delta`` [m]."""
    d = np.maximum(np.asarray(delta, dtype=float), 0.0)
    return np.asarray(ch * d * np.sqrt(d), dtype=float)


def static_compression(P: Array, ch: Array | float) -> Array:
    """Compression [m] under a static load P [N]: (P / C_H)^(2/3)."""
    P = np.asarray(P, dtype=float)
    if np.any(P < 0):
        raise InputError("static_compression: loads must be >= 0 N")
    return np.asarray((P / ch) ** (2.0 / 3.0), dtype=float)


@njit(cache=True)
def contact_work_size(n_dof: int, n_w: int) -> int:  # pragma: no cover - compiled
    """Length of the work array of :func:`vehicle_contact_step_into` (vehicle DOFs, wheels)."""
    return 4 * n_dof + 2 * n_w * n_w + 7 * n_w


@njit(cache=True)
def _residual(d: Array, d0: Array, A: Array, p: Array, out: Array) -> float:  # pragma: no cover - compiled
    """out = d - d0 + A p; return max |out| (NaN if any entry is NaN)."""
    n = d.shape[0]
    rn = 0.0
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += A[i, j] * p[j]
        out[i] = d[i] - d0[i] + s
        r = abs(out[i])
        if r > rn or r != r:
            rn = r
    for i in range(n):
        if out[i] != out[i]:
            return np.nan
    return rn


@njit(cache=True)
def _solve_in_place(J: Array, b: Array) -> None:  # pragma: no cover - compiled
    """b <- J^-1 b by Gaussian elimination with partial pivoting (J is overwritten)."""
    n = b.shape[0]
    for k in range(n):
        piv = k
        big = abs(J[k, k])
        for i in range(k + 1, n):
            if abs(J[i, k]) > big:
                piv, big = i, abs(J[i, k])
        if piv != k:
            for j in range(n):
                J[k, j], J[piv, j] = J[piv, j], J[k, j]
            b[k], b[piv] = b[piv], b[k]
        for i in range(k + 1, n):
            f = J[i, k] / J[k, k]
            for j in range(k + 1, n):
                J[i, j] -= f * J[k, j]
            b[i] -= f * b[k]
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, n):
            s -= J[k, j] * b[j]
        b[k] = s / J[k, k]


@njit(cache=True)
def _newton_into(
    d0: Array, A: Array, ch: Array, delta: Array, tol: float, maxit: int, d: Array, p: Array, work: Array
) -> tuple[int, float]:  # pragma: no cover - compiled
    """Newton's method with backtracking on R(d) = d - d0 + A p(d); solution into d, forces into p.

    ``work``: at least n^2 + 4 n values. ``d`` may be ``delta``. Returns
    (iterations, residual max-norm [m]); a non-finite residual means failure.
    """
    n = d0.shape[0]
    J = work[: n * n].reshape((n, n))
    R = work[n * n : n * n + n]
    step = work[n * n + n : n * n + 2 * n]
    trial = work[n * n + 2 * n : n * n + 3 * n]
    pt = work[n * n + 3 * n : n * n + 4 * n]
    for i in range(n):
        d[i] = delta[i]
        dp = max(d[i], 0.0)
        p[i] = ch[i] * dp * np.sqrt(dp)
    rn = _residual(d, d0, A, p, R)
    it = 0
    while rn > tol and it < maxit:
        it += 1
        for i in range(n):
            for j in range(n):
                J[i, j] = (1.0 if i == j else 0.0) + A[i, j] * (1.5 * ch[j] * np.sqrt(max(d[j], 0.0)))
            step[i] = -R[i]
        _solve_in_place(J, step)
        lam = 1.0
        rt = rn
        for _ in range(40):
            for i in range(n):
                trial[i] = d[i] + lam * step[i]
                tp = max(trial[i], 0.0)
                pt[i] = ch[i] * tp * np.sqrt(tp)
            rt = _residual(trial, d0, A, pt, R)  # R is free once the step is known: the last trial is taken
            if rt < rn or lam < 1e-10:
                break
            lam *= 0.5
        for i in range(n):
            d[i] = trial[i]
            p[i] = pt[i]
        rn = rt
    return it, rn


@njit(cache=True)
def _newton(
    d0: Array, A: Array, ch: Array, delta: Array, tol: float, maxit: int
) -> tuple[Array, Array, int, float]:  # pragma: no cover - compiled
    n = d0.shape[0]
    d = np.empty(n)
    p = np.empty(n)
    it, rn = _newton_into(d0, A, ch, delta, tol, maxit, d, p, np.empty(n * n + 4 * n))
    return d, p, it, rn


@njit(cache=True)
def vehicle_contact_step_into(
    Kinv: Array, KinvB: Array, H: Array, M: Array, C: Array, grav: Array, wdof: NDArray[np.int64],
    u: Array, v: Array, a: Array, dt: float, w_free: Array, G: Array, r: Array, ch: Array, delta: Array,
    tol: float, maxit: int, d: Array, P: Array, work: Array,
) -> tuple[int, float]:  # pragma: no cover - compiled
    """One vehicle step with the contact, without allocation: Newmark prediction, Newton, update.

    The vehicle's trapezoidal Newmark step (constant average acceleration)
    predicts the free displacement u_free = K_hat^-1 (f_g + M (a0 u + 4/dt v
    + a) + C (2/dt u + v)), a0 = 4/dt^2; the wheels' compressions with zero
    contact forces are d0 = u_free[wheels] - w_free - r; Newton's method
    solves d = d0 - (H + G) p(d) for the compressions d [m] and forces P [N]
    (the Hertz law p = C_H max(d, 0)^1.5); then u = u_free - K_hat^-1 B P,
    and v, a by the Newmark update (in place on u, v, a).

    Parameters
    ----------
    Kinv, KinvB, H : arrays
        K_hat^-1, K_hat^-1 B, B^T K_hat^-1 B of the vehicle.
    M, C, grav, wdof : arrays
        Vehicle mass and damping matrices, gravity force [N], wheel DOFs.
    u, v, a : (n_dof,) arrays
        Vehicle state (updated in place).
    dt : float
        Time step [s].
    w_free, G : arrays
        The track's free rail deflection under the wheels [m] and compliance [m/N] over the step.
    r, ch, delta : (n_w,) arrays
        Irregularity [m], Hertz constants [N/m^1.5], start compressions [m].
    tol, maxit : float, int
        Newton tolerance [m] and iteration limit.
    d, P : (n_w,) arrays
        Outputs: compressions [m] and contact forces [N] (``d`` may be ``delta``).
    work : array
        At least :func:`contact_work_size` (n_dof, n_w) values.

    Returns
    -------
    (iterations, residual [m])
    """
    n = u.shape[0]
    m = w_free.shape[0]
    y1 = work[:n]
    y2 = work[n : 2 * n]
    rhs = work[2 * n : 3 * n]
    uf = work[3 * n : 4 * n]
    o = 4 * n
    A = work[o : o + m * m].reshape((m, m))
    d0 = work[o + m * m : o + m * m + m]
    nw = work[o + m * m + m :]
    a0 = 4.0 / dt**2
    c1 = 4.0 / dt
    c2 = 2.0 / dt
    for i in range(n):
        y1[i] = a0 * u[i] + c1 * v[i] + a[i]
        y2[i] = c2 * u[i] + v[i]
    for i in range(n):
        s1 = 0.0
        s2 = 0.0
        for k in range(n):
            s1 += M[i, k] * y1[k]
            s2 += C[i, k] * y2[k]
        rhs[i] = grav[i] + s1 + s2
    for i in range(n):
        s = 0.0
        for k in range(n):
            s += Kinv[i, k] * rhs[k]
        uf[i] = s
    for i in range(m):
        d0[i] = uf[wdof[i]] - w_free[i] - r[i]
        for j in range(m):
            A[i, j] = H[i, j] + G[i, j]
    it, rn = _newton_into(d0, A, ch, delta, tol, maxit, d, P, nw)
    for i in range(n):
        s = 0.0
        for j in range(m):
            s += KinvB[i, j] * P[j]
        un = uf[i] - s
        du = un - u[i]
        vn = c2 * du - v[i]
        a[i] = a0 * du - c1 * v[i] - a[i]
        v[i] = vn
        u[i] = un
    return it, rn


@njit(cache=True)
def fused_vehicle_contact_step(
    Kinv: Array, KinvB: Array, H: Array, M: Array, C: Array, grav: Array, wdof: NDArray[np.int64],
    u: Array, v: Array, a: Array, dt: float, w_free: Array, G: Array, r: Array, ch: Array, delta: Array,
    tol: float, maxit: int,
) -> tuple[Array, Array, int, float]:  # pragma: no cover - compiled
    """Vehicle Newmark prediction, contact Newton solution and vehicle update in one call (in place on u, v, a).

    :func:`vehicle_contact_step_into` with new output arrays; returns (d, P, iterations, residual).
    """
    m = w_free.shape[0]
    d = np.empty(m)
    P = np.empty(m)
    work = np.empty(contact_work_size(u.shape[0], m))
    it, rn = vehicle_contact_step_into(Kinv, KinvB, H, M, C, grav, wdof, u, v, a, dt, w_free, G, r, ch, delta,
                                       tol, maxit, d, P, work)
    return d, P, it, rn


def solve_contact(
    d0: Array, A: Array, ch: Array, delta_guess: Array, tol: float = 1e-14, maxit: int = 50
) -> tuple[Array, Array, int]:
    """Solve delta = d0 - A p(delta), p = C_H max(delta, 0)^1.5, by Newton's method.

    Parameters
    ----------
    d0 : (n_w,) array
        Compressions [m] the wheels would have with zero contact forces.
    A : (n_w, n_w) array
        Combined compliance [m/N] of vehicle and track over the step (H + G).
    ch : (n_w,) array
        Hertz constants [N/m^1.5].
    delta_guess : (n_w,) array
        Start value [m] (the previous step's solution).
    tol : float
        Convergence on the max-norm of the residual [m] (1e-14 m is ~1e-10
        of a typical static compression of 1e-4 m).
    maxit : int
        Iteration limit.

    Returns
    -------
    delta : (n_w,) array
        Compressions [m] (negative: no contact).
    P : (n_w,) array
        Contact forces [N].
    iterations : int
        Newton iterations used.

    Raises
    ------
    InputError
        The iteration did not converge (non-finite inputs or an ill-posed A).
    """
    delta, P, it, rn = _newton(
        np.ascontiguousarray(d0, dtype=np.float64), np.ascontiguousarray(A, dtype=np.float64),
        np.ascontiguousarray(ch, dtype=np.float64), np.array(delta_guess, dtype=np.float64), tol, maxit,
    )
    if not (np.all(np.isfinite(P)) and rn <= tol):
        raise InputError(
            f"contact Newton iteration did not converge in {maxit} iterations (residual {rn:.3g} m, "
            f"max |d0| = {np.max(np.abs(d0)):.3g} m); check the inputs for NaN or an excessive time step"
        )
    return delta, P, it
