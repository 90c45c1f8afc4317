"""The shared value checks (:mod:`clm_core.checks`): what they take, what they refuse, the message they give."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from clm_core.calibration import CalibrationError
from clm_core.checks import finite, integer, nonnegative, odd_count, positive
from clm_core.errors import ParameterError


@pytest.mark.parametrize("value", [3, np.int64(3), np.uint8(3)])
def test_integer_takes_python_and_numpy_integers(value: Any) -> None:
    n = integer("n", value, 1, 5)
    assert n == 3 and type(n) is int


@pytest.mark.parametrize(
    ("value", "minimum", "maximum", "message"),
    [
        (3.0, None, None, "n = 3.0: must be an integer"),  # never rounded, even when whole
        (True, None, None, "n = True: must be an integer"),
        ("3", None, None, "n = '3': must be an integer"),
        (None, 0, None, "n = None: must be an integer >= 0"),
        (float("nan"), 0, None, "n = nan: must be an integer >= 0"),
        (0, 1, 5, "n = 0: must be an integer in 1..5 (the hint)"),
        (6, 1, 5, "n = 6: must be an integer in 1..5 (the hint)"),
        (9, None, 8, "n = 9: must be an integer <= 8"),
    ],
)
def test_integer_refuses_with_the_rule(value: Any, minimum: int | None, maximum: int | None, message: str) -> None:
    with pytest.raises(ParameterError) as exc:
        integer("n", value, minimum, maximum, hint="the hint" if maximum == 5 else "")
    assert str(exc.value) == message


def test_the_caller_chooses_the_error_type() -> None:
    for check in (lambda: integer("k", -1, 0, error=CalibrationError),
                  lambda: positive("fs", 0.0, CalibrationError, "Hz"),
                  lambda: nonnegative("run_in", -1.0, CalibrationError, "m"),
                  lambda: finite("x", float("inf"), CalibrationError)):
        with pytest.raises(CalibrationError):
            check()
    assert positive("fs", 2, unit="Hz") == 2.0 and nonnegative("d", 0) == 0.0


def test_odd_count_is_an_integer_first() -> None:
    assert odd_count("n_areas", np.int32(41)) == 41
    with pytest.raises(ParameterError, match=r"n_areas = 4\.0: must be an integer"):
        odd_count("n_areas", 4.0)
    with pytest.raises(ParameterError, match="must be odd and >= 3"):
        odd_count("n_areas", 4, minimum=3)
