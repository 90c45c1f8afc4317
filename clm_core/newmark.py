"""Reference linear Newmark integration with a sparse LU factorisation.

This is the straightforward implementation: average-acceleration Newmark
(gamma = 1/2, beta = 1/4), unconditionally stable for M, K positive definite
and C positive semi-definite, factorised once. It serves the paper's route to
receptances (pulse response + FFT) and is the reference the streaming
engine is benchmarked and tested against.

A mode of frequency f is integrated at f' = tan(pi f dt) / (pi dt) (period
elongation of the average-acceleration scheme).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from clm_core.arrays import Array
from clm_core.checks import integer, positive
from clm_core.errors import ParameterError


class NewmarkLinear:
    """Average-acceleration Newmark integrator for M a + C v + K u = f(t).

    Parameters
    ----------
    M, C, K : sparse matrices, shape (n, n)
        Mass [kg], damping [N s/m] and stiffness [N/m] matrices. M may be
        singular on massless DOFs (Winkler areas): the scheme stays defined
        because K + 2/dt C + 4/dt^2 M is non-singular.
    dt : float
        Time step [s].

    Raises
    ------
    ParameterError
        ``dt`` not finite and > 0, M, C, K not square of one size, or
        K + 2/dt C + 4/dt^2 M singular.
    """

    def __init__(self, M: sp.spmatrix, C: sp.spmatrix, K: sp.spmatrix, dt: float) -> None:
        dt = positive("dt", dt, unit="s")
        self.M, self.C, self.K = (sp.csc_matrix(x) for x in (M, C, K))
        n = self.K.shape[0]
        shapes = [x.shape for x in (self.M, self.C, self.K)]
        if any(shape != (n, n) for shape in shapes):
            raise ParameterError(f"M, C, K: shapes {shapes}: must be square of one size")
        self.dt = dt
        a0, a1 = 4.0 / dt**2, 2.0 / dt
        try:
            self._lu = spla.splu(sp.csc_matrix(self.K + a1 * self.C + a0 * self.M))
        except RuntimeError:
            raise ParameterError(
                f"M, C, K with dt = {dt:g} s: K + 2/dt C + 4/dt^2 M is singular (a DOF without mass, damping "
                "and stiffness, or non-finite entries)"
            ) from None
        self.u = np.zeros(n)
        self.v = np.zeros(n)
        self.a = np.zeros(n)

    def step(self, f_next: Array) -> None:
        """Advance one step to the force ``f_next`` [N] at t + dt (in place)."""
        dt = self.dt
        a0, a1 = 4.0 / dt**2, 2.0 / dt
        rhs = f_next + self.M @ (a0 * self.u + (4.0 / dt) * self.v + self.a) + self.C @ (a1 * self.u + self.v)
        u_new = self._lu.solve(rhs)
        v_new = a1 * (u_new - self.u) - self.v
        a_new = a0 * (u_new - self.u) - (4.0 / dt) * self.v - self.a
        self.u, self.v, self.a = u_new, v_new, a_new

    def run(self, force: Callable[[float], Array] | Array, n_steps: int) -> tuple[Array, Array, Array]:
        """Integrate from rest; return time [s], displacement and velocity histories.

        Parameters
        ----------
        force : callable t -> (n,) array, or array (n_steps + 1, n)
            Load vector [N].
        n_steps : int
            Number of steps.

        Returns
        -------
        t : (n_steps + 1,) array
        u, v : (n_steps + 1, n) arrays [m], [m/s]

        Raises
        ------
        ParameterError
            ``n_steps`` not an integer >= 0, or a ``force`` array not of
            shape (n_steps + 1, n).
        """
        n = self.K.shape[0]
        n_steps = integer("n_steps", n_steps, 0)
        if isinstance(force, np.ndarray) and force.shape != (n_steps + 1, n):
            raise ParameterError(f"force: shape {force.shape}: must be (n_steps + 1, n) = ({n_steps + 1}, {n})")
        t: Array = np.arange(n_steps + 1, dtype=np.float64) * self.dt
        F = force if isinstance(force, np.ndarray) else None

        def get(k: int) -> Array:
            if F is not None:
                return np.asarray(F[k], dtype=np.float64)
            return np.asarray(force(float(t[k])), dtype=np.float64)  # type: ignore[operator]

        u = np.empty((n_steps + 1, n))
        v = np.empty((n_steps + 1, n))
        self.u[:] = 0.0
        self.v[:] = 0.0
        f0 = np.asarray(get(0), dtype=float)
        # consistent initial acceleration on DOFs with mass; zero on massless ones
        self.a = _initial_acceleration(self.M, f0)
        u[0], v[0] = self.u, self.v
        for k in range(1, n_steps + 1):
            self.step(np.asarray(get(k), dtype=float))
            u[k], v[k] = self.u, self.v
        return t, u, v


def _initial_acceleration(M: sp.csc_matrix, f0: Array) -> Array:
    d = M.diagonal()
    massive = d > 0
    a = np.zeros_like(f0)
    if massive.any() and np.any(f0[massive] != 0.0):
        Mm = M[massive][:, massive]
        a[massive] = spla.spsolve(sp.csc_matrix(Mm), f0[massive])
    return a
