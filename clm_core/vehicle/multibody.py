"""Vertical multibody railway vehicles and trains on one rail line.

Each vehicle is the classic vertical model of the vehicle–track literature
(Zhai, Wang & Cai 2009, "Fundamentals of vehicle–track coupled dynamics",
Vehicle Syst. Dyn. 47(11):1349–1376; Kouroussis, Verlinden & Conti 2011,
ref. [18] of the CLM paper): a car body (bounce z_c, pitch phi_c) on two
bogies (bounce z_b, pitch phi_b) through the secondary suspension, each bogie
on two wheelsets (bounce z_w) through the primary suspension. Trains are
sequences of vehicles; articulated trainsets (TGV/Thalys Jacobs bogies) share
a bogie between two consecutive car bodies.

One rail line
-------------
The track model of :mod:`clm_core.track` is ONE rail line. The vehicle model
is therefore the half vehicle running on that rail (symmetric vehicle, both
rails loaded alike): masses and pitch inertias are half the full-vehicle
values, the primary suspension is the one of one axle box (one wheel), the
secondary suspension the one of one bogie side. The contact force on the rail
is the *wheel* load, half the axle load. Parameters are given for the full
vehicle (masses, inertias) and per axle box / per bogie side (suspension), as
vehicle data sheets give them; :class:`Train` does the halving.

Conventions
-----------
SI units. Displacements and forces positive downwards. Longitudinal
positions of the train's points are *offsets* measured backwards from the
first wheelset [m] (first wheelset at offset 0). A point of a rigid body at
offset ``s`` moves by ``z + (s - s_cg) phi``: a positive pitch ``phi`` [rad]
lowers the rear of the body.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from clm_core.arrays import Array, IntArray
from clm_core.checks import finite as _finite
from clm_core.checks import nonnegative as _nonnegative
from clm_core.checks import positive as _positive
from clm_core.errors import InputError, ParameterError

#: Standard gravity [m/s^2].
GRAVITY = 9.81


@dataclass(frozen=True)
class VehicleType:
    """One railway vehicle (full-vehicle values), vertical model.

    Parameters
    ----------
    name : str
        Identifier used in train compositions.
    body_mass : float
        Car body mass M_c [kg] (whole vehicle; includes payload).
    body_pitch_inertia : float
        Car body pitch moment of inertia J_c about its centre of gravity [kg m^2].
    bogie_mass : float
        Mass of one bogie frame M_b [kg] (without wheelsets).
    bogie_pitch_inertia : float
        Pitch moment of inertia of one bogie J_b [kg m^2].
    wheelset_mass : float
        Mass of one wheelset M_w [kg] (both wheels and the axle: the unsprung
        mass per axle). The one-rail model uses M_w / 2 per wheel.
    wheel_radius : float
        Nominal rolling radius R [m] (wheel flats, Hertz constant).
    primary_stiffness, primary_damping : float
        Primary suspension of ONE axle box (one wheel), k_1 [N/m], c_1 [N s/m].
    secondary_stiffness, secondary_damping : float
        Secondary suspension of ONE bogie side, k_2 [N/m], c_2 [N s/m].
    bogie_spacing : float
        Distance between the two bogie centres, 2 l_c [m].
    axle_spacing : float
        Bogie wheelbase, 2 l_t [m].
    length : float
        Distance from this vehicle's front end to the next vehicle's front end
        [m] (length over couplers; for articulated cars the pivot-to-end length).
    front_overhang : float or None
        Distance from the vehicle's front end to its front bogie centre [m];
        ``None``: symmetric, ``(length - bogie_spacing) / 2``.
    cg_offset : float
        Position of the car body centre of gravity behind the midpoint of the
        bogie centres [m] (0 for a symmetric body).
    hertz_constant : float or None
        Hertz contact constant C_H [N/m^1.5]; ``None``: computed from the
        wheel radius (:func:`clm_core.vehicle.contact.hertz_constant`).
    source : str
        Where the values come from.
    """

    name: str
    body_mass: float
    body_pitch_inertia: float
    bogie_mass: float
    bogie_pitch_inertia: float
    wheelset_mass: float
    wheel_radius: float
    primary_stiffness: float
    primary_damping: float
    secondary_stiffness: float
    secondary_damping: float
    bogie_spacing: float
    axle_spacing: float
    length: float
    front_overhang: float | None = None
    cg_offset: float = 0.0
    hertz_constant: float | None = None
    source: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ParameterError(f"vehicle.name = {self.name!r}: must be a non-empty string")
        p = f"vehicle {self.name!r}"
        for n in (
            "body_mass",
            "body_pitch_inertia",
            "bogie_mass",
            "bogie_pitch_inertia",
            "wheelset_mass",
            "wheel_radius",
            "primary_stiffness",
            "secondary_stiffness",
            "bogie_spacing",
            "axle_spacing",
            "length",
        ):
            object.__setattr__(self, n, _positive(f"{p}: {n}", getattr(self, n)))
        for n in ("primary_damping", "secondary_damping"):
            object.__setattr__(self, n, _nonnegative(f"{p}: {n}", getattr(self, n)))
        object.__setattr__(self, "cg_offset", _finite(f"{p}: cg_offset", self.cg_offset))
        if self.front_overhang is None:
            object.__setattr__(self, "front_overhang", 0.5 * (self.length - self.bogie_spacing))
        fo = _finite(f"{p}: front_overhang", self.front_overhang)
        object.__setattr__(self, "front_overhang", fo)
        if self.hertz_constant is not None:
            object.__setattr__(self, "hertz_constant", _positive(f"{p}: hertz_constant", self.hertz_constant))
        if self.axle_spacing >= self.bogie_spacing:
            raise ParameterError(
                f"{p}: axle_spacing = {self.axle_spacing:g} m: must be smaller than bogie_spacing = "
                f"{self.bogie_spacing:g} m (the bogies would overlap)"
            )
        if abs(self.cg_offset) >= 0.5 * self.bogie_spacing:
            raise ParameterError(
                f"{p}: cg_offset = {self.cg_offset:g} m: the centre of gravity must lie between the bogie "
                f"centres (|cg_offset| < {0.5 * self.bogie_spacing:g} m), otherwise a bogie is lifted"
            )
        if fo < 0.0 or fo + self.bogie_spacing > self.length + 1e-9:
            raise ParameterError(
                f"{p}: front_overhang = {fo:g} m: the bogie centres must lie within the vehicle length "
                f"(0 <= front_overhang <= length - bogie_spacing = {self.length - self.bogie_spacing:g} m)"
            )

    @property
    def rear_overhang(self) -> float:
        """Distance from the rear bogie centre to the vehicle's rear end [m]."""
        assert self.front_overhang is not None
        return self.length - self.bogie_spacing - self.front_overhang

    def reversed(self) -> VehicleType:
        """The same vehicle running the other way round (overhangs and CG offset mirrored)."""
        return replace(self, front_overhang=self.rear_overhang, cg_offset=-self.cg_offset)

    @property
    def total_mass(self) -> float:
        """Mass of the vehicle with its own two bogies and four wheelsets [kg]."""
        return self.body_mass + 2 * self.bogie_mass + 4 * self.wheelset_mass

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping in the preset-file layout."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass(frozen=True)
class CarSpec:
    """One vehicle of a train composition.

    Parameters
    ----------
    vehicle : VehicleType
        The vehicle.
    shares_front_bogie : bool
        Articulated coupling: the vehicle's front end rests on the rear bogie
        of the previous vehicle (Jacobs bogie) instead of a bogie of its own.
    reversed : bool
        The vehicle runs rear end first (e.g. the trailing power car).
    """

    vehicle: VehicleType
    shares_front_bogie: bool = False
    reversed: bool = False


