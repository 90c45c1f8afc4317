"""A fixed-window reference track engine with the TrackSimulator coupling API.

:class:`FixedTrack` implements the interface the coupled vehicle–track
simulation needs from :class:`clm_core.solver.TrackSimulator`
(``initialize``, ``begin_step``, ``finish_step``, ``step``, ``snapshot``)
the straightforward way: one long track assembled once
(:func:`clm_core.track.assemble`), average-acceleration Newmark with a
sparse LU factorisation of K + (2/dt) C + (4/dt^2) M (the scheme of
:class:`clm_core.newmark.NewmarkLinear`), the wheel loads distributed with
the Hermite shape functions of :meth:`TrackSystem.point_load`. It does not
move with the train: the track must be long enough for the whole run.

It is slower than the streaming engine and exists to validate it: the same
coupled run on both engines must agree (tests/vehicle/test_coupled.py), and
its full state gives the total energy of the coupled system.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import ArrayLike, NDArray

from clm_core.arrays import Array
from clm_core.errors import InputError, ParameterError
from clm_core.params import ModelParams
from clm_core.track import TrackSystem, assemble


@dataclass(frozen=True)
class FixedSnapshot:
    """Responses of :class:`FixedTrack` at one instant (same fields as the streaming engine's)."""

    t: float
    sleeper_index: NDArray[np.int64]
    sleeper_x: Array
    soil_force: Array
    rail_deflection: Array
    sleeper_displacement: Array
    area_displacement: Array
    wheel_deflection: Array
    wheel_velocity: Array
    wheel_positions: Array


class FixedTrack:
    """Reference (non-moving) track engine with the coupling API of the streaming TrackSimulator.

    Parameters
    ----------
    params : ModelParams
        Track and soil.
    dt : float
        Time step [s].
    x_from, x_to : float
        The track must cover these positions [m] with at least ``margin``
        sleepers beyond each end.
    elements_per_bay : int
        Rail elements per sleeper bay.
    margin : int
        Sleepers beyond the range (10 by default: the paper's Sec. 5 rule).
    """

    def __init__(
        self,
        params: ModelParams,
        dt: float,
        x_from: float,
        x_to: float,
        elements_per_bay: int = 2,
        margin: int = 10,
    ) -> None:
        if not dt > 0:
            raise ParameterError(f"dt = {dt}: time step must be > 0 s")
        d = params.track.spacing
        first = int(np.floor(x_from / d)) - margin
        last = int(np.ceil(x_to / d)) + margin
        self.system: TrackSystem = assemble(params, last - first + 1, elements_per_bay, first_sleeper=first)
        s = self.system
        self.dt = float(dt)
        self.t = 0.0
        a0, a1 = 4.0 / dt**2, 2.0 / dt
        self._M = sp.csc_matrix(s.M)
        self._C = sp.csc_matrix(s.C)
        self._K = sp.csc_matrix(s.K)
        self._lu = spla.splu(sp.csc_matrix(self._K + a1 * self._C + a0 * self._M))
        n = s.n_dof
        self.u = np.zeros(n)
        self.v = np.zeros(n)
        self.a = np.zeros(n)
        self._pos = np.zeros(0)
        self._B: Array | None = None
        self._X = np.zeros((n, 0))
        self._u_free = np.zeros(n)
        self._pk_force = np.full(s.n_sleepers, -np.inf)

    # ---------------------------------------------------------------- helpers
    def _load_matrix(self, positions: Array) -> Array:
        """Dense (n_dof, n_w) consistent-load matrix (Hermite weights of each wheel's element)."""
        s = self.system
        xs = s.node_x
        if np.any(positions < xs[0]) or np.any(positions > xs[-1]):
            raise InputError(
                f"wheel positions [{positions.min():g}, {positions.max():g}] m: outside the reference "
                f"track [{xs[0]:g}, {xs[-1]:g}] m"
            )
        e = np.clip(np.searchsorted(xs, positions, side="right") - 1, 0, len(xs) - 2)
        L = xs[e + 1] - xs[e]
        xi = (positions - xs[e]) / L
        N = np.stack([1 - 3 * xi**2 + 2 * xi**3, L * (xi - 2 * xi**2 + xi**3),
                      3 * xi**2 - 2 * xi**3, L * (-(xi**2) + xi**3)], axis=1)
        dofs = np.stack([s.rail_w[e], s.rail_th[e], s.rail_w[e + 1], s.rail_th[e + 1]], axis=1)
        B = np.zeros((s.n_dof, len(positions)))
        for j in range(len(positions)):
            ok = dofs[j] >= 0
            B[dofs[j][ok], j] += N[j][ok]
        return B

    @staticmethod
    def _check(positions: ArrayLike, forces: ArrayLike | None = None) -> tuple[Array, Array | None]:
        x = np.asarray(positions, dtype=float).ravel()
        if not np.all(np.isfinite(x)):
            raise InputError("wheel positions: non-finite value")
        if forces is None:
            return x, None
        f = np.asarray(forces, dtype=float).ravel()
        if f.shape != x.shape:
            raise InputError(f"wheel forces: shape {f.shape} does not match positions {x.shape}")
        if not np.all(np.isfinite(f)):
            raise InputError("wheel forces: non-finite value")
        return x, f

    # ---------------------------------------------------------------- API
    def initialize(
        self, positions: ArrayLike, forces: ArrayLike, t0: float = 0.0,
        state: Literal["static", "rest"] = "static",
    ) -> None:
        """Start at time t0 [s]: static equilibrium under the wheel forces [N], or at rest (zero)."""
        x, f = self._check(positions, forces)
        assert f is not None
        B = self._load_matrix(x)
        self.t = float(t0)
        n = self.system.n_dof
        self.v = np.zeros(n)
        if state == "static":
            self.u = spla.spsolve(self._K, B @ f)
            self.a = np.zeros(n)
        elif state == "rest":
            self.u = np.zeros(n)
            self.a = np.zeros(n)  # massless DOFs aside, the load is applied from the next step
        else:
            raise ParameterError(f"state = {state!r}: one of 'static', 'rest'")
        self._pos, self._B = x, B
        self._pk_force = self.system.ballast_force(self.u, self.v)

    def begin_step(self, positions_next: ArrayLike) -> tuple[Array, Array, Array]:
        """Free rail deflection [m], velocity [m/s] under the wheels at t + dt and the compliance G [m/N]."""
        x, _ = self._check(positions_next)
        dt = self.dt
        B = self._load_matrix(x)
        rhs = self._M @ ((4.0 / dt**2) * self.u + (4.0 / dt) * self.v + self.a) + self._C @ (
            (2.0 / dt) * self.u + self.v
        )
        self._u_free = self._lu.solve(rhs)
        self._X = self._lu.solve(B)
        self._B = B
        self._pos = x
        Bt = B.T
        w_free = Bt @ self._u_free
        v_free = Bt @ ((2.0 / dt) * (self._u_free - self.u) - self.v)
        G = np.asarray(Bt @ self._X)
        return np.asarray(w_free), np.asarray(v_free), G

    def finish_step(self, forces_next: ArrayLike) -> None:
        """Advance to t + dt with the wheel forces [N] at t + dt."""
        P = np.asarray(forces_next, dtype=float).ravel()
        if P.shape != self._pos.shape or not np.all(np.isfinite(P)):
            raise InputError("finish_step: forces must be finite, one per wheel")
        dt = self.dt
        u_new = self._u_free + self._X @ P
        v_new = (2.0 / dt) * (u_new - self.u) - self.v
        a_new = (4.0 / dt**2) * (u_new - self.u) - (4.0 / dt) * self.v - self.a
        self.u, self.v, self.a = u_new, v_new, a_new
        self.t += dt
        np.maximum(self._pk_force, self.system.ballast_force(self.u, self.v), out=self._pk_force)

    def step(self, positions: ArrayLike, forces: ArrayLike) -> None:
        """One step with prescribed wheel forces [N] at positions [m] (time t + dt)."""
        self.begin_step(positions)
        self.finish_step(forces)

    def peaks(self) -> tuple[NDArray[np.int64], Array, Array]:
        """Running maxima since :meth:`initialize`: (sleeper index, soil force [N], rail deflection [m])."""
        s = self.system
        return s.sleeper_index.copy(), self._pk_force.copy(), np.full(s.n_sleepers, np.nan)

    def snapshot(self) -> FixedSnapshot:
        """Responses at the current time."""
        s = self.system
        B = self._B
        assert B is not None
        area = s.area_dof
        return FixedSnapshot(
            t=self.t,
            sleeper_index=s.sleeper_index.copy(),
            sleeper_x=s.sleeper_x.copy(),
            soil_force=s.ballast_force(self.u, self.v),
            rail_deflection=s.rail_above_sleepers(self.u),
            sleeper_displacement=self.u[s.sleeper_dof],
            area_displacement=np.where(area >= 0, self.u[np.maximum(area, 0)], 0.0),
            wheel_deflection=np.asarray(B.T @ self.u),
            wheel_velocity=np.asarray(B.T @ self.v),
            wheel_positions=self._pos.copy(),
        )

    def energy(self) -> float:
        """Kinetic plus elastic energy of the track [J] (about the unloaded state)."""
        return float(0.5 * self.v @ (self._M @ self.v) + 0.5 * self.u @ (self._K @ self.u))
