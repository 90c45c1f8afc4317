"""Figures of parametric studies (``clm study``): the critical-speed picture and exceedance curves over seeds."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes

from clm_core.arrays import Array
from clm_core.outputs.plots._base import figure_legend, legend, new_figure, save, style

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


#: km/h per m/s.
KMH = 3.6


def soil_wave_speeds(soil: Any) -> tuple[float, float] | None:
    """Shear-wave and Rayleigh-wave speeds [m/s] of the top layer of a soil preset or file; None without a profile."""
    from clm_core.errors import ClmError
    from clm_core.profile import load_profile

    if soil is None:
        return None
    try:
        top = load_profile(str(soil)).layers[0]
    except (ClmError, OSError, ValueError, KeyError, TypeError):
        return None
    return float(top.cs), float(top.cr)


def _peak_text(x: Array, y: Array, unit: str) -> str:
    k = int(np.argmax(y))
    where = " (the fastest run)" if k == len(x) - 1 and len(x) > 1 else ""
    return f"{y[k]:.3g} {unit} at {x[k]:.0f} km/h ({x[k] / KMH:.0f} m/s){where}"


def _unit(name: str) -> str:
    """`` <unit>`` of a run setting for a caption (empty for settings without one and for model parameters)."""
    from clm_core import settings

    try:
        unit = str(settings.setting(name).unit)
    except (KeyError, ValueError, AttributeError):
        return ""
    return "" if unit in ("", "-") else f" {unit}"


def _varied_text(rows: Sequence[Mapping[str, Any]], varied: Sequence[str]) -> str:
    parts = []
    for k in varied:
        vals: list[Any] = sorted({r[k] for r in rows if r.get(k) is not None}, key=lambda v: (str(type(v)), v))
        if k == "speed":
            parts.append(f"speed {min(vals):g}-{max(vals):g} m/s ({len(vals)} values)")
        elif k in REPLICATE_PARAMETERS:
            parts.append(f"irregularity {k} ({len(vals)} values: mean, band = their range)")
        elif all(isinstance(v, (int, float)) for v in vals) and len(vals) > 4:
            parts.append(f"{k} {min(vals):g}-{max(vals):g} ({len(vals)} values)")
        else:
            parts.append(f"{k} ({', '.join(f'{v:g}' if isinstance(v, float) else str(v) for v in vals)})")
    return "; ".join(parts)


def plot_critical_speed(rows: Sequence[Mapping[str, Any]], varied: Sequence[str], path: str | Path,
                        title: str = "", fixed: Mapping[str, Any] | None = None) -> Path | None:
    """Peak sleeper soil force and maximum rail deflection against train speed, one curve per group.

    A group is a combination of the varied parameters other than ``speed``
    and the seed (e.g. one soil); the curve is the mean over the seeds and
    the shaded band their range. Failed cases are left out. The speed axis is
    in km/h, with m/s on a secondary axis above. Every soil's shear-wave
    speed c_s (dashed) and Rayleigh-wave speed c_R (dotted) of its top layer
    (:attr:`clm_core.profile.Layer.cs`, :attr:`~clm_core.profile.Layer.cr`)
    is marked in its curve's colour where it lies in the speed range, and
    named in the caption where it lies beyond; each curve's peak is marked
    (a star) and given in the legend. The caption says what was varied and
    what was fixed.

    Parameters
    ----------
    rows : sequence of mapping
        Study rows (``speed`` [m/s], ``peak_sleeper_soil_force_N``, ``max_rail_deflection_m``, ``status``).
    varied : sequence of str
        The study's varied parameters (``speed`` among them).
    path : str or Path
        The PNG file to write.
    title : str, optional
        Put before the figure's own title (the study's name).
    fixed : mapping, optional
        The study's fixed settings (the soil when it is not varied; the caption).

    Returns
    -------
    Path or None
        The file, or None when speed is not varied or no case succeeded.
    """
    from clm_core import settings

    ok = [r for r in rows if r.get("status") == "ok" and r.get("speed") is not None]
    if "speed" not in varied or not ok:
        return None
    fixed = dict(fixed or {})
    keys = [k for k in varied if k != "speed" and k not in REPLICATE_PARAMETERS]
    groups = _groups(ok, keys)
    names = list(groups)
    shown = _spread(len(names))
    all_speeds = sorted({float(r["speed"]) for r in ok})
    v_lo, v_hi = all_speeds[0], all_speeds[-1]
    beyond: list[str] = []
    with style():
        fig, axs = new_figure(2, 1, (8.6, 8.4), sharex=True)
        ax1, ax2 = axs[:, 0]
        marked: set[str] = set()
        for j, gi in enumerate(shown):
            g = groups[names[gi]]
            color = f"C{j % 10}"
            speeds = sorted({float(r["speed"]) for r in g})
            peaks: dict[str, str] = {}
            lines = []
            for ax, metric, scale, unit in ((ax1, "peak_sleeper_soil_force_N", 1e-3, "kN"),
                                            (ax2, "max_rail_deflection_m", 1e3, "mm")):
                stats = [_values([r for r in g if float(r["speed"]) == s], metric) * scale for s in speeds]
                keep = [i for i, v in enumerate(stats) if v.size]
                if not keep:
                    continue
                x = KMH * np.array([speeds[i] for i in keep])
                mean = np.array([stats[i].mean() for i in keep])
                lo = np.array([stats[i].min() for i in keep])
                hi = np.array([stats[i].max() for i in keep])
                if np.any(hi > lo):
                    ax.fill_between(x, lo, hi, color=color, alpha=0.18, lw=0)
                label = _label(keys, names[gi]) if keys else "mean over the seeds"
                lines += ax.plot(x, mean, marker=_MARKERS[j % len(_MARKERS)], ms=4, color=color, label=label)
                k = int(np.argmax(mean))
                ax.plot([x[k]], [mean[k]], marker="*", ms=13, color=color, mec="black", mew=0.7, ls="none",
                        label="_peak")
                peaks[unit] = _peak_text(x, mean, unit)
            soil = dict(zip(keys, names[gi])).get("soil", fixed.get("soil", settings.SOIL.default))
            speeds_of_soil = soil_wave_speeds(soil)
            if speeds_of_soil is not None and str(soil) not in marked:
                marked.add(str(soil))
                cs, cr = speeds_of_soil
                for c, ls, sym in ((cs, "--", "c_s"), (cr, ":", "c_R")):
                    if v_lo <= c <= v_hi:
                        for ax in (ax1, ax2):
                            ax.axvline(KMH * c, color=color, ls=ls, lw=1.2)
                        ax1.annotate(f"{sym} {soil}\n{c:.0f} m/s", (KMH * c, 1.0), xycoords=("data", "axes fraction"),
                                     xytext=(3 if sym == "c_s" else -3, -3), textcoords="offset points",
                                     ha="left" if sym == "c_s" else "right", va="top", fontsize=7, color=color)
                    else:
                        beyond.append(f"{sym} of {soil} = {c:.0f} m/s ({KMH * c:.0f} km/h)")
            if "mm" in peaks and lines:  # the legend gives the peak rail deflection
                lines[0].set_label(f"{lines[0].get_label()}: deflection peak {peaks['mm']}")
        # the peak and wave-speed markers, once each, in the legend
        ax1.plot([], [], marker="*", ms=11, color="0.6", mec="black", mew=0.7, ls="none", label="peak of each curve")
        ax1.plot([], [], color="0.3", ls="--", lw=1.2, label="shear-wave speed c_s of the soil")
        ax1.plot([], [], color="0.3", ls=":", lw=1.2, label="Rayleigh-wave speed c_R of the soil")
        n_seeds = max(len(v) for g in groups.values() for v in _groups(g, ["speed"]).values())
        ax1.set_ylabel("peak sleeper soil force [kN]")
        ax2.set_ylabel("max rail deflection [mm]")
        ax2.set_xlabel("train speed [km/h]")
        top = ax1.secondary_xaxis("top", functions=(lambda v: v / KMH, lambda v: v * KMH))
        top.set_xlabel("train speed [m/s]")
        band = f"; mean over {n_seeds} seeds, band: their range" if n_seeds > 1 else ""
        more = f" ({len(shown)} of {len(names)} groups)" if len(shown) < len(names) else ""
        fig.suptitle((title + ": " if title else "") + f"peaks against speed{band}{more}", fontsize=10)
        handles, labels = ax1.get_legend_handles_labels()  # on the lower panel, where the curves leave room
        leg = legend(ax2, "center right", handles=handles, labels=labels, fontsize=7.5)
        leg.set_zorder(5)
        fixed_text = ", ".join(f"{k} = {v}{_unit(k)}" for k, v in fixed.items() if k not in varied)
        caption = (f"Varied: {_varied_text(ok, varied)}. Fixed: {fixed_text or 'the defaults'}. "
                   "Peaks exclude the start-up transient and the sleepers not fully passed (clm_core.peaks). "
                   "Wave speeds of each soil's top layer, from E, nu, rho.")
        if beyond:
            caption += " Beyond the speeds run: " + "; ".join(beyond) + "."
        fig.supxlabel(textwrap.fill(caption, 140), fontsize=7, ha="center")  # the layout keeps room for it
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
               title: str = "", fixed: Mapping[str, Any] | None = None) -> list[Path]:
    """Every study figure that the varied parameters allow: ``critical_speed.png``, ``exceedance.png``.

    Returns
    -------
    list of Path
        The files written (none when neither speed nor the seed is varied).
    """
    d = Path(out)
    files = [plot_critical_speed(rows, varied, d / "critical_speed.png", title, fixed),
             plot_exceedance(rows, varied, d / "exceedance.png", title)]
    return [f for f in files if f is not None]