@dataclass(frozen=True)
class Train:
    """An assembled train on one rail line: DOFs, matrices and geometry.

    Attributes
    ----------
    cars : tuple of CarSpec
        The composition, front to rear.
    M, C, K : (n, n) arrays
        Mass [kg], damping [N s/m] and stiffness [N/m] of the half train.
    gravity_force : (n,) array
        Weight on each DOF [N] (zero on pitch DOFs).
    wheel_dof : (n_w,) int array
        DOF index of each wheel, front to rear.
    wheel_offset : (n_w,) array
        Offset of each wheel behind the first one [m].
    wheel_radius : (n_w,) array
        Rolling radius of each wheel [m].
    hertz_constant : (n_w,) array or None entries
        Per-wheel Hertz constant from the vehicle data (NaN: not given).
    wheel_car : (n_w,) int array
        Index of the car whose bogie carries the wheel.
    dof_names : tuple of str
        Human-readable name of each DOF (``car0.body.z``, ``bogie3.phi``, ...).
    body_dofs, bogie_dofs : (n_bodies, 2), (n_bogies, 2) int arrays
        (bounce, pitch) DOFs.
    """

    cars: tuple[CarSpec, ...]
    M: Array
    C: Array
    K: Array
    gravity_force: Array
    wheel_dof: IntArray
    wheel_offset: Array
    wheel_radius: Array
    hertz_constant: Array
    wheel_car: IntArray
    dof_names: tuple[str, ...]
    body_dofs: IntArray
    bogie_dofs: IntArray
    bogie_offset: Array = field(default_factory=lambda: np.zeros(0))
    body_cg_offset: Array = field(default_factory=lambda: np.zeros(0))

    @property
    def n_dof(self) -> int:
        """Number of degrees of freedom of the half train."""
        return int(self.M.shape[0])

    @property
    def n_wheels(self) -> int:
        """Number of wheels on the rail (= number of wheelsets)."""
        return len(self.wheel_dof)

    @property
    def wheelbase(self) -> float:
        """Distance from the first to the last wheel [m]."""
        return float(self.wheel_offset[-1] - self.wheel_offset[0])

    @property
    def weight_per_rail(self) -> float:
        """Weight carried by the rail line: half the train weight [N]."""
        return float(self.gravity_force.sum())

    def static_wheel_loads(self) -> Array:
        """Static wheel loads P_0 on the rail [N] (per wheel, half the axle load).

        Equilibrium with the wheels held in place: the reactions of the
        wheel DOFs. The vehicles are statically determinate (each body on two
        bogies, each bogie on two wheelsets), so these loads do not depend on
        the track stiffness.
        """
        w = self.wheel_dof
        free = np.setdiff1d(np.arange(self.n_dof), w)
        Kff = self.K[np.ix_(free, free)]
        uf = np.linalg.solve(Kff, self.gravity_force[free])
        return np.asarray(self.gravity_force[w] - self.K[np.ix_(w, free)] @ uf, dtype=float)

    def static_state(self, wheel_displacement: Array) -> Array:
        """Static displacements [m] of all DOFs with the wheels at ``wheel_displacement``."""
        wd = np.asarray(wheel_displacement, dtype=float)
        if wd.shape != (self.n_wheels,):
            raise InputError(f"wheel_displacement: shape {wd.shape}, expected ({self.n_wheels},)")
        w = self.wheel_dof
        free = np.setdiff1d(np.arange(self.n_dof), w)
        u = np.zeros(self.n_dof)
        u[w] = wd
        rhs = self.gravity_force[free] - self.K[np.ix_(free, w)] @ wd
        u[free] = np.linalg.solve(self.K[np.ix_(free, free)], rhs)
        return u

    def natural_frequencies(self, clamped_wheels: bool = True) -> Array:
        """Undamped natural frequencies [Hz] of the half train (wheels held fixed by default)."""
        import scipy.linalg as sla

        keep = np.setdiff1d(np.arange(self.n_dof), self.wheel_dof) if clamped_wheels else np.arange(self.n_dof)
        ev = sla.eigh(self.K[np.ix_(keep, keep)], self.M[np.ix_(keep, keep)], eigvals_only=True)
        return np.asarray(np.sqrt(np.maximum(ev, 0.0)) / (2 * np.pi), dtype=float)

    def energy(self, u: Array, v: Array, u_ref: Array) -> float:
        """Kinetic plus elastic energy relative to the state ``u_ref`` [J].

        E = 1/2 v^T M v + 1/2 (u - u_ref)^T K (u - u_ref): the mechanical
        energy of the vibration about a static state (gravity balanced there).
        """
        du = u - u_ref
        return float(0.5 * v @ self.M @ v + 0.5 * du @ self.K @ du)


