"""Calibration figures: ``clm calibrate`` (measured vs fitted) and ``clm soil-calibrate`` (rigorous vs CLM)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from clm_core.outputs.plots._base import label_receptance_axes, legend, new_figure, receptance_lines, save, style

if TYPE_CHECKING:
    from clm_core.calibration.api import CalibrationResult
    from clm_core.halfspace.calibrate import SoilCalibration

_QUANT_UNIT = {"displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}


def _pick_channels(result: CalibrationResult, k_max: int = 6) -> list[int]:
    chans = result.recording.channels
    if result.method == "impact":
        want = [0, 1, 2, 5, 10, 20, -1]
        out = [i for w in want for i, c in enumerate(chans) if c.index == w]
        out = list(dict.fromkeys(out))
        if len(out) < min(k_max, len(chans)):
            out += [i for i in range(len(chans)) if i not in out]
        return out[:k_max]
    return list(range(min(k_max, len(chans))))


def _transfer_functions(result: CalibrationResult, path: Path) -> Figure | None:
    """Amplitude [m/N] and phase [deg] of measured (solid) and fitted (dashed) receptances of a few channels.

    Drawn when the fit used spectra (impact and receptance tests); the
    Lysmer and Winkler comparison fits of area 0 are dotted.
    """
    from clm_core.calibration.impact import SoilFit

    data = result.data
    if data is None:
        return None
    fit = result.main_fit
    Hm = fit.H_model if isinstance(fit, SoilFit) else np.asarray(fit.model_response)
    with style():
        fig, axs = new_figure(2, 1, (9.0, 7.5), sharex=True)
        a1, a2 = axs[:, 0]
        f = data.frequency
        for n, k in enumerate(_pick_channels(result)):
            col = f"C{n}"
            receptance_lines(a1, a2, f, data.H[:, k], color=col, lw=1.0, label=data.channels[k].name)
            receptance_lines(a1, a2, f, Hm[:, k], color=col, ls="--", lw=1.4)
        for c in result.comparisons:
            k0 = [k for k, ch in enumerate(data.channels) if ch.index == 0 and ch.location == "area"]
            if k0:
                a1.semilogy(f, np.abs(c.H_model[:, k0[0]]), ":", color="k" if c.model == "lysmer" else "0.5",
                            lw=1.2, label=f"area 0, {c.model} fit")
        label_receptance_axes(a1, a2, "|H| [m/N]")
        s_note = f", window decay {data.sigma:.3g} 1/s (H at s = sigma + j w)" if data.sigma > 0 else ""
        fig.suptitle(f"{result.method}: measured (solid) vs fitted {result.model} (dashed), "
                     f"{result.norm} norm{s_note}", fontsize=9.5)
        legend(a1, ncol=2)
        save(fig, path)
    return fig


def _sums(result: CalibrationResult, path: Path) -> Figure | None:
    """Impact test: the impedances over the total and alternating sums, Eq. (16) and (18), measured and fitted.

    Drawn for an impact test with a soil fit and measured neighbours.
    """
    from clm_core.calibration.impact import SoilFit, measured_sums

    data = result.data
    fit = result.main_fit
    if data is None or not isinstance(fit, SoilFit):
        return None
    meas = measured_sums(data)
    if meas is None:
        return None
    tot, alt, _, how = meas
    model = measured_sums(replace(data, H=fit.H_model[:, list(range(len(data.channels)))]))
    if model is None:
        return None
    f = data.frequency
    with style():
        fig, axs = new_figure(1, 2, (11.0, 4.5))
        for ax, part, fn in ((axs[0, 0], "real", np.real), (axs[0, 1], "imaginary", np.imag)):
            ax.plot(f, fn(tot) / 1e6, color="C0", lw=1, label="F / sum X_j, measured (Eq. 16)")
            ax.plot(f, fn(model[0]) / 1e6, color="C0", ls="--", lw=1.4, label="fitted CLM")
            ax.plot(f, fn(alt) / 1e6, color="C1", lw=1, label="F / sum (-1)^j X_j, measured (Eq. 18)")
            ax.plot(f, fn(model[1]) / 1e6, color="C1", ls="--", lw=1.4, label="fitted CLM")
            ax.set_xlabel("frequency [Hz]")
            ax.set_ylabel(f"{part} part [MN/m]")
        legend(axs[0, 0])
        s = f" at s = {data.sigma:.3g} + j w" if data.sigma > 0 else ""
        fig.suptitle(f"Impedance sums of {how}{s}", fontsize=9.5)
        save(fig, path)
    return fig


def _time_histories(result: CalibrationResult, path: Path) -> Figure | None:
    """Measured time histories of a few channels against the fitted model driven by the measured input.

    Drawn when the calibration produced a time model.
    """
    tm = result.time_model
    if tm is None:
        return None
    rec = result.recording
    picks = _pick_channels(result, 4)
    with style():
        fig, axs = new_figure(len(picks), 1, (9.0, 2.0 * len(picks) + 0.9), sharex=True)
        t = rec.t
        if result.data is not None and result.data.hit_times:
            t0 = result.data.hit_times[0] - 0.02
            t1 = min(t[-1], t0 + min(0.15, result.data.segment))
        else:
            t0, t1 = t[0], t[-1]
        sel = (t >= t0) & (t <= t1)
        for ax, k in zip(axs[:, 0], picks, strict=True):
            ch = rec.channels[k]
            ax.plot(t[sel], rec.responses[sel, k], color="0.35", lw=0.8, label="measured")
            ax.plot(t[sel], tm[sel, k], color="C3", ls="--", lw=1.2, label="fitted model")
            ax.set_ylabel(f"{ch.name}\n[{_QUANT_UNIT[ch.quantity]}]", fontsize=7.5)
        legend(axs[0, 0])
        axs[-1, 0].set_xlabel("time [s]")
        what = "the measured force" if result.method != "passby" else "the measured wheel loads"
        axs[0, 0].set_title(f"{result.method}: fitted model driven by {what}", fontsize=9)
        save(fig, path)
    return fig


def plot_calibration(result: CalibrationResult, out: str | Path) -> list[str]:
    """The calibration figures that apply to ``result``; returns their file names in ``out``.

    ``transfer_functions.png`` (when spectra were fitted), ``sums.png``
    (impact test with a soil fit), ``time_histories.png`` (when a fitted
    time model exists). ``result`` is what :func:`clm_core.calibration.calibrate`
    returned. Each figure is drawn by a function of ``(result, path)`` that
    writes the PNG file ``path`` and returns the figure, or writes nothing and
    returns None when the figure does not apply.
    """
    d = Path(out)
    names = []
    for name, fn in (("transfer_functions.png", _transfer_functions), ("sums.png", _sums),
                     ("time_histories.png", _time_histories)):
        if fn(result, d / name) is not None:
            names.append(name)
    return names


def plot_soil_calibration(cal: SoilCalibration, out: str | Path) -> list[str]:
    """``sums.png`` and ``receptances.png`` of ``clm soil-calibrate``: rigorous row against the fitted CLM.

    Parameters
    ----------
    cal : SoilCalibration
        From :func:`clm_core.halfspace.calibrate.calibrate_profile`.
    out : path
        Output directory (must exist).

    Returns
    -------
    list of str
        File names written in ``out``.
    """
    d = Path(out)
    f = cal.freqs
    fit = cal.fit
    n_areas = cal.row.geometry.n_areas
    clm = cal.clm_response()
    j = np.arange(n_areas) - n_areas // 2
    sign = np.where(j % 2 == 0, 1.0, -1.0)
    S_clm = 1.0 / clm.sum(axis=1)
    A_clm = 1.0 / (clm * sign).sum(axis=1)
    every = max(1, f.size // 14)
    with style():
        fig, axs = new_figure(2, 2, (11.0, 7.5), sharex=True)
        for col, (name, ref, formula, chain) in enumerate(
            (
                ("F / sum X_j  (Eq. 16)", cal.total_sum, fit.total_sum(f), S_clm),
                ("F / sum (-1)^j X_j  (Eq. 18)", cal.alternating_sum, fit.alternating_sum(f), A_clm),
            )
        ):
            for row, part in enumerate(("real", "imag")):
                ax = axs[row, col]
                get = np.real if part == "real" else np.imag
                ax.plot(f, get(ref) / 1e6, color="k", lw=1.2, label="rigorous (BEM)")
                ax.plot(f, get(chain) / 1e6, color="C0", lw=3.0, alpha=0.45, label=f"CLM chain, N = {n_areas}")
                ax.plot(f, get(formula) / 1e6, color="C3", ls="--", lw=1.1, marker="o", ms=4, mfc="white",
                        markevery=(every // 2, every), zorder=3, label="CLM formula")
                ax.axvspan(fit.band[0], fit.band[1], color="0.9", zorder=0)
                ax.set_ylabel(f"{'Re' if part == 'real' else 'Im'} [MN/m]")
                if row == 0:
                    ax.set_title(name)
                else:
                    ax.set_xlabel("frequency [Hz]")
        legend(axs[0, 0])
        fig.suptitle(f"{cal.profile.name}: fit band {fit.band[0]:g}-{fit.band[1]:g} Hz (shaded), norm '{fit.norm}'")
        save(fig, d / "sums.png")

        fig, axs = new_figure(2, 1, (9.0, 7.0), sharex=True)
        a0, a1 = axs[:, 0]
        c = n_areas // 2
        for k, colr in zip(range(3), ("k", "C3", "C0"), strict=False):
            if c + k >= n_areas:
                break
            receptance_lines(a0, a1, f, cal.row.centre_column[:, c + k], unwrap=True, color=colr, ls="-",
                             label=f"area {k}: rigorous")
            receptance_lines(a0, a1, f, clm[:, c + k], unwrap=True, color=colr, ls="--", label=f"area {k}: CLM")
        label_receptance_axes(a0, a1, "|X_j / F| [m/N]")
        legend(a0, ncol=3)
        a0.set_title(f"{cal.profile.name}: receptances of the loaded area (0) and its neighbours")
        save(fig, d / "receptances.png")
    return ["sums.png", "receptances.png"]
