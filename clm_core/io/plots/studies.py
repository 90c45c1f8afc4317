"""Figures of parametric studies (``clm study``): the critical-speed picture and exceedance curves over seeds."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes

from clm_core.arrays import Array
from clm_core.io.plots._base import figure_legend, legend, new_figure, save, style

#: Most groups (curves) drawn in one panel; beyond that a spread selection, said in the title.
MAX_CURVES = 8

#: Varied parameters over which results are replicates (not groups): the irregularity seed.
REPLICATE_PARAMETERS: tuple[str, ...] = ("seed",)

_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


def _groups(rows: Sequence[Mapping[str, Any]], keys: Sequence[str]) -> dict[tuple[Any, ...], list[Mapping[str, Any]]]:
    out: dict[tuple[Any, ...], list[Mapping[str, Any]]] = {}
    for r in rows:
        out.setdefault(tuple(r.get(k) for k in keys), []).append(r)
    return out


def _label(keys: Sequence[str], values: Sequence[Any]) -> str:
    return ", ".join(f"{k} = {v:g}" if isinstance(v, float) else f"{k} = {v}" for k, v in zip(keys, values)) \
        or "all cases"


def _spread(n: int, most: int = MAX_CURVES) -> list[int]:
    if n <= most:
        return list(range(n))
    return sorted({int(i) for i in np.linspace(0, n - 1, most).round()})


def _values(rows: Sequence[Mapping[str, Any]], metric: str) -> Array:
    v: Array = np.array([np.nan if r.get(metric) is None else float(r[metric]) for r in rows], dtype=float)
    return v[np.isfinite(v)]


def plot_critical_speed(rows: Sequence[Mapping[str, Any]], varied: Sequence[str], path: str | Path,
                        title: str = "") -> Path | None:
    """Peak sleeper soil force and maximum rail deflection against train speed, one curve per group.

    A group is a combination of the varied parameters other than ``speed``
    and the seed (e.g. one soil); the curve is the mean over the seeds and
    the shaded band their range. Failed cases are left out.

    Parameters
    ----------
    rows : sequence of mapping
        Study rows (``speed``, ``peak_sleeper_soil_force_N``, ``max_rail_deflection_m``, ``status``).
    varied : sequence of str
        The study's varied parameters (``speed`` among them).
    path : str or Path
        The PNG file to write.
    title : str, optional
        Put before the figure's own title (the study's name).

    Returns
    -------
    Path or None
        The file, or None when speed is not varied or no case succeeded.
    """
    ok = [r for r in rows if r.get("status") == "ok" and r.get("speed") is not None]
    if "speed" not in varied or not ok:
        return None
    keys = [k for k in varied if k != "speed" and k not in REPLICATE_PARAMETERS]
    groups = _groups(ok, keys)
    names = list(groups)
    shown = _spread(len(names))
    with style():
        fig, axs = new_figure(2, 1, (8.0, 7.0), sharex=True)
        ax1, ax2 = axs[:, 0]
        for j, gi in enumerate(shown):
            g = groups[names[gi]]
            speeds = sorted({float(r["speed"]) for r in g})
            for ax, metric, scale in ((ax1, "peak_sleeper_soil_force_N", 1e-3), (ax2, "max_rail_deflection_m", 1e3)):
                stats = [_values([r for r in g if float(r["speed"]) == s], metric) * scale for s in speeds]
                keep = [i for i, v in enumerate(stats) if v.size]
                x = np.array([speeds[i] for i in keep])
                mean = np.array([stats[i].mean() for i in keep])
                lo = np.array([stats[i].min() for i in keep])
                hi = np.array([stats[i].max() for i in keep])
                color = f"C{j % 10}"
                if np.any(hi > lo):
                    ax.fill_between(x, lo, hi, color=color, alpha=0.18, lw=0)
                ax.plot(x, mean, marker=_MARKERS[j % len(_MARKERS)], ms=4, color=color,
                        label=_label(keys, names[gi]) if keys else "mean over the seeds")
        n_seeds = max(len(v) for g in groups.values() for v in _groups(g, ["speed"]).values())
        ax1.set_ylabel("peak sleeper soil force [kN]")
        ax2.set_ylabel("max rail deflection [mm]")
        ax2.set_xlabel("train speed [m/s]")
        band = f"; mean over {n_seeds} seeds, band: their range" if n_seeds > 1 else ""
        more = f" ({len(shown)} of {len(names)} groups)" if len(shown) < len(names) else ""
        ax1.set_title((title + ": " if title else "") + f"peaks against speed{band}{more}")
        ax2.set_title("start-up transient and sleepers not fully passed excluded", fontsize=8)
        legend(ax1, "upper left")
        out = save(fig, path)
    return out


def _exceedance(ax: Axes, values: Array, label: str, j: int) -> None:
    x = np.sort(values)
    p = 1.0 - np.arange(x.size) / x.size  # fraction of the seeds with a value >= x
    ax.step(x, p, where="post", color=f"C{j % 10}", marker=_MARKERS[j % len(_MARKERS)], ms=3, label=label)


def plot_exceedance(rows: Sequence[Mapping[str, Any]], varied: Sequence[str], path: str | Path,
                    title: str = "", min_seeds: int = 3) -> Path | None:
    """Exceedance curves over the seeds: fraction of seeds whose peak soil force (peak wheel load) is >= x.

    One curve per group (the varied parameters other than the seed) with at
    least ``min_seeds`` successful seeds; at most :data:`MAX_CURVES`, spread.

    Returns
    -------
    Path or None
        The file, or None when the seed is not varied or no group has enough seeds.
    """
    if not any(k in varied for k in REPLICATE_PARAMETERS):
        return None
    ok = [r for r in rows if r.get("status") == "ok"]
    keys = [k for k in varied if k not in REPLICATE_PARAMETERS]
    groups = {k: g for k, g in _groups(ok, keys).items() if len(g) >= min_seeds}
    if not groups:
        return None
    names = list(groups)
    shown = _spread(len(names))
    with style():
        fig, axs = new_figure(1, 2, (10.0, 5.2), sharey=True)
        ax1, ax2 = axs[0]
        for j, gi in enumerate(shown):
            g = groups[names[gi]]
            label = _label(keys, names[gi]) + f" ({len(g)} seeds)"
            _exceedance(ax1, _values(g, "peak_sleeper_soil_force_N") / 1e3, label, j)
            _exceedance(ax2, _values(g, "peak_wheel_load_N") / 1e3, label, j)
        ax1.set_xlabel("peak sleeper soil force [kN]")
        ax2.set_xlabel("peak wheel load [kN]")
        ax1.set_ylabel("exceedance probability [-]")
        ax2.set_ylabel("exceedance probability [-]")
        ax1.set_ylim(0.0, 1.05)
        more = f" ({len(shown)} of {len(names)} groups)" if len(shown) < len(names) else ""
        fig.suptitle((title + ": " if title else "") + f"exceedance over the irregularity seeds{more}", fontsize=9.5)
        figure_legend(fig, [ax1])
        out = save(fig, path)
    return out


def plot_study(rows: Sequence[Mapping[str, Any]], varied: Sequence[str], out: str | Path,
               title: str = "") -> list[Path]:
    """Every study figure that the varied parameters allow: ``critical_speed.png``, ``exceedance.png``.

    Returns
    -------
    list of Path
        The files written (none when neither speed nor the seed is varied).
    """
    d = Path(out)
    files = [plot_critical_speed(rows, varied, d / "critical_speed.png", title),
             plot_exceedance(rows, varied, d / "exceedance.png", title)]
    return [f for f in files if f is not None]