def build_train(cars: Sequence[CarSpec | VehicleType]) -> Train:
    """Assemble the half-train model (one rail line) of a composition.

    Parameters
    ----------
    cars : sequence of CarSpec or VehicleType
        Front to rear. A bare :class:`VehicleType` is a non-articulated car.

    Returns
    -------
    Train

    Raises
    ------
    ParameterError
        Empty composition, or an articulated first car.
    """
    specs = tuple(c if isinstance(c, CarSpec) else CarSpec(c) for c in cars)
    if not specs:
        raise ParameterError("train composition = []: at least one vehicle needed")
    if specs[0].shares_front_bogie:
        raise ParameterError(
            f"train composition: car 0 ({specs[0].vehicle.name!r}) has shares_front_bogie = true, "
            "but there is no previous car to share a bogie with"
        )

    # ---- geometry: bodies and bogies in offsets from the train front end
    body_cg: list[float] = []
    body_mass: list[float] = []
    body_inertia: list[float] = []
    body_support: list[tuple[int, int, float, float]] = []  # (bogie front, bogie rear, k2, c2)
    bogie_x: list[float] = []
    bogie_owner: list[VehicleType] = []
    front = 0.0
    for spec in specs:
        veh = spec.vehicle.reversed() if spec.reversed else spec.vehicle
        assert veh.front_overhang is not None
        if spec.shares_front_bogie:
            ib_front = len(bogie_x) - 1  # the previous car's rear bogie
            front = bogie_x[ib_front] - veh.front_overhang
        else:
            bogie_x.append(front + veh.front_overhang)
            bogie_owner.append(veh)
            ib_front = len(bogie_x) - 1
        bogie_x.append(bogie_x[ib_front] + veh.bogie_spacing)
        bogie_owner.append(veh)
        ib_rear = len(bogie_x) - 1
        mid = 0.5 * (bogie_x[ib_front] + bogie_x[ib_rear])
        body_cg.append(mid + veh.cg_offset)
        body_mass.append(veh.body_mass)
        body_inertia.append(veh.body_pitch_inertia)
        body_support.append((ib_front, ib_rear, veh.secondary_stiffness, veh.secondary_damping))
        front = front + veh.length

    n_bodies, n_bogies = len(body_cg), len(bogie_x)
    n_wheels = 2 * n_bogies
    n = 2 * n_bodies + 2 * n_bogies + n_wheels
    body_dofs = np.arange(2 * n_bodies, dtype=np.int64).reshape(n_bodies, 2)
    bogie_dofs = (2 * n_bodies + np.arange(2 * n_bogies, dtype=np.int64)).reshape(n_bogies, 2)
    wheel_dof = 2 * n_bodies + 2 * n_bogies + np.arange(n_wheels, dtype=np.int64)

    wheel_x = np.empty(n_wheels)
    wheel_r = np.empty(n_wheels)
    wheel_ch = np.full(n_wheels, np.nan)
    wheel_car = np.empty(n_wheels, dtype=np.int64)
    # car owning each bogie: the car that created it (a shared bogie belongs to the earlier car)
    owner_car: list[int] = []
    for ci, spec in enumerate(specs):
        owner_car.extend([ci] * (1 if spec.shares_front_bogie else 2))

    M = np.zeros((n, n))
    K = np.zeros((n, n))
    C = np.zeros((n, n))
    grav = np.zeros(n)
    names: list[str] = [""] * n

    def link(dofs: Sequence[int], coef: Sequence[float], k: float, c: float) -> None:
        """Spring-dashpot whose elongation is sum(coef * u[dofs])."""
        L = np.zeros(n)
        for d, a in zip(dofs, coef):
            L[d] += a
        K[:, :] += k * np.outer(L, L)
        C[:, :] += c * np.outer(L, L)

    for i in range(n_bodies):
        zc, pc = body_dofs[i]
        M[zc, zc] = 0.5 * body_mass[i]
        M[pc, pc] = 0.5 * body_inertia[i]
        grav[zc] = 0.5 * body_mass[i] * GRAVITY
        names[zc], names[pc] = f"car{i}.body.z", f"car{i}.body.phi"
        bf, br, k2, c2 = body_support[i]
        for bj in (bf, br):
            zb = bogie_dofs[bj, 0]
            arm = bogie_x[bj] - body_cg[i]
            link([zc, pc, zb], [1.0, arm, -1.0], k2, c2)

    for j in range(n_bogies):
        veh = bogie_owner[j]
        zb, pb = bogie_dofs[j]
        M[zb, zb] = 0.5 * veh.bogie_mass
        M[pb, pb] = 0.5 * veh.bogie_pitch_inertia
        grav[zb] = 0.5 * veh.bogie_mass * GRAVITY
        names[zb], names[pb] = f"bogie{j}.z", f"bogie{j}.phi"
        for a, sgn in enumerate((-0.5, 0.5)):
            iw = 2 * j + a
            arm = sgn * veh.axle_spacing
            wd = wheel_dof[iw]
            wheel_x[iw] = bogie_x[j] + arm
            wheel_r[iw] = veh.wheel_radius
            if veh.hertz_constant is not None:
                wheel_ch[iw] = veh.hertz_constant
            wheel_car[iw] = owner_car[j]
            M[wd, wd] = 0.5 * veh.wheelset_mass
            grav[wd] = 0.5 * veh.wheelset_mass * GRAVITY
            names[wd] = f"wheel{iw}.z"
            link([zb, pb, wd], [1.0, arm, -1.0], veh.primary_stiffness, veh.primary_damping)

    x0 = wheel_x[0]
    return Train(
        cars=specs,
        M=M,
        C=C,
        K=K,
        gravity_force=grav,
        wheel_dof=wheel_dof,
        wheel_offset=wheel_x - x0,
        wheel_radius=wheel_r,
        hertz_constant=wheel_ch,
        wheel_car=wheel_car,
        dof_names=tuple(names),
        body_dofs=body_dofs,
        bogie_dofs=bogie_dofs,
        bogie_offset=np.asarray(bogie_x) - x0,
        body_cg_offset=np.asarray(body_cg) - x0,
    )


