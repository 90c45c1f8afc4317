"""Pass-by test: output-error fit of track parameters through the time-domain engine.

Measured wheel loads (``clm_msgs/msg/WheelLoads``: positions and forces per
instant) drive the streaming simulator :class:`clm_core.solver.TrackSimulator`
(Newmark average acceleration on the assembled track, paper Sec. 5) over a
fixed window that holds every wheel position of the record; its rail,
sleeper or soil-area displacements at the instrumented sleepers are compared
with the measured responses sample by sample (output error). The parameters
the user selects (default k_p, k_b) are fitted by bounded least squares with
the constraints of :mod:`clm_core.calibration.receptance`.

Residual of channel j at sample i: (y_sim - y_meas) / sigma_j, sigma_j the
noise of the channel measured while no wheel is within ``quiet_distance`` of
its sleeper (before the train arrives); without such a quiet stretch, the
channel's rms (each channel counts alike). Velocity and acceleration
channels are compared with the derivative of the simulated displacement
(central differences on the record's grid). The measured channels' offset is
removed with the quiet-stretch mean (displacement sensors have no absolute
zero). The fit starts from a static state under the first loads.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.calibration.bagio import WheelLoadRecord
from clm_core.calibration.channels import ChannelSpec
from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.lsq import FitControls, fit_constrained
from clm_core.calibration.receptance import TrackFit, free_parameters, starting_set
from clm_core.calibration.signals import Recording
from clm_core.errors import ParameterError
from clm_core.params import ModelParams

_FIELD = {"rail": "rail_deflection", "sleeper": "sleeper_displacement", "soil": "area_displacement"}
DEFAULT_PASSBY_FIT: tuple[str, ...] = ("kp", "kb")


def simulate_channels(
    params: ModelParams,
    loads: WheelLoadRecord,
    channels: Sequence[ChannelSpec],
    t_out: Array,
    dt: float,
    margin: int = 12,
) -> Array:
    """Responses of the track at the channels' sleepers under recorded wheel loads.

    Parameters
    ----------
    params : ModelParams
        Track and soil.
    loads : WheelLoadRecord
        Wheel positions [m] and forces [N] in time (linearly interpolated).
    channels : sequence of ChannelSpec
        Location ``rail``/``sleeper``/``soil`` at global sleeper ``index``;
        quantity displacement [m], velocity [m/s] or acceleration [m/s^2].
    t_out : (n,) array
        Output times [s] (same origin as ``loads.t``), uniform.
    dt : float
        Integration step [s].
    margin : int
        Bays of track beyond the extreme wheel positions and sleepers.

    Returns
    -------
    (n, n_ch) array
        Simulated responses; NaN outside the loads' time span.
    """
    from clm_core.solver import LoadTable, TrackSimulator

    d = params.track.spacing
    idx = [int(c.index) for c in channels]
    lo = int(math.floor(min(float(np.nanmin(loads.positions)) / d, min(idx)))) - margin
    hi = int(math.ceil(max(float(np.nanmax(loads.positions)) / d, max(idx)))) + margin
    n_sl = hi - lo + 1
    sim = TrackSimulator(
        params, dt, n_sleepers=n_sl, start_position=0.5 * (lo + hi) * d, follow=False,
        margin_sleepers=min(10, margin - 1), lead_sleepers=min(10, margin - 1),
    )
    t0 = float(loads.t[0])
    sim.initialize(loads.positions[0], loads.forces[0], t0=t0, state="static")
    blocks: list[Any] = []
    sim.advance(float(loads.t[-1]), LoadTable(loads.t, loads.positions, loads.forces), callback=blocks.append)
    ts = np.concatenate([[t0]] + [b.t for b in blocks])
    cols = []
    for ch in channels:
        field = _FIELD.get(ch.location)
        if field is None:
            raise CalibrationError(
                f"channel {ch.name}: location {ch.location!r}; a pass-by needs rail, sleeper or soil"
            )
        parts = []
        for b in blocks:
            j = int(ch.index) - b.first_sleeper
            if not 0 <= j < len(b.sleeper_x):
                raise CalibrationError(f"channel {ch.name}: sleeper {ch.index} not in the simulated window")
            parts.append(getattr(b, field)[:, j])
        cols.append(np.concatenate([[np.nan], *parts]))
    Y = np.column_stack(cols)
    Y[0] = Y[1]  # the initial state is static: the first output stands for t0 too
    out = np.full((t_out.size, len(channels)), np.nan)
    inside = (t_out >= ts[0]) & (t_out <= ts[-1])
    for k, ch in enumerate(channels):
        y = np.interp(t_out[inside], ts, Y[:, k])
        p = {"displacement": 0, "velocity": 1, "acceleration": 2}[ch.quantity]
        for _ in range(p):
            y = np.gradient(y, t_out[inside])
        out[inside, k] = y
    return out


def quiet_mask(loads: WheelLoadRecord, channels: Sequence[ChannelSpec], t: Array, spacing: float,
               distance: float) -> NDArray[np.bool_]:
    """(n, n_ch) True where no wheel is within ``distance`` [m] of the channel's sleeper."""
    P = np.empty((t.size, loads.positions.shape[1]))
    for w in range(P.shape[1]):
        ok = np.isfinite(loads.positions[:, w])
        P[:, w] = np.interp(t, loads.t[ok], loads.positions[ok, w], left=np.nan, right=np.nan) if ok.any() else np.nan
    out = np.zeros((t.size, len(channels)), dtype=bool)
    for k, ch in enumerate(channels):
        x = ch.index * spacing
        dist = np.nanmin(np.abs(P - x), axis=1, initial=np.inf)
        out[:, k] = dist > distance
    return out


