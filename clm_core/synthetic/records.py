"""Synthetic calibration records from known parameters, with sensor noise (written by :mod:`.writer`).

The records are made the way a measurement would be, by an independent route
from the one the fit uses:

- impact and receptance tests: time integration (Newmark average
  acceleration, :class:`clm_core.newmark.NewmarkLinear`) of the CLM chain
  (:func:`clm_core.soil.chain.chain_matrices`) or of the assembled track
  (:func:`clm_core.track.assemble`) under a hammer pulse, at ``oversample``
  times the output rate; then the acquisition: the same anti-alias FIR filter
  and decimation on every channel (:func:`scipy.signal.resample_poly`);
- pass-by: the streaming engine :class:`clm_core.solver.TrackSimulator`
  under moving wheel loads, at a finer step than the output rate;
- noise: white Gaussian noise on every channel, force included, at a stated
  signal-to-noise ratio SNR = 20 log10(rms_active / sigma_noise), rms_active
  being the rms of the clean channel over ``snr_window`` seconds from each
  hit (impact, receptance) or over the whole record (pass-by).

The records are written to bags by :mod:`clm_core.synthetic.writer`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from scipy.signal import resample_poly

from clm_core.arrays import Array
from clm_core.calibration.bagio import WheelLoadRecord
from clm_core.calibration.channels import ChannelSpec, unit_factor
from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.passby import simulate_channels
from clm_core.calibration.signals import Signal, fractional_delay
from clm_core.checks import finite, integer, nonnegative, positive
from clm_core.excitation import decay_pulse
from clm_core.newmark import NewmarkLinear
from clm_core.params import ModelParams, SoilParams, load_model, load_soil
from clm_core.soil.chain import chain_matrices
from clm_core.track import assemble

#: Where each SleeperResponse displacement field is measured.
_FIELD_LOCATION = {"rail_deflection": "rail", "sleeper_displacement": "sleeper", "area_displacement": "soil"}


@dataclass(frozen=True)
class SyntheticRecord:
    """A synthetic test before it is written to a bag.

    Attributes
    ----------
    method : {'impact', 'receptance', 'passby'}
    force : Signal or None
        Hammer force [N].
    responses : tuple of Signal
        Responses in SI units.
    loads : WheelLoadRecord or None
        Wheel loads (pass-by).
    truth : mapping
        The parameters the record was made with (parameter-file layout).
    settings : mapping
        Generator settings (for truth.yaml).
    snr_db : float or None
        Noise level (None: noise-free).
    """

    method: str
    force: Signal | None
    responses: tuple[Signal, ...]
    loads: WheelLoadRecord | None
    truth: Mapping[str, Any]
    settings: Mapping[str, Any]
    snr_db: float | None = None


def hammer_pulse(
    t: Array,
    kind: Literal["half-sine", "eq1"] = "half-sine",
    amplitude: float = 10e3,
    t_hit: float = 0.1,
    duration: float = 0.003,
) -> Array:
    """Hammer force [N], positive downwards.

    Parameters
    ----------
    t : array
        Times [s].
    kind : {'half-sine', 'eq1'}
        ``half-sine``: A sin(pi (t - t_hit) / duration) for t_hit <= t <= t_hit + duration;
        ``eq1``: the decay pulse of Eq. (1), A exp(-(t - t_hit) / duration) (``duration`` = t_d).
    amplitude : float
        Peak force A [N].
    t_hit : float
        Onset [s].
    duration : float
        Contact time of the half-sine, or t_d of Eq. (1) [s].
    """
    if kind == "half-sine":
        on = (t >= t_hit) & (t <= t_hit + duration)
        out = np.zeros_like(t)
        out[on] = amplitude * np.sin(np.pi * (t[on] - t_hit) / duration)
        return out
    if kind == "eq1":
        return decay_pulse(t, amplitude, t_hit, duration)
    raise CalibrationError(f"pulse = {kind!r}: must be 'half-sine' or 'eq1'")


def _check_hammer_test(fs: float, duration: float, hit_times: Sequence[float], pulse_duration: float,
                       amplitude: float, oversample: int, what: str) -> None:
    """The acquisition settings of a hammer test: rate, length, hits inside the record, a resolved pulse."""
    fs = positive(f"{what}: fs", fs, CalibrationError, "Hz")
    duration = positive(f"{what}: duration", duration, CalibrationError, "s")
    integer(f"{what}: oversample", oversample, 1, error=CalibrationError)
    if duration * fs < 2:
        raise CalibrationError(f"{what}: duration = {duration:g} s at fs = {fs:g} Hz: fewer than 2 samples")
    td = positive(f"{what}: pulse_duration", pulse_duration, CalibrationError, "s")
    dt = 1.0 / (fs * oversample)
    if td < 4 * dt:
        raise CalibrationError(f"{what}: pulse_duration = {td:g} s: shorter than 4 simulation steps of "
                               f"1 / (fs oversample) = {dt:g} s; raise oversample")
    positive(f"{what}: amplitude", amplitude, CalibrationError, "N")
    if len(hit_times) == 0:
        raise CalibrationError(f"{what}: hit_times is empty: at least one hit")
    for th in hit_times:
        if not (math.isfinite(th) and 0.0 <= th and th + td <= duration):
            raise CalibrationError(f"{what}: hit at {th!r} s: the pulse (onset to onset + pulse_duration) must lie "
                                   f"in the record [0, {duration:g}] s")


def _spec(topic: str, quantity: str, units: str, location: str, index: int, name: str | None = None,
          field: str | None = None) -> ChannelSpec:
    return ChannelSpec(
        name=name or topic,
        topic=topic,
        quantity=quantity,  # type: ignore[arg-type]
        units=units,
        factor=unit_factor(quantity, units, topic),
        location=location,  # type: ignore[arg-type]
        index=index,
        field=field,
    )


def _area_topic(j: int) -> str:
    return f"/soil/area_{'p' if j >= 0 else 'm'}{abs(j):02d}"


def _acquire(t_fine: Array, signals: Array, oversample: int) -> tuple[Array, Array]:
    """Anti-alias filter and decimate every column alike (linear-phase FIR, no delay)."""
    if oversample == 1:
        return t_fine, signals
    out = resample_poly(signals, 1, oversample, axis=0)
    t = t_fine[0] + np.arange(out.shape[0]) * (t_fine[1] - t_fine[0]) * oversample
    return t, out


def _newmark(M: Any, C: Any, K: Any, dt: float, F: Array, dofs: Sequence[int], what: str) -> Array:
    """Displacement, velocity and acceleration of ``dofs`` (3, n_t, n_dofs), from rest."""
    integ = NewmarkLinear(M, C, K, dt)
    n_t = F.shape[0]
    out = np.zeros((3, n_t, len(dofs)))
    d = np.asarray(dofs)
    for k in range(1, n_t):
        integ.step(F[k])
        out[0, k], out[1, k], out[2, k] = integ.u[d], integ.v[d], integ.a[d]
    if not np.all(np.isfinite(out)):
        raise CalibrationError(f"{what}: the simulation diverged")
    return out


def _hammer_test(
    M: Any,
    C: Any,
    K: Any,
    force_dof: int,
    dofs: Sequence[int],
    quantity: str,
    fs: float,
    duration: float,
    hit_times: Sequence[float],
    pulse: Literal["half-sine", "eq1"],
    pulse_duration: float,
    amplitude: float,
    oversample: int,
    what: str,
) -> tuple[Array, Array, dict[str, Any]]:
    """Hammer hits on ``force_dof`` of the system (M, C, K), integrated and acquired.

    Parameters
    ----------
    M, C, K : matrices
        Mass [kg], damping [N s/m] and stiffness [N/m] matrices (n_dof, n_dof).
    force_dof : int
        The hit DOF.
    dofs : sequence of int
        DOFs with a sensor.
    quantity : {'displacement', 'velocity', 'acceleration'}
        What the sensors measure.
    fs, duration, hit_times, pulse, pulse_duration, amplitude, oversample
        As in :func:`simulate_impact` ([Hz], [s], [s], -, [s], [N], -).
    what : str
        Name of the test for the divergence error.

    Returns
    -------
    t : (n,) array
        Sample times [s].
    data : (n, 1 + len(dofs)) array
        Force [N], then the sensors (SI units), after the anti-alias filter.
    settings : dict
        The acquisition settings for ``truth.yaml`` (``fs_hz`` ... ``simulation``).

    Raises
    ------
    CalibrationError
        A rate, length, pulse or amplitude that is not finite and positive,
        ``oversample`` not an integer >= 1, a hit whose pulse is not inside
        the record, a pulse shorter than 4 simulation steps, a diverged
        simulation.
    """
    _check_hammer_test(fs, duration, hit_times, pulse_duration, amplitude, oversample, what)
    dt = 1.0 / (fs * oversample)
    n_t = int(round(duration * fs)) * oversample
    t = np.arange(n_t, dtype=np.float64) * dt
    f = np.zeros_like(t)
    for th in hit_times:
        f += hammer_pulse(t, pulse, amplitude, th, pulse_duration)
    F = np.zeros((n_t, M.shape[0]))
    F[:, force_dof] = f
    uva = _newmark(M, C, K, dt, F, dofs, what)
    q = {"displacement": 0, "velocity": 1, "acceleration": 2}[quantity]
    ts, data = _acquire(t, np.column_stack([f, uva[q]]), oversample)
    settings = {
        "fs_hz": fs,
        "duration_s": duration,
        "hit_times_s": list(hit_times),
        "pulse": pulse,
        "pulse_duration_s": pulse_duration,
        "amplitude_N": amplitude,
        "simulation": f"Newmark average acceleration, dt = {dt:g} s, anti-alias FIR + decimation by {oversample}",
    }
    return ts, data, settings


def simulate_impact(
    soil: SoilParams | None = None,
    n_areas: int = 41,
    measured: Sequence[int] | None = None,
    quantity: Literal["displacement", "velocity", "acceleration"] = "velocity",
    units: str | None = None,
    fs: float = 1000.0,
    duration: float = 1.0,
    hit_times: Sequence[float] = (0.2,),
    pulse: Literal["half-sine", "eq1"] = "half-sine",
    pulse_duration: float = 0.003,
    amplitude: float = 10e3,
    oversample: int = 40,
    coupling2: float = 0.0,
    skew: float = 0.0,
) -> SyntheticRecord:
    """Noise-free soil impact test on a CLM chain (Eq. 7–8) of ``n_areas`` areas.

    Parameters
    ----------
    soil : SoilParams, optional
        Truth (default: Mevergnies, Table 1, CLM).
    n_areas : int
        Areas of the chain 2n + 1; the hammer hits the centre one (area 0).
    measured : sequence of int, optional
        Area indices with a sensor (default: all, -n..n).
    quantity : {'displacement', 'velocity', 'acceleration'}
        What the sensors measure (geophones: velocity).
    units : str, optional
        Recorded unit (default SI: m, m/s, m/s^2).
    fs : float
        Sample rate [Hz].
    duration : float
        Record length [s].
    hit_times : sequence of float
        Hammer hits [s] (onsets).
    pulse : {'half-sine', 'eq1'}
        Pulse shape (:func:`hammer_pulse`).
    pulse_duration : float
        Contact time (half-sine) or t_d (Eq. 1) [s].
    amplitude : float
        Peak force [N].
    oversample : int
        Simulation steps per output sample. The Newmark average-acceleration
        rule is the bilinear transform: it evaluates the chain at the warped
        frequency (2 / dt) tan(w dt / 2), w (1 + (w dt)^2 / 12), which reads
        as a larger m_f: +0.19 % at 1 kHz with 10 steps per sample, +0.012 %
        with 40 (the default; issue 24's bound on the noise-free bias is
        0.02 %).
    coupling2 : float
        Second-neighbour coupling, a fraction of k_c and d_c between areas
        i and i +- 2 (springs and dampers like the first-neighbour ones):
        a truth **outside the CLM family** for testing the model-adequacy
        check (issue 24) [-]; 0: the CLM chain of Eq. (7)-(8).
    skew : float
        Delay of every response channel behind the force channel [s] (a
        timing error of the acquisition, band-limited shift after the
        anti-alias filter; issue 24); 0: simultaneous channels.
    """
    soil = soil or load_soil("mevergnies")
    n = n_areas // 2
    measured = list(range(-n, n + 1)) if measured is None else list(measured)
    if any(abs(j) > n for j in measured):
        raise CalibrationError(f"measured areas {measured}: must lie in -{n}..{n}")
    units = units or {"displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}[quantity]
    M, C, K = chain_matrices(soil, n_areas)
    finite("impact simulation: skew", skew, CalibrationError)
    if finite("impact simulation: coupling2", coupling2, CalibrationError):
        L2 = _second_neighbour_laplacian(n_areas)
        K = K + coupling2 * soil.kc * L2
        C = C + coupling2 * soil.dc * L2
    ts, data, acquisition = _hammer_test(M, C, K, n, [n + j for j in measured], quantity, fs, duration, hit_times,
                                         pulse, pulse_duration, amplitude, oversample, "impact simulation")
    if skew:
        data[:, 1:] = fractional_delay(data[:, 1:], skew * fs)
    fspec = _spec("/hammer/force", "force", "N", "area", 0)
    force = Signal(fspec, ts, data[:, 0])
    resp = tuple(
        Signal(_spec(_area_topic(j), quantity, units, "area", j), ts, data[:, 1 + k]) for k, j in enumerate(measured)
    )
    settings = {
        "n_areas": n_areas,
        "measured_areas": (
            f"{min(measured)}..{max(measured)}"
            if measured == list(range(min(measured), max(measured) + 1))
            else measured
        ),
        "quantity": quantity,
        "units": units,
        **acquisition,
    }
    if coupling2:
        settings["coupling2"] = coupling2
    if skew:
        settings["skew_s"] = skew
    return SyntheticRecord("impact", force, resp, None, {"soil": soil.to_dict()}, settings)


def _second_neighbour_laplacian(n: int) -> Any:
    """Laplacian of the graph linking areas i and i + 2 (sparse, n x n)."""
    import scipy.sparse as sp

    deg = np.full(n, 2.0)
    deg[[0, 1, -2, -1]] = 1.0
    off = -np.ones(max(n - 2, 0))
    return sp.diags([off, deg, off], [-2, 0, 2], shape=(n, n), format="csr")


def simulate_receptance(
    params: ModelParams | None = None,
    n_sleepers: int = 41,
    rail_sleepers: Sequence[int] = (0, 1, 2, 3, 4),
    sleeper_sleepers: Sequence[int] = (0,),
    quantity: Literal["displacement", "velocity", "acceleration"] = "acceleration",
    units: str | None = None,
    fs: float = 2000.0,
    duration: float = 0.6,
    hit_times: Sequence[float] = (0.1,),
    pulse: Literal["half-sine", "eq1"] = "half-sine",
    pulse_duration: float = 0.0008,
    amplitude: float = 20e3,
    oversample: int = 40,
) -> SyntheticRecord:
    """Noise-free rail receptance (hammer) test on the assembled track (paper Sec. 5).

    The hammer hits the rail above the central sleeper (sleeper 0); sensors
    sit on the rail above sleepers ``rail_sleepers`` and on sleepers
    ``sleeper_sleepers`` (indices relative to the hit sleeper).

    Parameters
    ----------
    params : ModelParams, optional
        Truth (default: Mevergnies track, Table 2, on the Mevergnies CLM soil, Table 1).
    n_sleepers : int
        Sleepers of the model track (odd; the hit one at the centre).
    rail_sleepers, sleeper_sleepers : sequence of int
        Instrumented positions.
    quantity, units, fs, duration, hit_times, pulse, pulse_duration, amplitude
        As in :func:`simulate_impact` (accelerometers by default).
    oversample : int
        Simulation steps per output sample; 40 keeps the Newmark frequency
        error f'/f - 1 = (pi f dt)^2 / 3 below 2e-5 at 500 Hz (sharp track
        resonances turn a larger one into percent errors of |H|).
    """
    params = params or load_model("mevergnies", "mevergnies", "clm")
    system = assemble(params, n_sleepers)
    c = n_sleepers // 2
    units = units or {"displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}[quantity]
    for j in [*rail_sleepers, *sleeper_sleepers]:
        if not 0 <= c + j < n_sleepers:
            raise CalibrationError(f"sleeper {j}: outside the {n_sleepers}-sleeper model track")
    dofs = [int(system.rail_w[system.sleeper_node[c + j]]) for j in rail_sleepers]
    dofs += [int(system.sleeper_dof[c + j]) for j in sleeper_sleepers]
    ts, data, acquisition = _hammer_test(system.M, system.C, system.K, int(system.rail_w[system.sleeper_node[c]]),
                                         dofs, quantity, fs, duration, hit_times, pulse, pulse_duration, amplitude,
                                         oversample, "receptance simulation")
    force = Signal(_spec("/track/hammer/force", "force", "N", "rail", 0), ts, data[:, 0])
    specs = [_spec(f"/track/rail_s{j:02d}/{quantity}", quantity, units, "rail", j) for j in rail_sleepers]
    specs += [_spec(f"/track/sleeper_s{j:02d}/{quantity}", quantity, units, "sleeper", j) for j in sleeper_sleepers]
    resp = tuple(Signal(sp, ts, data[:, 1 + k]) for k, sp in enumerate(specs))
    settings = {
        "n_sleepers": n_sleepers,
        "rail_sleepers": list(rail_sleepers),
        "sleeper_sleepers": list(sleeper_sleepers),
        "quantity": quantity,
        "units": units,
        **acquisition,
    }
    return SyntheticRecord("receptance", force, resp, None, params.to_dict(), settings)


def simulate_passby(
    params: ModelParams | None = None,
    sleepers: Sequence[int] = (0, 1),
    fields: Sequence[str] = ("rail_deflection", "sleeper_displacement"),
    speed: float = 25.0,
    axle_offsets: Sequence[float] = (0.0, 2.5),
    static_load: float = 80e3,
    dynamic_amplitude: float = 0.1,
    dynamic_frequency: float = 9.0,
    run_in: float = 12.0,
    fs: float = 1000.0,
    dt: float = 1e-4,
) -> SyntheticRecord:
    """Noise-free pass-by: wheel loads moving over instrumented sleepers (TrackSimulator).

    Parameters
    ----------
    params : ModelParams, optional
        Truth (default: Mevergnies track on the Mevergnies CLM soil).
    sleepers : sequence of int
        Instrumented global sleeper indices (sleeper ``g`` at ``x = g d``).
    fields : sequence of str
        Measured ``SleeperResponse`` fields (``rail_deflection``,
        ``sleeper_displacement``, ``area_displacement``).
    speed : float
        Train speed [m/s].
    axle_offsets : sequence of float
        Wheel positions behind the first wheel [m].
    static_load : float
        Wheel load [N].
    dynamic_amplitude, dynamic_frequency : float
        Relative amplitude [-] and frequency [Hz] of a load fluctuation
        (wheel bounce), which makes the damping visible.
    run_in : float
        Distance from the first wheel's start to the first sleeper, and
        from the last wheel to the end [m].
    fs : float
        Output (recording) rate [Hz].
    dt : float
        Simulation step [s] (an integer fraction of 1 / fs).

    Raises
    ------
    CalibrationError
        Unknown fields, no sleeper or wheel, a speed, rate, step or load that
        is not finite and positive, a negative run-in or axle offset, a
        ``dt`` that does not divide 1 / fs.
    """
    params = params or load_model("mevergnies", "mevergnies", "clm")
    what = "pass-by simulation"
    if any(f not in _FIELD_LOCATION for f in fields):
        raise CalibrationError(f"fields {list(fields)}: each must be one of {', '.join(_FIELD_LOCATION)}")
    if len(sleepers) == 0 or len(axle_offsets) == 0:
        raise CalibrationError(f"{what}: sleepers {list(sleepers)}, axle_offsets {list(axle_offsets)}: "
                               "at least one of each")
    speed = positive(f"{what}: speed", speed, CalibrationError, "m/s")
    fs = positive(f"{what}: fs", fs, CalibrationError, "Hz")
    dt = positive(f"{what}: dt", dt, CalibrationError, "s")
    positive(f"{what}: static_load", static_load, CalibrationError, "N")
    finite(f"{what}: dynamic_amplitude", dynamic_amplitude, CalibrationError)
    nonnegative(f"{what}: dynamic_frequency", dynamic_frequency, CalibrationError, "Hz")
    nonnegative(f"{what}: run_in", run_in, CalibrationError, "m")
    for off in axle_offsets:
        nonnegative(f"{what}: axle offset", off, CalibrationError, "m")
    every = int(round(1.0 / (fs * dt)))
    if abs(every * dt * fs - 1.0) > 1e-9:
        raise CalibrationError(f"dt = {dt:g} s: must divide the output interval 1/fs = {1 / fs:g} s")
    d = params.track.spacing
    offs = np.asarray(axle_offsets, dtype=float)
    x0 = min(sleepers) * d - run_in
    x1 = max(sleepers) * d + run_in + float(offs.max())
    T = (x1 - x0) / speed
    n_t = int(round(T / dt))
    t = np.arange(n_t + 1, dtype=np.float64) * dt
    P = x0 - offs[None, :] + speed * t[:, None]
    phase = 1.3 * np.arange(offs.size)
    F = static_load * (1.0 + dynamic_amplitude * np.sin(2 * np.pi * dynamic_frequency * t[:, None] + phase[None, :]))
    specs = [
        _spec("/clm/sleeper_response", "displacement", "m", _FIELD_LOCATION[fl], g, name=f"{fl}[{g}]", field=fl)
        for fl in fields for g in sleepers
    ]
    kk = np.arange(0, n_t + 1, every)
    loads = WheelLoadRecord(t=t, wheel_ids=np.arange(offs.size, dtype=np.int64), positions=P, forces=F)
    tt = t[kk]
    out = simulate_channels(params, loads, specs, tt, dt)
    resp = tuple(Signal(sp, tt, out[:, k]) for k, sp in enumerate(specs))
    loads = WheelLoadRecord(t=tt, wheel_ids=loads.wheel_ids, positions=P[kk], forces=F[kk])
    settings = {
        "sleepers": list(sleepers),
        "fields": list(fields),
        "speed_m_per_s": speed,
        "axle_offsets_m": offs.tolist(),
        "static_load_N": static_load,
        "dynamic_amplitude": dynamic_amplitude,
        "dynamic_frequency_hz": dynamic_frequency,
        "fs_hz": fs,
        "simulation": f"TrackSimulator (Newmark average acceleration), dt = {dt:g} s, fixed window",
    }
    return SyntheticRecord("passby", None, resp, loads, params.to_dict(), settings)


def add_noise(rec: SyntheticRecord, snr_db: float, seed: int = 0, snr_window: float = 0.1) -> SyntheticRecord:
    """Add white Gaussian noise to every channel at the given SNR.

    sigma = rms_active / 10^(snr_db / 20), rms_active the rms of the clean
    channel over ``snr_window`` seconds from each hit (impact, receptance), or
    over the whole record (pass-by). The force channel gets noise too.
    """
    rng = np.random.default_rng(seed)
    hits = rec.settings.get("hit_times_s")

    def noisy(sig: Signal) -> Signal:
        if hits:
            mask = np.zeros(sig.t.size, dtype=bool)
            for th in hits:
                mask |= (sig.t >= th) & (sig.t < th + snr_window)
            active = sig.values[mask]
        else:
            active = sig.values - np.mean(sig.values)
        rms = float(np.sqrt(np.mean(active**2)))
        sigma = rms / 10 ** (snr_db / 20)
        return replace(sig, values=sig.values + rng.normal(0.0, sigma, sig.values.size))

    settings = dict(rec.settings)
    settings["noise"] = {
        "snr_db": snr_db,
        "seed": seed,
        "definition": (
            "white Gaussian noise on every channel (force included), sigma = rms_active / 10^(SNR/20), rms_active = "
            + (f"rms of the clean channel over {snr_window:g} s from each hit" if hits else "rms of the clean record")
        ),
    }
    return replace(
        rec,
        force=noisy(rec.force) if rec.force is not None else None,
        responses=tuple(noisy(s) for s in rec.responses),
        settings=settings,
        snr_db=snr_db,
    )
