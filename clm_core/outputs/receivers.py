"""``clm simulate --receivers``: free-field outputs of a finished run (files, figure, summary entries).

:func:`receivers_for_run` reads the run's sleeper forces (``history.npz`` of a
moving-load run, ``vehicle_history.npz`` of a vehicle run), computes the
receiver velocities (:func:`clm_core.freefield.free_field`) and writes

- ``receivers.npz``: ``t`` (n,) [s], ``velocity`` (R, n) [m/s],
  ``receivers`` (R, 2) [m], ``kb_f`` (R, n) [mm/s], ``band_centres_hz`` (20,),
  ``lv_db`` (R, 20) [dB re 5e-8 m/s], ``ppv_mm_per_s`` (R,),
  ``kb_fmax_mm_per_s`` (R,);
- ``receivers.csv``: ``t_s`` then ``v{r}_m_per_s`` per receiver;
- ``receivers.png`` (:func:`clm_core.outputs.plots.receivers.plot_receivers`);
- the ``receivers`` entry of ``summary.json`` (per receiver: x, y, PPV,
  KB_F,max, dominant band, L_v per band; plus the soil and model settings).

Receivers: ``--receivers 8,16,32`` (distances from the track axis [m], at
``--receiver-x``, by default the middle of the stretch of sleepers the run
recorded) or ``--receivers-file`` (CSV with columns x_m, y_m, header line
optional). Soil: ``--receiver-soil`` (a preset, a profile YAML, or
``E=...,rho=...,nu=...[,beta=...]`` for a homogeneous half-space), by default
the profile of the run's ``--soil`` preset.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from clm_core.arrays import Array
from clm_core.errors import InputError
from clm_core.profile import Layer, SoilProfile, load_profile

__all__ = ["parse_receivers", "receiver_soil", "receivers_for_run", "write_receiver_outputs"]


def receiver_soil(spec: str | None, run_soil: str | None) -> SoilProfile:
    """The receivers' soil: ``spec`` (preset, YAML, ``E=..,rho=..,nu=..[,beta=..,xi=..]``) or the run's soil."""
    text = (spec or "").strip()
    if text and "=" in text:
        vals: dict[str, float] = {}
        for part in text.split(","):
            key, _, val = part.partition("=")
            key = key.strip()
            if key not in ("E", "rho", "nu", "beta", "xi"):
                raise InputError(f"--receiver-soil {text!r}: unknown key {key!r}; give E, rho, nu[, beta, xi]")
            try:
                vals[key] = float(val)
            except ValueError:
                raise InputError(f"--receiver-soil {text!r}: {key} = {val!r} is not a number") from None
        missing = [k for k in ("E", "rho", "nu") if k not in vals]
        if missing:
            raise InputError(f"--receiver-soil {text!r}: missing {', '.join(missing)} (homogeneous half-space)")
        return SoilProfile(layers=(Layer(thickness=None, **vals),), name="half-space", source=text)
    name = text or run_soil
    if not name:
        raise InputError("--receivers: no soil profile (the run has none): give --receiver-soil")
    return load_profile(name)


def parse_receivers(distances: str | None, file: str | None, x_default: float) -> Array:
    """Receivers (R, 2) [m] from ``--receivers`` distances and/or ``--receivers-file`` rows (x, y)."""
    rows: list[tuple[float, float]] = []
    if distances:
        for s in str(distances).split(","):
            if not s.strip():
                continue
            try:
                y = float(s)
            except ValueError:
                raise InputError(f"--receivers {distances!r}: {s!r} is not a distance [m]") from None
            if not math.isfinite(y):
                raise InputError(f"--receivers {distances!r}: distances must be finite [m]")
            rows.append((x_default, y))
    if file:
        p = Path(file)
        try:
            lines = p.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"--receivers-file {p}: cannot read ({exc})") from None
        for k, line in enumerate(lines, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = [q.strip() for q in s.split(",")]
            try:
                x, y = (float(q) for q in parts[:2]) if len(parts) >= 2 else (math.nan, math.nan)
            except ValueError:
                if k == 1:
                    continue  # header line
                raise InputError(f"--receivers-file {p}, line {k}: {s!r} is not 'x, y' in metres") from None
            if len(parts) != 2 or not (math.isfinite(x) and math.isfinite(y)):
                raise InputError(f"--receivers-file {p}, line {k}: {s!r}: need two finite numbers x, y [m]")
            rows.append((x, y))
    if not rows:
        raise InputError("--receivers / --receivers-file: no receiver given")
    return np.asarray(rows, dtype=float)


def _run_forces(d_out: Path) -> tuple[Array, Array, Array, float, list[int]]:
    """(t, first_sleeper, soil_force window-relative, spacing, [min, max] sleeper index) of a finished run."""
    h = d_out / "history.npz"
    if h.exists():
        with np.load(h) as z:
            t, first, F, d = z["t"], z["first_sleeper"], z["soil_force"], float(z["spacing"])
        span = [int(first.min()), int(first.max()) + F.shape[1] - 1]
        return t, first, F, d, span
    vh = d_out / "vehicle_history.npz"
    if vh.exists():
        from clm_core.outputs.history import read_vehicle_history

        z = read_vehicle_history(vh, dense=False)
        t, first = z["t_out"], z["first_sleeper"].astype(np.int64)
        idx, x = z["sleeper_index"].astype(np.int64), z["sleeper_x"]
        if idx.size < 2 or not np.all(np.diff(idx) == 1):
            raise InputError(f"{vh}: the recorded sleepers are not consecutive; cannot place them")
        d = float((x[-1] - x[0]) / (idx[-1] - idx[0]))
        F = np.where(np.isfinite(z["soil_force"]), z["soil_force"], 0.0)
        return t, first, F, d, [int(first.min()), int(first.max()) + F.shape[1] - 1]
    raise InputError(f"{d_out}: no history.npz or vehicle_history.npz to compute receivers from")


def receivers_for_run(args: Any, params: Any, d_out: Path) -> dict[str, Any] | None:
    """Receiver outputs of the run in ``d_out`` (module docstring); None when no receiver was asked for."""
    if not (getattr(args, "receivers", None) or getattr(args, "receivers_file", None)):
        return None
    from clm_core.freefield import free_field
    from clm_core.progress import Progress

    t, first, F, d, span = _run_forces(d_out)
    x_mid = 0.5 * (span[0] + span[1]) * d
    x0 = float(args.receiver_x) if getattr(args, "receiver_x", None) is not None else x_mid
    rec = parse_receivers(args.receivers, args.receivers_file, x0)
    soil = receiver_soil(getattr(args, "receiver_soil", None), None if args.params_file else args.soil)
    track = params.track
    with Progress(1, "clm simulate: free-field receivers", unit="model") as bar:
        res = free_field(soil, rec, t, first, F, d, contact_length=track.contact_length,
                         contact_width=track.contact_width, influence_length=float(args.receiver_influence))
        bar.update(1)
    return write_receiver_outputs(res, soil.name, d_out)


def write_receiver_outputs(res: Any, soil_name: str, d_out: Path, title: str | None = None) -> dict[str, Any]:
    """Write ``receivers.npz``, ``receivers.csv``, ``receivers.png`` and the ``receivers`` entry of ``summary.json``.

    Parameters
    ----------
    res : FreeFieldResult
        From :func:`clm_core.freefield.free_field`.
    soil_name : str
        Name of the soil profile (for the summary and the figure title).
    d_out : Path
        Output directory (its ``summary.json``, when present, gets the entry).
    title : str, optional
        Figure title.

    Returns
    -------
    dict
        The summary entry (module docstring); the per-receiver figures are also printed.
    """
    from clm_core.freefield import kb_f
    from clm_core.io.files import write_json, write_npz
    from clm_core.outputs.plots.receivers import plot_receivers

    m = res.measures
    rec = res.receivers
    write_npz(d_out / "receivers.npz", {
        "t": res.t, "velocity": res.velocity, "receivers": rec,
        "kb_f": kb_f(res.velocity, res.model.model_dt),
        "band_centres_hz": m.band_centres_hz, "lv_db": m.lv_db, "ppv_mm_per_s": m.ppv_mm_s,
        "kb_fmax_mm_per_s": m.kb_fmax_mm_s,
    })
    head = ",".join(["t_s"] + [f"v{r}_m_per_s" for r in range(rec.shape[0])])
    np.savetxt(d_out / "receivers.csv", np.column_stack([res.t, res.velocity.T]), delimiter=",", header=head,
               comments="", fmt="%.9g")
    plot_receivers(res, d_out / "receivers.png",
                   title=title or f"Free-field vertical velocity, soil '{soil_name}' (two-step method)")
    per_receiver = res.summary()
    entry: dict[str, Any] = {
        "soil": soil_name, "influence_length_m": res.model.influence_length, "band_limit_hz": res.model.band,
        "model_step_s": res.model.model_dt, "filters_from_cache": bool(res.model.cached),
        "kb_filter": "DIN 4150-2: KB high-pass f0 = 5.6 Hz, running rms FAST tau = 0.125 s",
        "lv_reference_m_per_s": 5e-8, "receivers": per_receiver,
    }
    s_path = d_out / "summary.json"
    if s_path.exists():
        summary = json.loads(s_path.read_text(encoding="utf-8"))
        summary["receivers"] = entry
        write_json(s_path, summary)
    for r in per_receiver:
        print(f"receiver x = {r['x_m']:g} m, y = {r['y_m']:g} m: PPV {r['ppv_mm_per_s']:.3g} mm/s, "
              f"KB_F,max {r['kb_fmax_mm_per_s']:.3g} mm/s, dominant band {r['dominant_third_octave_hz']:g} Hz")
    return entry
