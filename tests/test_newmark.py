"""Bad input to the Newmark integrator (clm_core.newmark): a ParameterError naming the value and the rule."""

from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.sparse as sp

from clm_core.errors import ParameterError
from clm_core.newmark import NewmarkLinear

M, C, K = sp.identity(3), 0.1 * sp.identity(3), 10.0 * sp.identity(3)


@pytest.mark.parametrize(
    ("dt", "fragment"),
    [(0.0, "dt = 0 s: must be > 0"), (float("nan"), "dt = nan: must be finite"),
     (float("inf"), "dt = inf: must be finite"), ("x", "dt = 'x': must be a real number"),
     (None, "dt = None: must be a real number")],
)
def test_time_step_refused(dt: object, fragment: str) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        NewmarkLinear(M, C, K, dt)  # type: ignore[arg-type]


def test_matrices_of_different_sizes_refused() -> None:
    with pytest.raises(ParameterError, match=re.escape("must be square of one size")):
        NewmarkLinear(M, C, sp.identity(4), 0.01)


@pytest.mark.parametrize(
    ("force", "n_steps", "fragment"),
    [(np.zeros((5, 3)), -1, "n_steps = -1: must be an integer >= 0"),
     (np.zeros((5, 3)), 1.5, "n_steps = 1.5: must be an integer >= 0"),
     (np.zeros((2, 3)), 4, "force: shape (2, 3): must be (n_steps + 1, n) = (5, 3)"),
     (np.zeros((5, 2)), 4, "force: shape (5, 2): must be (n_steps + 1, n) = (5, 3)")],
)
def test_run_refuses_bad_steps_and_forces(force: np.ndarray, n_steps: int, fragment: str) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        NewmarkLinear(M, C, K, 0.01).run(force, n_steps)


@pytest.mark.parametrize("scale", [0.0, np.nan])
def test_singular_or_nonfinite_matrices_refused(scale: float) -> None:
    with pytest.raises(ParameterError, match=re.escape("K + 2/dt C + 4/dt^2 M is singular")):
        NewmarkLinear(M * scale, C * scale, K * scale, 0.01)
