"""Synthetic test records (:mod:`clm_core.synthetic.records`): acquisition settings are checked before anything runs.

A bad rate, length, pulse, hit, speed or step gives a CalibrationError that
names the test, the setting, its value and the rule, never a numpy error
from inside the simulation and never a record without the hit it was asked for.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from clm_core.calibration import CalibrationError
from clm_core.synthetic import simulate_impact, simulate_passby, simulate_receptance

NAN, INF = float("nan"), float("inf")

HAMMER_CASES = [
    ({"fs": -1.0}, "fs = -1 Hz: must be > 0"),
    ({"fs": NAN}, "fs = nan: must be finite"),
    ({"duration": 0.0}, "duration = 0 s: must be > 0"),
    ({"duration": 0.0015}, "fewer than 2 samples"),
    ({"oversample": 0}, "oversample = 0: must be an integer >= 1"),
    ({"oversample": 2.5}, "oversample = 2.5: must be an integer >= 1"),
    ({"pulse_duration": -0.001}, "pulse_duration = -0.001 s: must be > 0"),
    ({"pulse_duration": 1e-6}, "shorter than 4 simulation steps"),
    ({"amplitude": INF}, "amplitude = inf: must be finite"),
    ({"hit_times": ()}, "hit_times is empty"),
    ({"hit_times": (5.0,)}, "hit at 5.0 s: the pulse (onset to onset + pulse_duration) must lie in the record"),
    ({"hit_times": (-0.01,)}, "hit at -0.01 s"),
    ({"hit_times": (NAN,)}, "hit at nan s"),
]


@pytest.mark.parametrize(("kwargs", "match"), HAMMER_CASES)
def test_impact_settings_are_checked(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(CalibrationError, match="^impact simulation: ") as exc:
        simulate_impact(n_areas=3, **{"duration": 0.1, "hit_times": (0.02,), **kwargs})
    assert match in str(exc.value)


@pytest.mark.parametrize(("kwargs", "match"), HAMMER_CASES[:3] + HAMMER_CASES[-3:])
def test_receptance_settings_are_checked(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(CalibrationError, match="^receptance simulation: ") as exc:
        simulate_receptance(n_sleepers=11, **{"duration": 0.1, "hit_times": (0.02,), **kwargs})
    assert match in str(exc.value)


def test_a_hit_whose_pulse_ends_at_the_record_end_is_taken() -> None:
    """The limit of the hit rule: onset + pulse_duration = duration is inside; the force is the whole half-sine."""
    rec = simulate_impact(n_areas=3, fs=1000.0, duration=0.1, hit_times=(0.097,), pulse_duration=0.003,
                          amplitude=1e4, oversample=10)
    assert rec.force is not None
    f = rec.force.values
    assert f.size == 100 and np.argmax(f) >= 97 and f.max() > 0.5e4


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"speed": 0.0}, "pass-by simulation: speed = 0 m/s: must be > 0"),
        ({"speed": -25.0}, "speed = -25 m/s: must be > 0"),
        ({"fs": INF}, "fs = inf: must be finite"),
        ({"dt": 0.0}, "dt = 0 s: must be > 0"),
        ({"dt": 3e-4}, "must divide the output interval"),
        ({"static_load": NAN}, "static_load = nan: must be finite"),
        ({"run_in": -1.0}, "run_in = -1 m: must be >= 0"),
        ({"axle_offsets": (0.0, -2.5)}, "axle offset = -2.5 m: must be >= 0"),
        ({"axle_offsets": ()}, "at least one of each"),
        ({"sleepers": ()}, "at least one of each"),
        ({"dynamic_frequency": NAN}, "dynamic_frequency = nan: must be finite"),
    ],
)
def test_passby_settings_are_checked(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(CalibrationError) as exc:
        simulate_passby(**kwargs)
    assert match in str(exc.value)
