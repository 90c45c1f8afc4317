"""Value checks shared by every parameter object: one message style everywhere.

Each returns the value as a float or raises :class:`clm_core.errors.ParameterError`
naming the parameter, its value and the rule.
"""

from __future__ import annotations

import math
from typing import Any

from clm_core.errors import ParameterError


def finite(name: str, value: Any) -> float:
    """``value`` as a finite float."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: must be a real number") from None
    if not math.isfinite(v):
        raise ParameterError(f"{name} = {v}: must be finite (no NaN or infinity)")
    return v


def positive(name: str, value: Any) -> float:
    """``value`` as a finite float > 0."""
    v = finite(name, value)
    if v <= 0.0:
        raise ParameterError(f"{name} = {v:g}: must be > 0")
    return v


def nonnegative(name: str, value: Any) -> float:
    """``value`` as a finite float >= 0."""
    v = finite(name, value)
    if v < 0.0:
        raise ParameterError(f"{name} = {v:g}: must be >= 0")
    return v
