"""Writing a calibration: parameter files, summary, Markdown report and plots.

The figures are drawn by :func:`clm_core.outputs.plots.plot_calibration`.

:func:`write_outputs` writes into one directory:

``params.yaml``
    Full parameter file (rail, track, soil) with the fitted values;
    ``clm receptance --params params.yaml`` and the track node load it.
``soil.yaml``
    Soil preset (``clm:`` section, the format of ``clm_core/presets/soils``)
    for a fitted CLM or Lysmer soil; ``--soil soil.yaml`` loads it.
``track.yaml``
    Track preset (``rail:``, ``track:``) for receptance and pass-by fits.
``summary.json``
    :meth:`CalibrationResult.summary`: values, intervals, band, norm,
    residuals, warnings.
``report.md``
    The table of parameters with intervals, the fit quality and the plots.
``transfer_functions.png``, ``sums.png``, ``time_histories.png``
    Measured against fitted: amplitude and phase of the receptances, the
    impedance sums of Eq. (16) and (18) (impact), and time histories.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from clm_core.calibration.api import CalibrationResult
from clm_core.calibration.impact import SoilFit
from clm_core.io.files import write_json


def _fmt(x: float) -> str:
    if not math.isfinite(x):
        return "-"
    return f"{x:.4g}"


def report_markdown(result: CalibrationResult, files: list[str]) -> str:
    """The Markdown report text."""
    r = result
    lines = [
        f"# Calibration report: {r.method} test",
        "",
        f"- bag: `{r.bag}` ({r.storage}), channel map `{r.channel_map.source}`",
        f"- record: {r.recording.duration:.3f} s at {r.recording.fs:.6g} Hz, "
        f"{len(r.recording.channels)} response channel(s)",
        f"- model: **{r.model}**; band **{r.band[0]:g}-{r.band[1]:g} Hz**; error norm **{r.norm}**",
        f"- first estimate: {r.first_estimate_method}",
        f"- wall time {r.elapsed_s:.2f} s",
        "",
        "## Fitted parameters (95 % intervals)",
        "",
        "| parameter | value | unit | 95 % interval | +- % | first estimate | notes |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in r.parameters:
        notes = []
        if not p.identifiable:
            notes.append("NOT IDENTIFIABLE")
        if p.at_bound:
            notes.append("on a constraint")
        rel = p.rel_halfwidth
        lines.append(
            f"| {p.name} | {_fmt(p.value)} | {p.unit} | [{_fmt(p.ci_low)}, {_fmt(p.ci_high)}] | "
            f"{_fmt(100 * rel) if math.isfinite(rel) else '-'} | {_fmt(p.initial)} | {', '.join(notes)} |"
        )
    s = r.stats
    lines += [
        "",
        "## Fit quality",
        "",
        f"- relative misfit in the {r.norm} norm, ||W (model - data)|| / ||W data||: {r.misfit:.4g}",
        f"- rms of the residuals in the {r.norm} norm: {s.rms:.4g}"
        + (" (about 1 means the model explains the data down to the noise)" if r.norm == "weighted" else ""),
        f"- residuals over their noise expectation: {_fmt(s.noise_ratio)}",
        f"- {s.n_residuals} residuals, {s.n_params} parameters, {s.nfev} residual evaluations of the optimiser "
        f"(Jacobians not counted); {s.status}",
        f"- covariance: {s.covariance}, intervals '{s.interval}'; scaled-Jacobian condition number {s.condition:.3g}",
    ]
    main = r.main_fit
    if isinstance(main, SoilFit):
        trials = ", ".join(f"{n} areas: {rr:.4g}" for n, rr in main.chain_trials)
        lines.append(
            f"- model chain: {main.n_areas} areas ({main.chain_selection}"
            + (f"; rms residual of the lengths tried: {trials}" if len(main.chain_trials) > 1 else "")
            + ")"
        )
        if main.whiteness is not None:
            w = main.whiteness
            lines.append(
                f"- residuals whitened by the noise model: rms {w.rms:.3g}, lag-1 autocorrelation {w.lag1:.3f}, "
                f"Ljung-Box Q = {w.ljung_box:.4g} ({w.lags} lags, p = {w.p_value:.2g}); noise alone gives about 1, 0 "
                "and p uniform in (0, 1)"
            )
        if main.first_estimate_parameters:
            lines += [
                "",
                "## First estimate (Eq. 16/18 sums) with its 95 % intervals",
                "",
                "| parameter | value | unit | 95 % interval |",
                "|---|---|---|---|",
            ]
            lines += [
                f"| {p.name} | {_fmt(p.value)} | {p.unit} | [{_fmt(p.ci_low)}, {_fmt(p.ci_high)}] |"
                for p in main.first_estimate_parameters
            ]
    if r.data is not None:
        d = r.data
        snr = d.snr_db[np.isfinite(d.snr_db)]
        lines += [
            f"- {d.n_hits} hit(s) at {', '.join(f'{x:.3f}' for x in d.hit_times)} s, segments of {d.segment:.3f} s, "
            f"{d.frequency.size} lines; exponential window decay {d.sigma:.3g} 1/s"
            + (
                f"; estimated SNR {snr.min():.1f}-{snr.max():.1f} dB (force {d.force_snr_db:.1f} dB)"
                if snr.size
                else ""
            ),
        ]
    if r.comparisons:
        lines += [
            "",
            "## Comparison of soil models (same data, band and norm)",
            "",
            "| model | parameters | misfit on area 0 | rms residual |",
            "|---|---|---|---|",
        ]
        main = r.main_fit
        assert isinstance(main, SoilFit)
        for c in (main, *r.comparisons):
            vals = ", ".join(f"{p.name} = {_fmt(p.value)} {p.unit}" for p in c.parameters)
            lines.append(f"| {c.model} | {vals} | {c.misfit_loaded:.4g} | {c.stats.rms:.4g} |")
    if r.warnings:
        lines += ["", "## Warnings", ""] + [f"- {w}" for w in r.warnings]
    if r.notes:
        lines += ["", "## Processing notes", ""] + [f"- {n}" for n in r.notes]
    lines += ["", "## Files", ""] + [f"- `{f}`" for f in files]
    for f in files:
        if f.endswith(".png"):
            lines += ["", f"![{f}]({f})"]
    return "\n".join(lines) + "\n"


def write_outputs(result: CalibrationResult, out_dir: str | Path, plots: bool = True) -> list[Path]:
    """Write parameter files, summary.json, report.md and plots (module docstring).

    Parameters
    ----------
    result : CalibrationResult
        What :func:`clm_core.calibration.calibrate` returned.
    out_dir : path
        Output directory (created if needed; files in it are overwritten).
    plots : bool
        Write the PNG plots.

    Returns
    -------
    list of Path
        The files written.
    """
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    header = (
        f"# Calibrated by `clm calibrate` ({result.method} test, {result.model}, band "
        f"{result.band[0]:g}-{result.band[1]:g} Hz, {result.norm} norm) from {result.bag}\n"
    )
    (d / "params.yaml").write_text(header + result.parameters_yaml())
    written.append(d / "params.yaml")
    soil = result.params.soil
    if soil.model in ("clm", "lysmer") and (result.method == "impact" or result.options.soil == "joint"):
        vals = {k: float(getattr(soil, k)) for k in ("mf", "df", "kf", "dc", "kc")}
        preset: dict[str, Any] = {
            "name": "calibrated",
            "source": f"clm calibrate, {result.method} test, {result.model} fit, band "
            f"{result.band[0]:g}-{result.band[1]:g} Hz, {result.norm} norm, bag {result.bag}",
            "clm": vals,
        }
        (d / "soil.yaml").write_text(
            f"# Soil preset from a calibration ({soil.model}; kc = dc = 0 for Lysmer); load with --soil soil.yaml"
            + (" --model lysmer" if soil.model == "lysmer" else "")
            + "\n"
            + yaml.safe_dump(preset, sort_keys=False)
        )
        written.append(d / "soil.yaml")
    if result.method != "impact":
        pd = result.params.to_dict()
        trk = {"name": "calibrated", "source": f"clm calibrate, {result.method} test", "rail": pd["rail"],
               "track": pd["track"]}
        (d / "track.yaml").write_text(header + yaml.safe_dump(trk, sort_keys=False))
        written.append(d / "track.yaml")
    written.append(write_json(d / "summary.json", result.summary()))
    pngs: list[str] = []
    if plots:
        from clm_core.outputs.plots import plot_calibration

        pngs = plot_calibration(result, d)
    written += [d / p for p in pngs]
    names = [p.name for p in written] + ["report.md"]
    (d / "report.md").write_text(report_markdown(result, names))
    written.append(d / "report.md")
    return written
