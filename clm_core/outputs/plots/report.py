"""Report figures shared by every time-domain run: spectra, one-third-octave bands, the soil-force envelope.

Used by :func:`~clm_core.outputs.plots.plot_run` (moving loads),
:func:`~clm_core.outputs.plots.plot_vehicle_run` (vehicle runs) and
:func:`~clm_core.outputs.plots.plot_demo` (the ROS demo), so the three outputs
carry the same figures:

- ``spectra.png``: single-sided amplitude spectra (:func:`clm_core.spectra.amplitude_spectrum`)
  of the dynamic part of each record, 0-80 Hz (the band of ground-borne
  vibration, DIN 4150) beside 80-500 Hz on its own scale (linear axes);
- ``third_octave.png``: one-third-octave band rms (:func:`clm_core.spectra.third_octave_bands`);
- ``soil_forces.png``: soil force over time of a few sleepers with the peak
  sleeper among them, and the envelope along the track (largest and
  smallest force of every sleeper) with the peak sleeper marked and tensile
  (negative) forces flagged.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.outputs.plots._base import decimate, figure_legend, legend, new_figure, save, style
from clm_core.peaks import SleeperEnvelope
from clm_core.spectra import amplitude_spectrum, nominal_frequency, third_octave_bands

#: Upper end of the linear spectrum panel [Hz] (ground-borne vibration band).
F_EMPHASIS = 80.0
#: Highest frequency drawn on the right-hand panels [Hz].
F_TOP = 500.0


@dataclass(frozen=True)
class Record:
    """A uniformly sampled record to draw in the spectra.

    Attributes
    ----------
    label : str
        Legend entry.
    x : (n,) array
        Values in SI units (finite).
    dt : float
        Sampling interval [s].
    reference : float or None
        Value removed first (e.g. the static wheel load); None: the mean.
    """

    label: str
    x: Array
    dt: float
    reference: float | None = None


@dataclass(frozen=True)
class Quantity:
    """A row of panels: records of one quantity, with its unit and scale from SI."""

    name: str
    unit: str
    scale: float
    records: Sequence[Record]


def uniform(t: Array, y: Array) -> tuple[Array, float] | None:
    """The finite stretch of ``y(t)`` resampled on a uniform grid of the median step: (values, dt); None if < 16."""
    ok = np.isfinite(y) & np.isfinite(t)
    if ok.sum() < 16:
        return None
    i = np.flatnonzero(ok)
    tt, yy = t[i[0]: i[-1] + 1], y[i[0]: i[-1] + 1]
    fin = np.isfinite(yy)
    dt = float(np.median(np.diff(tt[fin])))
    if not dt > 0:
        return None
    grid = tt[0] + dt * np.arange(int(np.floor((tt[-1] - tt[0]) / dt + 1e-9)) + 1)
    if grid.size == tt.size and np.allclose(grid, tt, rtol=0, atol=1e-9 * max(1.0, abs(float(tt[-1])))) and fin.all():
        return yy.astype(float), dt
    return np.interp(grid, tt[fin], yy[fin]), dt


def plot_spectra(path: Path, quantities: Sequence[Quantity], title: str,
                 marks: Sequence[tuple[float, str]] = ()) -> Path:
    """``spectra.png``: per quantity, amplitude spectra 0-80 Hz and 80-500 Hz (own scale), linear axes.

    ``marks``: (frequency [Hz], label) drawn as dashed verticals (e.g. the sleeper-passing frequency V/d).
    """
    rows = [q for q in quantities if q.records]
    with style():
        fig, axs = new_figure(max(1, len(rows)), 2, (10.0, 2.6 * max(1, len(rows)) + 0.8),
                              gridspec_kw={"width_ratios": [1.25, 1.0]})
        colour = 0
        for (lo, hi), q in zip(axs, rows, strict=False):
            top = 0.0
            for r in q.records:
                k, colour = colour, colour + 1
                s = amplitude_spectrum(r.x, r.dt, r.reference)
                f, a = s.frequency, s.amplitude * q.scale
                top = max(top, float(f[-1]))
                band = (f > 0) & (f <= F_EMPHASIS)
                lo.plot(*decimate(f[band], a[band]), lw=0.8, color=f"C{k}", label=r.label)
                keep = (f >= F_EMPHASIS) & (f <= F_TOP)
                if keep.any():
                    hi.plot(*decimate(f[keep], a[keep]), lw=0.6, color=f"C{k}")
            for fm, lab in marks:
                for ax in (lo, hi):
                    if (0 < fm <= F_EMPHASIS) if ax is lo else (F_EMPHASIS < fm <= F_TOP):
                        ax.axvline(fm, color="0.3", ls="--", lw=0.7, label=lab if ax is lo and q is rows[0] else None)
            lo.set_xlim(0.0, F_EMPHASIS)
            hi.set_xlim(F_EMPHASIS, min(F_TOP, top) if top > F_EMPHASIS else F_TOP)
            lo.set_ylabel(f"{q.name}\namplitude [{q.unit}]")
            hi.set_ylabel(f"amplitude [{q.unit}]")
            lo.set_title(f"{q.name}: 0-{F_EMPHASIS:g} Hz", fontsize=8.5)
            hi.set_title(f"{F_EMPHASIS:g}-{min(F_TOP, top):.0f} Hz (own scale)", fontsize=8.5)
        for ax in axs.ravel():
            ax.set_xlabel("frequency [Hz]")
        # one legend below the panels (outside every axes: nothing to move, one layout pass)
        figure_legend(fig, list(axs[:, 0]))
        fig.suptitle(title + "\nsingle-sided amplitude spectra of the dynamic part (static or mean value removed)",
                     fontsize=9.5)
        return save(fig, path)


def plot_third_octave(path: Path, quantities: Sequence[Quantity], title: str, f_max: float = 400.0) -> Path:
    """``third_octave.png``: one-third-octave band rms of each record, 1 Hz to ``f_max`` (or below Nyquist)."""
    rows = [q for q in quantities if q.records]
    with style():
        fig, axs = new_figure(max(1, len(rows)), 1, (9.0, 2.7 * max(1, len(rows)) + 0.8))
        colour = 0
        for ax, q in zip(axs[:, 0], rows, strict=False):
            lo_b, hi_b = 10**6, -(10**6)
            for r in q.records:
                k, colour = colour, colour + 1
                b = third_octave_bands(r.x, r.dt, f_min=1.0, f_max=min(f_max, 0.5 / r.dt / 10 ** (1 / 20)),
                                       reference=r.reference)
                rms = np.where(b.lines > 0, b.rms * q.scale, np.nan)  # a band without FFT line: not resolved
                # bands at equal spacing (a log-frequency axis), labelled by their nominal centres
                band = np.round(10.0 * np.log10(b.centre / 1000.0)).astype(int)
                ax.plot(band, rms, "o-", ms=3, lw=0.9, color=f"C{k}", label=r.label)
                lo_b, hi_b = min(lo_b, int(band[0])), max(hi_b, int(band[-1]))
            ticks = np.arange(lo_b, hi_b + 1)
            ticks = ticks[ticks % 3 == 0]
            ax.set_xticks(ticks, [f"{v:g}" for v in nominal_frequency(1000.0 * 10.0 ** (ticks / 10.0))])
            ax.axvspan(-30.5, 10.0 * np.log10(F_EMPHASIS / 1000.0) + 0.5, color="0.9", zorder=0, lw=0)
            ax.set_xlim(lo_b - 0.5, hi_b + 0.5)
            ax.set_xlabel("one-third-octave band centre frequency [Hz]")
            ax.set_ylabel(f"{q.name}\nband rms [{q.unit}]")
        figure_legend(fig, list(axs[:, 0]))
        fig.suptitle(title + f"\none-third-octave band rms of the dynamic part (shaded: 1-{F_EMPHASIS:g} Hz; bands "
                     "narrower than the record's line spacing left out)",
                     fontsize=9.5)
        return save(fig, path)


def envelope_panel(ax: Axes, env: SleeperEnvelope, spacing: float, admitted: NDArray[np.bool_] | None = None) -> None:
    """Largest and smallest soil force of every sleeper along the track [kN], peak marked, tension flagged."""
    x = env.sleeper_index * spacing
    ax.fill_between(x, env.minimum / 1e3, env.maximum / 1e3, color="C0", alpha=0.15, lw=0)
    ax.plot(x, env.maximum / 1e3, color="C3", lw=0.9, label="largest (compression +)")
    ax.plot(x, env.minimum / 1e3, color="C0", lw=0.9, label="smallest")
    ax.axhline(0.0, color="0.2", lw=0.6)
    d = env.describe(admitted)
    g = d["envelope_peak_sleeper_index"]
    ax.plot([g * spacing], [d["envelope_peak_soil_force_N"] / 1e3], "v", color="k", ms=6, ls="none",
            label=f"peak: sleeper {g}, {d['envelope_peak_soil_force_N'] / 1e3:.1f} kN")
    if d["tensile_sleepers"]:
        ten = env.tensile if admitted is None else env.tensile & np.asarray(admitted, bool)
        ax.plot(x[ten], env.minimum[ten] / 1e3, ".", color="C1", ms=3, ls="none", label="tensile (negative)")
    ax.set_xlabel("position along the line [m]")
    ax.set_ylabel("soil force [kN]")
    note = (f"\nNOTE: tensile (negative) soil force at {d['tensile_sleepers']} sleeper(s), down to "
            f"{d['envelope_min_soil_force_N'] / 1e3:.2f} kN: the model's ballast spring carries tension"
            if d["tensile_sleepers"] else "")
    ax.set_title("envelope along the track: largest and smallest soil force of each sleeper" + note, fontsize=8.5)
    legend(ax, "center right")


def plot_soil_forces(path: Path, series: Sequence[tuple[int, Array, Array]], peak_sleeper: int,
                     env: SleeperEnvelope, spacing: float, title: str, admitted: NDArray[np.bool_] | None = None,
                     note: str = "") -> Path:
    """``soil_forces.png``: soil force over time of the sleepers of ``series`` ((index, t [s], F [N])), the peak
    sleeper drawn heavier; below, the envelope along the track (:func:`envelope_panel`)."""
    with style():
        fig, axs = new_figure(2, 1, (9.0, 7.0))
        a0, a1 = axs[:, 0]
        spans = [float(t[-1] - t[0]) for _, t, _ in series if t.size > 1]
        whole = (max(float(t[-1]) for _, t, _ in series if t.size) - min(float(t[0]) for _, t, _ in series if t.size)
                 if spans else 0.0)
        # sleepers passed far apart in time (a long run): each from its entry into the window, overlaid
        aligned = bool(spans) and whole > 4.0 * max(spans)
        for k, (g, t, F) in enumerate(series):
            peak = g == peak_sleeper
            tt = t - t[0] if aligned and t.size else t
            a0.plot(*decimate(tt, F / 1e3), lw=1.3 if peak else 0.8, color="k" if peak else f"C{k}",
                    zorder=3 if peak else 2,
                    label=f"sleeper {g} (x = {g * spacing:.1f} m)" + (", peak" if peak else ""))
        a0.axhline(0.0, color="0.2", lw=0.6)
        a0.set_xlabel("time since the sleeper entered the simulated window (it moves with the train) [s]"
                      if aligned else "time [s]")
        a0.set_ylabel("soil force under sleeper [kN]")
        a0.set_title(title + (f" ({note})" if note else ""), fontsize=9)
        if series:
            legend(a0)
        envelope_panel(a1, env, spacing, admitted)
        return save(fig, path)


def pick_series(first_sleeper: Array, soil_force: Array, t: Array, candidates: Sequence[int],
                peak_sleeper: int) -> list[tuple[int, Array, Array]]:
    """(index, t, force) of the ``candidates`` and the peak sleeper from window-relative forces (NaN removed)."""
    out = []
    for g in sorted({*candidates, peak_sleeper}):
        col = g - first_sleeper
        ok = np.flatnonzero((col >= 0) & (col < soil_force.shape[1]))
        if ok.size:
            y = soil_force[ok, col[ok]]
            out.append((int(g), t[ok], np.asarray(y, dtype=float)))
    return out


def report_figures(out: Path, quantities: Sequence[Quantity], title: str, marks: Sequence[tuple[float, str]],
                   on_file: Callable[[Path], None] | None = None) -> list[Path]:
    """``spectra.png`` and ``third_octave.png`` of ``quantities`` into ``out``."""
    written = [plot_spectra(out / "spectra.png", quantities, title, marks)]
    if on_file:
        on_file(written[-1])
    written.append(plot_third_octave(out / "third_octave.png", quantities, title))
    if on_file:
        on_file(written[-1])
    return written
