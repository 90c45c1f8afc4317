#!/usr/bin/env python3
"""Benchmark (issues 14, 24): are the impact calibration's 95 % intervals honest, and does it know when not?

    nice -n 10 .venv/bin/python benchmarks/calibration_coverage.py --seeds 100 --workers 2 [--out FILE.md]
    nice -n 10 .venv/bin/python benchmarks/calibration_coverage.py --issue14 [--seeds 6]   # the issue-14 grid

Default (issue 24): the stiff soil of issues 14 and 24 (m_f 600 kg, k_f
150 MN/m, d_f 1.1 MN s/m, k_c 300 MN/m, d_c -250 kN s/m), 21 geophones,
one hit, 1 s, records from the **independent integrator**
(``benchmarks/calibration_truth.py``), calibrated as ``calibrate`` does
(:func:`run_issue24`), scenario by scenario, per parameter: the mean and
standard deviation of z = (estimate - truth) / sigma, the coverage of the 95 %
interval, the mean error, and how often the delay and model-adequacy
warnings fire. Scenarios: noise-free (SNR 140 dB) at 1 and 2 kHz (bias); an
SNR sweep at 1 kHz (2, 1, 0.5, 0.25 % noise); a causal FIR anti-alias filter;
short pulses (1 ms); a 10 us channel skew (fitted, ``delay: fit``); a truth
outside the CLM family (1 % second-neighbour coupling). Each scenario's table
is printed as soon as its seeds are done. Workers: processes under the
caller's niceness (run it under ``nice -n 10``).

The issue-14 grid (``--issue14``):

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


@dataclass(frozen=True)
class Case:
    """One issue-24 scenario."""

    name: str
    fs: float = 1000.0
    level: float = 0.01
    anti_alias: str = "iir"
    pulse: float = 0.003
    skew: float = 0.0
    coupling2: float = 0.0
    delay: str = "check"
    seeds: int | None = None  # None: --seeds

    @property
    def noise_free(self) -> bool:
        return self.level < 1e-5


CASES: tuple[Case, ...] = (
    Case("noise-free 1 kHz", level=1e-7, seeds=1),
    Case("noise-free 2 kHz", fs=2000.0, level=1e-7, seeds=1),
    Case("noise-free 1 kHz, causal FIR", level=1e-7, anti_alias="fir", seeds=1),
    Case("SNR sweep 2 %", level=0.02),
    Case("SNR sweep 1 %", level=0.01),
    Case("SNR sweep 0.5 %", level=0.005),
    Case("SNR sweep 0.25 %", level=0.0025),
    Case("causal FIR anti-alias, 1 %", anti_alias="fir"),
    Case("short pulse 1 ms, 1 %", pulse=0.001),
    Case("skew 10 us, 1 %, delay: fit", skew=1e-5, delay="fit"),
    Case("skew 10 us, 0.5 %, delay: check", level=0.005, skew=1e-5),
    Case("outside the CLM: 1 % second-neighbour coupling, 2 %", level=0.02, coupling2=0.01),
)
STIFF = SOILS["stiff"]
_CLEAN: dict[Case, CleanRecord] = {}


def run_case(task: tuple[Case, int]) -> tuple[Case, int, dict[str, object]]:
    """Calibrate one replicate of a scenario (as ``calibrate`` does); what it gave."""
    case, seed = task
    if case not in _CLEAN:
        _CLEAN[case] = exact_impact(STIFF, list(range(-10, 11)), fs=case.fs, pulse_duration=case.pulse,
                                    anti_alias=case.anti_alias, coupling2=case.coupling2, skew=case.skew)
    rec = add_noise_exact(_CLEAN[case], "proportional", case.level, seed)
    data, _ = transfer_functions(rec, 2.0, 150.0)
    fit = fit_impact(data, "clm", delay=case.delay)
    truth = np.array([getattr(STIFF, k) for k in NAMES])
    p = np.array([getattr(fit.soil, k) for k in NAMES])
    std = np.array([e.std for e in fit.parameters])
    dl = fit.delay
    return case, seed, {
        "z": (p - truth) / std,
        "err": p / truth - 1.0,
        "inside": np.array([e.contains(t) for e, t in zip(fit.parameters, truth)]),
        "outside": any("outside the CLM model" in w for w in fit.warnings),
        "delay_warned": bool(dl is not None and dl.rejects()),
        "tau": float(dl.estimate[0]) if dl is not None else float("nan"),
        "tau_std": float(dl.std[0]) if dl is not None else float("nan"),
        "first_vs": fit.first_vs_fit.statistic if fit.first_vs_fit is not None else float("nan"),
        "c2_p": fit.coupling2.p_value if fit.coupling2 is not None else float("nan"),
        "n_areas": fit.n_areas,
    }


def case_report(case: Case, reps: Sequence[dict[str, object]]) -> Iterator[str]:
    """The table of one scenario (Markdown)."""
    z = np.array([r["z"] for r in reps])
    err = 100 * np.array([r["err"] for r in reps])
    inside = np.array([r["inside"] for r in reps])
    n = len(reps)
    yield f"#### {case.name} ({n} seed{'s' if n > 1 else ''}, {case.fs / 1000:g} kHz)"
    yield ""
    if case.noise_free:
        yield "| | " + " | ".join(NAMES) + " |"
        yield "|---|" + "---|" * len(NAMES)
        yield "| bias [%] | " + " | ".join(f"{e:+.4f}" for e in err.mean(axis=0)) + " |"
    else:
        yield "| | " + " | ".join(NAMES) + " |"
        yield "|---|" + "---|" * len(NAMES)
        yield "| mean z | " + " | ".join(f"{x:+.2f}" for x in z.mean(axis=0)) + " |"
        yield "| sd z | " + " | ".join(f"{x:.2f}" for x in z.std(axis=0)) + " |"
        yield "| coverage 95 % [%] | " + " | ".join(f"{100 * x:.0f}" for x in inside.mean(axis=0)) + " |"
        yield "| mean error [%] | " + " | ".join(f"{x:+.3f}" for x in err.mean(axis=0)) + " |"
        yield "| sd error [%] | " + " | ".join(f"{x:.3f}" for x in err.std(axis=0)) + " |"
    tau = 1e6 * np.array([r["tau"] for r in reps])
    tsd = 1e6 * np.array([r["tau_std"] for r in reps])
    yield ""
    yield (
        f"warned outside the CLM: {100 * np.mean([r['outside'] for r in reps]):.0f} %; delay warned (significant): "
        f"{100 * np.mean([r['delay_warned'] for r in reps]):.0f} %; delay estimate {np.mean(tau):+.2f} us "
        f"(sd over seeds {np.std(tau):.2f}, stated {np.mean(tsd):.2f}); first vs refined max |z| median "
        f"{np.median([r['first_vs'] for r in reps]):.2f}; coupling test p < 0.01 in "
        f"{100 * np.mean([float(r['c2_p']) < 0.01 for r in reps]):.0f} %; chains "  # type: ignore[arg-type]
        f"{'/'.join(map(str, sorted({r['n_areas'] for r in reps})))}"  # type: ignore[type-var]
    )
    yield ""


def run_issue24(seeds: int, workers: int, only: str | None = None) -> Iterator[str]:
    """Every issue-24 scenario, each table as soon as its seeds are done."""
    import multiprocessing as mp

    cases = [c for c in CASES if only is None or only in c.name]
    tasks = [(c, k) for c in cases for k in range(c.seeds or seeds)]
    todo = {c: c.seeds or seeds for c in cases}
    got: dict[Case, list[dict[str, object]]] = {c: [] for c in cases}
    t0 = time.perf_counter()
    ctx = mp.get_context("fork")
    with ctx.Pool(workers) as pool:
        for case, _, out in pool.imap_unordered(run_case, tasks):
            got[case].append(out)
            if len(got[case]) == todo[case]:
                yield from case_report(case, got[case])
                yield f"<!-- {case.name}: done at {time.perf_counter() - t0:.0f} s -->"
                yield ""
    yield (
        f"Wall time {time.perf_counter() - t0:.0f} s ({platform.machine()}, {workers} workers, {os.cpu_count()} "
        f"cores shared, load average at the end {os.getloadavg()[0]:.1f})."
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=100, help="replicates per scenario (default 100; --issue14: 6)")
    ap.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--only", help="issue 24: only the scenarios whose name contains this text")
    ap.add_argument("--issue14", action="store_true", help="the issue-14 grid and estimators instead")
    ap.add_argument("--level", type=float, default=0.02, help="issue 14: noise level (default 0.02)")
    ap.add_argument("--quick", action="store_true", help="issue 14: 6 scenarios only")
    ap.add_argument("--out", help="also write the tables to this Markdown file")
    args = ap.parse_args()
    t0 = time.perf_counter()
    lines: list[str] = []
    if args.issue14:
        res = run(grid(args.quick), args.seeds if args.seeds != 100 else 6, args.level)
        lines = list(report(res, args.level, time.perf_counter() - t0))
        print("\n".join(lines))
    else:
        for line in run_issue24(args.seeds, args.workers, args.only):
            print(line, flush=True)
            lines.append(line)
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
