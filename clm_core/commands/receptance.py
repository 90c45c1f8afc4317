"""``clm receptance``: track receptances H_11..H_51 (paper Sec. 5, Fig. 8).

:func:`receptance_report` computes and writes one report (``receptance.csv``,
``receptance.png``, ``summary.json``); ``clm report`` calls it for every preset.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from clm_core.commands._common import add_command, add_model_arguments, model_from_args, output_dir
from clm_core.commands._options import add_overwrite, add_setting
from clm_core.errors import ParameterError
from clm_core.params import ModelParams

#: Sleepers of the finite frequency-domain track (>= 21: 10 each side of the loaded one, paper Sec. 5).
SLEEPERS = 41


def register(sub: Any) -> None:
    """Add the ``receptance`` sub-command."""
    p = add_command(sub, "receptance", run)
    add_model_arguments(p)
    p.add_argument("--sleepers", type=int, default=SLEEPERS,
                   help=f"sleepers of the finite track [-]; >= 21 (10 each side of the loaded one, paper Sec. 5); "
                   f"default {SLEEPERS}")
    add_setting(p, "elements_per_bay")
    p.add_argument("--fmin", type=float, default=1.0, help="lowest frequency [Hz] (default 1)")
    p.add_argument("--fmax", type=float, default=400.0, help="highest frequency [Hz] (default 400)")
    p.add_argument("--df", type=float, default=0.25, help="frequency step [Hz] (default 0.25)")
    p.add_argument("--out", required=True, help="output directory")
    add_overwrite(p)


def check_band(fmin: float, fmax: float, df: float, sleepers: int) -> None:
    """Refuse a bad frequency band or a track too short for the receptance (paper Sec. 5)."""
    if not (df > 0 and 0 <= fmin < fmax):
        raise ParameterError(f"--fmin {fmin} --fmax {fmax} --df {df}: need 0 <= fmin < fmax and df > 0")
    if sleepers < 21:
        raise ParameterError(f"--sleepers {sleepers}: at least 21 (10 each side of the loaded one, paper Sec. 5)")


def receptance_report(
    params: ModelParams, out: Path, *, sleepers: int = SLEEPERS, elements_per_bay: int = 2,
    fmin: float = 1.0, fmax: float = 400.0, df: float = 0.25,
) -> dict[str, Any]:
    """Compute the receptances H_11..H_51 of ``params`` and write them into ``out`` (existing directory).

    Parameters
    ----------
    params : ModelParams
    out : Path
        Directory for ``receptance.csv`` (``frequency_hz``, then ``H{i}1_re``,
        ``H{i}1_im`` [m/N]), ``receptance.png`` and ``summary.json``.
    sleepers, elements_per_bay : int
        The finite track (>= 21 sleepers) and its rail mesh.
    fmin, fmax, df : float
        Frequencies [Hz].

    Returns
    -------
    dict
        The summary (``peaks_hz``, ``peak_amplitudes_m_per_N``, sizes, solve time, parameters).
    """
    import numpy as np

    from clm_core.frequency import receptance
    from clm_core.io.files import write_json
    from clm_core.outputs.plots import plot_receptance
    from clm_core.track import assemble

    check_band(fmin, fmax, df, sleepers)
    system = assemble(params, sleepers, elements_per_bay=elements_per_bay)
    f = np.arange(fmin, fmax + 0.5 * df, df)
    t0 = time.perf_counter()
    rec = receptance(system, f, n_out=5)
    elapsed = time.perf_counter() - t0
    cols = [rec.frequency]
    header = ["frequency_hz"]
    for i in range(5):
        cols += [rec.H[:, i].real, rec.H[:, i].imag]
        header += [f"H{i + 1}1_re", f"H{i + 1}1_im"]
    np.savetxt(
        out / "receptance.csv", np.column_stack(cols), delimiter=",", header=",".join(header), comments="",
        fmt="%.10e",
    )
    plot_receptance(rec, out / "receptance.png", title=f"Track receptance: {params.name or 'parameter file'}")
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
    write_json(out / "summary.json", summary)
    return summary


def run(args: argparse.Namespace) -> int:
    """Track receptances H11..H51 in the frequency domain.

    Rail receptances above sleepers 1..5 for a force above sleeper 1 (the central sleeper), by direct banded
    solution.
    """
    check_band(args.fmin, args.fmax, args.df, args.sleepers)
    params = model_from_args(args)
    with output_dir(args.out, args.overwrite) as d:
        s = receptance_report(params, d, sleepers=args.sleepers, elements_per_bay=args.elements_per_bay,
                              fmin=args.fmin, fmax=args.fmax, df=args.df)
    peaks = s["peaks_hz"]
    print(f"receptance: {params.name}: peaks of |H11| at {', '.join(f'{p:.1f}' for p in peaks)} Hz -> {d}")
    return 0
