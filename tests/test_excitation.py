"""Bad input to the Eq. (1) pulse (clm_core.excitation): a ParameterError naming the value and the rule."""

from __future__ import annotations

import re

import numpy as np
import pytest

from clm_core.errors import ParameterError
from clm_core.excitation import decay_pulse, decay_pulse_spectrum

BAD = [
    ({"A": float("nan")}, "A = nan: must be finite"),
    ({"A": "x"}, "A = 'x': must be a real number"),
    ({"t0": float("inf")}, "t0 = inf: must be finite"),
    ({"t0": None}, "t0 = None: must be a real number"),
    ({"td": 0.0}, "td = 0 s: must be > 0"),
    ({"td": -1.0}, "td = -1 s: must be > 0"),
    ({"td": float("nan")}, "td = nan: must be finite"),
]


@pytest.mark.parametrize(("kwargs", "fragment"), BAD)
def test_pulse_refuses_bad_parameters(kwargs: dict[str, object], fragment: str) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        decay_pulse(np.linspace(0.0, 0.1, 11), **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(("kwargs", "fragment"), BAD)
def test_spectrum_refuses_bad_parameters(kwargs: dict[str, object], fragment: str) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        decay_pulse_spectrum([1.0, 2.0], **kwargs)  # type: ignore[arg-type]


def test_nonfinite_times_and_frequencies_refused() -> None:
    with pytest.raises(ParameterError, match=re.escape("t = nan s: times must be finite")):
        decay_pulse([0.0, np.nan])
    with pytest.raises(ParameterError, match=re.escape("f = inf Hz: frequencies must be finite")):
        decay_pulse_spectrum([1.0, np.inf])


def test_text_times_refused() -> None:
    with pytest.raises(ParameterError, match=re.escape("t = 'x': times must be real numbers")):
        decay_pulse("x")
