"""Time-domain figures: moving-load runs, coupled vehicle runs and the ROS demo."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.outputs.plots._base import (
    decimate,
    figure_legend,
    legend,
    new_figure,
    pick_wheels,
    save,
    style,
    wheel_panels,
)
from clm_core.outputs.plots.report import Quantity, Record, pick_series, plot_soil_forces, report_figures, uniform
from clm_core.peaks import SleeperEnvelope, sleeper_envelope

if TYPE_CHECKING:
    from clm_core.outputs.history import RunDigest
    from clm_core.vehicle.coupled import CoupledResult

#: Figures of a vehicle run (:func:`plot_vehicle_run`), in the order written.
VEHICLE_FIGURES = ("wheel_loads.png", "soil_forces.png", "spectra.png", "third_octave.png")
#: Figures of the ROS demo (:func:`plot_demo`).
DEMO_FIGURES = ("sleeper_soil_forces.png", "rail_deflection.png", "wheel_loads.png", "soil_forces.png",
                "spectra.png", "third_octave.png")
#: Report figures of a moving-load run beside ``simulate.png`` (:func:`plot_run_report`).
RUN_FIGURES = ("soil_forces.png", "spectra.png", "third_octave.png")


def plot_run(
    history_npz: str | Path, digest: RunDigest, sleepers: list[int], path: str | Path, title: str = ""
) -> Figure:
    """Sleeper soil forces over time for a few sleepers, and the rail deflection along the track at its maximum.

    Parameters
    ----------
    history_npz : path
        The run's ``history.npz``.
    digest : RunDigest
        From :meth:`clm_core.outputs.history.HistoryWriter.close`.
    sleepers : list of int
        Global indices of the sleepers to plot.
    path : path
        PNG file.
    title : str
        Title of the upper panel.

    Returns
    -------
    Figure
        The figure written.
    """
    with style():
        fig, axs = new_figure(2, 1, (9.0, 7.0))
        ax1, ax2 = axs[:, 0]
        with np.load(history_npz, mmap_mode="r") as z:
            t = z["t"]
            first = z["first_sleeper"]
            sf = z["soil_force"]
            spacing = float(z["spacing"])
            for g in sleepers:
                col = g - first
                ok = np.nonzero((col >= 0) & (col < sf.shape[1]))[0]
                if ok.size:
                    ax1.plot(*decimate(t[ok], sf[ok, col[ok]] / 1e3), label=f"sleeper {g} (x = {g * spacing:.1f} m)")
        ax1.set_xlabel("time [s]")
        ax1.set_ylabel("soil force under sleeper [kN]")
        if sleepers:
            legend(ax1)
        ax2.plot(digest.profile_x, digest.profile_rail * 1e3, "o-", ms=3, label="rail above sleepers")
        for i, xw in enumerate(digest.profile_wheels[np.isfinite(digest.profile_wheels)]):
            ax2.axvline(xw, color="C3", lw=0.8, ls="--", label="wheels" if i == 0 else None)
        ax2.invert_yaxis()
        ax2.set_xlabel("position along the line [m]")
        ax2.set_ylabel("rail deflection [mm] (down)")
        ax2.set_title(f"at t = {digest.t_max:.4f} s (largest rail deflection)", fontsize=9)
        legend(ax2, "lower right")
        ax1.set_title(title or "Moving wheel loads")
        save(fig, path)
    return fig


def plot_vehicle_run(res: CoupledResult, out: str | Path, title: str = "", envelope: SleeperEnvelope | None = None,
                     on_file: Callable[[Path], None] | None = None) -> list[Path]:
    """The figures of a coupled vehicle run (:data:`VEHICLE_FIGURES`).

    ``wheel_loads.png`` (one panel per wheel, static load dashed, dynamic
    factor in the title), ``soil_forces.png`` (time histories with the peak
    sleeper, the envelope along the track), ``spectra.png`` and
    ``third_octave.png`` (wheel loads about their static value, soil force of
    the peak sleeper, rail deflection under wheel 0).

    Parameters
    ----------
    res : CoupledResult
        The run.
    out : path
        Output directory (must exist).
    title : str
        Title of the wheel-load figure.
    envelope : SleeperEnvelope, optional
        The soil-force envelope (:func:`clm_core.peaks.sleeper_envelope`); default from ``res``.
    on_file : callable, optional
        Called with each file once written.

    Returns
    -------
    list of Path
        The PNG files written.
    """
    d = Path(out)
    nw = res.wheel_load.shape[1]
    wheels = pick_wheels(nw)
    written = []
    tell = on_file or (lambda _p: None)
    with style():
        n = len(wheels) + 1
        fig, axs = new_figure(n, 1, (9.0, 1.3 * n + 1.2), sharex=True,
                           gridspec_kw={"height_ratios": [1.0] * len(wheels) + [1.2]})
        wheel_panels(list(axs[:-1, 0]), res.t, res.wheel_load, wheels, res.static_wheel_load)
        ax = axs[-1, 0]
        ax.plot(*decimate(res.t, res.irregularity[:, 0] * 1e3), color="C2", lw=0.8,
                label="irregularity r under wheel 0 (down +)")
        ax.plot(*decimate(res.t, res.rail_deflection[:, 0] * 1e3), color="C1", lw=0.8,
                label="rail deflection under wheel 0")
        ax.set_ylabel("wheel 0\n[mm]")
        ax.set_xlabel("time [s]")
        figure_legend(fig, list(axs[:, 0]))
        shown = "" if len(wheels) == nw else f" (wheels {', '.join(map(str, wheels))} of {nw})"
        fig.suptitle((title or "Wheel loads") + shown, fontsize=9.5)
        written.append(save(fig, d / "wheel_loads.png"))
        tell(written[-1])

    spacing = float(res.sleeper_x[1] - res.sleeper_x[0]) if res.sleeper_x.size > 1 else 0.6
    lo = int(res.sleeper_index[0]) if res.sleeper_index.size else 0
    if envelope is None:
        fin = np.isfinite(res.soil_force)
        first = np.where(fin.any(axis=1), np.argmax(fin, axis=1), 0)
        cols = np.minimum(first[:, None] + np.arange(max(1, int(fin.sum(axis=1).max())))[None, :],
                          res.sleeper_index.size - 1)
        envelope = sleeper_envelope(first + lo, np.take_along_axis(res.soil_force, cols, axis=1),
                                    res.sleeper_index, res.peak_soil_force)
    window = res.peak_window()
    admitted = window.sleepers(envelope.sleeper_index * spacing)
    g_peak = int(envelope.describe(admitted)["envelope_peak_sleeper_index"])
    held = np.isfinite(res.peak_soil_force)  # sleepers the window held (no pass over the (instants, sleepers) arrays)
    good = np.flatnonzero(held & window.sleepers(res.sleeper_x))
    good = good if good.size else np.flatnonzero(held)
    picks = [int(res.sleeper_index[j]) for j in good[np.linspace(0, good.size - 1, min(3, good.size)).round()
                                                       .astype(int)]] if good.size else []
    series = []
    for g in sorted({*picks, g_peak}):
        y = res.soil_force[:, g - lo]
        ok = np.isfinite(y)
        series.append((g, res.t_out[ok], y[ok]))
    written.append(plot_soil_forces(d / "soil_forces.png", series, g_peak, envelope, spacing,
                                    "sleeper soil forces (ballast force on the soil, compression +)", admitted))
    tell(written[-1])

    dt = float(res.t[1] - res.t[0]) if res.t.size > 1 else 1.0
    sel = res.t >= float(res.meta.get("stats_from", 0.0))
    loads = [Record(f"wheel {i} (static {res.static_wheel_load[i] / 1e3:.1f} kN removed)", res.wheel_load[sel, i], dt,
                    float(res.static_wheel_load[i])) for i in wheels[:3]] if sel.sum() > 16 else []
    peak_rec = uniform(res.t_out, res.soil_force[:, g_peak - lo])
    rail = [Record("rail under wheel 0", res.rail_deflection[sel, 0], dt)] if sel.sum() > 16 else []
    V = float(res.meta.get("speed", 0.0))
    marks = [(V / spacing, f"V/d = {V / spacing:.1f} Hz")] if V > 0 else []
    written += report_figures(d, [
        Quantity("wheel load", "kN", 1e-3, loads),
        Quantity("soil force", "kN", 1e-3, [Record(f"sleeper {g_peak} (peak)", *peak_rec)] if peak_rec else []),
        Quantity("rail deflection", "mm", 1e3, rail),
    ], (title or "Vehicle run"), marks, on_file=on_file)
    return written


def plot_run_report(history_npz: str | Path, out: str | Path, title: str, admitted_x: tuple[float, float],
                    on_file: Callable[[Path], None] | None = None) -> tuple[list[Path], SleeperEnvelope]:
    """Report figures of a moving-load run (:data:`RUN_FIGURES`) from its ``history.npz``; and the envelope.

    Parameters
    ----------
    history_npz : path
        The run's ``history.npz``.
    out : path
        Output directory.
    title : str
        Title of the figures.
    admitted_x : (float, float)
        Positions [m] of the first and last sleeper the peaks are taken over (:class:`clm_core.peaks.PeakWindow`).
    on_file : callable, optional
        Called with each file once written.
    """
    d = Path(out)
    with np.load(history_npz) as z:
        t, first, sf = z["t"], z["first_sleeper"], z["soil_force"]
        spacing = float(z["spacing"])
        env = sleeper_envelope(first, sf, z["peak_sleeper_index"], z["peak_soil_force"])
        wd = z["wheel_deflection"][:, 0] if z["wheel_deflection"].shape[1] else np.zeros(0)
    x = env.sleeper_index * spacing
    admitted = (x >= admitted_x[0] - 1e-9) & (x <= admitted_x[1] + 1e-9)
    g_peak = int(env.describe(admitted)["envelope_peak_sleeper_index"])
    ok = env.sleeper_index[admitted] if admitted.any() else env.sleeper_index
    picks = [int(ok[int(round(q * (ok.size - 1)))]) for q in (0.0, 0.5, 1.0)]
    written = [plot_soil_forces(d / "soil_forces.png", pick_series(first, sf, t, picks, g_peak), g_peak, env,
                                spacing, "sleeper soil forces (ballast force on the soil, compression +)", admitted)]
    if on_file:
        on_file(written[-1])
    peak_rec = None
    s = pick_series(first, sf, t, [], g_peak)
    if s:
        peak_rec = uniform(s[0][1], s[0][2])
    rail = uniform(t, wd) if wd.size else None
    written += report_figures(d, [
        Quantity("soil force", "kN", 1e-3, [Record(f"sleeper {g_peak} (peak)", *peak_rec)] if peak_rec else []),
        Quantity("rail deflection", "mm", 1e3, [Record("rail under wheel 0", *rail)] if rail else []),
    ], title, [], on_file=on_file)
    return written, env


def plot_demo(
    out: str | Path,
    t: Array,
    soil_force: Array,
    first_sleeper: int,
    t_profile: float,
    profile_x: Array,
    profile_deflection: Array,
    profile_force: Array,
    wheel_t: Array,
    wheel_load: Array,
    static_wheel_load: Array | None = None,
    speed: float | None = None,
    admitted_sleepers: NDArray[np.bool_] | None = None,
) -> list[Path]:
    """The figures of a demo bag (:data:`DEMO_FIGURES`).

    ``sleeper_soil_forces.png``, ``rail_deflection.png``, ``wheel_loads.png``
    as recorded; and the report figures of every run: ``soil_forces.png``
    (the peak sleeper's history and the envelope along the track),
    ``spectra.png`` and ``third_octave.png`` (wheel loads, soil force of the
    peak sleeper; records resampled on their median message interval).

    Parameters
    ----------
    out : path
        Output directory (must exist).
    t : (k,) array
        Times of the sleeper responses from the first wheel-load message [s].
    soil_force : (k, n) array
        Soil force of the global sleepers ``first_sleeper .. first_sleeper + n - 1``
        at each response [N] (NaN while outside the node's window).
    first_sleeper : int
        Global index of column 0.
    t_profile : float
        Moment of the profile: that of the peak soil force [s].
    profile_x, profile_deflection, profile_force : (m,) arrays
        Positions [m], rail deflection [m] and soil force [N] of the window
        sleepers at ``t_profile``.
    wheel_t : (p,) array
        Times of the wheel-load messages [s] (same origin as ``t``).
    wheel_load : (p, W) array
        Wheel loads [N] (NaN: wheel absent from a message).
    static_wheel_load : (W,) array, optional
        Static wheel loads [N]: dashed in the wheel panels, removed before the spectra (default: the mean).
    speed : float, optional
        Train speed [m/s] (marks the sleeper-passing frequency V/d in the spectra).
    admitted_sleepers : (n,) bool array, optional
        The columns of ``soil_force`` the reported peak is taken over (:meth:`clm_core.peaks.PeakWindow.sleepers`),
        so that the marked peak sleeper is the summary's; default the sleepers held 90 % of the longest time.

    Returns
    -------
    list of Path
        The PNG files written.
    """
    d = Path(out)
    written = []
    with style():
        fig, axs = new_figure(1, 1, (9.0, 4.8))
        ax = axs[0, 0]
        # the window follows the train: each sleeper is simulated while the train is near it;
        # show sleepers passed over their whole time in the window, spread along the line
        cover = np.isfinite(soil_force).sum(axis=0)
        cols = np.where(cover >= 0.9 * cover.max())[0]
        pick = cols[np.linspace(0, len(cols) - 1, min(6, len(cols))).astype(int)] if len(cols) else []
        for j in pick:
            ax.plot(t, soil_force[:, j] / 1e3, lw=0.9, label=f"sleeper {first_sleeper + j}")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("soil reaction force [kN]")
        ax.set_title("Sleeper soil reaction forces (ballast force on the contact area)")
        if len(pick):
            legend(ax, ncol=2)
        written.append(save(fig, d / "sleeper_soil_forces.png"))

        fig, axs = new_figure(1, 1, (9.0, 4.8))
        ax = axs[0, 0]
        ax.plot(profile_x, profile_deflection * 1e3, "o-", ms=3, color="C0", label="rail deflection above sleepers")
        tw = ax.twinx()
        tw.grid(False)
        tw.plot(profile_x, profile_force / 1e3, "s--", ms=3, lw=0.9, color="C3", alpha=0.85,
                label="soil force under sleepers")
        # both downwards (compression +), zero lines aligned
        w_hi = max(float(np.max(profile_deflection)) * 1e3, 1e-12)
        f_hi = max(float(np.max(profile_force)) / 1e3, 1e-12)
        up = max(0.0, -float(np.min(profile_deflection)) * 1e3 / w_hi, -float(np.min(profile_force)) / 1e3 / f_hi)
        ax.set_ylim(1.12 * w_hi, -(up + 0.08) * w_hi)
        tw.set_ylim(1.12 * f_hi, -(up + 0.08) * f_hi)
        ax.set_xlabel("position along the line [m]")
        ax.set_ylabel("rail deflection [mm] (downwards)", color="C0")
        tw.set_ylabel("soil force [kN] (compression, downwards)", color="C3")
        ax.set_title(f"Rail deflection along the track at t = {t_profile:.3f} s (moment of the peak soil force)")
        h1, l1 = ax.get_legend_handles_labels()
        h2, l2 = tw.get_legend_handles_labels()
        legend(tw, "lower right", handles=h1 + h2, labels=l1 + l2)
        written.append(save(fig, d / "rail_deflection.png"))

        wheels = pick_wheels(wheel_load.shape[1])
        n = len(wheels)
        fig, axs = new_figure(n, 1, (9.0, 1.3 * n + 1.0), sharex=True)
        wheel_panels(list(axs[:, 0]), wheel_t, wheel_load, wheels, static_wheel_load)
        figure_legend(fig, list(axs[:, 0]))
        axs[-1, 0].set_xlabel("time [s]")
        shown = "" if n == wheel_load.shape[1] else f" (wheels {', '.join(map(str, wheels))} of {wheel_load.shape[1]})"
        fig.suptitle("Wheel loads (vehicle simulator node)" + shown, fontsize=9.5)
        written.append(save(fig, d / "wheel_loads.png"))
    written += _demo_report(d, t, soil_force, first_sleeper, profile_x, wheel_t, wheel_load, static_wheel_load, speed,
                            admitted_sleepers)
    return written


def _demo_report(d: Path, t: Array, soil_force: Array, first_sleeper: int, profile_x: Array, wheel_t: Array,
                 wheel_load: Array, static: Array | None, speed: float | None,
                 admitted_sleepers: NDArray[np.bool_] | None) -> list[Path]:
    """``soil_forces.png``, ``spectra.png``, ``third_octave.png`` of the demo (see :func:`plot_demo`)."""
    px = np.asarray(profile_x, dtype=float)
    spacing = round(float(np.median(np.diff(px))), 9) if px.size > 1 else 0.6
    first = np.full(t.size, int(first_sleeper))
    env = sleeper_envelope(first, soil_force)
    cover = np.isfinite(soil_force).sum(axis=0)
    full = cover >= 0.9 * max(1, cover.max())
    admitted = (full if admitted_sleepers is None else np.asarray(admitted_sleepers, bool))[
        env.sleeper_index - first_sleeper]
    g_peak = int(env.describe(admitted)["envelope_peak_sleeper_index"])
    cols = np.flatnonzero(full)
    picks = [first_sleeper + int(cols[int(round(q * (cols.size - 1)))]) for q in (0.0, 0.5, 1.0)] if cols.size else []
    written = [plot_soil_forces(d / "soil_forces.png", pick_series(first, soil_force, t, picks, g_peak), g_peak, env,
                                spacing, "sleeper soil forces (ballast force on the soil, compression +)", admitted,
                                note="envelope over the sleepers passed while in the window")]
    loads = []
    for i in pick_wheels(wheel_load.shape[1])[:3]:
        u = uniform(wheel_t, wheel_load[:, i])
        if u is not None:
            ref = float(static[i]) if static is not None else None
            loads.append(Record(f"wheel {i} ({'static' if ref is not None else 'mean'} removed)", *u, ref))
    peak = uniform(t, soil_force[:, g_peak - first_sleeper])
    marks = [(speed / spacing, f"V/d = {speed / spacing:.1f} Hz")] if speed else []
    written += report_figures(d, [
        Quantity("wheel load", "kN", 1e-3, loads),
        Quantity("soil force", "kN", 1e-3, [Record(f"sleeper {g_peak} (peak)", *peak)] if peak else []),
    ], "clm demo", marks)
    return written
