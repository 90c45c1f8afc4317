"""Track receptance test: railpad, ballast (and sleeper, soil) parameters from a hammer on the rail.

A hammer hits the rail above one sleeper (sleeper 0); accelerometers (or
velocity/displacement sensors) on the rail above sleepers j and on sleepers
give receptances H_j = X_j / F (:mod:`clm_core.calibration.spectra`). The
model is the assembled track (:func:`clm_core.track.assemble`, paper Sec. 5,
Fig. 6) with ``n_sleepers`` sleepers, the hit one at the centre, solved at
the windowed complex frequency (:func:`clm_core.calibration.models.track_response`).

Fitted parameters (user's choice): k_p, d_p, k_b, d_b and optionally the
sleeper mass m (``ms``), with the soil fixed (from the base parameter set)
or fitted jointly (its model's parameters). Constraints keep every iterate
admissible: stiffnesses and masses > 0, dampings >= 0, and for the CLM soil
d_f + 4 d_c >= 0 (damping matrix positive semi-definite, Sec. 4.2). Error
norms as in :mod:`clm_core.calibration.residuals`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array, CArray
from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.lsq import FitControls, FitResult, fit_constrained
from clm_core.calibration.models import track_response
from clm_core.calibration.residuals import corr_factor, make_sandwich, misfit, norm_weights, stack_residual
from clm_core.calibration.spectra import TransferData
from clm_core.errors import ParameterError
from clm_core.params import SOIL_USED, ModelParams
from clm_core.soil.chain import CHAIN_PARAMS
from clm_core.track import TrackSystem, assemble

TRACK_FIT_NAMES: tuple[str, ...] = ("kp", "dp", "ms", "kb", "db")
DEFAULT_FIT: tuple[str, ...] = ("kp", "dp", "kb", "db")


@dataclass(frozen=True)
class TrackFit(FitResult):
    """Result of a track fit (receptance or pass-by): :class:`~clm_core.calibration.lsq.FitResult` and the following.

    Attributes
    ----------
    params : ModelParams
        The full fitted parameter set (fixed parameters from the base set).
    n_sleepers : int
        Sleepers of the model track (0: pass-by, the simulator's window).
    model_response : array
        Receptance: (n_f, n_ch) complex model H at the data's s [m/N];
        pass-by: (n_t, n_ch) simulated responses [SI].
    """

    params: ModelParams
    n_sleepers: int
    model_response: NDArray[np.generic]


def free_parameters(base: ModelParams, fit: Sequence[str], soil: str) -> tuple[str, ...]:
    """The fitted names, in a fixed order: track names, then the soil model's (joint fit).

    Raises
    ------
    CalibrationError
        Unknown names, a soil name without ``soil='joint'``, or a soil model
        without parameters (rigid) in a joint fit.
    """
    if soil not in ("fixed", "joint"):
        raise CalibrationError(f"soil = {soil!r}: must be 'fixed' or 'joint'")
    names = [str(n) for n in fit]
    unknown = [n for n in names if n not in TRACK_FIT_NAMES and n not in CHAIN_PARAMS]
    if unknown:
        raise CalibrationError(f"fit: unknown parameter(s) {unknown}; track: {', '.join(TRACK_FIT_NAMES)}")
    soil_names = [n for n in names if n not in TRACK_FIT_NAMES]
    used = SOIL_USED[base.soil.model]
    if soil == "joint":
        if not used:
            raise CalibrationError("soil = 'joint' with a rigid soil: there is no soil parameter to fit")
        soil_names = list(used)
    elif soil_names:
        raise CalibrationError(f"fit: {soil_names} are soil parameters; use soil: joint to fit them")
    bad = [n for n in soil_names if n not in used]
    if bad:
        raise CalibrationError(f"fit: {bad} are not parameters of the {base.soil.model!r} soil model")
    track = [n for n in TRACK_FIT_NAMES if n in names]
    if not track and not soil_names:
        raise CalibrationError("fit: no parameter to fit")
    return tuple(track + [n for n in ("mf", "kf", "df", "kc", "dc") if n in soil_names])


def starting_set(base: ModelParams, initial: Mapping[str, float] | None) -> ModelParams:
    """The fit's starting parameter set: ``base`` with the ``initial`` values (SI units) put in.

    Parameters
    ----------
    base : ModelParams
        Fixed values and default starting point.
    initial : mapping name -> value, optional
        Starting values overriding ``base`` [SI].

    Raises
    ------
    CalibrationError
        An unknown name or an inadmissible value (the parameter rule is named).
    """
    if not initial:
        return base
    try:
        return base.override(**{k: float(v) for k, v in initial.items()})
    except ParameterError as exc:
        raise CalibrationError(f"initial values: {exc}") from None


def out_dofs(system: TrackSystem, channels: Sequence[object], centre: int) -> list[int]:
    """DOF of each channel (rail above, or sleeper, or soil area under sleeper ``centre + index``).

    Raises
    ------
    CalibrationError
        A channel outside the model track or at an impossible place.
    """
    dofs = []
    for ch in channels:
        loc, j = getattr(ch, "location"), int(getattr(ch, "index"))  # noqa: B009
        g = centre + j
        if not 0 <= g < system.n_sleepers:
            raise CalibrationError(
                f"channel {getattr(ch, 'name')}: sleeper {j} lies outside the {system.n_sleepers}-sleeper model "  # noqa: B009
                "track; raise n_sleepers"
            )
        if loc == "rail":
            dofs.append(int(system.rail_w[system.sleeper_node[g]]))
        elif loc == "sleeper":
            dofs.append(int(system.sleeper_dof[g]))
        elif loc == "soil":
            if system.area_dof[g] < 0:
                raise CalibrationError(f"channel {getattr(ch, 'name')}: a soil channel needs a non-rigid soil model")  # noqa: B009
            dofs.append(int(system.area_dof[g]))
        else:
            raise CalibrationError(
                f"channel {getattr(ch, 'name')}: location {loc!r}; track tests need rail, sleeper or soil"  # noqa: B009
            )
    return dofs


def fit_receptance(
    data: TransferData,
    base: ModelParams,
    fit: Sequence[str] = DEFAULT_FIT,
    soil: str = "fixed",
    norm: str = "weighted",
    n_sleepers: int = 41,
    initial: Mapping[str, float] | None = None,
    *,
    controls: FitControls | None = None,
) -> TrackFit:
    """Fit track (and soil) parameters to the receptances of a hammer test on the rail.

    Parameters
    ----------
    data : TransferData
        Measured receptances; channels at ``rail``/``sleeper``/``soil``,
        index relative to the hit sleeper.
    base : ModelParams
        Rail, track and soil parameters: fixed values and starting point.
    fit : sequence of str
        Track parameters to fit (``kp dp ms kb db``).
    soil : {'fixed', 'joint'}
        Keep the soil of ``base`` or fit its parameters too.
    norm : {'weighted', 'absolute', 'relative', 'log'}
    n_sleepers : int
        Model track length (odd; >= 21 recommended, paper Sec. 5).
    initial : mapping, optional
        Starting values overriding ``base``.
    controls : FitControls, optional
        Budget and identifiability rules (default: :class:`~clm_core.calibration.lsq.FitControls`
        with 100 evaluations).

    Returns
    -------
    TrackFit

    Raises
    ------
    CalibrationError
        Bad names, channels or sizes; an invalid starting set.
    """
    if n_sleepers < 3 or n_sleepers % 2 == 0:
        raise CalibrationError(f"n_sleepers = {n_sleepers}: must be odd and >= 3 (hit sleeper at the centre)")
    names = free_parameters(base, fit, soil)
    warns: list[str] = []
    start = starting_set(base, initial)
    p0 = np.array([_get(start, k) for k in names])
    method = "the base parameter set" + (" with the given initial values" if initial else "") + (
        f" ({base.name})" if base.name else ""
    )
    c = n_sleepers // 2
    try:
        sys0 = assemble(start, n_sleepers)
    except ParameterError as exc:
        raise CalibrationError(f"the starting parameter set is not admissible: {exc}") from None
    dofs = out_dofs(sys0, data.channels, c)
    cols = list(range(len(data.channels)))
    W, norm_used, w1 = norm_weights(data, cols, norm)
    warns += w1
    Hd = data.H
    s = data.s

    def model(p: Array) -> CArray:
        prm = start.override(**dict(zip(names, p.tolist())))
        system = assemble(prm, n_sleepers, check_stability=False)
        fdof = int(system.rail_w[system.sleeper_node[c]])
        return track_response(system, s, fdof, dofs)

    def residual(p: Array) -> tuple[Array, Array | None]:
        Hm = model(p)
        e = np.log(Hm / Hd) if W is None else (Hm - Hd) * W
        return stack_residual(e)

    D = (1.0 / Hd) if W is None else W.astype(complex)
    p, est, stats, w2 = fit_constrained(
        residual,
        names,
        p0,
        corr_factor=corr_factor(data, norm_used),
        controls=controls or FitControls(max_nfev=100),
        jacobian=False,
        sandwich=make_sandwich(data, cols, D),
    )
    warns += w2
    fitted = start.override(**dict(zip(names, p.tolist())))
    try:
        assemble(fitted, n_sleepers)  # stability check of the whole system
    except ParameterError as exc:  # pragma: no cover - the constraints make this unreachable
        raise CalibrationError(f"the fitted set is not admissible: {exc}") from None
    Hm = model(p)
    mis = misfit(Hm, Hd, W)
    return TrackFit(
        params=fitted,
        parameters=est,
        stats=stats,
        norm=norm_used,
        band=data.band if data.band[1] > 0 else (float(data.frequency[0]), float(data.frequency[-1])),
        n_sleepers=n_sleepers,
        channels_used=tuple(ch.name for ch in data.channels),
        model_response=Hm,
        misfit=mis,
        first_estimate=dict(zip(names, p0.tolist())),
        first_estimate_method=method,
        warnings=tuple(warns),
    )


def _get(params: ModelParams, name: str) -> float:
    if name in TRACK_FIT_NAMES:
        return float(getattr(params.track, name))
    v = float(getattr(params.soil, name))
    if not math.isfinite(v):
        raise CalibrationError(f"{name} = {v}: not a finite starting value")
    return v
