"""Soil impact-test bags from the rigorous half-space reference (data the CLM did not generate).

(Was ``clm_core.halfspace.impact_bag``; it sits above :mod:`clm_core.halfspace`
and :mod:`clm_core.calibration`, which do not import each other.)

:func:`write_reference_impact_bag` writes the response of the 2n + 1
contact areas of a soil profile to the decay pulse of Eq. (1) (Kouroussis et
al. 2011), computed from the rigorous model (Green's functions + boundary
elements, :mod:`clm_core.halfspace.bem`; time histories by
:func:`clm_core.halfspace.impact.impact_response`), as a soil impact test
bag in exactly the format of the calibration bags
(:mod:`clm_core.synthetic.writer`: same topics, message types,
channel map, noise definition and writer). Instead of ``truth.yaml`` the
bag directory holds ``reference.yaml``: the profile, the rigorous model's
settings and the CLM parameters fitted directly from the rigorous sums of
Eq. (16) and (18) (:func:`clm_core.halfspace.calibrate.calibrate_profile`),
for comparison with what ``clm calibrate`` recovers from the bag.

Route
-----
1. Rigorous flexibility X_j(f) / F of the row for a unit force on the centre
   area, on a uniform grid 0..f_max (default 0..150 Hz, 1 Hz: record length
   T = 1 / df = 1 s), and the direct CLM fit of its sums (stated band, norm).
2. Time histories by inverse FFT (:func:`~clm_core.halfspace.impact.impact_response`)
   at the output rate ``fs`` (default 1 kHz, the calibration bags' rate;
   zero padding above f_max).
3. Band limit of the pulse (``shaping``). The flexibility is known only up
   to f_max, so the Eq. (1) pulse must be low-passed:

   - ``"gaussian"`` (default): a Gaussian taper exp(-(f / f_g)^2), f_g chosen
     so that the taper is ``taper_db`` (40 dB) down at f_max (f_g = 70 Hz for
     150 Hz), delayed by 6 of its time standard deviations (19 ms) so that it
     is causal to 1e-8, times a first-order pole at f_max
     (``impact_response(order=1, cutoff=1)``). Its impulse response is
     positive, so the hammer force never pulls on the soil: with f_max =
     150 Hz it is a pulse of 8 ms at half height, peak 0.11 A at t0 + 21 ms,
     whose spectrum (Eq. 1 included) is -3.4 / -13.4 / -40.6 dB at
     40 / 80 / 141 Hz (calibrate in 0-80 Hz, the paper's range for td = 1 ms);
   - ``"butterworth"``: :func:`~clm_core.halfspace.impact.impact_response`'s
     own default (8th-order Butterworth at f_max / 2). Its force rings with
     a negative lobe of 32 % of the peak; the calibration's force window
     (cut 4 ms after the force first drops below 2 % of its peak) truncates
     that lobe and biases the transfer functions (a CLM-generated control
     record is then fitted with an rms residual of 7 instead of 1). Use it
     only with a long force window (``window: {force_margin: 0.1}``).

   The applied force is computed through the same inverse FFT as the
   responses (the taper is an extra "area" column of the flexibility), so
   force and responses are an exact input-output pair of the rigorous model.
4. Acquisition and noise as :mod:`clm_core.synthetic.records`: channels
   ``/hammer/force`` (``geometry_msgs/msg/WrenchStamped``) and
   ``/soil/area_m20`` .. ``/soil/area_p20`` (``Vector3Stamped``, geophones:
   vertical velocity [m/s]), white Gaussian noise on every channel, force
   included, at SNR = 20 log10(rms over 0.1 s from the pulse onset / sigma)
   (:func:`~clm_core.synthetic.records.add_noise`), written by
   :func:`~clm_core.synthetic.writer.write_record` (mcap + zstd, or sqlite3).

``model="clm"`` sends the CLM chain fitted from the rigorous sums through the
identical route: a control record that the CLM *can* explain, with the same
pulse, sampling and noise.

Conventions: SI units; force, displacement and velocity positive downwards;
time dependence exp(+i w t).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypedDict, Unpack

import numpy as np
import yaml
from numpy.typing import NDArray

from clm_core.calibration.errors import CalibrationError
from clm_core.calibration.signals import Signal
from clm_core.errors import ParameterError
from clm_core.halfspace.calibrate import SoilCalibration, calibrate_profile
from clm_core.halfspace.impact import ImpactResponse, impact_response
from clm_core.profile import SoilProfile, load_profile
from clm_core.soil.chain import chain_frequency_response
from clm_core.synthetic.records import SyntheticRecord, _area_topic, _spec, add_noise
from clm_core.synthetic.writer import BagFormat, Storage, Style, plain, write_record

__all__ = [
    "RecordOptions",
    "ReferenceImpactBag",
    "RigorousReference",
    "reference_impact_record",
    "rigorous_reference",
    "write_reference_impact_bag",
]

Shaping = Literal["gaussian", "butterworth"]
Source = Literal["rigorous", "clm"]
Quantity = Literal["displacement", "velocity"]


class RecordOptions(TypedDict, total=False):
    """Keywords of :func:`reference_impact_record` passed on by :func:`write_reference_impact_bag` (its defaults)."""

    source: Source
    quantity: Quantity
    fs: float
    amplitude: float
    t0: float
    td: float
    shaping: Shaping
    taper_db: float

#: Default rigorous sweep: 0..150 Hz by 1 Hz (record length 1 s).
DEFAULT_SWEEP_MAX = 150.0
DEFAULT_DF = 1.0
#: Delay of the Gaussian taper in units of its time standard deviation (causal to exp(-18)).
_GAUSS_DELAY_SIGMAS = 6.0


@dataclass(frozen=True)
class RigorousReference:
    """Rigorous row flexibility and its direct CLM fit, as needed to write a bag.

    Attributes
    ----------
    freqs : ndarray, shape (nf,)
        Uniform frequency grid from 0 [Hz].
    flexibility : ndarray of complex, shape (nf, n_areas)
        X_j / F for a unit force on the centre area [m/N].
    positions : ndarray, shape (n_areas,)
        Area positions along the track [m], 0 at the loaded area.
    summary : mapping
        :meth:`clm_core.halfspace.calibrate.SoilCalibration.summary` (profile,
        geometry, conventions, direct CLM fit with band, norm and residuals,
        sums at 0/10/50/100 Hz, single area vs Eq. (6)), possibly with
        ``preset_clm`` (the paper's values of the preset).
    """

    freqs: NDArray[np.float64]
    flexibility: NDArray[np.complex128]
    positions: NDArray[np.float64]
    summary: Mapping[str, Any]

    @property
    def n_areas(self) -> int:
        """Number of areas 2n + 1."""
        return int(self.flexibility.shape[1])

    @property
    def clm_fit(self) -> dict[str, float]:
        """The CLM parameters fitted directly from the rigorous sums {mf, kf, df, kc, dc} [SI]."""
        fit = self.summary["fit"]
        return {k: float(fit[k]) for k in ("mf", "kf", "df", "kc", "dc")}

    @classmethod
    def from_calibration(cls, cal: SoilCalibration, preset_clm: Mapping[str, float] | None = None) -> RigorousReference:
        """From a :class:`~clm_core.halfspace.calibrate.SoilCalibration` (its centre column and summary)."""
        summary = cal.summary()
        if preset_clm is not None:
            summary["preset_clm"] = dict(preset_clm)
        return cls(
            freqs=np.asarray(cal.freqs, dtype=np.float64),
            flexibility=np.asarray(cal.row.centre_column, dtype=np.complex128),
            positions=np.asarray(cal.row.positions, dtype=np.float64),
            summary=summary,
        )

    @classmethod
    def from_soil_calibrate_output(cls, directory: str | Path) -> RigorousReference:
        """From the ``sweep.npz`` and ``summary.json`` that ``clm soil-calibrate --out DIR`` writes."""
        d = Path(directory)
        try:
            with np.load(d / "sweep.npz") as z:
                freqs = np.asarray(z["freqs"], dtype=np.float64)
                col = np.asarray(z["centre_column"], dtype=np.complex128)
                pos = np.asarray(z["positions"], dtype=np.float64)
            summary = json.loads((d / "summary.json").read_text(encoding="utf-8"))
        except (OSError, KeyError, ValueError) as exc:
            raise ParameterError(
                f"{d}: not a complete 'clm soil-calibrate' output (sweep.npz, summary.json): {exc}"
            ) from exc
        return cls(freqs=freqs, flexibility=col, positions=pos, summary=summary)


@dataclass(frozen=True)
class ReferenceImpactBag:
    """A written reference impact bag.

    Attributes
    ----------
    path : Path
        rosbag2 directory.
    channels : Path
        Channel map (``channels.yaml`` in the bag directory).
    reference : Path
        ``reference.yaml`` in the bag directory.
    record : SyntheticRecord
        What was written (SI units, noise included).
    response : ImpactResponse
        Noise-free time histories from :func:`~clm_core.halfspace.impact.impact_response`
        (with the taper column last for ``shaping="gaussian"``).
    rigorous : RigorousReference
        The rigorous flexibility and its direct CLM fit.
    """

    path: Path
    channels: Path
    reference: Path
    record: SyntheticRecord
    response: ImpactResponse
    rigorous: RigorousReference


def _preset_clm(profile: str | Path) -> dict[str, float] | None:
    """The CLM values (paper tables) of a soil preset or preset-format file, if it has any."""
    from clm_core.errors import ClmError
    from clm_core.params import load_soil

    try:
        soil = load_soil(profile)
    except (ClmError, OSError, ValueError, TypeError):
        return None
    d = soil.to_dict()
    return {k: float(d[k]) for k in ("mf", "kf", "df", "kc", "dc") if k in d}


def rigorous_reference(
    profile: str | Path | SoilProfile,
    *,
    n_areas: int = 41,
    spacing: float = 0.6,
    sweep_max: float = DEFAULT_SWEEP_MAX,
    df: float = DEFAULT_DF,
    fmin: float = 0.0,
    fmax: float = 80.0,
    norm: Literal["ls", "relative"] = "ls",
) -> RigorousReference:
    """Run the rigorous model and the direct CLM fit (:func:`~clm_core.halfspace.calibrate.calibrate_profile`).

    Parameters
    ----------
    profile : str, Path or SoilProfile
        Soil preset name, profile file or profile.
    n_areas : int
        Areas 2n + 1 (odd).
    spacing : float
        Sleeper spacing d [m].
    sweep_max, df : float
        Sweep 0..sweep_max by df [Hz]; the record length is 1 / df.
    fmin, fmax : float
        Band of the direct CLM fit [Hz].
    norm : {"ls", "relative"}
        Norm of the direct CLM fit.

    Returns
    -------
    RigorousReference
    """
    prof = profile if isinstance(profile, SoilProfile) else load_profile(profile)
    if not (df > 0 and math.isfinite(df) and sweep_max > 0):
        raise ParameterError(f"df = {df}, sweep_max = {sweep_max}: need positive values [Hz]")
    freqs = np.arange(0.0, sweep_max + 0.5 * df, df)
    if freqs[-1] > sweep_max + 1e-9:
        freqs = freqs[:-1]
    cal = calibrate_profile(prof, freqs=freqs, fmin=fmin, fmax=fmax, norm=norm, n_areas=n_areas, spacing=spacing)
    preset = None if isinstance(profile, SoilProfile) else _preset_clm(profile)
    return RigorousReference.from_calibration(cal, preset)


def reference_impact_record(
    reference: RigorousReference,
    *,
    source: Source = "rigorous",
    quantity: Quantity = "velocity",
    fs: float = 1000.0,
    amplitude: float = 10e3,
    t0: float = 0.2,
    td: float = 0.001,
    shaping: Shaping = "gaussian",
    taper_db: float = 40.0,
) -> tuple[SyntheticRecord, ImpactResponse]:
    """Noise-free soil impact record of the row under the Eq. (1) pulse on the centre area.

    Parameters
    ----------
    reference : RigorousReference
        Rigorous flexibility (uniform grid from 0 Hz) and direct CLM fit.
    source : {"rigorous", "clm"}
        ``rigorous``: the rigorous flexibility; ``clm``: the CLM chain
        (same number of areas) with the parameters fitted directly from the
        rigorous sums, through the identical route (control record).
    quantity : {"displacement", "velocity"}
        What the sensors measure (geophones: velocity).
    fs : float
        Sample rate [Hz]; fs / df must be an even integer and fs >= 2 f_max.
    amplitude : float
        A of Eq. (1) [N] (10 kN, as the calibration bags' hammer).
    t0 : float
        Onset of the Eq. (1) pulse [s] (0.2 s leaves a noise stretch before the hit).
    td : float
        Decay time of Eq. (1) [s] (the paper: 1 ms).
    shaping : {"gaussian", "butterworth"}
        Band limit of the pulse (module docstring).
    taper_db : float
        Attenuation of the Gaussian taper at f_max [dB] (> 0).

    Returns
    -------
    SyntheticRecord
        Force and response channels in the calibration bags' layout, with
        the generator settings (no noise).
    ImpactResponse
        The time histories as returned by :func:`~clm_core.halfspace.impact.impact_response`.
    """
    f = np.asarray(reference.freqs, dtype=np.float64)
    H = np.asarray(reference.flexibility, dtype=np.complex128)
    n = reference.n_areas
    if n % 2 == 0:
        raise ParameterError(f"{n} areas: need an odd number 2n + 1 (loaded area at the centre)")
    if f.size < 8 or f[0] != 0.0:
        raise ParameterError("reference.freqs: need a uniform grid of >= 8 frequencies starting at 0 Hz")
    df = float(f[1] - f[0])
    f_max = float(f[-1])
    if quantity not in ("displacement", "velocity"):
        raise ParameterError(f"quantity = {quantity!r}: must be 'displacement' or 'velocity'")
    if source not in ("rigorous", "clm"):
        raise ParameterError(f"source = {source!r}: must be 'rigorous' or 'clm'")
    if shaping not in ("gaussian", "butterworth"):
        raise ParameterError(f"shaping = {shaping!r}: must be 'gaussian' or 'butterworth'")
    ratio = fs / df
    if not (fs > 0 and abs(ratio - round(ratio)) < 1e-9 * ratio and round(ratio) % 2 == 0):
        raise ParameterError(f"fs = {fs:g} Hz: fs / df (df = {df:g} Hz) must be an even integer")
    if fs < 2.0 * f_max * (1 - 1e-12):
        raise ParameterError(f"fs = {fs:g} Hz: must be >= 2 f_max = {2 * f_max:g} Hz")
    if not taper_db > 0:
        raise ParameterError(f"taper_db = {taper_db:g}: must be > 0 [dB]")
    if source == "clm":
        H = chain_frequency_response(dict(reference.clm_fit), n, f)
    # n_half = ceil(oversample f_max / df) + 1 must equal fs / (2 df) + 1 exactly
    oversample = fs / (2.0 * f_max) * (1.0 - 1e-12)
    settings_pulse: dict[str, Any] = {
        "equation": "Eq. (1): A exp(-(t - t0) / td) for t >= t0",
        "amplitude_N": amplitude,
        "t0_s": t0,
        "td_s": td,
        "shaping": shaping,
    }
    if shaping == "gaussian":
        a = f_max / math.sqrt(taper_db / 20.0 * math.log(10.0))
        sig_t = 1.0 / (math.sqrt(2.0) * math.pi * a)
        tau = _GAUSS_DELAY_SIGMAS * sig_t
        G = np.exp(-((f / a) ** 2)) * np.exp(-2j * math.pi * f * tau)
        r = impact_response(
            f,
            np.column_stack([H * G[:, None], G]),
            amplitude=amplitude,
            t0=t0,
            td=td,
            cutoff=1.0,
            order=1,
            oversample=oversample,
        )
        force = r.displacement[-1]
        motion = (r.displacement if quantity == "displacement" else r.velocity)[:-1]
        settings_pulse.update(
            {
                "taper": "exp(-(f/f_g)^2) exp(-i 2 pi f tau), times a first-order low-pass pole at f_max",
                "taper_f_g_hz": a,
                "taper_db_at_fmax": taper_db,
                "taper_delay_s": tau,
                "lowpass": {"order": 1, "cutoff_fraction_of_fmax": 1.0},
            }
        )
    else:
        r = impact_response(f, H, amplitude=amplitude, t0=t0, td=td, oversample=oversample)
        force = r.force
        motion = r.displacement if quantity == "displacement" else r.velocity
        settings_pulse["lowpass"] = {"order": 8, "cutoff_fraction_of_fmax": 0.5, "kind": "causal Butterworth"}
        settings_pulse["warning"] = (
            "the band-limited force rings (negative lobe ~32 % of the peak): calibrate with a long force window, "
            "e.g. options window: {force_margin: 0.1}"
        )
    t = r.time
    if abs((t[1] - t[0]) * fs - 1.0) > 1e-9:  # pragma: no cover - guarded by the checks above
        raise ParameterError(f"internal: time step {t[1] - t[0]:g} s differs from 1/fs")
    c = n // 2
    units = "m" if quantity == "displacement" else "m/s"
    force_sig = Signal(_spec("/hammer/force", "force", "N", "area", 0), t, np.asarray(force, dtype=np.float64))
    resp = tuple(
        Signal(_spec(_area_topic(j), quantity, units, "area", j), t, np.asarray(motion[c + j], dtype=np.float64))
        for j in range(-c, c + 1)
    )
    geo = reference.summary.get("geometry", {})
    settings: dict[str, Any] = {
        "n_areas": n,
        "measured_areas": f"{-c}..{c}",
        "quantity": quantity,
        "units": units,
        "fs_hz": fs,
        "duration_s": float(t.size / fs),
        "hit_times_s": [t0],
        "pulse": "eq1-bandlimited",
        "pulse_duration_s": td,
        "amplitude_N": amplitude,
        "pulse_detail": settings_pulse,
        "source": source,
        "simulation": (
            ("rigorous half-space BEM flexibility" if source == "rigorous" else "CLM chain fitted to the rigorous sums")
            + f", 0..{f_max:g} Hz by {df:g} Hz, inverse FFT (clm_core.halfspace.impact.impact_response), "
            f"zero padding to fs = {fs:g} Hz"
        ),
        "spacing_m": geo.get("spacing"),
        "precursor": r.precursor,
        "wrap_residual": r.wrap_residual,
    }
    truth: dict[str, Any] = {"reference": "reference.yaml (rigorous half-space; no CLM truth)"}
    if source == "clm":
        truth = {"soil": {"model": "clm", **reference.clm_fit}}
    rec = SyntheticRecord("impact", force_sig, resp, None, truth, settings)
    return rec, r


def _reference_yaml(ref: RigorousReference, rec: SyntheticRecord, fmt: BagFormat) -> dict[str, Any]:
    s = ref.summary
    fit = dict(s.get("fit", {}))
    f = ref.freqs
    out: dict[str, Any] = {
        "method": "impact",
        "generator": "clm_core.synthetic.reference",
        "source": rec.settings.get("source", "rigorous"),
        "profile": s.get("profile"),
        "rigorous_model": {
            "description": (
                "rigid massless rectangular contact areas on a layered viscoelastic half-space: Green's functions "
                "(clm_core.halfspace.green) + boundary elements (clm_core.halfspace.bem); docs/halfspace.md"
            ),
            "geometry": s.get("geometry"),
            "sweep_hz": {"fmin": float(f[0]), "fmax": float(f[-1]), "df": float(f[1] - f[0]), "n": int(f.size)},
            "conventions": s.get("conventions"),
            "sums_at_hz": s.get("sums_at"),
            "single_area": s.get("single_area"),
            "row_info": s.get("row_info"),
        },
        "clm_fitted_from_rigorous_sums": {
            "how": "clm_core.halfspace.calibrate.calibrate_profile: Eq. (16)/(18) sums of the rigorous row, "
            "band- and norm-explicit least squares (clm_core.soil.fit.fit_clm_sums)",
            **fit,
        },
    }
    if s.get("preset_clm"):
        out["paper_clm"] = {"what": "the preset's CLM values (paper tables), for comparison", **s["preset_clm"]}
    out["settings"] = dict(rec.settings)
    out["storage"] = fmt.storage
    out["style"] = fmt.style
    return plain(out)  # type: ignore[no-any-return]


def write_reference_impact_bag(
    path: str | Path,
    profile: str | Path | SoilProfile = "mevergnies",
    *,
    snr_db: float | None = 30.0,
    seed: int = 1,
    storage: Storage = "mcap",
    style: Style = "stamped",
    reference: RigorousReference | SoilCalibration | None = None,
    **record: Unpack[RecordOptions],
) -> ReferenceImpactBag:
    """Write a soil impact test bag of the rigorous half-space response to the Eq. (1) pulse.

    Parameters
    ----------
    path : path
        New bag directory (must not exist).
    profile : str, Path or SoilProfile
        Soil preset name (``mevergnies``, ...), profile file, or profile
        (ignored when ``reference`` is given).
    snr_db : float or None
        Noise level, as in the calibration bags (None: noise-free).
    seed : int
        Noise seed.
    storage : {"mcap", "sqlite3"}
        rosbag2 storage plugin (mcap: zstd chunk compression).
    style : {"stamped", "float64", "block"}
        Message style (:func:`clm_core.synthetic.writer.write_bag`).
    reference : RigorousReference or SoilCalibration, optional
        A rigorous computation to reuse (its grid must start at 0 Hz and be
        uniform; every area is instrumented); default:
        ``rigorous_reference(profile)`` with its defaults (41 areas, 0-150 Hz
        sweep, direct CLM fit in 0-80 Hz; about 15-30 s). Other areas,
        spacing, sweep or fit band: pass ``reference=rigorous_reference(profile, ...)``.
    **record
        ``source``, ``quantity``, ``fs`` [Hz], ``amplitude`` [N], ``t0`` [s],
        ``td`` [s], ``shaping``, ``taper_db`` [dB]: the record, as in
        :func:`reference_impact_record` (its defaults apply).

    Returns
    -------
    ReferenceImpactBag

    Raises
    ------
    CalibrationError
        The bag path exists, or bad storage/style.
    ParameterError
        Bad profile, grid or record settings.
    """
    out = Path(path)
    if out.exists():
        raise CalibrationError(f"bag {str(out)!r} exists; choose a new path")
    fmt = BagFormat(storage, style)
    if reference is None:
        ref = rigorous_reference(profile)
    elif isinstance(reference, SoilCalibration):
        preset = None if isinstance(profile, SoilProfile) or profile != reference.profile.name else _preset_clm(profile)
        ref = RigorousReference.from_calibration(reference, preset)
    else:
        ref = reference
    rec, resp = reference_impact_record(ref, **record)
    if snr_db is not None:
        rec = add_noise(rec, snr_db, seed)
    data = _reference_yaml(ref, rec, fmt)
    text = (
        "# Rigorous half-space reference this soil impact bag was generated from (SI units: N, m, s, kg).\n"
        "# Not a CLM truth: 'clm_fitted_from_rigorous_sums' is the CLM fitted directly to the rigorous sums,\n"
        "# for comparison with a calibration from the bag (docs/validation.md, 'Rigorous half-space reference').\n"
        + yaml.safe_dump(data, sort_keys=False)
    )
    bag_path = write_record(rec, out, fmt, {"reference.yaml": text})
    return ReferenceImpactBag(
        path=bag_path, channels=bag_path / "channels.yaml", reference=bag_path / "reference.yaml", record=rec,
        response=resp, rigorous=ref
    )
