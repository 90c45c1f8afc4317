"""Frequency-domain figures: track receptance (paper Fig. 8) and the CLM soil chain (Sec. 4)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from clm_core.outputs.plots._base import label_receptance_axes, legend, new_figure, receptance_lines, save, style

if TYPE_CHECKING:
    from clm_core.frequency import Receptance
    from clm_core.soil.chain import ChainSums, ChainTimeResponse


def plot_receptance(rec: Receptance, path: str | Path, title: str = "") -> Figure:
    """Amplitude [dB re 1 m/N] and phase [deg] of H_11 .. H_n1, as the paper's Fig. 8.

    The resonance peaks of |H_11| are marked and labelled with their frequency [Hz].

    Parameters
    ----------
    rec : Receptance
        From :func:`clm_core.frequency.receptance`.
    path : path
        PNG file.
    title : str
        Figure title.

    Returns
    -------
    Figure
        The figure written.
    """
    with style():
        fig, axs = new_figure(2, 1, (8.5, 7.0), sharex=True)
        ax1, ax2 = axs[:, 0]
        for i in range(rec.H.shape[1]):
            receptance_lines(ax1, ax2, rec.frequency, rec.H[:, i], db=True, color=f"C{i}", label=f"H{i + 1}1")
        peaks = rec.peaks_hz()
        db11 = 20 * np.log10(np.abs(rec.H[:, 0]))
        for ax in (ax1, ax2):
            for p in peaks:
                ax.axvline(p, color="0.6", lw=0.8, ls="--", zorder=0)
        if peaks:
            yp = np.interp(peaks, rec.frequency, db11)
            ax1.plot(peaks, yp, "v", color="k", ms=6, zorder=5, label="peaks of |H11|")
            for p, y in zip(peaks, yp, strict=True):
                ax1.annotate(f"{p:.1f} Hz", (p, y), xytext=(5, 7), textcoords="offset points", fontsize=8,
                             zorder=6, bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8})
            lo, hi = ax1.get_ylim()
            ax1.set_ylim(lo, hi + 0.08 * (hi - lo))  # room for the peak labels
        label_receptance_axes(ax1, ax2, "|H| [dB re 1 m/N]")
        legend(ax1, ncol=3)
        ax1.set_title(title or "Track receptance (force on the rail above sleeper 1)")
        save(fig, path)
    return fig


def plot_chain(
    sums: ChainSums,
    model_total: NDArray[np.complex128],
    model_alternating: NDArray[np.complex128],
    resp: ChainTimeResponse,
    path: str | Path,
    title: str = "",
) -> Figure:
    """Impedance sums of the chain against Eq. (16)/(18), and the Eq. (1) pulse response.

    The closed forms coincide with the chain's sums: they are drawn dashed
    with hollow markers every few points, above the wide translucent chain
    curves, so both stay visible.

    Parameters
    ----------
    sums : ChainSums
        F / sum X_j and F / sum (-1)^j X_j of the chain [N/m].
    model_total, model_alternating : (n_f,) complex arrays
        Eq. (16) and Eq. (18) at the same frequencies [N/m].
    resp : ChainTimeResponse
        Response of the chain to the Eq. (1) pulse on its centre area.
    path : path
        PNG file.
    title : str
        Figure title.

    Returns
    -------
    Figure
        The figure written.
    """
    with style():
        fig, axs = new_figure(2, 2, (11.0, 7.5))
        f = sums.frequency
        every = max(1, f.size // 14)
        for ax, part, fn in ((axs[0, 0], "real", np.real), (axs[0, 1], "imaginary", np.imag)):
            for col, chain, model, lab_c, lab_m in (
                ("C0", sums.total, model_total, "chain: F / sum X_j", "Eq. (16)"),
                ("C1", sums.alternating, model_alternating, "chain: F / sum (-1)^j X_j", "Eq. (18)"),
            ):
                ax.plot(f, fn(chain) / 1e6, color=col, lw=3.2, alpha=0.45, zorder=2, label=lab_c)
                ax.plot(f, fn(model) / 1e6, color=col, ls=(0, (4, 2)), lw=1.1, marker="o", ms=4.5, mfc="white",
                        mew=1.0, markevery=(every // 2, every), zorder=3, label=lab_m)
            ax.set_xlabel("frequency [Hz]")
            ax.set_ylabel(f"{part} part [MN/m]")
        legend(axs[0, 0])
        c = resp.x.shape[1] // 2
        for k in range(min(3, resp.x.shape[1] - c)):
            axs[1, 0].plot(resp.t * 1e3, resp.x[:, c + k] * 1e9, label="loaded area" if k == 0 else f"neighbour {k}")
        axs[1, 0].set_xlabel("time [ms]")
        axs[1, 0].set_ylabel("displacement [nm] (A = 1 N)")
        legend(axs[1, 0])
        amp = np.max(np.abs(resp.x), axis=0)[c:]
        axs[1, 1].semilogy(np.arange(amp.size), amp * 1e9, "o-")
        axs[1, 1].set_xlabel("area index from the loaded one [-]")
        axs[1, 1].set_ylabel("peak |x| [nm]")
        fig.suptitle(title or "CLM chain")
        save(fig, path)
    return fig
