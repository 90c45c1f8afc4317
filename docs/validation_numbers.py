"""Regenerate the numbers of docs/validation.md (prints Markdown tables).

Usage: .venv/bin/python docs/validation_numbers.py
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from clm_core.frequency import receptance
from clm_core.params import load_model, load_soil, load_track, soil_track
from clm_core.profile import load_profile
from clm_core.soil.chain import chain_time_response
from clm_core.soil.formulas import (
    layer_resonances,
    resonance_frequency,
    time_lag_coupling,
    time_lag_mulliken,
    time_lag_transmissibility,
)
from clm_core.track import assemble

F = np.arange(1.0, 400.0, 0.25)


def peaks(track: str, soil: str, model: str, **over: float) -> list[float]:
    p = load_model(track, soil, model, over or None)
    return receptance(assemble(p, 61), F).peaks_hz()


def two_mass(track: str) -> list[float]:
    """Rail mass of one bay on the pad, sleeper on the ballast, rigid ground."""
    p = load_model(track, None, "rigid")
    mr = p.rail.mass_per_length * p.track.spacing
    M = np.diag([mr, p.track.ms])
    K = np.array([[p.track.kp, -p.track.kp], [-p.track.kp, p.track.kp + p.track.kb]])
    return sorted(np.sqrt(sla.eigh(K, M, eigvals_only=True)) / (2 * np.pi))


def fmt(x: list[float]) -> str:
    return " / ".join(f"{v:.0f}" for v in x)


def main() -> None:
    print("| case | paper [Hz] | rigid | Lysmer | CLM | two-mass model |")
    print("|---|---|---|---|---|---|")
    print(
        f"| Sec. 5.1 Mevergnies (Table 1, 2) | 65 / 325 | {fmt(peaks('mevergnies', 'mevergnies', 'rigid'))} | "
        f"{fmt(peaks('mevergnies', 'mevergnies', 'lysmer'))} | {fmt(peaks('mevergnies', 'mevergnies', 'clm'))} | "
        f"{fmt(two_mass('mevergnies'))} |"
    )
    for soil in ("soft", "medium", "stiff"):
        print(
            f"| Sec. 5.2 soil-study track, {soil} soil (Table 3) | 124 / 289 | {fmt(peaks('soil-study', soil, 'rigid'))} | "
            f"{fmt(peaks('soil-study', soil, 'lysmer'))} | {fmt(peaks('soil-study', soil, 'clm'))} | {fmt(two_mass('soil-study'))} |"
        )
    for kb in (50e6, 120e6, 600e6):
        print(
            f"| Sec. 5.3 medium soil, k_b = {kb / 1e6:.0f} MN/m | 82 ... 228 (first) | "
            f"{fmt(peaks('soil-study', 'medium', 'rigid', kb=kb))} | {fmt(peaks('soil-study', 'medium', 'lysmer', kb=kb))} | "
            f"{fmt(peaks('soil-study', 'medium', 'clm', kb=kb))} | |"
        )
    print(
        f"| Sec. 5.4 Haren (Table 4) | ~70 (track), 15 and 40 (soil) | {fmt(peaks('mevergnies', 'haren', 'rigid'))} | "
        f"{fmt(peaks('mevergnies', 'haren', 'lysmer'))} | {fmt(peaks('mevergnies', 'haren', 'clm'))} | |"
    )
    print()
    print(
        "| soil | track (d [m]) | Eq. (21) [ms] | Eq. (21) with d = 0.6 m [ms] | Eq. (23) [ms] | "
        "Eq. (22) low-f delay [ms] | measured area 0->1, 1->2 [ms] | Eq. (24) f_R [Hz] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for soil in ("mevergnies", "soft", "medium", "stiff", "haren"):
        s = load_soil(soil)
        cs = load_profile(soil).layers[0].cs
        track_name = soil_track(soil) or "mevergnies"
        trk = load_track(track_name)[1]  # Eq. (21) with the spacing of the track this soil goes with
        r = chain_time_response(s, 41, dt=1e-5)
        _, t = r.peaks(2)
        print(
            f"| {soil} | {track_name} ({trk.spacing:g}) | {time_lag_mulliken(trk.spacing, trk.contact_width, cs) * 1e3:.2f} | "
            f"{time_lag_mulliken(0.6, trk.contact_width, cs) * 1e3:.2f} | {time_lag_coupling(s) * 1e3:.2f} | "
            f"{time_lag_transmissibility(s) * 1e3:.2f} | {(t[1] - t[0]) * 1e3:.2f}, {(t[2] - t[1]) * 1e3:.2f} | "
            f"{resonance_frequency(s):.0f} |"
        )
    print()
    prof = load_profile("haren")
    lay = prof.layers[0]
    print(
        f"Haren layer 1 (h = {lay.thickness} m): Eq. (26) S: {fmt(list(layer_resonances(lay.thickness or 1, lay.cs, 2)))} Hz, "
        f"P: {fmt(list(layer_resonances(lay.thickness or 1, lay.cp, 2)))} Hz"
    )
    h2 = sum(x.thickness or 0 for x in prof.layers[:2])
    cs2 = h2 / sum((x.thickness or 0) / x.cs for x in prof.layers[:2])
    cp2 = h2 / sum((x.thickness or 0) / x.cp for x in prof.layers[:2])
    print(
        f"Haren layers 1+2 (h = {h2} m, travel-time averaged): S: {cs2 / (4 * h2):.1f} Hz, P: {cp2 / (4 * h2):.1f} Hz"
    )
    print()
    print("| track, soil | max |H11| difference CLM vs Lysmer, 1-100 Hz [dB] | at 1 Hz [dB] |")
    print("|---|---|---|")
    f = np.arange(1.0, 100.0, 0.5)
    for track, soil in (
        ("soil-study", "soft"),
        ("soil-study", "medium"),
        ("soil-study", "stiff"),
        ("mevergnies", "mevergnies"),
        ("mevergnies", "haren"),
    ):
        h = {m: np.abs(receptance(assemble(load_model(track, soil, m), 61), f).H[:, 0]) for m in ("lysmer", "clm")}
        d = 20 * np.log10(h["lysmer"] / h["clm"])
        print(f"| {track}, {soil} | {np.max(np.abs(d)):.1f} | {d[0]:.1f} |")


if __name__ == "__main__":
    main()
