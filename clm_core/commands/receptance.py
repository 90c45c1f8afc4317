"""``clm receptance``: track receptances H_11..H_51 (paper Sec. 5, Fig. 8)."""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from clm_core.commands._common import add_model_arguments, model_from_args, out_dir, write_json
from clm_core.errors import ParameterError
from clm_core.frequency import receptance
from clm_core.report import plot_receptance
from clm_core.track import assemble


def register(sub: Any) -> None:
    """Add the ``receptance`` sub-command."""
    p = sub.add_parser(
        "receptance",
        help="track receptances H11..H51 in the frequency domain",
        description="Rail receptances above sleepers 1..5 for a force above sleeper 1 "
        "(the central sleeper), by direct banded solution.",
    )
    add_model_arguments(p, sleepers_default=41)
    p.add_argument("--fmin", type=float, default=1.0, help="lowest frequency [Hz] (default 1)")
    p.add_argument("--fmax", type=float, default=400.0, help="highest frequency [Hz] (default 400)")
    p.add_argument("--df", type=float, default=0.25, help="frequency step [Hz] (default 0.25)")
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Compute and write receptance.csv, receptance.png and summary.json."""
    if not (args.df > 0 and 0 <= args.fmin < args.fmax):
        raise ParameterError(f"--fmin {args.fmin} --fmax {args.fmax} --df {args.df}: need 0 <= fmin < fmax and df > 0")
    if args.sleepers < 21:
        raise ParameterError(f"--sleepers {args.sleepers}: at least 21 (10 each side of the loaded one, paper Sec. 5)")
    params = model_from_args(args)
    system = assemble(params, args.sleepers, elements_per_bay=args.elements_per_bay)
    f = np.arange(args.fmin, args.fmax + 0.5 * args.df, args.df)
    t0 = time.perf_counter()
    rec = receptance(system, f, n_out=5)
    elapsed = time.perf_counter() - t0
    d = out_dir(args.out)
    cols = [rec.frequency]
    header = ["frequency_hz"]
    for i in range(5):
        cols += [rec.H[:, i].real, rec.H[:, i].imag]
        header += [f"H{i + 1}1_re", f"H{i + 1}1_im"]
    np.savetxt(
        d / "receptance.csv", np.column_stack(cols), delimiter=",", header=",".join(header), comments="", fmt="%.10e"
    )
    plot_receptance(rec, d / "receptance.png", title=f"Track receptance: {params.name or 'parameter file'}")
    peaks = rec.peaks_hz()
    summary: dict[str, Any] = {
        "peaks_hz": peaks,
        "peak_amplitudes_m_per_N": [float(np.interp(p, rec.frequency, np.abs(rec.H[:, 0]))) for p in peaks],
        "static_receptance_m_per_N": float(abs(rec.H[0, 0])) if f[0] == 0 else None,
        "n_sleepers": system.n_sleepers,
        "elements_per_bay": system.elements_per_bay,
        "n_dof": system.n_dof,
        "n_frequencies": int(f.size),
        "solve_time_s": elapsed,
        "parameters": params.to_dict(),
    }
    write_json(d / "summary.json", summary)
    print(f"receptance: {params.name}: peaks of |H11| at {', '.join(f'{p:.1f}' for p in peaks)} Hz -> {d}")
    return 0
