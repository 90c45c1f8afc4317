"""Matplotlib figures of the frequency-domain results (PNG, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from clm_core.frequency import Receptance
from clm_core.soil.chain import ChainSums, ChainTimeResponse


def plot_receptance(rec: Receptance, path: str | Path, title: str = "") -> None:
    """Amplitude [dB re 1 m/N] and phase [deg] of H_11 .. H_n1, as the paper's Fig. 8."""
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    for i in range(rec.H.shape[1]):
        h = rec.H[:, i]
        ax1.plot(rec.frequency, 20 * np.log10(np.abs(h)), label=f"H{i + 1}1")
        ax2.plot(rec.frequency, np.degrees(np.angle(h)), label=f"H{i + 1}1")
    for p in rec.peaks_hz():
        ax1.axvline(p, color="0.7", lw=0.8, ls="--")
    ax1.set_ylabel("|H| [dB re 1 m/N]")
    ax2.set_ylabel("phase [deg]")
    ax2.set_xlabel("frequency [Hz]")
    ax1.legend(ncol=5, fontsize=8)
    ax1.grid(True, alpha=0.3)
    ax2.grid(True, alpha=0.3)
    ax1.set_title(title or "Track receptance (force on the rail above sleeper 1)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_chain(
    sums: ChainSums,
    model_total: np.ndarray,
    model_alternating: np.ndarray,
    resp: ChainTimeResponse,
    path: str | Path,
    title: str = "",
) -> None:
    """Impedance sums of the chain against Eq. (16)/(18), and the Eq. (1) pulse response."""
    fig, axs = plt.subplots(2, 2, figsize=(11, 7))
    f = sums.frequency
    for ax, part, fn in ((axs[0, 0], "real", np.real), (axs[0, 1], "imaginary", np.imag)):
        ax.plot(f, fn(sums.total) / 1e6, "C0", label="chain: F / sum X_j")
        ax.plot(f, fn(model_total) / 1e6, "C0--", label="Eq. (16)")
        ax.plot(f, fn(sums.alternating) / 1e6, "C1", label="chain: F / sum (-1)^j X_j")
        ax.plot(f, fn(model_alternating) / 1e6, "C1--", label="Eq. (18)")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(f"{part} part [MN/m]")
        ax.grid(True, alpha=0.3)
    axs[0, 0].legend(fontsize=8)
    c = resp.x.shape[1] // 2
    for k in range(3):
        axs[1, 0].plot(resp.t * 1e3, resp.x[:, c + k] * 1e9, label="loaded area" if k == 0 else f"neighbour {k}")
    axs[1, 0].set_xlabel("time [ms]")
    axs[1, 0].set_ylabel("displacement [nm] (A = 1 N)")
    axs[1, 0].legend(fontsize=8)
    axs[1, 0].grid(True, alpha=0.3)
    amp = np.max(np.abs(resp.x), axis=0)[c:]
    axs[1, 1].semilogy(np.arange(amp.size), amp * 1e9, "o-")
    axs[1, 1].set_xlabel("area index from the loaded one")
    axs[1, 1].set_ylabel("peak |x| [nm]")
    axs[1, 1].grid(True, alpha=0.3)
    fig.suptitle(title or "CLM chain")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
