"""Benchmark: throughput of ``clm study`` with 1 and 2 workers, and its per-case overhead against ``clm simulate``.

The cases are 2-s runs of the Thalys power car at 83.33 m/s on Mevergnies
with a german-low profile (the defaults of ``clm simulate --vehicle``), one
irregularity seed per case. In the same run, ``--repeats`` times:

- the in-process core call (:func:`clm_core.studies.runner.simulate_case`,
  what ``clm simulate --vehicle`` and every study case compute), after a
  warm-up; and the CLI, ``clm simulate --vehicle --duration 2 --no-csv``, as a
  user runs it (a new process: imports, compiled-code loading, outputs, plots);
- the study of ``--cases`` cases on a local cluster of 1 worker, then of 2
  workers (:func:`clm_core.studies.run_study`): cases per minute over the
  engine phase (first case submitted to last case stored; the cluster start
  and warm-up are given apart), the ratio of the two, the scaling efficiency
  (ratio / 2);
- the per-case overhead of the study: wall time per case with 1 worker minus
  the in-process core call, and minus the case's own wall time in its worker
  (what dask, the store and the table cost per case).

The machine is shared (other jobs run on its 2 cores): the load average
is printed before and after each measurement, every repeat is listed, the
worst too, and CPU times (``cpu_time_s`` of each case in its worker, and
``getrusage`` of the whole study including its worker processes) give
figures that do not depend on the other jobs.

With ``--first-case``, it measures instead the compile-cache warm-up of the
workers (:class:`clm_core.studies.warm.WarmUp`): the wall time of the first
case on fresh worker processes of a local cluster, without the warm-up and
with it, on a cold numba cache (``NUMBA_CACHE_DIR`` an empty folder: a new
host) and on the cache this checkout already holds; with the warm-up, also
each worker's warm-up time and how long it waited for the host's lock.

Usage::

    python benchmarks/study_scaling.py [--cases 24] [--repeats 3] [--duration 2] [--json FILE]
    python benchmarks/study_scaling.py --first-case [--workers 2] [--repeats 1] [--duration 2]

Figures are printed, never asserted.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

from clm_core.studies import parse_study, run_study  # noqa: E402
from clm_core.studies.runner import simulate_case, warm_up  # noqa: E402


def load() -> str:
    """The 1, 5 and 15-minute load averages."""
    one, five, fifteen = os.getloadavg()
    return f"load {one:.2f} {five:.2f} {fifteen:.2f}"


def rusage_cpu(who: int) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def core_calls(duration: float, seeds: list[int]) -> list[tuple[float, float]]:
    """(wall, CPU) [s] of the in-process core call, one per seed."""
    out = []
    for s in seeds:
        t, c = time.perf_counter(), time.process_time()
        simulate_case({"duration": duration, "seed": s})
        out.append((time.perf_counter() - t, time.process_time() - c))
    return out


def cli_calls(duration: float, seeds: list[int], tmp: Path) -> list[tuple[float, float]]:
    """(wall, CPU of the child) [s] of ``clm simulate --vehicle`` in a new process, one per seed."""
    out = []
    for s in seeds:
        d = tmp / f"cli{s}"
        c0 = rusage_cpu(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "clm_core.cli", "simulate", "--vehicle", "--duration", str(duration),
                        "--seed", str(s), "--no-csv", "--out", str(d), "--overwrite"], check=True,
                       capture_output=True)
        out.append((time.perf_counter() - t, rusage_cpu(resource.RUSAGE_CHILDREN) - c0))
    return out


def study(n_cases: int, duration: float, workers: int, tmp: Path, tag: str) -> dict[str, Any]:
    """One study of ``n_cases`` cases on ``workers`` local worker processes."""
    spec = parse_study({"name": f"bench-{tag}", "settings": {"duration": duration},
                        "grid": {"seed": list(range(1, n_cases + 1))}}, "bench")
    c0 = rusage_cpu(resource.RUSAGE_SELF) + rusage_cpu(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    o = run_study(spec, tmp / tag, workers=workers, figures=False)
    total = time.perf_counter() - t
    cpu_all = rusage_cpu(resource.RUSAGE_SELF) + rusage_cpu(resource.RUSAGE_CHILDREN) - c0
    assert o.failed == 0 and o.computed == n_cases, (o.failed, o.computed)
    walls = [float(r["wall_time_s"]) for r in o.rows]
    cpus = [float(r["cpu_time_s"]) for r in o.rows]
    engine_cpu = o.cpu_s["client"] + o.cpu_s["workers"]
    return {
        "workers": workers, "cases": n_cases, "engine_s": o.elapsed_s, "total_s": total,
        "engine_cpu_s": engine_cpu, "engine_cpu_per_case_s": engine_cpu / n_cases,
        "client_cpu_s": o.cpu_s["client"], "workers_cpu_s": o.cpu_s["workers"],
        # the share of a core each worker got (1.0: a core of its own all along; less: the machine is shared)
        "core_share": o.cpu_s["workers"] / (o.elapsed_s * workers),
        "startup_s": total - o.elapsed_s, "cases_per_min": 60.0 * n_cases / o.elapsed_s,
        "case_wall_mean_s": statistics.fmean(walls), "case_cpu_mean_s": statistics.fmean(cpus),
        "cpu_total_s": cpu_all, "cases_per_cpu_min": 60.0 * n_cases / sum(cpus),
    }


def first_case(duration: float, workers: int, warm: bool, cold: bool) -> dict[str, Any]:
    """Fresh local workers, one case each submitted at once: their wall times [s], warm-up or not, cold cache or not."""
    from clm_core.studies.engine import Engine, Task
    from clm_core.studies.runner import run_case

    saved = os.environ.get("NUMBA_CACHE_DIR")
    with tempfile.TemporaryDirectory(prefix="numba-cold-") as cache:
        if cold:
            os.environ["NUMBA_CACHE_DIR"] = cache  # the workers inherit it: nothing compiled yet, a new host
        try:
            rows: list[dict[str, Any]] = []
            t0 = time.perf_counter()
            with Engine(workers=workers, warm=warm_up if warm else None) as engine:
                t1 = time.perf_counter()
                tasks = [Task(f"first-{i}", run_case, ({"duration": duration, "seed": i + 1},)) for i in range(workers)]
                engine.run(tasks, lambda _t, row, _why: rows.append(dict(row or {})))
                t2 = time.perf_counter()
                info = engine.info
        finally:
            if saved is None:
                os.environ.pop("NUMBA_CACHE_DIR", None)
            else:
                os.environ["NUMBA_CACHE_DIR"] = saved
    assert all(r.get("status") == "ok" for r in rows), rows
    return {"warm": warm, "cold_cache": cold, "start_s": t1 - t0, "cases_s": t2 - t1,
            "first_case_s": sorted(float(r["wall_time_s"]) for r in rows),
            "first_case_cpu_s": sorted(float(r["cpu_time_s"]) for r in rows),
            "workers_on": len({r["worker"] for r in rows}), "warm_up": info.warm}


def run_first_case(a: argparse.Namespace) -> int:
    """``--first-case``: the first case on fresh workers, without and with the warm-up plugin."""
    print(f"study_scaling --first-case: {a.workers} fresh workers, one {a.duration:g}-s case each, "
          f"{a.repeats} repeats; {load()}")
    results = []
    for rep in range(a.repeats):
        for cold in (True, False):
            for warm in (False, True):
                l0 = load()
                r = first_case(a.duration, a.workers, warm, cold)
                r.update(repeat=rep, load=[l0, load()])
                results.append(r)
                warm_text = ("; warm-up per worker " + ", ".join(
                    f"{w['warm_s']:.2f} s (waited {w['lock_wait_s']:.2f} s for the host lock)" for w in r["warm_up"])
                    if warm else "")
                print(f"  {'cold' if cold else 'warm'} numba cache, {'with' if warm else 'no'} warm-up: first case "
                      f"{', '.join(f'{x:.2f}' for x in r['first_case_s'])} s wall "
                      f"({', '.join(f'{x:.2f}' for x in r['first_case_cpu_s'])} s CPU) on {r['workers_on']} "
                      f"worker(s); engine start {r['start_s']:.2f} s{warm_text}   [{r['load'][0]} -> {r['load'][1]}]")
    if a.json:
        Path(a.json).write_text(json.dumps({"first_case": results}, indent=2))
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=24, help="cases per study (default 24)")
    ap.add_argument("--repeats", type=int, default=3, help="repeats of every measurement (default 3)")
    ap.add_argument("--duration", type=float, default=2.0, help="simulated time per case [s] (default 2)")
    ap.add_argument("--cli-runs", type=int, default=3, help="clm simulate runs per repeat (default 3)")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    ap.add_argument("--first-case", action="store_true",
                    help="measure the first case on fresh workers, without and with the compile-cache warm-up")
    ap.add_argument("--workers", type=int, default=2, help="--first-case: local workers (default 2)")
    a = ap.parse_args()
    if a.first_case:
        return run_first_case(a)

    print(f"study_scaling: {a.cases} cases of {a.duration:g}-s Thalys runs, {a.repeats} repeats, "
          f"{os.cpu_count()} cores; {load()}")
    warm_up()
    results: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for rep in range(a.repeats):
            core = core_calls(a.duration, list(range(1, a.cases + 1)))  # the study's own cases, in this process
            cli = cli_calls(a.duration, list(range(1, a.cli_runs + 1)), tmp)
            l0 = load()
            if rep % 2 == 0:  # alternate the order (the load of the other jobs drifts)
                one = study(a.cases, a.duration, 1, tmp, f"w1-{rep}")
                l1 = load()
                two = study(a.cases, a.duration, 2, tmp, f"w2-{rep}")
            else:
                two = study(a.cases, a.duration, 2, tmp, f"w2-{rep}")
                l1 = load()
                one = study(a.cases, a.duration, 1, tmp, f"w1-{rep}")
            l2 = load()
            core_wall = statistics.fmean(w for w, _ in core)
            r = {
                "repeat": rep, "core_wall_s": core_wall, "core_cpu_s": statistics.fmean(c for _, c in core),
                "cli_wall_s": statistics.fmean(w for w, _ in cli), "cli_cpu_s": statistics.fmean(c for _, c in cli),
                "one": one, "two": two, "loads": [l0, l1, l2],
                "ratio": two["cases_per_min"] / one["cases_per_min"],
                "ratio_cpu": two["cases_per_cpu_min"] / one["cases_per_cpu_min"],
                "overhead_vs_core": one["engine_s"] / a.cases - core_wall,
                "overhead_vs_case": one["engine_s"] / a.cases - one["case_wall_mean_s"],
                "cpu_overhead_vs_core": one["engine_cpu_per_case_s"] - statistics.fmean(c for _, c in core),
                "cpu_overhead_vs_case": one["engine_cpu_per_case_s"] - one["case_cpu_mean_s"],
            }
            r["efficiency"] = r["ratio"] / 2.0
            results.append(r)
            print(f"\nrepeat {rep + 1}/{a.repeats}")
            print(f"  core call (in process)   {core_wall:.3f} s wall, {r['core_cpu_s']:.3f} s CPU per 2-s run (the "
                  f"study's {a.cases} cases one after the other)")
            print(f"  clm simulate (CLI)       {r['cli_wall_s']:.3f} s wall, {r['cli_cpu_s']:.3f} s CPU per run "
                  "(new process, outputs and plots)")
            for s, lo in ((one, l0), (two, l1)):
                print(f"  study, {s['workers']} worker{'s' if s['workers'] > 1 else ' '}        "
                      f"{s['cases_per_min']:7.1f} cases/min ({s['engine_s']:.2f} s for {s['cases']} cases; start "
                      f"{s['startup_s']:.2f} s); per case {s['case_wall_mean_s']:.3f} s wall, "
                      f"{s['case_cpu_mean_s']:.3f} s CPU; each worker got {s['core_share']:.0%} of a core; study CPU "
                      f"{s['cpu_total_s']:.1f} s   [{lo}]")
            print(f"  2 vs 1 workers           x{r['ratio']:.2f} (efficiency {r['efficiency']:.0%}); per CPU time "
                  f"x{r['ratio_cpu']:.2f}, so x{2 * r['ratio_cpu']:.2f} with a core per worker   [{l2}]")
            print(f"  per-case CPU overhead    {r['cpu_overhead_vs_core'] * 1e3:+.1f} ms "
                  f"({r['cpu_overhead_vs_core'] / r['core_cpu_s']:+.1%} of the core call's CPU), "
                  f"{r['cpu_overhead_vs_case'] * 1e3:+.1f} ms "
                  f"({r['cpu_overhead_vs_case'] / one['case_cpu_mean_s']:+.1%}) vs the case's own CPU in its worker: "
                  f"the engine phase used {one['engine_cpu_per_case_s']:.3f} s CPU per case (workers "
                  f"{one['workers_cpu_s']:.2f} s, client and scheduler {one['client_cpu_s']:.2f} s in all)")
            print(f"  per-case overhead        {r['overhead_vs_core'] * 1e3:+.1f} ms vs the core call "
                  f"({r['overhead_vs_core'] / core_wall:+.1%} of a 2-s run), "
                  f"{r['overhead_vs_case'] * 1e3:+.1f} ms vs the case's own wall time; "
                  f"clm simulate alone costs {(r['cli_wall_s'] - core_wall) * 1e3:+.0f} ms more than the core call")
    worst_ratio = min(r["ratio"] for r in results)
    worst_over = max(r["overhead_vs_core"] / r["core_wall_s"] for r in results)
    worst_cpu = max(r["cpu_overhead_vs_core"] / r["core_cpu_s"] for r in results)
    worst_case = max(r["overhead_vs_case"] / r["one"]["case_wall_mean_s"] for r in results)
    worst_cpu_case = max(r["cpu_overhead_vs_case"] / r["one"]["case_cpu_mean_s"] for r in results)
    print("\nsummary")
    cpu_ratio = statistics.fmean(r["ratio_cpu"] for r in results)
    print(f"  2 vs 1 workers: x{statistics.fmean(r['ratio'] for r in results):.2f} mean, x{worst_ratio:.2f} worst "
          f"(target >= 1.7); per CPU time x{cpu_ratio:.2f} mean, x{min(r['ratio_cpu'] for r in results):.2f} worst: "
          f"x{2 * cpu_ratio:.2f} when each worker has a core of its own")
    print(f"  per-case overhead vs the core call: {statistics.fmean(r['overhead_vs_core'] for r in results) * 1e3:.1f}"
          f" ms mean, worst {worst_over:.1%} of a {a.duration:g}-s run (target < 5 %); in CPU time "
          f"{statistics.fmean(r['cpu_overhead_vs_core'] for r in results) * 1e3:.1f} ms mean, worst {worst_cpu:.1%}")
    print(f"  per-case overhead vs the case's own time in its worker: wall "
          f"{statistics.fmean(r['overhead_vs_case'] for r in results) * 1e3:.1f} ms mean, worst {worst_case:.1%}; "
          f"CPU {statistics.fmean(r['cpu_overhead_vs_case'] for r in results) * 1e3:.1f} ms mean, worst "
          f"{worst_cpu_case:.1%}")
    print(f"  {load()}")
    if a.json:
        Path(a.json).write_text(json.dumps({"cases": a.cases, "duration": a.duration, "repeats": results}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