class VehicleNewmark:
    """Average-acceleration Newmark integrator of the half train, affine in the wheel forces.

    The equations of motion are M a + C v + K u = F_g - B P, where P (n_w,)
    are the contact forces on the rail [N] (positive downwards on the rail,
    hence upwards on the wheels) and B selects the wheel DOFs. One step
    (gamma = 1/2, beta = 1/4, the scheme of :mod:`clm_core.newmark`) gives

        u_{n+1} = u_free - K_hat^{-1} B P,   z_wheel = z_free - H P,

    with K_hat = K + (2/dt) C + (4/dt^2) M and H = B^T K_hat^{-1} B [m/N]
    constant: :meth:`predict` returns ``z_free`` and :meth:`commit` applies
    the forces found by the contact solution.

    Parameters
    ----------
    train : Train
        The assembled half train.
    dt : float
        Time step [s].
    """

    def __init__(self, train: Train, dt: float) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ParameterError(f"dt = {dt}: time step must be a finite value > 0 s")
        self.train = train
        self.dt = float(dt)
        a0, a1 = 4.0 / dt**2, 2.0 / dt
        Khat = train.K + a1 * train.C + a0 * train.M
        self._Kinv: Array = np.ascontiguousarray(np.linalg.inv(Khat), dtype=np.float64)
        w = train.wheel_dof
        self._KinvB = np.ascontiguousarray(self._Kinv[:, w])
        #: Wheel compliance of the vehicle over one step, H = B^T K_hat^{-1} B [m/N].
        self.H = np.ascontiguousarray(self._KinvB[w, :])
        n = train.n_dof
        self.u = np.zeros(n)
        self.v = np.zeros(n)
        self.a = np.zeros(n)
        self._u_free = np.zeros(n)

    def set_state(self, u: Array, v: Array | None = None, P: Array | None = None) -> None:
        """Set displacement [m], velocity [m/s]; acceleration from equilibrium with wheel forces P [N]."""
        tr = self.train
        self.u = np.array(u, dtype=float)
        self.v = np.zeros(tr.n_dof) if v is None else np.array(v, dtype=float)
        f = tr.gravity_force.copy()
        if P is not None:
            f[tr.wheel_dof] -= P
        r = f - tr.C @ self.v - tr.K @ self.u
        self.a = r / np.diag(tr.M)

    def predict(self) -> Array:
        """Wheel displacements [m] at t + dt if the contact forces at t + dt were zero."""
        tr, dt = self.train, self.dt
        a0 = 4.0 / dt**2
        rhs = (
            tr.gravity_force
            + tr.M @ (a0 * self.u + (4.0 / dt) * self.v + self.a)
            + tr.C @ ((2.0 / dt) * self.u + self.v)
        )
        self._u_free = self._Kinv @ rhs
        return np.asarray(self._u_free[tr.wheel_dof])

    def commit(self, P: Array) -> None:
        """Advance to t + dt with the contact forces ``P`` [N] at t + dt."""
        dt = self.dt
        u_new = self._u_free - self._KinvB @ P
        v_new = (2.0 / dt) * (u_new - self.u) - self.v
        a_new = (4.0 / dt**2) * (u_new - self.u) - (4.0 / dt) * self.v - self.a
        self.u, self.v, self.a = u_new, v_new, a_new

    def step_with_contact(
        self, w_free: Array, G: Array, r: Array, ch: Array, delta: Array, tol: float = 1e-14, maxit: int = 50
    ) -> tuple[Array, Array, int]:
        """One coupled step in a single compiled call: :meth:`predict`, Newton on the contact, :meth:`commit`.

        Parameters
        ----------
        w_free, G : arrays
            The track's free rail deflection [m] under the wheels and compliance
            [m/N] at t + dt (``TrackSimulator.begin_step``).
        r : (n_w,) array
            Irregularity under each wheel at t + dt [m] (positive downwards).
        ch : (n_w,) array
            Hertz constants [N/m^1.5].
        delta : (n_w,) array
            Start value of the compressions [m] (the previous step's).
        tol : float
            Convergence tolerance of the Newton iteration on the contact [m].
        maxit : int
            Most Newton iterations.

        Returns
        -------
        delta, P, iterations
            Compressions [m], contact forces [N], Newton iterations. The
            vehicle state is advanced to t + dt.

        Raises
        ------
        InputError
            The Newton iteration did not converge.
        """
        from clm_core.vehicle.contact import fused_vehicle_contact_step

        tr = self.train
        d, P, it, rn = fused_vehicle_contact_step(
            self._Kinv,
            self._KinvB,
            self.H,
            tr.M,
            tr.C,
            tr.gravity_force,
            tr.wheel_dof,
            self.u,
            self.v,
            self.a,
            self.dt,
            np.ascontiguousarray(w_free),
            np.ascontiguousarray(G),
            np.ascontiguousarray(r),
            ch,
            np.ascontiguousarray(delta),
            tol,
            maxit,
        )
        if not (rn <= tol and np.all(np.isfinite(P))):
            raise InputError(
                f"contact Newton iteration did not converge in {maxit} iterations (residual {rn:.3g} m); "
                "check the inputs for NaN or an excessive time step"
            )
        return d, P, it
