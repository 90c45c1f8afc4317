"""``clm soil-calibrate``: CLM soil parameters from a soil profile (rigorous half-space).

Computes the flexibility of a row of rigid sleeper–ballast contact areas on
the profile's layered half-space (:mod:`clm_core.halfspace`), fits the CLM
parameters to the impedance sums of Eq. (16) and (18) in a stated band and
norm (both sums jointly by default; ``--route total-first`` fits m_f, k_f, d_f
to the total sum alone first), and writes to ``--out``:

- ``soil.yaml``: the fitted soil in the preset format (``name``, ``source``,
  ``clm: {mf, df, kf, dc, kc}``, ``profile: layers``);
- ``summary.json``: fitted values, the fit quality of both sums (and of the
  other route), band, norm, the sums at 0, 10,
  50, 100 Hz, the single-area static stiffness vs Eq. (6), the preset's own
  CLM values if the profile came from a preset;
- ``sums.png``: real and imaginary parts of F / sum X_j and F / sum (-1)^j X_j,
  rigorous vs CLM;
- ``receptances.png``: |X_j / F| and phase of the loaded area and its first
  two neighbours, rigorous vs the fitted CLM chain;
- ``sweep.npz``: frequencies, centre column of the flexibility, sums.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from clm_core.commands._common import add_command, check_output, output_dir, quantity, remove_bag
from clm_core.commands._options import add_overwrite, add_setting
from clm_core.errors import ParameterError, PresetError
from clm_core.io.files import write_json


def register(subparsers: Any) -> None:
    """Add the ``soil-calibrate`` sub-command (with ``--impact-bag``) to ``subparsers``."""
    p = add_command(subparsers, "soil-calibrate", run)
    p.add_argument(
        "--profile", required=True, help="soil preset name (mevergnies, soft, medium, stiff, haren) or YAML file"
    )
    p.add_argument("--out", required=True, type=Path, help="output directory (created)")
    p.add_argument("--areas", type=int, default=41, help="number of contact areas 2n+1 (default 41)")
    p.add_argument("--fmin", type=float, default=0.0, help="lower end of the fit band [Hz] (default 0)")
    p.add_argument("--fmax", type=float, default=80.0, help="upper end of the fit band [Hz] (default 80)")
    p.add_argument("--df", type=float, default=1.0, help="frequency step of the sweep [Hz] (default 1)")
    p.add_argument(
        "--sweep-max", type=float, default=150.0, help="highest frequency of the sweep [Hz] (default 150, >= fmax)"
    )
    p.add_argument("--norm", choices=("ls", "relative"), default="ls", help="fit norm (default ls)")
    p.add_argument(
        "--route",
        choices=("joint", "total-first"),
        default="joint",
        help="fit both sums jointly (default: the CLM is defined by both), or m_f, k_f, d_f from the total "
        "sum alone and then k_c, d_c from the alternating sum (the old route)",
    )
    p.add_argument("--spacing", type=float, default=0.6, help="sleeper spacing d [m] (default 0.6)")
    p.add_argument(
        "--on-unstable",
        choices=("raise", "clip"),
        default="raise",
        help="non-positive-definite chain damping: refuse (default) or clip d_c to 95%% of the bound",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    add_overwrite(p)
    _add_impact_bag_arguments(p)


def _check_args(args: argparse.Namespace) -> None:
    if args.areas < 1 or args.areas % 2 == 0:
        raise ParameterError(f"--areas = {args.areas}: must be odd and >= 1 (2n + 1 areas)")
    if not (args.df > 0 and math.isfinite(args.df)):
        raise ParameterError(f"--df = {args.df}: must be > 0 [Hz]")
    if not (0 <= args.fmin < args.fmax):
        raise ParameterError(f"--fmin = {args.fmin}, --fmax = {args.fmax}: need 0 <= fmin < fmax [Hz]")
    if args.sweep_max < args.fmax:
        raise ParameterError(f"--sweep-max = {args.sweep_max}: must be >= --fmax = {args.fmax} [Hz]")
    if args.spacing <= 0.285:
        raise ParameterError(f"--spacing = {args.spacing}: must exceed the area width 0.285 m")


def _preset_clm(spec: str) -> dict[str, float] | None:
    """The ``clm`` block of the preset or file the profile came from, if any."""
    from importlib import resources

    path = Path(spec)
    try:
        if path.exists():
            text = path.read_text(encoding="utf-8")
        else:
            res = resources.files("clm_core") / "presets" / "soils" / f"{spec}.yaml"
            if not res.is_file():
                return None
            text = res.read_text(encoding="utf-8")
        data = yaml.safe_load(text)
    except (OSError, yaml.YAMLError):
        return None
    clm = data.get("clm") if isinstance(data, dict) else None
    if not isinstance(clm, dict):
        return None
    try:
        return {k: float(clm[k]) for k in ("mf", "kf", "df", "kc", "dc") if k in clm}
    except (TypeError, ValueError):
        return None


def _run_calibration(args: argparse.Namespace) -> int:
    """Run the calibration (without the reference impact bag); returns 0 on success."""
    from clm_core.halfspace.calibrate import calibrate_profile
    from clm_core.profile import load_profile
    from clm_core.progress import Progress

    _check_args(args)
    check_output(args.out, args.overwrite)
    profile = load_profile(args.profile)
    freqs = np.arange(0.0, args.sweep_max + 0.5 * args.df, args.df)
    if freqs[-1] > args.sweep_max + 1e-9:
        freqs = freqs[:-1]
    with Progress(100, "clm soil-calibrate", unit="%") as bar:
        cal = calibrate_profile(
            profile,
            freqs=freqs,
            fmin=args.fmin,
            fmax=args.fmax,
            norm=args.norm,
            n_areas=args.areas,
            spacing=args.spacing,
            on_unstable=args.on_unstable,
            route=args.route,
            progress=bar.fraction,
        )
    with output_dir(args.out, args.overwrite) as out:
        _write(args, profile, cal, out)
    fit = cal.fit
    print(
        f"{profile.name}: mf = {quantity(fit.mf, 'kg')}, kf = {fit.kf / 1e6:.4g} MN/m, df = {fit.df / 1e3:.4g} kN s/m, "
        f"kc = {fit.kc / 1e6:.4g} MN/m, dc = {fit.dc / 1e3:.4g} kN s/m "
        f"(band {fit.band[0]:g}-{fit.band[1]:g} Hz, norm {fit.norm}, route {fit.route}"
        + (f", {', '.join(fit.constrained)}" if fit.constrained else "")
        + f") -> {out}"
    )
    print(_quality_line("fit quality", fit))
    other = cal.other_route
    if isinstance(other, str):
        print(f"  other route: not admissible ({other})")
    else:
        print(
            _quality_line(f"{other.route} route", other)
            + f"; mf = {quantity(other.mf, 'kg')} (unconstrained {quantity(other.mf_unconstrained, 'kg')}), "
            f"kf = {other.kf / 1e6:.4g} MN/m"
        )
    return 0


def _write(args: argparse.Namespace, profile: Any, cal: Any, out: Path) -> None:
    fit = cal.fit
    g = cal.row.geometry
    soil = {
        "name": f"{profile.name}-fitted",
        "source": (
            f"clm soil-calibrate: rigorous half-space BEM, {g.n_areas} areas {g.length} m x {g.width} m at "
            f"{g.spacing} m; fit band {fit.band[0]:g}-{fit.band[1]:g} Hz, norm '{fit.norm}', route '{fit.route}'; "
            f"residual total sum {fit.residual_total:.3f}, alternating sum {fit.residual_alternating:.3f}"
            + (f"; constraints: {', '.join(fit.constrained)}" if fit.constrained else "")
        ),
        "clm": {"mf": fit.mf, "df": fit.df, "kf": fit.kf, "dc": fit.dc, "kc": fit.kc},
        "profile": profile.to_dict(),
    }
    (out / "soil.yaml").write_text(
        "# CLM soil parameters fitted by `clm soil-calibrate` (SI units: kg, N s/m, N/m).\n"
        + yaml.safe_dump(soil, sort_keys=False),
        encoding="utf-8",
    )
    summary = cal.summary()
    summary["preset_clm"] = _preset_clm(args.profile)
    summary["command"] = {
        "profile": str(args.profile),
        "areas": args.areas,
        "fmin": args.fmin,
        "fmax": args.fmax,
        "df": args.df,
        "sweep_max": args.sweep_max,
        "norm": args.norm,
        "route": fit.route,
        "spacing": args.spacing,
        "on_unstable": args.on_unstable,
    }
    np.savez(
        out / "sweep.npz",
        freqs=cal.freqs,
        centre_column=cal.row.centre_column,
        positions=cal.row.positions,
        total_sum=cal.total_sum,
        alternating_sum=cal.alternating_sum,
        single_impedance=cal.single_impedance,
    )
    files = ["soil.yaml", "summary.json", "sweep.npz"]
    if not args.no_plots:
        from clm_core.outputs.plots import plot_soil_calibration

        files += plot_soil_calibration(cal, out)
    summary["files"] = files
    write_json(out / "summary.json", summary)


def _quality_line(label: str, fit: Any) -> str:
    """Relative RMS residual and largest relative error of both sums, one line."""
    return (
        f"  {label}: total sum (Eq. 16) residual {fit.residual_total:.3f}, max {fit.max_rel_error_total:.3f}; "
        f"alternating sum (Eq. 18) residual {fit.residual_alternating:.3f}, max {fit.max_rel_error_alternating:.3f}"
    )


# ----------------------------------------------------------------------------- --impact-bag (issue 7)
#
# ``--impact-bag`` also writes ``DIR/reference_impact_bag``: a soil impact test
# bag (calibration-bag format) of the rigorous row's response to the Eq. (1)
# pulse, with ``reference.yaml`` (clm_core.synthetic.reference). It reuses
# the sweep just written (``sweep.npz``, ``summary.json``): no second BEM run.
# Its options are a group of their own; without the flag nothing changes.

#: Sample rate of the reference impact bag [Hz] (that of the calibration bags).
IMPACT_BAG_FS = 1000.0
#: Directory of the reference impact bag inside ``--out``.
IMPACT_BAG_DIR = "reference_impact_bag"


def _snr_arg(text: str) -> float | None:
    """``--bag-snr`` value: a number [dB] or ``none`` (noise-free)."""
    if text.strip().lower() in ("none", "inf", "off"):
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give an SNR in dB or 'none'") from None


def _add_impact_bag_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``--impact-bag`` (their own group of ``clm soil-calibrate --help``)."""
    g = p.add_argument_group("reference impact bag (--impact-bag)")
    g.add_argument(
        "--impact-bag",
        action="store_true",
        help=f"also write DIR/{IMPACT_BAG_DIR}: a soil impact test bag (calibration format, geophones on all "
        "areas) of the rigorous response to the Eq. (1) pulse, with reference.yaml; needs --df <= 2 with "
        f"{IMPACT_BAG_FS:g}/df an even integer (default 1 Hz: 1 s record) and --sweep-max <= {IMPACT_BAG_FS / 2:g}",
    )
    add_setting(g, "storage")
    g.add_argument("--bag-snr", type=_snr_arg, default=30.0, help="SNR of the bag's noise [dB] or 'none' (default 30)")
    g.add_argument("--bag-seed", type=int, default=1, help="noise seed (default 1)")


