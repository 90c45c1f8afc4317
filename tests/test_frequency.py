"""Bad input to the receptance routes (clm_core.frequency): a ParameterError naming the value and the rule."""

from __future__ import annotations

import re

import numpy as np
import pytest

from clm_core.errors import ParameterError
from clm_core.frequency import dynamic_solve, receptance, receptance_from_pulse
from clm_core.params import load_model
from clm_core.track import TrackSystem, assemble


@pytest.fixture(scope="module")
def system() -> TrackSystem:
    return assemble(load_model(), 11)


@pytest.mark.parametrize(
    ("n_out", "fragment"),
    [(0, "n_out = 0: must be an integer in 1..6"), (-1, "n_out = -1: must be an integer in 1..6"),
     (7, "n_out = 7: must be an integer in 1..6"), (1.5, "n_out = 1.5: must be an integer"),
     (float("nan"), "n_out = nan: must be an integer"), ("x", "n_out = 'x': must be an integer")],
)
def test_receptance_refuses_bad_output_count(system: TrackSystem, n_out: object, fragment: str) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        receptance(system, [1.0, 2.0], n_out)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        receptance_from_pulse(system, fmax=100.0, dt=1e-3, duration=0.1, n_out=n_out)  # type: ignore[arg-type]


@pytest.mark.parametrize("f", [[np.nan], [-1.0], [], [[1.0, 2.0]], "abc"])
def test_bad_frequencies_refused(system: TrackSystem, f: object) -> None:
    with pytest.raises(ParameterError, match="frequencies"):
        receptance(system, f)  # type: ignore[arg-type]


@pytest.mark.parametrize("force", [np.zeros(3), "nan"])
def test_dynamic_solve_refuses_bad_force(system: TrackSystem, force: object) -> None:
    F = np.full(system.n_dof, np.nan) if isinstance(force, str) else force
    with pytest.raises(ParameterError, match=re.escape(f"must be ({system.n_dof},) finite values")):
        dynamic_solve(system, [1.0], F)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [({"fmax": float("nan")}, "fmax = nan: must be finite"), ({"fmax": 0.0}, "fmax = 0 Hz: must be > 0"),
     ({"dt": 0.0}, "dt = 0 s: must be > 0"), ({"dt": "x"}, "dt = 'x': must be a real number"),
     ({"duration": -1.0}, "duration = -1 s: must be > 0"),
     ({"duration": float("inf")}, "duration = inf: must be finite"),
     ({"duration": 0.005}, "duration = 0.005 s: must be >= 1/fmax"),
     ({"td": 0.0}, "td = 0 s: must be > 0"), ({"t0": float("nan")}, "t0 = nan: must be finite"),
     ({"t0": 10.0}, "t0 = 10 s: the pulse onset must be inside the record")],
)
def test_pulse_route_refuses_bad_settings(system: TrackSystem, kwargs: dict[str, object], fragment: str) -> None:
    args = {"fmax": 100.0, "dt": 1e-3, "duration": 0.1} | kwargs
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        receptance_from_pulse(system, **args)  # type: ignore[arg-type]
