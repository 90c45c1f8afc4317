#!/usr/bin/env python3
"""Benchmark (issue 14): are the impact calibration's 95 % intervals honest? And its first estimate?

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/calibration_coverage.py [--seeds 6] [--out FILE.md]

Noisy replicates of soil impact tests (one hit, 1 s, geophones on areas
-n..n) over a grid of scenarios:

- truth from an **independent integrator** (``benchmarks/calibration_truth.py``:
  closed-form modal response of a chain 40 areas longer than the geophones
  span, Chebyshev IIR anti-alias filter and decimation) for every
  combination of soil (mevergnies, Table 1; the stiff soil of issue 14,
  m_f 600 kg, k_f 150 MN/m, d_f 1.1 MN s/m, k_c 300 MN/m, d_c -250 kN s/m;
  soft, Table 3), sample rate (1 and 2 kHz), noise model (proportional,
  equal floor, coloured) and 21 or 41 geophones;
- truth from the **project's generator** (:mod:`clm_core.synthetic`:
  Newmark, ``resample_poly``; its chain is as long as the geophones span, its
  noise white per channel at the stated SNR) for each soil with 21 and 41
  geophones at 1 kHz.

Noise level 2 % (standard deviation over the rms of the 0.1 s after the hit,
SNR 34 dB) unless ``--level``. Every replicate is calibrated as ``calibrate``
does (windowed H1, first estimate, refinement on the chosen chain), and the
intervals of several estimators are evaluated at the same optimum:

- ``before``: the calibration as it was before issue 14 (chain of
  2 max|index| + 1 areas, the paper-route first estimate, noise sandwich
  without the pseudo-covariance, one global inflation factor); its own fit;
- ``noise-nopcov``: the automatic chain, sandwich without pseudo-covariance;
- ``noise``: sandwich with the pseudo-covariance, one global factor;
- ``inflated`` (the default): the same, each channel's noise covariance
  scaled by its excess residual power;
- ``hac3``, ``hac12``: Newey–West over the frequency lines (L = 3, 12).

Printed (Markdown): empirical coverage of the nominal 95 % intervals per
scenario and per parameter, overall; the first-estimate errors (mean and
spread over the replicates) of the weighted and the paper route, and the
coverage of the first estimate's own intervals; chain lengths chosen;
how often the residual warning fires; the wall time.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import platform
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from calibration_truth import CleanRecord, exact_impact
from calibration_truth import add_noise as add_noise_exact

from clm_core.calibration.impact import SoilFit, fit_impact
from clm_core.calibration.lsq import covariance
from clm_core.calibration.residuals import (
    make_sandwich,
    norm_weights,
    residual_layout,
    stack_residual,
)
from clm_core.calibration.signals import Recording, SamplingRules, common_grid
from clm_core.calibration.spectra import TransferData, WindowSpec, transfer_functions
from clm_core.params import SoilParams, load_soil
from clm_core.soil.chain import CHAIN_PARAMS, chain_response
from clm_core.synthetic import add_noise as add_noise_synthetic
from clm_core.synthetic import simulate_impact

NAMES = CHAIN_PARAMS
ESTIMATORS = ("before", "noise-nopcov", "noise", "inflated", "hac3", "hac12")
Z95 = 1.959964
SOILS = {
    "mevergnies": load_soil("mevergnies"),
    "stiff": SoilParams(model="clm", mf=600.0, kf=150e6, df=1.1e6, kc=300e6, dc=-250e3),
    "soft": load_soil("soft"),
}


@dataclass(frozen=True)
class Scenario:
    """One cell of the grid."""

    soil: str
    fs: float
    noise: str
    geophones: int
    generator: str = "exact"

    @property
    def reach(self) -> int:
        return self.geophones // 2

    def label(self) -> str:
        return f"{self.generator} {self.soil} {self.fs / 1000:g} kHz {self.noise} {self.geophones} geo"


@dataclass
class Replicate:
    """What one noisy replicate gave."""

    z: dict[str, np.ndarray] = field(default_factory=dict)  # estimator -> (5,) standardised errors
    first_err: dict[str, np.ndarray] = field(default_factory=dict)  # route -> (5,) relative errors
    first_z: np.ndarray | None = None
    n_areas: int = 0
    warned: bool = False
    warned_before: bool = False
    rms: float = float("nan")
    rms_before: float = float("nan")


def grid(quick: bool = False) -> list[Scenario]:
    """The scenarios (module docstring); ``quick``: a 6-cell subset."""
    if quick:
        return [
            Scenario("mevergnies", 1000.0, "proportional", 21),
            Scenario("stiff", 1000.0, "floor", 41),
            Scenario("soft", 2000.0, "coloured", 21),
            Scenario("stiff", 1000.0, "proportional", 21),
            Scenario("mevergnies", 2000.0, "floor", 41),
            Scenario("soft", 1000.0, "proportional", 41, "newmark"),
        ]
    out = [
        Scenario(s, fs, nm, g)
        for s in SOILS
        for fs in (1000.0, 2000.0)
        for nm in ("proportional", "floor", "coloured")
        for g in (21, 41)
    ]
    out += [Scenario(s, 1000.0, "proportional", g, "newmark") for s in SOILS for g in (21, 41)]
    return out


def clean_record(sc: Scenario) -> CleanRecord | object:
    """Noise-free record of a scenario (independent integrator, or the project's generator)."""
    soil = SOILS[sc.soil]
    meas = list(range(-sc.reach, sc.reach + 1))
    if sc.generator == "exact":
        return exact_impact(soil, meas, fs=sc.fs, duration=1.0, hit_times=(0.2,))
    return simulate_impact(soil, n_areas=sc.geophones, fs=sc.fs, duration=1.0, hit_times=(0.2,))


def noisy(sc: Scenario, clean: object, level: float, seed: int) -> Recording:
    """A noisy recording of the clean record."""
    if sc.generator == "exact":
        assert isinstance(clean, CleanRecord)
        return add_noise_exact(clean, sc.noise, level, seed)
    rec = add_noise_synthetic(clean, 20 * np.log10(1.0 / level), seed)  # type: ignore[arg-type]
    return common_grid(rec.force, list(rec.responses), SamplingRules())


def _residual_at(data: TransferData, fit: SoilFit) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """r, J, W of the weighted-norm CLM fit at its optimum (same layout as the fit)."""
    cols = list(range(len(data.channels)))
    c = fit.n_areas // 2
    mcols = [c + ch.index for ch in data.channels]
    W, _, _ = norm_weights(data, cols, "weighted")
    assert W is not None
    X, dX = chain_response(fit.soil, fit.n_areas, data.s, jacobian=True)
    assert dX is not None
    r, J = stack_residual((X[:, mcols] - data.H) * W, dX[:, :, mcols] * W[None])
    assert J is not None
    return r, J, W


def run_replicate(sc: Scenario, clean: object, level: float, seed: int) -> Replicate:
    """Calibrate one noisy replicate and evaluate every estimator (module docstring)."""
    truth = np.array([getattr(SOILS[sc.soil], k) for k in NAMES])
    rec = noisy(sc, clean, level, seed)
    data, _ = transfer_functions(rec, 2.0, 150.0)
    first, _ = transfer_functions(rec, 2.0, 150.0, WindowSpec(exp_end=1.0))
    out = Replicate()
    fit = fit_impact(data, "clm", first_data=first)
    p = np.array([getattr(fit.soil, k) for k in NAMES])
    std = np.array([e.std for e in fit.parameters])
    out.z["inflated"] = (p - truth) / std
    out.n_areas = fit.n_areas
    out.rms = fit.stats.rms
    out.warned = any("not the measurement noise" in w for w in fit.warnings)
    r, J, W = _residual_at(data, fit)
    old = replace(data, line_pcov=None, force_pcov=None)
    cols = list(range(len(data.channels)))
    sw_new = make_sandwich(data, cols, W.astype(complex))
    sw_old = make_sandwich(old, cols, W.astype(complex))
    lines, _ = residual_layout(data.frequency.size, len(cols))
    for name, kw in (
        ("noise", {"method": "noise", "sandwich": sw_new}),
        ("noise-nopcov", {"method": "noise", "sandwich": sw_old}),
        ("hac3", {"method": "hac", "lines": lines, "hac_lags": 3}),
        ("hac12", {"method": "hac", "lines": lines, "hac_lags": 12}),
    ):
        cov = covariance(J, r, p, **kw)[0]  # type: ignore[arg-type]
        assert cov is not None
        out.z[name] = (p - truth) / np.sqrt(np.diag(cov))
    fe = fit.first_estimate_parameters
    out.first_err["weighted"] = np.array([e.value for e in fe]) / truth - 1.0
    out.first_z = (np.array([e.value for e in fe]) - truth) / np.array([e.std for e in fe])
    # the calibration before issue 14: fixed chain, paper first estimate, no pseudo-covariance, global factor
    bef = fit_impact(old, "clm", n_areas=sc.geophones, first_data=first, first="paper", interval="noise")
    pb = np.array([getattr(bef.soil, k) for k in NAMES])
    out.z["before"] = (pb - truth) / np.array([e.std for e in bef.parameters])
    out.first_err["paper"] = np.array([bef.first_estimate[k] for k in NAMES]) / truth - 1.0
    out.rms_before = bef.stats.rms
    out.warned_before = any("not the measurement noise" in w for w in bef.warnings)
    return out


def run(
    scenarios: Sequence[Scenario], seeds: int, level: float, progress: bool = True
) -> dict[Scenario, list[Replicate]]:
    """Every replicate of every scenario."""
    res: dict[Scenario, list[Replicate]] = {}
    for i, sc in enumerate(scenarios):
        t0 = time.perf_counter()
        clean = clean_record(sc)
        res[sc] = [run_replicate(sc, clean, level, 1000 * i + k) for k in range(seeds)]
        if progress:
            print(f"<!-- {sc.label()}: {time.perf_counter() - t0:.1f} s -->", file=sys.stderr, flush=True)
    return res


def coverage(reps: Sequence[Replicate], est: str) -> np.ndarray:
    """Fraction of replicates whose interval holds the truth, per parameter (5,)."""
    z = np.array([r.z[est] for r in reps])
    return np.asarray(np.mean(np.abs(z) <= Z95, axis=0))


def _fmt_cov(x: float) -> str:
    return f"{100 * x:.0f}"


def report(res: dict[Scenario, list[Replicate]], level: float, elapsed: float) -> Iterator[str]:
    """The Markdown tables (module docstring)."""
    allreps = [r for v in res.values() for r in v]
    n = len(allreps)
    yield f"Replicates: {n} ({len(res)} scenarios x {n // max(len(res), 1)}), noise {100 * level:g} % "
    yield f"(SNR {20 * np.log10(1 / level):.0f} dB), band 2-150 Hz, weighted norm, one hit, 1 s."
    yield ""
    yield "### Coverage of the nominal 95 % intervals, all parameters together [%]"
    yield ""
    yield "| scenario | " + " | ".join(ESTIMATORS) + " | chain (auto) | rms | rms before |"
    yield "|---|" + "---|" * (len(ESTIMATORS) + 3)
    for sc, reps in res.items():
        cov = [_fmt_cov(float(np.mean(coverage(reps, e)))) for e in ESTIMATORS]
        chains = sorted({r.n_areas for r in reps})
        rms = np.mean([r.rms for r in reps])
        rmsb = np.mean([r.rms_before for r in reps])
        yield f"| {sc.label()} | " + " | ".join(cov) + f" | {'/'.join(map(str, chains))} | {rms:.2f} | {rmsb:.2f} |"
    yield ""
    yield "### Overall coverage per parameter [%] and rms of the standardised errors"
    yield ""
    yield "| estimator | " + " | ".join(NAMES) + " | all | z rms (m_f k_f d_f k_c d_c) |"
    yield "|---|" + "---|" * (len(NAMES) + 2)
    for e in ESTIMATORS:
        cov = coverage(allreps, e)
        z = np.array([r.z[e] for r in allreps])
        zr = " ".join(f"{x:.2f}" for x in np.sqrt(np.mean(z**2, axis=0)))
        yield f"| {e} | " + " | ".join(_fmt_cov(x) for x in cov) + f" | {_fmt_cov(float(np.mean(cov)))} | {zr} |"
    yield ""
    yield "### Coverage of the default (inflated) intervals by factor [%]"
    yield ""
    yield "| factor | value | " + " | ".join(NAMES) + " | all | replicates |"
    yield "|---|---|" + "---|" * (len(NAMES) + 2)
    for attr in ("generator", "soil", "fs", "noise", "geophones"):
        for val in sorted({getattr(sc, attr) for sc in res}, key=str):
            reps = [r for sc, v in res.items() if getattr(sc, attr) == val for r in v]
            cov = coverage(reps, "inflated")
            yield (
                f"| {attr} | {val:g} | " if isinstance(val, float) else f"| {attr} | {val} | "
            ) + " | ".join(_fmt_cov(x) for x in cov) + f" | {_fmt_cov(float(np.mean(cov)))} | {len(reps)} |"
    yield ""
    yield "### First estimate (Eq. 16/18 sums): error over the replicates, mean +- standard deviation [%]"
    yield ""
    yield "| scenario | route | " + " | ".join(NAMES) + " |"
    yield "|---|---|" + "---|" * len(NAMES)
    for sc, reps in res.items():
        for route in ("weighted", "paper"):
            e = 100 * np.array([r.first_err[route] for r in reps])
            cells = " | ".join(f"{m:+.1f} +- {s:.1f}" for m, s in zip(e.mean(axis=0), e.std(axis=0)))
            yield f"| {sc.label()} | {route} | {cells} |"
    yield ""
    for route in ("weighted", "paper"):
        e = 100 * np.array([r.first_err[route] for r in allreps])
        cells = ", ".join(
            f"{k} {m:+.1f} +- {s:.1f} (|err| <= 5 %: {100 * np.mean(np.abs(x) <= 5):.0f} %)"
            for k, m, s, x in zip(NAMES, e.mean(axis=0), e.std(axis=0), e.T)
        )
        yield f"- all scenarios, {route} route: {cells}"
    fz = np.array([r.first_z for r in allreps])
    fc = np.mean(np.abs(fz) <= Z95, axis=0)
    yield (
        "- coverage of the weighted first estimate's own 95 % intervals: "
        + ", ".join(f"{k} {_fmt_cov(c)} %" for k, c in zip(NAMES, fc))
        + f"; all {_fmt_cov(float(np.mean(fc)))} %"
    )
    yield ""
    yield "### Residual warning (residuals not the noise)"
    yield ""
    for gen, g, noise in sorted({(sc.generator, sc.geophones, sc.noise) for sc in res}):
        rr = [r for sc, v in res.items() if (sc.generator, sc.geophones, sc.noise) == (gen, g, noise) for r in v]
        yield (
            f"- {gen}, {g} geophones, {noise} noise: warned on {100 * np.mean([r.warned for r in rr]):.0f} % "
            f"of the default fits (automatic chain) and on {100 * np.mean([r.warned_before for r in rr]):.0f} "
            f"% of the fixed {g}-area chains"
        )
    yield ""
    yield (
        f"Wall time {elapsed:.0f} s ({platform.machine()}, {os.cpu_count()} cores shared, load average at the end "
        f"{os.getloadavg()[0]:.1f})."
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=6, help="replicates per scenario (default 6)")
    ap.add_argument("--level", type=float, default=0.02, help="noise level over the active rms (default 0.02)")
    ap.add_argument("--quick", action="store_true", help="6 scenarios only")
    ap.add_argument("--out", help="also write the tables to this Markdown file")
    args = ap.parse_args()
    t0 = time.perf_counter()
    res = run(grid(args.quick), args.seeds, args.level)
    text = "\n".join(report(res, args.level, time.perf_counter() - t0))
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