def fit_passby(
    rec: Recording,
    loads: WheelLoadRecord,
    base: ModelParams,
    fit: Sequence[str] = DEFAULT_PASSBY_FIT,
    soil: str = "fixed",
    initial: Mapping[str, float] | None = None,
    dt: float | None = None,
    quiet_distance: float = 6.0,
    *,
    controls: FitControls | None = None,
) -> TrackFit:
    """Output-error fit of track (and soil) parameters to a pass-by record.

    Parameters
    ----------
    rec : Recording
        Measured responses (no force channel); channel indices are global
        sleeper indices (sleeper g at x = g d).
    loads : WheelLoadRecord
        Wheel loads on the same time origin.
    base : ModelParams
        Fixed values and starting point.
    fit : sequence of str
        Parameters to fit (``kp dp ms kb db``; soil ones with ``soil='joint'``).
    soil : {'fixed', 'joint'}
    initial : mapping, optional
        Starting values overriding ``base``.
    dt : float, optional
        Integration step [s]; default the record's interval split so that
        dt <= 0.5 ms.
    quiet_distance : float
        Distance [m] beyond which a wheel does not move a sleeper (noise
        estimate and offset removal).
    controls : FitControls, optional
        Budget and identifiability rules (default: :class:`~clm_core.calibration.lsq.FitControls`
        with 60 evaluations, each a time-domain simulation; its ``progress``
        is called after each simulation of the fit).

    Returns
    -------
    TrackFit
        ``model_response`` holds the simulated responses (n_t, n_ch).

    Raises
    ------
    CalibrationError
        Channels at impossible places, no overlap of loads and record,
        a bad starting set.
    """
    names = free_parameters(base, fit, soil)
    warns: list[str] = []
    start = starting_set(base, initial)
    if dt is None:
        q = max(1, math.ceil((1.0 / rec.fs) / 5e-4))
        dt = 1.0 / (rec.fs * q)
    t = rec.t
    inside = (t >= loads.t[0]) & (t <= loads.t[-1])
    if inside.sum() < 16:
        raise CalibrationError(
            f"the wheel loads ({loads.t[0]:.3f}..{loads.t[-1]:.3f} s) and the responses ({t[0]:.3f}..{t[-1]:.3f} s) "
            "overlap in fewer than 16 samples: were they recorded together?"
        )
    Y = rec.responses.copy()
    quiet = quiet_mask(loads, rec.channels, t, base.track.spacing, quiet_distance) & inside[:, None]
    sig = np.empty(len(rec.channels))
    classical = False
    for k, ch in enumerate(rec.channels):
        qk = quiet[:, k]
        if qk.sum() >= 50:
            if ch.quantity == "displacement":
                Y[:, k] -= np.mean(Y[qk, k])
            sig[k] = float(np.std(Y[qk, k]))
        else:
            classical = True
            sig[k] = float(np.sqrt(np.mean(Y[inside, k] ** 2)))
    if classical:
        warns.append(
            f"no quiet stretch (no wheel within {quiet_distance:g} m) of >= 50 samples on every channel: channels "
            "weighted by their rms, intervals from the residual variance"
        )
    if np.any(sig <= 0):
        raise CalibrationError("a response channel is constant over the record")
    p0 = np.array([_get(start, k) for k in names])
    m = inside

    def sim(p: Array) -> Array:
        prm = start.override(**dict(zip(names, p.tolist())))
        return simulate_channels(prm, loads, rec.channels, t, dt)

    def residual(p: Array) -> tuple[Array, None]:
        Ys = sim(p)
        e = (Ys[m] - Y[m]) / sig[None, :]
        return np.nan_to_num(e.T.ravel(), nan=0.0), None

    try:
        p, est, stats, w2 = fit_constrained(
            residual,
            names,
            p0,
            controls=controls or FitControls(max_nfev=60),
            jacobian=False,
            sandwich=None if classical else (lambda J: (J.T @ J, float(J.shape[0]))),
        )
    except ParameterError as exc:
        raise CalibrationError(f"pass-by fit: {exc}") from None
    warns += w2
    fitted = start.override(**dict(zip(names, p.tolist())))
    Ys = sim(p)
    mis = float(np.linalg.norm((Ys[m] - Y[m]) / sig) / np.linalg.norm(Y[m] / sig))
    return TrackFit(
        params=fitted,
        parameters=est,
        stats=stats,
        norm="weighted" if not classical else "relative-rms",
        band=(0.0, 0.5 * rec.fs),
        n_sleepers=0,
        channels_used=tuple(ch.name for ch in rec.channels),
        model_response=Ys,
        misfit=mis,
        first_estimate=dict(zip(names, p0.tolist())),
        first_estimate_method="the base parameter set" + (" with the given initial values" if initial else ""),
        warnings=tuple(warns),
    )


def _get(params: ModelParams, name: str) -> float:
    if name in ("kp", "dp", "ms", "kb", "db"):
        return float(getattr(params.track, name))
    return float(getattr(params.soil, name))
