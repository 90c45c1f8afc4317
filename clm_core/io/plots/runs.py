"""Time-domain figures: moving-load runs, coupled vehicle runs and the ROS demo."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from clm_core.arrays import Array
from clm_core.io.plots._base import (
    figure_legend,
    legend,
    new_figure,
    pick_wheels,
    save,
    style,
    wheel_panels,
)

if TYPE_CHECKING:
    from clm_core.io.history import RunDigest
    from clm_core.vehicle.coupled import CoupledResult


def plot_run(
    history_npz: str | Path, digest: RunDigest, sleepers: list[int], path: str | Path, title: str = ""
) -> Figure:
    """Sleeper soil forces over time for a few sleepers, and the rail deflection along the track at its maximum.

    Parameters
    ----------
    history_npz : path
        The run's ``history.npz``.
    digest : RunDigest
        From :meth:`clm_core.io.history.HistoryWriter.close`.
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
                    ax1.plot(t[ok], sf[ok, col[ok]] / 1e3, label=f"sleeper {g} (x = {g * spacing:.1f} m)")
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


def plot_vehicle_run(res: CoupledResult, out: str | Path, title: str = "") -> list[Path]:
    """``wheel_loads.png``, ``soil_forces.png`` and ``spectra.png`` of a coupled vehicle run.

    Parameters
    ----------
    res : CoupledResult
        The run.
    out : path
        Output directory (must exist).
    title : str
        Title of the wheel-load figure.

    Returns
    -------
    list of Path
        The PNG files written.
    """
    from scipy.signal import welch

    d = Path(out)
    nw = res.wheel_load.shape[1]
    wheels = pick_wheels(nw)
    written = []
    with style():
        n = len(wheels) + 1
        fig, axs = new_figure(n, 1, (9.0, 1.3 * n + 1.2), sharex=True,
                           gridspec_kw={"height_ratios": [1.0] * len(wheels) + [1.2]})
        wheel_panels(list(axs[:-1, 0]), res.t, res.wheel_load, wheels, res.static_wheel_load)
        ax = axs[-1, 0]
        ax.plot(res.t, res.irregularity[:, 0] * 1e3, color="C2", lw=0.8, label="irregularity r under wheel 0 (down +)")
        ax.plot(res.t, res.rail_deflection[:, 0] * 1e3, color="C1", lw=0.8, label="rail deflection under wheel 0")
        ax.set_ylabel("wheel 0\n[mm]")
        ax.set_xlabel("time [s]")
        figure_legend(fig, list(axs[:, 0]))
        shown = "" if len(wheels) == nw else f" (wheels {', '.join(map(str, wheels))} of {nw})"
        fig.suptitle((title or "Wheel loads") + shown, fontsize=9.5)
        written.append(save(fig, d / "wheel_loads.png"))

        fig, axs = new_figure(2, 1, (9.0, 6.5))
        a0, a1 = axs[:, 0]
        counts = np.isfinite(res.soil_force).sum(axis=0)
        finite_cols = np.nonzero(counts > 0)[0]
        ok = np.isfinite(res.peak_soil_force)
        if finite_cols.size:
            pkv = np.where(ok, res.peak_soil_force, -np.inf)
            good = np.nonzero((counts >= 0.5 * counts.max()) & (pkv >= 0.5 * pkv.max()))[0]
            good = good if good.size else finite_cols
            picks = good[np.linspace(0, good.size - 1, 4).round().astype(int)]
            for j in np.unique(picks):
                a0.plot(res.t_out, res.soil_force[:, j] / 1e3, lw=0.8,
                        label=f"sleeper {int(res.sleeper_index[j])} (x = {res.sleeper_x[j]:.1f} m)")
            legend(a0)
        a0.set_xlabel("time [s]")
        a0.set_ylabel("soil force [kN]")
        a0.set_title("sleeper soil forces (ballast force on the soil, compression +)")
        a1.plot(res.sleeper_x[ok], res.peak_soil_force[ok] / 1e3, ".-", ms=3, lw=0.6)
        a1.set_xlabel("position along the line [m]")
        a1.set_ylabel("peak soil force [kN]")
        a1.set_title("largest soil force of each sleeper (every step)")
        written.append(save(fig, d / "soil_forces.png"))

        fig, axs = new_figure(2, 1, (9.0, 6.5))
        a0, a1 = axs[:, 0]
        dt = float(res.t[1] - res.t[0]) if res.t.size > 1 else 1.0
        sel = res.t >= float(res.meta.get("stats_from", 0.0))
        V = float(res.meta.get("speed", 0.0))
        spacing = float(res.sleeper_x[1] - res.sleeper_x[0]) if res.sleeper_x.size > 1 else 0.6
        if sel.sum() > 16:
            for i in wheels[:4]:
                x = res.wheel_load[sel, i] - res.wheel_load[sel, i].mean()
                f, S = welch(x, fs=1 / dt, nperseg=min(x.size, 4096))
                a0.semilogy(f, np.maximum(S, 1e-30), lw=0.7, label=f"wheel {i}")
            if V > 0:
                a0.axvline(V / spacing, color="k", ls="--", lw=0.7, label=f"V/d = {V / spacing:.1f} Hz")
            a0.set_xlim(0, min(0.5 / dt, 500.0))
            legend(a0)
        a0.set_xlabel("frequency [Hz]")
        a0.set_ylabel("PSD of wheel load [N^2/Hz]")
        a0.set_title("wheel loads (dynamic part)")
        if finite_cols.size:
            j = int(np.argmax(np.where(ok, res.peak_soil_force, -np.inf)))
            y = res.soil_force[:, j]
            fin = np.isfinite(y)
            if fin.sum() > 16 and res.t_out.size > 1:
                dto = float(res.t_out[1] - res.t_out[0])
                yy = y[fin] - np.mean(y[fin])
                f, S = welch(yy, fs=1 / dto, nperseg=min(yy.size, 1024))
                a1.semilogy(f, np.maximum(S, 1e-30), lw=0.8, label=f"sleeper {int(res.sleeper_index[j])}")
                a1.set_xlim(0, min(0.5 / dto, 250.0))
                legend(a1)
        a1.set_xlabel("frequency [Hz]")
        a1.set_ylabel("PSD of soil force [N^2/Hz]")
        a1.set_title("most loaded sleeper")
        written.append(save(fig, d / "spectra.png"))
    return written


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
) -> list[Path]:
    """``sleeper_soil_forces.png``, ``rail_deflection.png``, ``wheel_loads.png`` of a demo bag.

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
        wheel_panels(list(axs[:, 0]), wheel_t, wheel_load, wheels, None)
        figure_legend(fig, list(axs[:, 0]))
        axs[-1, 0].set_xlabel("time [s]")
        shown = "" if n == wheel_load.shape[1] else f" (wheels {', '.join(map(str, wheels))} of {wheel_load.shape[1]})"
        fig.suptitle("Wheel loads (vehicle simulator node)" + shown, fontsize=9.5)
        written.append(save(fig, d / "wheel_loads.png"))
    return written
