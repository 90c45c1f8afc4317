"""``clm soil-chain``: the CLM chain alone (paper Sec. 4, Eq. 16, 18, 21, 23)."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from clm_core.commands._common import out_dir, write_json
from clm_core.errors import ParameterError
from clm_core.params import SOIL_MODELS, load_soil, parse_assignments
from clm_core.profile import load_profile
from clm_core.report import plot_chain
from clm_core.soil.chain import chain_frequency_response, chain_sums, chain_time_response
from clm_core.soil.formulas import (
    alternating_sum_impedance,
    resonance_frequency,
    time_lag_coupling,
    time_lag_mulliken,
    time_lag_transmissibility,
    total_sum_impedance,
)


def register(sub: Any) -> None:
    """Add the ``soil-chain`` sub-command."""
    p = sub.add_parser(
        "soil-chain",
        help="the CLM soil chain alone: impedance sums and pulse response",
        description="Chain of 2n+1 contact areas, centre one loaded: the impedances over the "
        "total and alternating sums against Eq. (16)/(18), and the response to the Eq. (1) pulse.",
    )
    p.add_argument("--soil", default="mevergnies", help="soil preset or YAML file (default: mevergnies)")
    p.add_argument("--model", default="clm", choices=[m for m in SOIL_MODELS if m != "rigid"])
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="override a soil parameter")
    p.add_argument("--areas", type=int, default=41, help="number of areas 2n+1 (default 41)")
    p.add_argument("--fmax", type=float, default=150.0, help="highest frequency [Hz] (default 150)")
    p.add_argument("--df", type=float, default=0.5, help="frequency step [Hz] (default 0.5)")
    p.add_argument("--spacing", type=float, default=0.6, help="sleeper spacing d for Eq. (21) [m] (default 0.6)")
    p.add_argument("--width", type=float, default=0.285, help="contact width 2b along the track for Eq. (21) [m]")
    p.add_argument("--dt", type=float, default=1e-5, help="time step of the pulse response [s] (default 1e-5)")
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write chain.csv, chain_time.csv, chain.png and summary.json."""
    if args.areas < 3 or args.areas % 2 == 0:
        raise ParameterError(f"--areas {args.areas}: must be odd and >= 3 (2n+1 areas)")
    soil = load_soil(args.soil, args.model)
    sets = parse_assignments(args.set)
    if sets:
        from clm_core.params import SoilParams

        unknown = set(sets) - {"mf", "kf", "df", "kc", "dc"}
        if unknown:
            raise ParameterError(f"--set: unknown soil parameter(s) {sorted(unknown)}; allowed mf, kf, df, kc, dc")
        soil = SoilParams(**{**soil.to_dict(), **sets})
    f = np.arange(0.0, args.fmax + 0.5 * args.df, args.df)
    X = chain_frequency_response(soil, args.areas, f)
    sums = chain_sums(f, X)
    w = 2 * np.pi * f
    eq16, eq18 = total_sum_impedance(w, soil), alternating_sum_impedance(w, soil)
    resp = chain_time_response(soil, args.areas, dt=args.dt)
    d = out_dir(args.out)
    np.savetxt(
        d / "chain.csv",
        np.column_stack(
            [
                f,
                sums.total.real,
                sums.total.imag,
                eq16.real,
                eq16.imag,
                sums.alternating.real,
                sums.alternating.imag,
                eq18.real,
                eq18.imag,
            ]
        ),
        delimiter=",",
        comments="",
        fmt="%.10e",
        header="frequency_hz,total_re,total_im,eq16_re,eq16_im,alternating_re,alternating_im,eq18_re,eq18_im",
    )
    c = args.areas // 2
    np.savetxt(
        d / "chain_time.csv",
        np.column_stack([resp.t, resp.force, resp.x[:, c : c + 3]]),
        delimiter=",",
        comments="",
        fmt="%.10e",
        header="time_s,force_N,x0_m,x1_m,x2_m",
    )
    plot_chain(sums, eq16, eq18, resp, d / "chain.png", title=f"CLM chain, soil {args.soil} ({args.areas} areas)")
    amps, times = resp.peaks(2)
    cs = _cs(args.soil)
    summary: dict[str, Any] = {
        "soil": soil.to_dict(),
        "areas": args.areas,
        "peak_displacement_m": amps,
        "peak_time_s": times,
        "measured_delay_s": [times[1] - times[0], times[2] - times[1]],
        "eq21_delay_s": time_lag_mulliken(args.spacing, args.width, cs) if cs else None,
        "eq23_delay_s": time_lag_coupling(soil) if soil.kc > 0 else None,
        "eq22_low_frequency_delay_s": time_lag_transmissibility(soil) if soil.kc > 0 else None,
        "eq24_resonance_hz": resonance_frequency(soil) if soil.mf > 0 else None,
        "eq16_max_relative_error": float(np.max(np.abs(sums.total / eq16 - 1))),
        "eq18_max_relative_error": float(np.max(np.abs(sums.alternating / eq18 - 1))),
        "pulse": {"A_N": 1.0, "t0_s": 0.05, "td_s": 0.001},
    }
    write_json(d / "summary.json", summary)
    print(
        f"soil-chain: delays {summary['measured_delay_s'][0] * 1e3:.2f}, {summary['measured_delay_s'][1] * 1e3:.2f} ms "
        f"(Eq. 21: {summary['eq21_delay_s'] and summary['eq21_delay_s'] * 1e3:.2f} ms, Eq. 23: "
        f"{summary['eq23_delay_s'] and summary['eq23_delay_s'] * 1e3:.2f} ms) -> {d}"
    )
    return 0


def _cs(soil: str) -> float | None:
    try:
        return float(load_profile(soil).layers[0].cs)
    except Exception:
        return None