def _check_impact_bag(args: argparse.Namespace) -> Path:
    ratio = IMPACT_BAG_FS / args.df
    if args.df > 2.0 or abs(ratio - round(ratio)) > 1e-9 * ratio or round(ratio) % 2:
        raise ParameterError(
            f"--impact-bag with --df = {args.df:g} Hz: the record length is 1/df, which must exceed 0.5 s, and "
            f"{IMPACT_BAG_FS:g} Hz / df must be an even integer; use --df 1 (or 0.5, 2)"
        )
    if args.sweep_max > IMPACT_BAG_FS / 2:
        raise ParameterError(
            f"--impact-bag with --sweep-max = {args.sweep_max:g} Hz: must be <= {IMPACT_BAG_FS / 2:g} Hz "
            f"(the bag is sampled at {IMPACT_BAG_FS:g} Hz)"
        )
    bag = Path(args.out) / IMPACT_BAG_DIR
    if bag.exists() and not ((bag / "reference.yaml").is_file() and (bag / "metadata.yaml").is_file()):
        raise PresetError(f"{bag}: exists and is not a reference impact bag; remove it or choose another --out")
    return bag


def run(args: argparse.Namespace) -> int:
    """Fit CLM soil parameters to a rigorous half-space computation of a soil profile.

    Rigorous (Green's function + boundary element) flexibility of 2n+1 rigid contact areas (2.5 m x 0.285 m) on a
    layered viscoelastic half-space, and a band/norm-explicit fit of the CLM parameters to Eq. (16) and (18) of
    Kouroussis et al. (2011).
    """
    if not getattr(args, "impact_bag", False):
        return _run_calibration(args)
    from clm_core.synthetic.reference import RigorousReference, write_reference_impact_bag

    _check_args(args)
    bag_path = _check_impact_bag(args)
    code = _run_calibration(args)
    if code != 0:
        return code
    out: Path = args.out
    ref = RigorousReference.from_soil_calibrate_output(out)
    remove_bag(bag_path, "--out")
    # the bag's settings: written with them, and recorded as written in summary.json
    settings: dict[str, Any] = {"storage": args.storage, "snr_db": args.bag_snr, "seed": args.bag_seed}
    bag = write_reference_impact_bag(bag_path, reference=ref, fs=IMPACT_BAG_FS, **settings)
    summary_path = out / "summary.json"
    summary = json.loads(summary_path.read_text(encoding="utf-8"))
    summary["files"] = [*summary.get("files", []), IMPACT_BAG_DIR]
    summary["impact_bag"] = {"path": IMPACT_BAG_DIR, **settings, "fs_hz": IMPACT_BAG_FS}
    write_json(summary_path, summary)
    size = sum(p.stat().st_size for p in bag.path.iterdir())
    snr = "noise-free" if args.bag_snr is None else f"SNR {args.bag_snr:g} dB"
    print(
        f"reference impact bag ({bag.record.settings['n_areas']} areas, {snr}, {args.storage}, "
        f"{size / 1e6:.2f} MB) -> {bag.path}; calibrate with: clm calibrate {bag.path} --method impact"
    )
    return 0
