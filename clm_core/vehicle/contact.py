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

from clm_core.errors import InputError, ParameterError

Array = NDArray[np.float64]


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
    Rw = _pos("wheel_radius", wheel_radius)
    if method == "hertz":
        Rr = _pos("rail_head_radius", rail_head_radius)
        Ee = _pos("E", E)
        if not (-1.0 < nu < 0.5):
            raise ParameterError(f"nu = {nu}: Poisson's ratio must lie in (-1, 0.5)")
        Estar = Ee / (2.0 * (1.0 - nu**2))
        return float(4.0 / 3.0 * Estar * math.sqrt(math.sqrt(Rw * Rr)))
    if method == "zhai":
        G = 3.86e-8 * Rw ** (-0.115)
        return float(G ** (-1.5))
    raise ParameterError(f"method = {method!r}: one of 'hertz', 'zhai'")


def _pos(name: str, v: float) -> float:
    v = float(v)
    if not (math.isfinite(v) and v > 0):
        raise ParameterError(f"{name} = {v}: must be a finite value > 0")
    return v


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
def _newton(
    d0: Array, A: Array, ch: Array, delta: Array, tol: float, maxit: int
) -> tuple[Array, Array, int, float]:  # pragma: no cover - compiled
    n = d0.shape[0]
    I = np.eye(n)
    dp = np.maximum(delta, 0.0)
    p = ch * dp * np.sqrt(dp)
    R = delta - d0 + A @ p
    rn = np.max(np.abs(R))
    it = 0
    while rn > tol and it < maxit:
        it += 1
        dpp = 1.5 * ch * np.sqrt(np.maximum(delta, 0.0))
        J = I + A * dpp[np.newaxis, :]
        step = np.linalg.solve(J, -R)
        lam = 1.0
        for _ in range(40):
            trial = delta + lam * step
            tp = np.maximum(trial, 0.0)
            pt = ch * tp * np.sqrt(tp)
            Rt = trial - d0 + A @ pt
            rt = np.max(np.abs(Rt))
            if rt < rn or lam < 1e-10:
                break
            lam *= 0.5
        delta = trial
        p = pt
        R = Rt
        rn = rt
    return delta, p, it, rn


@njit(cache=True)
def fused_vehicle_contact_step(
    Kinv: Array, KinvB: Array, H: Array, M: Array, C: Array, grav: Array, wdof: NDArray[np.int64],
    u: Array, v: Array, a: Array, dt: float, w_free: Array, G: Array, r: Array, ch: Array, delta: Array,
    tol: float, maxit: int,
) -> tuple[Array, Array, int, float]:  # pragma: no cover - compiled
    """Vehicle Newmark prediction, contact Newton solution and vehicle update in one call (in place on u, v, a)."""
    a0 = 4.0 / dt**2
    rhs = grav + M @ (a0 * u + (4.0 / dt) * v + a) + C @ ((2.0 / dt) * u + v)
    u_free = Kinv @ rhs
    d0 = u_free[wdof] - w_free - r
    A = H + G
    d, P, it, rn = _newton(d0, A, ch, delta, tol, maxit)
    u_new = u_free - KinvB @ P
    du = u_new - u
    v_new = (2.0 / dt) * du - v
    a_new = a0 * du - (4.0 / dt) * v - a
    u[:] = u_new
    v[:] = v_new
    a[:] = a_new
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
