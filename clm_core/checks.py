"""Value checks shared by every parameter object: one message style everywhere.

Each returns the value as a float or raises :class:`clm_core.errors.ParameterError`
naming the parameter, its value and the rule.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Mapping
from typing import Any

from clm_core.errors import ClmError, ParameterError, StabilityError


def finite(name: str, value: Any, error: type[ClmError] = ParameterError) -> float:
    """``value`` as a finite float.

    ``error``: the exception raised for a value that is not a real number or
    not finite (default :class:`~clm_core.errors.ParameterError`; e.g. an
    input error of the caller's layer, with the same message).
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise error(f"{name} = {value!r}: must be a real number") from None
    if not math.isfinite(v):
        raise error(f"{name} = {v}: must be finite (no NaN or infinity)")
    return v


def positive(name: str, value: Any, error: type[ClmError] = ParameterError, unit: str = "") -> float:
    """``value`` as a finite float > 0.

    ``error``: as in :func:`finite`; ``unit``: shown after the value in the
    message (``sample_rate = -5 Hz: must be > 0``).
    """
    v = finite(name, value, error)
    if v <= 0.0:
        raise error(f"{name} = {v:g}{' ' + unit if unit else ''}: must be > 0")
    return v


def nonnegative(name: str, value: Any, error: type[ClmError] = ParameterError, unit: str = "") -> float:
    """``value`` as a finite float >= 0 (``error``, ``unit``: as in :func:`positive`)."""
    v = finite(name, value, error)
    if v < 0.0:
        raise error(f"{name} = {v:g}{' ' + unit if unit else ''}: must be >= 0")
    return v


def integer(
    name: str,
    value: Any,
    minimum: int | None = None,
    maximum: int | None = None,
    error: type[ClmError] = ParameterError,
    hint: str = "",
) -> int:
    """``value`` as an int in ``minimum..maximum`` (either bound optional).

    A bool or a float (even 3.0) is refused: a count or an index is never
    rounded. ``error``: as in :func:`finite`; ``hint``: what the range
    means, shown in parentheses (``n_out = 0: must be an integer in 1..21
    (sleepers from the centre of 41)``).
    """
    n: int | None = None
    if not isinstance(value, bool):
        try:
            n = operator.index(value)
        except TypeError:
            pass
    if n is None or (minimum is not None and n < minimum) or (maximum is not None and n > maximum):
        if minimum is not None and maximum is not None:
            rule = f" in {minimum}..{maximum}"
        elif minimum is not None:
            rule = f" >= {minimum}"
        else:
            rule = "" if maximum is None else f" <= {maximum}"
        raise error(f"{name} = {value!r}: must be an integer{rule}{f' ({hint})' if hint else ''}")
    return n


#: Most areas of one chain (:func:`odd_count`): 100 001 areas of 0.6 m are 60 km of line; a larger count is an input
#: mistake, and its matrices would not fit in memory.
MAX_AREAS = 100_001


def odd_count(name: str, value: Any, minimum: int = 1, maximum: int = MAX_AREAS) -> int:
    """``value`` as an odd integer in ``minimum..maximum`` (a chain of 2n + 1 areas, loaded one at the centre)."""
    n = integer(name, value, None, maximum, hint="a chain of 2n + 1 areas")
    if n < minimum or n % 2 == 0:
        raise ParameterError(f"{name} = {n}: must be odd and >= {minimum} (2n + 1 areas, the loaded one at the centre)")
    return n


def chain_min_eigenvalue(diag: float, coupling: float, n_areas: int | None = None) -> float:
    """Smallest eigenvalue of the CLM chain matrix a I + c L with free ends (Sec. 4.2).

    The damping matrix of a chain of N areas is d_f I + d_c L and its
    stiffness matrix k_f I + k_c L, with L the path-graph Laplacian
    (diagonal 2, end entries 1, off-diagonal -1) whose eigenvalues are
    2 - 2 cos(pi k / N), k = 0..N-1, in [0, 4).

    Parameters
    ----------
    diag : float
        a: d_f [N s/m] or k_f [N/m].
    coupling : float
        c: d_c [N s/m] or k_c [N/m].
    n_areas : int, optional
        N; None for the bound of every chain length, a + 4 min(c, 0).

    Returns
    -------
    float
        The smallest eigenvalue [unit of ``diag``].
    """
    if coupling >= 0:
        return float(diag)
    if n_areas is None:
        return float(diag + 4.0 * coupling)
    n = int(n_areas)
    if n < 1:
        raise ParameterError(f"n_areas = {n_areas}: must be >= 1")
    return float(diag + coupling * (2.0 - 2.0 * math.cos(math.pi * (n - 1) / n)))


#: Sign rules of the track parameters (paper Sec. 5, Table 2): name -> "> 0" or ">= 0".
TRACK_RULES: Mapping[str, str] = {
    "spacing": "> 0",
    "kp": "> 0",
    "dp": ">= 0",
    "ms": "> 0",
    "kb": "> 0",
    "db": ">= 0",
    "contact_length": "> 0",
    "contact_width": "> 0",
}


def track_values(values: Mapping[str, Any], *, prefix: str = "track.", where: str = "") -> dict[str, float]:
    """The value rules of track parameters, in one place: :data:`TRACK_RULES` for the names given.

    Parameters
    ----------
    values : mapping
        Any of ``spacing`` [m], ``kp`` [N/m], ``dp`` [N s/m], ``ms`` [kg], ``kb``
        [N/m], ``db`` [N s/m], ``contact_length``, ``contact_width`` [m].
    prefix, where : str
        Text before the name and after the value in messages.

    Returns
    -------
    dict
        The values as floats.

    Raises
    ------
    ParameterError
        An unknown name, or a value that breaks its rule (naming both).
    """
    out: dict[str, float] = {}
    for name, value in values.items():
        rule = TRACK_RULES.get(name)
        if rule is None:
            raise ParameterError(f"{prefix}{name}: not a track parameter; known: {', '.join(TRACK_RULES)}")
        v = finite(f"{prefix}{name}", value)
        if (rule == "> 0" and not v > 0.0) or (rule == ">= 0" and not v >= 0.0):
            raise ParameterError(f"{prefix}{name} = {v:g}{where}: must be {rule}")
        out[name] = v
    return out


#: The parameters each foundation model uses (Sec. 3-4).
SOIL_MODEL_PARAMETERS: Mapping[str, tuple[str, ...]] = {
    "rigid": (),
    "winkler": ("kf", "df"),
    "lysmer": ("mf", "kf", "df"),
    "clm": ("mf", "kf", "df", "kc", "dc"),
}


def soil_values(
    model: str, values: Mapping[str, Any], *, prefix: str = "soil.", where: str = "", stability: bool = True
) -> dict[str, float]:
    """The value rules of a foundation model for simulation, in one place (Sec. 3-4).

    Rules (for the parameters ``model`` uses): every value finite; k_f > 0;
    d_f >= 0; m_f > 0 (Lysmer, CLM); k_c >= 0 and d_f + 4 d_c >= 0 (CLM: the
    chain damping matrix d_f I + d_c L is positive semi-definite for every
    chain length, :func:`chain_min_eigenvalue`; else the response diverges,
    Sec. 4.2).

    Parameters
    ----------
    model : {'rigid', 'winkler', 'lysmer', 'clm'}
        Foundation model.
    values : mapping
        ``mf`` [kg], ``kf`` [N/m], ``df`` [N s/m], ``kc`` [N/m], ``dc`` [N s/m];
        missing ones count as 0.
    prefix, where : str
        Text before the parameter name and after its value in messages
        (e.g. ``prefix="soil."`` or ``where=" at sleeper 12"``).
    stability : bool
        Apply the chain damping rule d_f + 4 d_c >= 0 (False where the
        assembled damping matrix is checked instead, e.g. per-sleeper values
        whose d_c belongs to a link).

    Returns
    -------
    dict
        The five values as floats.

    Raises
    ------
    ParameterError
        Naming the parameter, its value and the rule.
    """
    if model not in SOIL_MODEL_PARAMETERS:
        raise ParameterError(f"{prefix}model = {model!r}: must be one of {', '.join(SOIL_MODEL_PARAMETERS)}")
    used = SOIL_MODEL_PARAMETERS[model]
    out = {n: finite(f"{prefix}{n}", values.get(n, 0.0)) for n in ("mf", "kf", "df", "kc", "dc")}
    rules: list[tuple[str, str]] = []
    if "kf" in used:
        rules += [("kf", "> 0"), ("df", ">= 0")]
    if "mf" in used:
        rules.append(("mf", "> 0"))
    if "kc" in used:
        rules.append(("kc", ">= 0"))
    for name, rule in rules:
        v = out[name]
        if (rule == "> 0" and not v > 0.0) or (rule == ">= 0" and not v >= 0.0):
            raise ParameterError(f"{prefix}{name} = {v:g}{where}: must be {rule}")
    if "dc" in used and stability:
        lam = chain_min_eigenvalue(out["df"], out["dc"])
        if lam < 0.0:
            raise ParameterError(
                f"{prefix}dc = {out['dc']:g} N s/m{where}: the CLM damping matrix is not positive "
                f"semi-definite (rule d_f + 4 d_c >= 0, here {lam:g}); "
                "the response would diverge (Kouroussis et al. 2011, Sec. 4.2)"
            )
    return out


def clm_chain_admissible(
    mf: float, kf: float, df: float, kc: float, dc: float, n_areas: int | None = None
) -> None:
    """Refuse a CLM set whose chain matrices are not admissible (fitted sets, Sec. 4.2).

    Rules: m_f >= 0 (mass matrix positive semi-definite); the damping and
    stiffness matrices d_f I + d_c L and k_f I + k_c L positive definite,
    i.e. d_f > 0 and d_f + 4 min(d_c, 0) > 0, k_f > 0 and k_f + 4 min(k_c, 0) > 0
    for every chain length, or the exact bound of :func:`chain_min_eigenvalue`
    for ``n_areas`` areas. This is the rule for a fitted frequency-domain
    model; a :class:`~clm_core.params.SoilParams` for simulation also needs
    m_f > 0 and k_c >= 0 (:func:`soil_values`).

    Parameters
    ----------
    mf, kf, df, kc, dc : float
        [kg], [N/m], [N s/m], [N/m], [N s/m].
    n_areas : int, optional
        Chain length (default: every length).

    Raises
    ------
    StabilityError
        Naming the parameter, its value and the rule.
    """
    if not mf >= 0:
        raise StabilityError(f"mf = {mf:.6g} kg: the mass matrix of the chain must be positive semidefinite (mf >= 0)")
    if not df > 0:
        raise StabilityError(f"df = {df:.6g} N s/m: must be > 0 (positive definite chain damping matrix)")
    if not kf > 0:
        raise StabilityError(f"kf = {kf:.6g} N/m: must be > 0 (positive definite chain stiffness matrix)")
    lam_c = chain_min_eigenvalue(df, dc, n_areas)
    if not lam_c > 0:
        raise StabilityError(
            f"dc = {dc:.6g} N s/m with df = {df:.6g} N s/m: the chain damping matrix is not positive definite "
            f"(smallest eigenvalue {lam_c:.6g} N s/m; rule: df > 0 and df + 4 dc > 0 for dc < 0)"
        )
    lam_k = chain_min_eigenvalue(kf, kc, n_areas)
    if not lam_k > 0:
        raise StabilityError(
            f"kc = {kc:.6g} N/m with kf = {kf:.6g} N/m: the chain stiffness matrix is not positive definite "
            f"(smallest eigenvalue {lam_k:.6g} N/m; rule: kf > 0 and kf + 4 kc > 0 for kc < 0)"
        )
