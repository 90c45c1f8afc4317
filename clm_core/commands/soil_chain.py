"""``clm soil-chain``: the CLM chain alone (paper Sec. 4, Eq. 16, 18, 21, 23).

:func:`soil_chain_report` computes and writes one report (``chain.csv``,
``chain_time.csv``, ``chain.png``, ``summary.json``); ``clm report`` calls it
for every soil preset.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, cast

from clm_core.commands._common import add_command, output_dir, quantity
from clm_core.commands._options import add_overwrite, add_setting
from clm_core.errors import ParameterError
from clm_core.params import SOIL_MODELS, SoilModel, SoilParams


def register(sub: Any) -> None:
    """Add the ``soil-chain`` sub-command."""
    p = add_command(sub, "soil-chain", run)
    add_setting(p, "soil")
    p.add_argument("--model", default="clm", choices=[m for m in SOIL_MODELS if m != "rigid"],
                   help="foundation model of the areas (default clm)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="override a soil parameter")
    p.add_argument("--areas", type=int, default=41, help="number of areas 2n+1 (default 41)")
    p.add_argument("--fmax", type=float, default=150.0, help="highest frequency [Hz] (default 150)")
    p.add_argument("--df", type=float, default=0.5, help="frequency step [Hz] (default 0.5)")
    add_setting(p, "track", default=None,
                note="; here the track whose sleeper spacing d and contact width 2b Eq. (21) uses (e.g. soil-study "
                "for the Sec. 5.2 soils; without it: --spacing and --width)")
    p.add_argument("--spacing", type=float, default=None,
                   help="sleeper spacing d for Eq. (21) [m] (default: the --track's, else 0.6)")
    p.add_argument("--width", type=float, default=None,
                   help="contact width 2b along the track for Eq. (21) [m] (default: the --track's, else 0.285)")
    p.add_argument("--dt", type=float, default=1e-5, help="time step of the pulse response [s] (default 1e-5)")
    p.add_argument("--out", required=True, help="output directory")
    add_overwrite(p)


def soil_from_args(soil: str, model: str, assignments: list[str]) -> SoilParams:
    """The soil of ``soil`` (preset or file) for ``model``, with ``NAME=VALUE`` overrides."""
    from clm_core.params import load_soil, parse_assignments

    params = load_soil(soil, cast(SoilModel, model))
    sets = parse_assignments(assignments)
    if sets:
        unknown = set(sets) - {"mf", "kf", "df", "kc", "dc"}
        if unknown:
            raise ParameterError(f"--set: unknown soil parameter(s) {sorted(unknown)}; allowed mf, kf, df, kc, dc")
        params = SoilParams(**{**params.to_dict(), **sets})
    return params


def eq21_geometry(
    track: str | None, spacing: float | None = None, width: float | None = None
) -> tuple[float, float, str]:
    """Sleeper spacing d [m] and contact width 2b [m] for Eq. (21), and where they come from.

    With ``track`` (a preset or file) its spacing and contact width; a
    ``spacing`` or ``width`` given as well must agree with them. Without it
    ``spacing`` and ``width``, by default 0.6 m and 0.285 m (the Mevergnies
    track).
    """
    from clm_core.params import load_track

    if track is None:
        src = "--spacing/--width" if spacing is not None or width is not None else "default (no --track)"
        return 0.6 if spacing is None else float(spacing), 0.285 if width is None else float(width), src
    _, trk = load_track(track)
    for opt, given, own in (("--spacing", spacing, trk.spacing), ("--width", width, trk.contact_width)):
        if given is not None and given != own:
            raise ParameterError(
                f"{opt} = {given:g} m differs from the value {own:g} m of --track {track}: give one of them"
            )
    return trk.spacing, trk.contact_width, f"track {track}"


def soil_chain_report(
    soil: SoilParams, out: Path, *, areas: int = 41, fmax: float = 150.0, df: float = 0.5, spacing: float = 0.6,
    width: float = 0.285, dt: float = 1e-5, cs: float | None = None, name: str = "", eq21_from: str = "",
) -> dict[str, Any]:
    """The chain of ``areas`` contact areas on ``soil``: sums, Eq. (16)/(18), pulse response; written to ``out``.

    Parameters
    ----------
    soil : SoilParams
    out : Path
        Existing directory for ``chain.csv``, ``chain_time.csv``, ``chain.png`` and ``summary.json``.
    areas : int
        Odd number of areas 2n + 1 (>= 3).
    fmax, df : float
        Frequencies 0..fmax step df [Hz].
    spacing, width : float
        Sleeper spacing d and contact width 2b for Eq. (21) [m] (:func:`eq21_geometry`).
    dt : float
        Time step of the Eq. (1) pulse response [s].
    cs : float, optional
        Shear-wave speed of the top layer [m/s] for Eq. (21) (None: not computed).
    name : str
        Soil name for the plot title.
    eq21_from : str
        Where ``spacing`` and ``width`` come from (recorded in the summary's ``eq21_inputs``).

    Returns
    -------
    dict
        The summary: peak displacements and times, measured delays, Eq. (21)-(24) values, the
        largest relative errors of the sums against Eq. (16) and (18).
    """
    import numpy as np

    from clm_core.io.files import write_json
    from clm_core.outputs.plots import plot_chain
    from clm_core.soil.chain import chain_impedance_sums, chain_time_response
    from clm_core.soil.formulas import (
        alternating_sum_impedance,
        resonance_frequency,
        time_lag_coupling,
        time_lag_mulliken,
        time_lag_transmissibility,
        total_sum_impedance,
    )

    if areas < 3 or areas % 2 == 0:
        raise ParameterError(f"--areas {areas}: must be odd and >= 3 (2n+1 areas)")
    f = np.arange(0.0, fmax + 0.5 * df, df)
    sums = chain_impedance_sums(soil, areas, f)
    w = 2 * np.pi * f
    eq16, eq18 = total_sum_impedance(w, soil), alternating_sum_impedance(w, soil)
    resp = chain_time_response(soil, areas, dt=dt)
    np.savetxt(
        out / "chain.csv",
        np.column_stack([f, sums.total.real, sums.total.imag, eq16.real, eq16.imag, sums.alternating.real,
                         sums.alternating.imag, eq18.real, eq18.imag]),
        delimiter=",", comments="", fmt="%.10e",
        header="frequency_hz,total_re,total_im,eq16_re,eq16_im,alternating_re,alternating_im,eq18_re,eq18_im",
    )
    c = areas // 2
    np.savetxt(
        out / "chain_time.csv",
        np.column_stack([resp.t, resp.force, resp.x[:, c : c + 3]]),
        delimiter=",", comments="", fmt="%.10e", header="time_s,force_N,x0_m,x1_m,x2_m",
    )
    plot_chain(sums, eq16, eq18, resp, out / "chain.png", title=f"CLM chain, soil {name} ({areas} areas)")
    amps, times = resp.peaks(2)
    summary: dict[str, Any] = {
        "soil": soil.to_dict(),
        "areas": areas,
        "peak_displacement_m": amps,
        "peak_time_s": times,
        "measured_delay_s": [times[1] - times[0], times[2] - times[1]],
        "eq21_delay_s": time_lag_mulliken(spacing, width, cs) if cs else None,
        "eq21_inputs": {"spacing_m": spacing, "width_m": width, "cs_m_s": cs, "from": eq21_from},
        "eq23_delay_s": time_lag_coupling(soil) if soil.kc > 0 else None,
        "eq22_low_frequency_delay_s": time_lag_transmissibility(soil) if soil.kc > 0 else None,
        "eq24_resonance_hz": resonance_frequency(soil) if soil.mf > 0 else None,
        "eq16_max_relative_error": float(np.max(np.abs(sums.total / eq16 - 1))),
        "eq18_max_relative_error": float(np.max(np.abs(sums.alternating / eq18 - 1))),
        "pulse": {"A_N": 1.0, "t0_s": 0.05, "td_s": 0.001},
    }
    write_json(out / "summary.json", summary)
    return summary


def shear_wave_speed(soil: str) -> float | None:
    """Shear-wave speed of the top layer of the profile of ``soil`` [m/s] (None if it has no profile)."""
    from clm_core.profile import load_profile

    try:
        return float(load_profile(soil).layers[0].cs)
    except Exception:
        return None


def run(args: argparse.Namespace) -> int:
    """The CLM soil chain alone: impedance sums and pulse response.

    Chain of 2n+1 contact areas, centre one loaded: the impedances over the total and alternating sums against Eq.
    (16)/(18), and the response to the Eq. (1) pulse.
    """
    if args.areas < 3 or args.areas % 2 == 0:
        raise ParameterError(f"--areas {args.areas}: must be odd and >= 3 (2n+1 areas)")
    soil = soil_from_args(args.soil, args.model, args.set)
    spacing, width, src = eq21_geometry(args.track, args.spacing, args.width)
    with output_dir(args.out, args.overwrite) as d:
        s = soil_chain_report(soil, d, areas=args.areas, fmax=args.fmax, df=args.df, spacing=spacing, width=width,
                              dt=args.dt, cs=shear_wave_speed(args.soil), name=args.soil, eq21_from=src)
    m = s["measured_delay_s"]
    print(f"soil-chain: delays {quantity(m[0], 's')}, {quantity(m[1], 's')} "
          f"(Eq. 21 with d = {spacing:g} m: {quantity(s['eq21_delay_s'], 's')}, "
          f"Eq. 23: {quantity(s['eq23_delay_s'], 's')}) -> {d}")
    return 0
