"""Writing a calibration: parameter files, summary, Markdown report and plots.

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

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import yaml

from clm_core.calibration.api import CalibrationResult
from clm_core.calibration.impact import SoilFit, measured_sums

_QUANT_UNIT = {"displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}


def _pick(result: CalibrationResult, k_max: int = 6) -> list[int]:
    chans = result.recording.channels
    if result.method == "impact":
        want = [0, 1, 2, 5, 10, 20, -1]
        out = [i for w in want for i, c in enumerate(chans) if c.index == w]
        out = list(dict.fromkeys(out))
        if len(out) < min(k_max, len(chans)):
            out += [i for i in range(len(chans)) if i not in out]
        return out[:k_max]
    return list(range(min(k_max, len(chans))))


def plot_transfer_functions(result: CalibrationResult, path: Path) -> None:
    """Amplitude [dB re 1 m/N] and phase [deg] of measured and fitted receptances."""
    data = result.data
    if data is None:
        return
    fit = result.main_fit
    Hm = fit.H_model if isinstance(fit, SoilFit) else np.asarray(fit.model_response)
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 7.5), sharex=True)
    f = data.frequency
    for n, k in enumerate(_pick(result)):
        col = f"C{n}"
        name = data.channels[k].name
        a1.semilogy(f, np.abs(data.H[:, k]), col, lw=1.0, label=name)
        a1.semilogy(f, np.abs(Hm[:, k]), col + "--", lw=1.4)
        a2.plot(f, np.degrees(np.angle(data.H[:, k])), col, lw=1.0)
        a2.plot(f, np.degrees(np.angle(Hm[:, k])), col + "--", lw=1.4)
    for c in result.comparisons:
        k0 = [k for k, ch in enumerate(data.channels) if ch.index == 0 and ch.location == "area"]
        if k0:
            a1.semilogy(f, np.abs(c.H_model[:, k0[0]]), ":", color="k" if c.model == "lysmer" else "0.5",
                        lw=1.2, label=f"area 0, {c.model} fit")
    a1.set_ylabel("|H| [m/N]")
    a2.set_ylabel("phase [deg]")
    a2.set_xlabel("frequency [Hz]")
    s_note = f", window decay {data.sigma:.3g} 1/s (H at s = sigma + j w)" if data.sigma > 0 else ""
    a1.set_title(f"{result.method}: measured (solid) vs fitted {result.model} (dashed), "
                 f"{result.norm} norm{s_note}", fontsize=9)
    a1.legend(fontsize=7, ncol=2)
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_sums(result: CalibrationResult, path: Path) -> bool:
    """Impact test: the impedances over the total and alternating sums, Eq. (16) and (18)."""
    data = result.data
    fit = result.main_fit
    if data is None or not isinstance(fit, SoilFit):
        return False
    meas = measured_sums(data)
    if meas is None:
        return False
    tot, alt, n_sum, how = meas
    cols = [k for k in range(len(data.channels))]
    from dataclasses import replace

    model = measured_sums(replace(data, H=fit.H_model[:, cols]))
    assert model is not None
    f = data.frequency
    fig, axs = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, part, fn in ((axs[0], "real", np.real), (axs[1], "imaginary", np.imag)):
        ax.plot(f, fn(tot) / 1e6, "C0", lw=1, label="F / sum X_j, measured (Eq. 16)")
        ax.plot(f, fn(model[0]) / 1e6, "C0--", lw=1.4, label="fitted CLM")
        ax.plot(f, fn(alt) / 1e6, "C1", lw=1, label="F / sum (-1)^j X_j, measured (Eq. 18)")
        ax.plot(f, fn(model[1]) / 1e6, "C1--", lw=1.4, label="fitted CLM")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(f"{part} part [MN/m]")
        ax.grid(True, alpha=0.3)
    axs[0].legend(fontsize=7)
    s = f" at s = {data.sigma:.3g} + j w" if data.sigma > 0 else ""
    fig.suptitle(f"Impedance sums of {how}{s}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def plot_time_histories(result: CalibrationResult, path: Path) -> bool:
    """Measured and fitted-model time histories of a few channels."""
    tm = result.time_model
    if tm is None:
        return False
    rec = result.recording
    picks = _pick(result, 4)
    fig, axs = plt.subplots(len(picks), 1, figsize=(9, 2.0 * len(picks) + 0.8), sharex=True, squeeze=False)
    t = rec.t
    if result.data is not None and result.data.hit_times:
        t0 = result.data.hit_times[0] - 0.02
        t1 = min(t[-1], t0 + min(0.15, result.data.segment))
    else:
        t0, t1 = t[0], t[-1]
    sel = (t >= t0) & (t <= t1)
    for ax, k in zip(axs[:, 0], picks):
        ch = rec.channels[k]
        ax.plot(t[sel], rec.responses[sel, k], "0.35", lw=0.8, label="measured")
        ax.plot(t[sel], tm[sel, k], "C3--", lw=1.2, label="fitted model")
        ax.set_ylabel(f"{ch.name}\n[{_QUANT_UNIT[ch.quantity]}]", fontsize=7)
        ax.grid(True, alpha=0.3)
    axs[0, 0].legend(fontsize=7)
    axs[-1, 0].set_xlabel("time [s]")
    what = "the measured force" if result.method != "passby" else "the measured wheel loads"
    axs[0, 0].set_title(f"{result.method}: fitted model driven by {what}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


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
        f"- covariance: {s.covariance}; scaled-Jacobian condition number {s.condition:.3g}",
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
    (d / "summary.json").write_text(result.summary_json() + "\n")
    written.append(d / "summary.json")
    pngs: list[str] = []
    if plots:
        if result.data is not None:
            plot_transfer_functions(result, d / "transfer_functions.png")
            pngs.append("transfer_functions.png")
        if plot_sums(result, d / "sums.png"):
            pngs.append("sums.png")
        if plot_time_histories(result, d / "time_histories.png"):
            pngs.append("time_histories.png")
    written += [d / p for p in pngs]
    names = [p.name for p in written] + ["report.md"]
    (d / "report.md").write_text(report_markdown(result, names))
    written.append(d / "report.md")
    return written
