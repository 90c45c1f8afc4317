"""``receivers.png``: free-field velocity at the receivers and their one-third-octave levels."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from clm_core.outputs.plots._base import legend, new_figure, save, style

if TYPE_CHECKING:
    from clm_core.freefield import FreeFieldResult

__all__ = ["plot_receivers"]


def plot_receivers(res: FreeFieldResult, path: str | Path, title: str = "") -> Figure:
    """Vertical velocity histories [mm/s] (PPV marked) and one-third-octave levels L_v [dB re 5e-8 m/s].

    Parameters
    ----------
    res : FreeFieldResult
        From :func:`clm_core.freefield.free_field`.
    path : path
        PNG file.
    title : str
        Figure title.
    """
    m = res.measures
    with style():
        fig, axs = new_figure(2, 1, (8.5, 7.0))
        ax1, ax2 = axs[:, 0]
        R = res.receivers.shape[0]
        for r in range(R):
            v = res.velocity[r] * 1e3
            lab = f"x = {res.receivers[r, 0]:g} m, y = {res.receivers[r, 1]:g} m (PPV {m.ppv_mm_s[r]:.3g} mm/s)"
            ax1.plot(res.t, v, color=f"C{r}", lw=0.9, ls=("-", "--", ":", "-.")[r % 4], label=lab, zorder=3 + R - r)
            i = int(np.argmax(np.abs(v)))
            ax1.plot(res.t[i], v[i], "o", color=f"C{r}", ms=4, zorder=10)
        ax1.set_xlabel("time [s]")
        ax1.set_ylabel("vertical velocity [mm/s]")
        ax1.set_title(title or "Free-field vertical velocity at the receivers (two-step method)")
        legend(ax1, fontsize=7)
        xb = np.arange(m.band_centres_hz.size)
        width = 0.8 / R
        for r in range(R):
            lv = np.where(np.isfinite(m.lv_db[r]), m.lv_db[r], np.nan)
            ax2.bar(xb + (r - (R - 1) / 2) * width, lv, width=width, color=f"C{r}",
                    label=f"y = {res.receivers[r, 1]:g} m (KB_F,max {m.kb_fmax_mm_s[r]:.3g} mm/s)")
        finite = m.lv_db[np.isfinite(m.lv_db)]
        if finite.size:
            ax2.set_ylim(max(0.0, float(finite.min()) - 10.0), float(finite.max()) + 12.0)
        ax2.set_xticks(xb, [f"{f:g}" for f in m.band_centres_hz], rotation=60, fontsize=7)
        ax2.set_xlabel("one-third-octave band centre [Hz]")
        ax2.set_ylabel("L_v [dB re 5e-8 m/s]")
        legend(ax2, loc="upper left", fontsize=7)
        save(fig, path)
    return fig
