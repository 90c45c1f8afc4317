"""Output files and plots of a coupled vehicle run (``clm simulate --vehicle``).

The run itself is built by :mod:`clm_core.vehicle.run` (typed spec, no
argparse). :func:`write_outputs` writes, into ``out_dir``:

``vehicle_history.npz``
    every array of :class:`clm_core.vehicle.coupled.CoupledResult`
    (``t``, ``wheel_position``, ``wheel_load``, ``static_wheel_load``,
    ``compression``, ``wheel_displacement``, ``rail_deflection``,
    ``irregularity``, ``vehicle_energy``, ``newton_iterations``, ``t_out``,
    ``sleeper_index``, ``sleeper_x``, ``soil_force``,
    ``sleeper_rail_deflection``, ``peak_soil_force``) plus ``meta_json``.
``wheels.csv``
    ``t_s`` then per wheel ``x{i}_m, P{i}_N`` (wheel load = contact force),
    ``delta{i}_m`` (Hertz compression), ``z{i}_m`` (axle), ``w{i}_m`` (rail
    under the wheel), ``r{i}_m`` (irregularity, positive downwards), every
    ``--output-dt``.
``sleepers.csv``
    long format ``t_s, sleeper_index, x_m, soil_force_N, rail_deflection_m``
    for the sleepers in the engine's window at each output instant.
``peaks.csv``
    ``sleeper_index, x_m, peak_soil_force_N`` (every step).
``wheel_loads.png``, ``soil_forces.png``, ``spectra.png``
    plots (matplotlib, Agg).
``summary.json``
    the summary (peak/RMS wheel load, peak sleeper soil force, contact
    losses, real-time factor) and the run settings.

Wheel loads are per wheel on the one simulated rail line: half the axle load.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from clm_core.vehicle.coupled import CoupledResult


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_outputs(res: CoupledResult, out: Path, csv_files: bool = True, title: str = "") -> None:
    """Write NPZ, CSV and PNG files of a coupled run into ``out`` (layout in the module docstring)."""
    np.savez_compressed(
        out / "vehicle_history.npz",
        t=res.t, wheel_position=res.wheel_position, wheel_load=res.wheel_load,
        static_wheel_load=res.static_wheel_load, compression=res.compression,
        wheel_displacement=res.wheel_displacement, rail_deflection=res.rail_deflection,
        irregularity=res.irregularity, vehicle_energy=res.vehicle_energy,
        newton_iterations=res.newton_iterations, t_out=res.t_out, sleeper_index=res.sleeper_index,
        sleeper_x=res.sleeper_x, soil_force=res.soil_force, sleeper_rail_deflection=res.sleeper_rail_deflection,
        peak_soil_force=res.peak_soil_force, meta_json=np.array(json.dumps(res.meta, default=_jsonable)),
    )
    every = int(res.meta.get("snapshot_every", 1))
    rows = np.arange(0, res.t.size, every)
    if csv_files:
        nw = res.wheel_load.shape[1]
        with (out / "wheels.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            head = ["t_s"]
            for i in range(nw):
                head += [f"x{i}_m", f"P{i}_N", f"delta{i}_m", f"z{i}_m", f"w{i}_m", f"r{i}_m"]
            w.writerow(head)
            for k in rows.tolist():
                row: list[str] = [f"{res.t[k]:.6g}"]
                for i in range(nw):
                    row += [f"{res.wheel_position[k, i]:.6f}", f"{res.wheel_load[k, i]:.6g}",
                            f"{res.compression[k, i]:.6g}", f"{res.wheel_displacement[k, i]:.6g}",
                            f"{res.rail_deflection[k, i]:.6g}", f"{res.irregularity[k, i]:.6g}"]
                w.writerow(row)
        with (out / "sleepers.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["t_s", "sleeper_index", "x_m", "soil_force_N", "rail_deflection_m"])
            for k in range(res.t_out.size):
                ok = np.isfinite(res.soil_force[k])
                for j in np.nonzero(ok)[0]:
                    w.writerow([f"{res.t_out[k]:.6g}", int(res.sleeper_index[j]), f"{res.sleeper_x[j]:.4f}",
                                f"{res.soil_force[k, j]:.6g}", f"{res.sleeper_rail_deflection[k, j]:.6g}"])
        with (out / "peaks.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["sleeper_index", "x_m", "peak_soil_force_N"])
            for j in np.nonzero(np.isfinite(res.peak_soil_force))[0]:
                w.writerow([int(res.sleeper_index[j]), f"{res.sleeper_x[j]:.4f}", f"{res.peak_soil_force[j]:.6g}"])
    plot_outputs(res, out, title)


def plot_outputs(res: CoupledResult, out: Path, title: str = "") -> None:
    """``wheel_loads.png``, ``soil_forces.png``, ``spectra.png`` (Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.signal import welch

    nw = res.wheel_load.shape[1]
    show = list(range(min(nw, 4)))
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i in show:
        ax[0].plot(res.t, res.wheel_load[:, i] / 1e3, lw=0.7, label=f"wheel {i}")
    ax[0].axhline(0, color="k", lw=0.5)
    ax[0].set_ylabel("wheel load [kN]")
    ax[0].legend(fontsize=7, ncol=4)
    ax[0].set_title(title, fontsize=9)
    ax[1].plot(res.t, res.irregularity[:, 0] * 1e3, lw=0.7, label="irregularity r, wheel 0 (down +)")
    ax[1].plot(res.t, (res.rail_deflection[:, 0]) * 1e3, lw=0.7, label="rail deflection, wheel 0")
    ax[1].set_ylabel("[mm]")
    ax[1].set_xlabel("t [s]")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "wheel_loads.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(2, 1, figsize=(9, 6))
    counts = np.isfinite(res.soil_force).sum(axis=0)
    finite_cols = np.nonzero(counts > 0)[0]
    if finite_cols.size:
        pkv = np.where(np.isfinite(res.peak_soil_force), res.peak_soil_force, -np.inf)
        good = np.nonzero((counts >= 0.5 * counts.max()) & (pkv >= 0.5 * pkv.max()))[0]
        good = good if good.size else finite_cols
        picks = good[np.linspace(0, good.size - 1, 4).round().astype(int)]
        for j in np.unique(picks):
            ax[0].plot(res.t_out, res.soil_force[:, j] / 1e3, lw=0.8, label=f"sleeper {int(res.sleeper_index[j])}")
        ax[0].legend(fontsize=7)
    ax[0].set_xlabel("t [s]")
    ax[0].set_ylabel("soil force [kN]")
    ax[0].set_title("sleeper soil forces (ballast force on the soil, compression +)", fontsize=9)
    ok = np.isfinite(res.peak_soil_force)
    ax[1].plot(res.sleeper_x[ok], res.peak_soil_force[ok] / 1e3, ".-", ms=3, lw=0.6)
    ax[1].set_xlabel("x [m]")
    ax[1].set_ylabel("peak soil force [kN]")
    fig.tight_layout()
    fig.savefig(out / "soil_forces.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(2, 1, figsize=(9, 6))
    dt = float(res.t[1] - res.t[0]) if res.t.size > 1 else 1.0
    sel = res.t >= float(res.meta.get("stats_from", 0.0))
    V = float(res.meta.get("speed", 0.0))
    spacing = float(res.sleeper_x[1] - res.sleeper_x[0]) if res.sleeper_x.size > 1 else 0.6
    if sel.sum() > 16:
        for i in show:
            x = res.wheel_load[sel, i] - res.wheel_load[sel, i].mean()
            f, S = welch(x, fs=1 / dt, nperseg=min(x.size, 4096))
            ax[0].semilogy(f, np.maximum(S, 1e-30), lw=0.7, label=f"wheel {i}")
        if V > 0:
            ax[0].axvline(V / spacing, color="k", ls="--", lw=0.7, label=f"V/d = {V / spacing:.1f} Hz")
        ax[0].set_xlim(0, min(0.5 / dt, 500.0))
        ax[0].legend(fontsize=7)
    ax[0].set_xlabel("f [Hz]")
    ax[0].set_ylabel("PSD wheel load [N^2/Hz]")
    if finite_cols.size:
        j = int(np.argmax(np.where(ok, res.peak_soil_force, -np.inf)))
        y = res.soil_force[:, j]
        fin = np.isfinite(y)
        if fin.sum() > 16 and res.t_out.size > 1:
            dto = float(res.t_out[1] - res.t_out[0])
            yy = y[fin] - np.mean(y[fin])
            f, S = welch(yy, fs=1 / dto, nperseg=min(yy.size, 1024))
            ax[1].semilogy(f, np.maximum(S, 1e-30), lw=0.8, label=f"sleeper {int(res.sleeper_index[j])}")
            ax[1].set_xlim(0, min(0.5 / dto, 250.0))
            ax[1].legend(fontsize=7)
    ax[1].set_xlabel("f [Hz]")
    ax[1].set_ylabel("PSD soil force [N^2/Hz]")
    fig.tight_layout()
    fig.savefig(out / "spectra.png", dpi=110)
    plt.close(fig)
