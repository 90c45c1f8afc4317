"""Compiled steps of the streaming vehicle: the per-message path of ``StreamingVehicle``.

One call advances the vehicle by the substeps behind one wheel-load message
(10 steps of 0.1 ms at 1 kHz), with everything a step needs computed inside
the compiled code:

1. wheel positions x_j(t) = x_start + V t - a_j at t = (k + 1 + i) dt (a_j the
   wheel's offset behind the first wheel);
2. the rail irregularity under each wheel, r = ramp(x) r_p(x): the sampled
   profile interpolated linearly (as :meth:`clm_core.vehicle.irregularity.Profile.__call__`),
   ramped in over ``lead_in`` from the wheel's start position by
   0.5 (1 - cos(pi s)), s = clip((x - x_j(0)) / lead_in, 0, 1)
   (:meth:`clm_core.vehicle.irregularity.Irregularity.wheel_irregularity`);
   a run with isolated defects or wheel flats passes r in, evaluated in Python;
3. per step the single-DOF track predictor of each wheel (mass M_t,
   damping C_t, stiffness K_t, :func:`clm_core.vehicle.impact.equivalent_track`)
   with the same trapezoidal Newmark step as the vehicle: its free deflection
   w_free = rhs / S + offset, S = K_t + 2 C_t / dt + 4 M_t / dt^2, and the
   step compliance G = I / S enter the vehicle's Newmark prediction and
   Hertz contact Newton solution
   (:func:`clm_core.vehicle.contact.fused_vehicle_contact_step`, the same
   compiled function as the monolithic coupled run); then the predictor is
   updated with the contact forces, w = (rhs + P) / S.

The arithmetic is that of the Python path (positions and irregularity with
numpy, then :func:`sdof_vehicle_steps`) operation by operation; only
library functions (``cos``, ``interp``) may round differently
(tests/vehicle/test_streaming.py compares the two).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.vehicle.contact import contact_work_size, vehicle_contact_step_into

#: Status of :func:`message_steps`: done.
OK = 0
#: Status of :func:`message_steps`: a wheel runs outside the sampled profile (nothing was advanced).
OUTSIDE_PROFILE = 1


@njit(cache=True)
def work_size(n_dof: int, n_w: int) -> int:  # pragma: no cover - compiled
    """Length of the work array of :func:`sdof_vehicle_steps` and :func:`message_steps`."""
    return contact_work_size(n_dof, n_w) + 2 * n_w


@njit(cache=True)
def sdof_vehicle_steps(
    Kinv: Array, KinvB: Array, H: Array, M: Array, C: Array, grav: Array, wdof: NDArray[np.int64],
    u: Array, v: Array, a: Array, dt: float, R: Array, ch: Array, delta: Array, P: Array,
    Mt: float, Ct: float, S: float, G: Array, w: Array, vw: Array, aw: Array, offset: Array,
    tol: float, maxit: int, work: Array,
) -> tuple[int, float, int]:  # pragma: no cover - compiled
    """``R.shape[0]`` steps of vehicle + Hertz contact + per-wheel SDOF track predictor (state in place).

    Parameters
    ----------
    Kinv, KinvB, H : arrays
        The vehicle's effective-stiffness inverse K_hat^-1, K_hat^-1 B and B^T K_hat^-1 B.
    M, C, grav, wdof : arrays
        Vehicle mass [kg] and damping [N s/m] matrices, gravity force [N], wheel DOFs.
    u, v, a : (n_dof,) arrays
        Vehicle displacement [m], velocity [m/s], acceleration [m/s^2] (updated).
    dt : float
        Time step [s].
    R : (n_steps, n_w) array
        Irregularity under each wheel at each step [m] (positive downwards).
    ch : (n_w,) array
        Hertz constants [N/m^1.5].
    delta, P : (n_w,) arrays
        Contact compressions [m] (the Newton start value; updated) and
        forces [N] (output: those of the last step).
    Mt, Ct, S : float
        Predictor mass [kg], damping [N s/m] and Newmark step stiffness [N/m].
    G : (n_w, n_w) array
        Predictor step compliance [m/N] (I / S).
    w, vw, aw : (n_w,) arrays
        Predictor deflection [m], velocity, acceleration under each wheel (updated).
    offset : (n_w,) array
        Track-minus-predictor correction added to the free deflection [m].
    tol, maxit : float, int
        Newton tolerance [m] and iteration limit.
    work : array
        :func:`work_size` (n_dof, n_w) values (nothing is allocated per step).

    Returns
    -------
    (iterations, residual, lost) : the largest Newton iteration count and
    residual [m] over the steps (infinite when a force is not finite), and
    the wheel-steps without contact.
    """
    n_w = w.shape[0]
    rhs = work[:n_w]
    w_free = work[n_w : 2 * n_w]
    cwork = work[2 * n_w :]
    c4 = 4.0 / dt**2
    c1 = 4.0 / dt
    c2 = 2.0 / dt
    worst = 0.0
    lost = 0
    maxit_used = 0
    for i in range(R.shape[0]):
        for j in range(n_w):
            rhs[j] = Mt * (c4 * w[j] + c1 * vw[j] + aw[j]) + Ct * (c2 * w[j] + vw[j])
            w_free[j] = rhs[j] / S + offset[j]
        it, rn = vehicle_contact_step_into(
            Kinv, KinvB, H, M, C, grav, wdof, u, v, a, dt, w_free, G, R[i], ch, delta, tol, maxit, delta, P, cwork
        )
        if not rn <= worst:  # NaN propagates
            worst = rn
        maxit_used = max(maxit_used, it)
        for j in range(n_w):
            w_new = (rhs[j] + P[j]) / S
            dw = w_new - w[j]
            vw_new = c2 * dw - vw[j]
            aw[j] = c4 * dw - c1 * vw[j] - aw[j]
            vw[j] = vw_new
            w[j] = w_new
            if P[j] <= 0.0:
                lost += 1
    for j in range(n_w):
        if not np.isfinite(P[j]):
            worst = np.inf
    return maxit_used, worst, lost


@njit(cache=True)
def wheel_path(
    k: int, n_steps: int, dt: float, x_start: float, speed: float, wheel_offset: Array,
    px: Array, pr: Array, lead_in: float, x0: Array, X: Array, R: Array,
) -> bool:  # pragma: no cover - compiled
    """Wheel positions X [m] and profile irregularity R [m] at steps k + 1 .. k + n_steps (into X, R).

    ``px`` empty: no profile (R = 0). Returns False (X filled, R not) when a
    wheel runs outside [px[0], px[-1]] (1e-9 m slack, as the Python profile).
    """
    n_w = wheel_offset.shape[0]
    lo = np.inf
    hi = -np.inf
    for i in range(n_steps):
        t = (k + 1 + i) * dt
        for j in range(n_w):
            x = x_start + speed * t - wheel_offset[j]
            X[i, j] = x
            lo = min(lo, x)
            hi = max(hi, x)
    if px.shape[0] == 0:
        R[:n_steps] = 0.0
        return True
    if lo < px[0] - 1e-9 or hi > px[-1] + 1e-9:
        return False
    for i in range(n_steps):
        R[i] = np.interp(X[i], px, pr)
        if lead_in > 0:
            for j in range(n_w):
                s = min(max((X[i, j] - x0[j]) / lead_in, 0.0), 1.0)
                R[i, j] = R[i, j] * 0.5 * (1.0 - math.cos(math.pi * s))
    return True


@njit(cache=True)
def message_steps(
    Kinv: Array, KinvB: Array, H: Array, M: Array, C: Array, grav: Array, wdof: NDArray[np.int64],
    u: Array, v: Array, a: Array, dt: float, ch: Array, delta: Array, P: Array,
    Mt: float, Ct: float, S: float, G: Array, w: Array, vw: Array, aw: Array, offset: Array,
    tol: float, maxit: int, work: Array,
    k: int, x_start: float, speed: float, wheel_offset: Array, px: Array, pr: Array, lead_in: float, x0: Array,
    X: Array, R: Array, given_R: bool,
) -> tuple[int, int, float, int]:  # pragma: no cover - compiled
    """The steps behind one message: wheel path, irregularity, ``X.shape[0]`` predictor + vehicle steps.

    Parameters are those of :func:`sdof_vehicle_steps` and :func:`wheel_path`;
    ``X``, ``R`` (n_steps, n_w) are work arrays (on return X holds the wheel
    positions [m] of every step, the last row those at the new time); with
    ``given_R`` the irregularity in ``R`` is used as passed (defects, flats).

    Returns
    -------
    (status, iterations, residual, lost) : :data:`OK` or
    :data:`OUTSIDE_PROFILE` (then the state is untouched), then as
    :func:`sdof_vehicle_steps`.
    """
    n = X.shape[0]
    if given_R:
        ok = wheel_path(k, n, dt, x_start, speed, wheel_offset, px[:0], pr[:0], lead_in, x0, X, R[:0])
    else:
        ok = wheel_path(k, n, dt, x_start, speed, wheel_offset, px, pr, lead_in, x0, X, R)
    if not ok:
        return OUTSIDE_PROFILE, 0, 0.0, 0
    it, rn, lost = sdof_vehicle_steps(
        Kinv, KinvB, H, M, C, grav, wdof, u, v, a, dt, R, ch, delta, P, Mt, Ct, S, G, w, vw, aw, offset, tol,
        maxit, work,
    )
    return OK, it, rn, lost
