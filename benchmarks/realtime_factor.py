"""Benchmark: real-time factor of the streaming time integrator (clm_core.solver).

Simulated seconds per wall-clock second, on one core, for the Mevergnies
track on its CLM soil (paper Tables 1-2) under a 100 kN load moving at
30 m/s, after warm-up (JIT cache loaded, first window factorised). In the
same run:

- the engine: :class:`clm_core.solver.TrackSimulator` (moving window,
  compiled envelope-LDL^T kernel, many steps per call);
- the straightforward reference: the same window's M, C, K stepped by
  :class:`clm_core.newmark.NewmarkLinear` (scipy sparse LU factorised once,
  one solve per step, load vector built per step with the Hermite weights);
- the same model in OpenSeesPy (elasticBeamColumn rail with consistent mass,
  zeroLength springs-dashpots, nodal masses, Newmark average acceleration,
  BandSPD, Linear -factorOnce, moving load as Path time series), run in a
  subprocess with LD_LIBRARY_PATH set to the wheel's own BLAS/LAPACK
  (openseespylinux/lib); skipped with a message when not installed. It is
  looked for on the current interpreter's path, then in ``$CLM_PEERS_DIR``
  (default ``~/.cache/clm-peers``; install there with
  ``pip install --target ~/.cache/clm-peers "openseespy<3.8"`` for
  Python 3.11, 3.8 needs Python >= 3.12).

Usage::

    python benchmarks/realtime_factor.py --sleepers 61 --dt 1e-4 [--json] [--scan 61,121,241,401]

Figures are printed, never asserted. The machine may be shared: each figure
is the best of ``--repeat`` runs.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import textwrap  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from clm_core.newmark import NewmarkLinear, _initial_acceleration  # noqa: E402
from clm_core.params import ModelParams, load_model  # noqa: E402
from clm_core.solver import TrackSimulator  # noqa: E402

SPEED = 30.0
LOAD = 100e3


def engine_rtf(p: ModelParams, n: int, dt: float, repeat: int, target_wall: float = 1.0) -> dict[str, Any]:
    """Real-time factor of TrackSimulator (best of ``repeat``), and its work per step."""
    sim = TrackSimulator(p, dt, n)
    sim.initialize([0.0], [LOAD])
    # warm-up: loads the compiled kernels, factorises, first shifts
    t_w = 0.02
    tic = time.perf_counter()
    sim.advance(t_w, ([SPEED * t_w], [LOAD]))
    est = max((time.perf_counter() - tic) / (t_w / dt), 1e-7)
    steps = int(max(2000, min(200_000, target_wall / est)))
    best = best_cpu = np.inf
    for _ in range(repeat):
        t0, x0 = sim.t, SPEED * sim.t
        T = steps * dt
        tic, cpu = time.perf_counter(), time.thread_time()
        sim.advance(t0 + T, ([x0 + SPEED * T], [LOAD]))
        best = min(best, time.perf_counter() - tic)
        best_cpu = min(best_cpu, time.thread_time() - cpu)
    op = sim.operator.kernel
    nnz = int(op.indptr[-1])
    env = int(op.ptr[-1])
    nd = sim.n_dof
    flops = 4 * nnz + 4 * env + 5 * nd + 12 * n  # rhs (2 FMA/nnz), solves (2 x 1 FMA/entry), update, sleepers
    bytes_op = 24 * nnz + 8 * env + 8 * 2 * (nd + 1) + 8 * nd  # CSR (index + 2 values), L, first/ptr, 1/D
    bytes_state = 4 * 8 * nd
    return {
        "sleepers": n, "n_dof": nd, "steps_timed": steps, "wall_s": best,
        "us_per_step": best / steps * 1e6, "rtf": steps * dt / best, "rtf_cpu": steps * dt / best_cpu,
        "nnz_rhs_pattern": nnz, "envelope_entries": env, "flops_per_step": flops,
        "operator_bytes": bytes_op, "state_bytes": bytes_state,
        "factorisations": sim.n_factorisations, "window_first_sleeper_at_end": sim.window[0],
    }


def reference_rtf(p: ModelParams, n: int, dt: float, repeat: int, target_wall: float = 0.5) -> dict[str, Any]:
    """The same window stepped by NewmarkLinear (scipy splu once, one solve + sparse matvecs per step)."""
    sim = TrackSimulator(p, dt, n, follow=False)
    s = sim.system
    ref = NewmarkLinear(s.M, s.C, s.K, dt)
    lo, hi = sim.allowed_range()
    x0 = lo

    def load(x: float) -> np.ndarray:
        f = np.zeros(s.n_dof)
        d, w = s.point_load(lo + (x - lo) % (hi - lo))  # the cost per step does not depend on where
        np.add.at(f, d, w * LOAD)
        return f

    ref.a = _initial_acceleration(ref.M, load(x0))
    tic = time.perf_counter()
    for k in range(1, 101):
        ref.step(load(x0 + SPEED * k * dt))
    est = (time.perf_counter() - tic) / 100
    steps = int(max(200, min(20_000, target_wall / est)))
    best = best_cpu = np.inf
    for _ in range(repeat):
        tic, cpu = time.perf_counter(), time.thread_time()
        for k in range(1, steps + 1):
            ref.step(load(x0 + SPEED * k * dt))
        best = min(best, time.perf_counter() - tic)
        best_cpu = min(best_cpu, time.thread_time() - cpu)
    return {"steps_timed": steps, "wall_s": best, "us_per_step": best / steps * 1e6, "rtf": steps * dt / best,
            "rtf_cpu": steps * dt / best_cpu}


OPENSEES_SCRIPT = r"""
import json, sys, time
import numpy as np
import openseespy.opensees as ops
cfg = json.loads(sys.argv[1])
node_x = np.array(cfg["node_x"]); sl_node = cfg["sleeper_node"]
E, I, mpl = cfg["E"], cfg["I"], cfg["mass_per_length"]
dt, nsteps = cfg["dt"], cfg["nsteps"]
ops.wipe(); ops.model("basic", "-ndm", 2, "-ndf", 3)
nn = len(node_x)
for j, x in enumerate(node_x):
    ops.node(j + 1, float(x), 0.0); ops.fix(j + 1, 1, 0, 0)
ops.geomTransf("Linear", 1)
for j in range(nn - 1):
    ops.element("elasticBeamColumn", j + 1, j + 1, j + 2, 1.0, E, I, 1, "-mass", mpl, "-cMass")
ground = 10 * nn
ops.node(ground, 0.0, 0.0); ops.fix(ground, 1, 1, 1)
mat = [0]
def spring(tag, a, b, k, c):
    mat[0] += 1
    ops.uniaxialMaterial("Elastic", mat[0], k, c)
    ops.element("zeroLength", tag, a, b, "-mat", mat[0], "-dir", 2)
et = nn
for i, j in enumerate(sl_node):
    s, a = 2 * nn + i + 1, 4 * nn + i + 1
    x = float(node_x[j])
    ops.node(s, x, 0.0); ops.fix(s, 1, 0, 1); ops.mass(s, 0.0, cfg["ms"], 0.0)
    et += 1; spring(et, j + 1, s, cfg["kp"], cfg["dp"])
    if cfg["soil"] == "rigid":
        ops.node(a, x, 0.0); ops.fix(a, 1, 1, 1)
    else:
        ops.node(a, x, 0.0); ops.fix(a, 1, 0, 1); ops.mass(a, 0.0, cfg["mf"], 0.0)
        et += 1; spring(et, a, ground, cfg["kf"], cfg["df"])
    et += 1; spring(et, s, a, cfg["kb"], cfg["db"])
if cfg["soil"] == "clm":
    for i in range(len(sl_node) - 1):
        et += 1; spring(et, 4 * nn + i + 1, 4 * nn + i + 2, cfg["kc"], cfg["dc"])
# moving load: nodal forces as Path time series (Hermite weights, y up = -our w, theta = -our theta)
t = dt * np.arange(nsteps + 1)
x = cfg["x0"] + cfg["speed"] * t
Le = node_x[1] - node_x[0]
e = np.clip(((x - node_x[0]) // Le).astype(int), 0, nn - 2)
xi = (x - node_x[e]) / Le
N = np.stack([1 - 3 * xi**2 + 2 * xi**3, Le * (xi - 2 * xi**2 + xi**3),
              3 * xi**2 - 2 * xi**3, Le * (-xi**2 + xi**3)], 1)
fw = np.zeros((nn, nsteps + 1)); fm = np.zeros((nn, nsteps + 1))
k = np.arange(nsteps + 1)
np.add.at(fw, (e, k), -cfg["F"] * N[:, 0]); np.add.at(fm, (e, k), -cfg["F"] * N[:, 1])
np.add.at(fw, (e + 1, k), -cfg["F"] * N[:, 2]); np.add.at(fm, (e + 1, k), -cfg["F"] * N[:, 3])
used = np.nonzero(np.any(fw != 0, axis=1) | np.any(fm != 0, axis=1))[0]
ts = 0
for j in used:
    ts += 1
    ops.timeSeries("Path", ts, "-dt", dt, "-values", *fw[j].tolist())
    ops.pattern("Plain", ts, ts); ops.load(int(j) + 1, 0.0, 1.0, 0.0)
    ts += 1
    ops.timeSeries("Path", ts, "-dt", dt, "-values", *fm[j].tolist())
    ops.pattern("Plain", ts, ts); ops.load(int(j) + 1, 0.0, 0.0, 1.0)
ops.system("BandSPD"); ops.numberer("RCM"); ops.constraints("Plain")
ops.integrator("Newmark", 0.5, 0.25); ops.algorithm("Linear", "-factorOnce"); ops.analysis("Transient")
ops.analyze(1, dt)  # set-up and factorisation outside the timing (the load at t = dt)
tic, cpu = time.perf_counter(), time.process_time()
ok = ops.analyze(nsteps - 1, dt)
wall, cpu = time.perf_counter() - tic, time.process_time() - cpu
jl = int(e[-1]); w_end = -(N[-1, 0] * ops.nodeDisp(jl + 1, 2) + N[-1, 2] * ops.nodeDisp(jl + 2, 2)
                             + N[-1, 1] * ops.nodeDisp(jl + 1, 3) + N[-1, 3] * ops.nodeDisp(jl + 2, 3))
print(json.dumps({"ok": ok, "wall_s": wall, "cpu_s": cpu, "steps": nsteps - 1, "w_end": w_end,
                  "version": ops.version() if hasattr(ops, "version") else "?"}))
"""


def _find_opensees() -> tuple[str | None, str]:
    """(PYTHONPATH entry or '' for the interpreter's own, LD_LIBRARY_PATH) of an openseespy install."""
    spec = importlib.util.find_spec("openseespylinux")
    if spec is not None and spec.submodule_search_locations:
        return "", str(Path(next(iter(spec.submodule_search_locations))) / "lib")
    d = Path(os.environ.get("CLM_PEERS_DIR", Path.home() / ".cache" / "clm-peers"))
    if (d / "openseespy").is_dir() and (d / "openseespylinux" / "lib").is_dir():
        return str(d), str(d / "openseespylinux" / "lib")
    return None, ""


def opensees_rtf(p: ModelParams, n: int, dt: float, repeat: int) -> dict[str, Any]:
    """The same fixed-window model in OpenSeesPy (subprocess); also our engine on it for the result check."""
    path, lib = _find_opensees()
    if path is None:
        return {"skipped": "openseespy not installed (pip install --target ~/.cache/clm-peers 'openseespy<3.8')"}
    d = p.track.spacing
    sim = TrackSimulator(p, dt, n, follow=False)
    s = sim.system
    lo, hi = sim.allowed_range()
    T = min(0.5, 0.95 * (hi - lo) / SPEED)
    nsteps = int(round(T / dt))
    x0 = lo + 0.37 * d
    t, pr = p.track, p.soil
    cfg = {"node_x": s.node_x.tolist(), "sleeper_node": s.sleeper_node.tolist(), "E": p.rail.E, "I": p.rail.I,
           "mass_per_length": p.rail.mass_per_length, "dt": dt, "nsteps": nsteps, "kp": t.kp, "dp": t.dp,
           "ms": t.ms, "kb": t.kb, "db": t.db, "mf": pr.mf, "kf": pr.kf, "df": pr.df, "kc": pr.kc, "dc": pr.dc,
           "soil": pr.model, "x0": x0, "speed": SPEED, "F": LOAD}
    env = dict(os.environ)
    env["LD_LIBRARY_PATH"] = lib + (":" + env["LD_LIBRARY_PATH"] if env.get("LD_LIBRARY_PATH") else "")
    if path:
        env["PYTHONPATH"] = path + (":" + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "opensees_track.py"
        script.write_text(textwrap.dedent(OPENSEES_SCRIPT))
        cfg_file = json.dumps(cfg)
        runs = []
        for _ in range(repeat):
            r = subprocess.run([sys.executable, str(script), cfg_file], capture_output=True, text=True, env=env,
                               timeout=1800)
            lines = [ln for ln in r.stdout.splitlines() if ln.startswith("{")]
            if r.returncode != 0 or not lines:
                return {"skipped": f"OpenSeesPy run failed: {(r.stderr or r.stdout).strip()[-300:]}"}
            runs.append(json.loads(lines[-1]))
    best = min(runs, key=lambda r: r["wall_s"])
    # our engine on the same fixed window, same load path: deflection under the load at the end
    sim.initialize([x0], [LOAD], state="rest")
    sim.advance(nsteps * dt, ([x0 + SPEED * nsteps * dt], [LOAD]))
    w_ours = float(sim.snapshot().wheel_deflection[0])
    return {"version": best["version"], "steps_timed": best["steps"], "wall_s": best["wall_s"],
            "us_per_step": best["wall_s"] / best["steps"] * 1e6, "rtf": best["steps"] * dt / best["wall_s"],
            "rtf_cpu": best["steps"] * dt / min(r["cpu_s"] for r in runs),
            "w_end_opensees_m": best["w_end"], "w_end_ours_m": w_ours,
            "w_end_rel_diff": abs(best["w_end"] / w_ours - 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sleepers", type=int, default=61, help="window size (default 61)")
    ap.add_argument("--dt", type=float, default=1e-4, help="time step [s] (default 1e-4)")
    ap.add_argument("--repeat", type=int, default=3, help="best of this many runs (default 3)")
    ap.add_argument("--scan", default="",
                    help="also the engine's cost per step for these window sizes, e.g. 61,121,241,401")
    ap.add_argument("--no-peer", action="store_true", help="skip OpenSeesPy")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args()
    p = load_model("mevergnies", "mevergnies", "clm")
    out: dict[str, Any] = {"model": p.name, "dt_s": a.dt, "speed_m_per_s": SPEED, "load_N": LOAD,
                           "machine": platform.machine(), "python": platform.python_version(),
                           "cpus_visible": os.cpu_count()}
    out["engine"] = engine_rtf(p, a.sleepers, a.dt, a.repeat)
    out["reference"] = reference_rtf(p, a.sleepers, a.dt, a.repeat)
    out["speedup_vs_reference"] = out["engine"]["rtf"] / out["reference"]["rtf"]
    if a.scan:
        out["scan"] = [{k: r[k] for k in ("sleepers", "n_dof", "us_per_step", "rtf", "rtf_cpu", "flops_per_step")}
                       | {"ns_per_dof": r["us_per_step"] * 1e3 / r["n_dof"]}
                       for r in (engine_rtf(p, int(n), a.dt, a.repeat, 0.5) for n in a.scan.split(","))]
    out["opensees"] = {"skipped": "--no-peer"} if a.no_peer else opensees_rtf(p, a.sleepers, a.dt, a.repeat)
    if "rtf" in out["opensees"]:
        out["speedup_vs_opensees"] = out["engine"]["rtf"] / out["opensees"]["rtf"]
    if a.json:
        print(json.dumps(out, indent=2))
        return
    e, r, o = out["engine"], out["reference"], out["opensees"]
    print(f"{p.name}: moving load {LOAD / 1e3:g} kN at {SPEED:g} m/s, dt = {a.dt:g} s, "
          f"window {e['sleepers']} sleepers ({e['n_dof']} DOFs), one core, best of {a.repeat}")
    print(f"  engine    (TrackSimulator, numba kernel)  RTF {e['rtf']:8.2f}   {e['us_per_step']:8.2f} us/step"
          f"   (CPU-time RTF {e['rtf_cpu']:.2f})")
    print(f"  reference (NewmarkLinear, scipy splu)     RTF {r['rtf']:8.2f}   {r['us_per_step']:8.2f} us/step"
          f"   (CPU-time RTF {r['rtf_cpu']:.2f})")
    print(f"  engine / reference                        x{out['speedup_vs_reference']:.1f}")
    if "rtf" in o:
        print(f"  OpenSeesPy {o['version']} (BandSPD, Linear -factorOnce)   RTF {o['rtf']:8.2f}   "
              f"{o['us_per_step']:8.2f} us/step   (CPU-time RTF {o['rtf_cpu']:.2f}; "
              f"engine x{out['speedup_vs_opensees']:.1f})"
              "\n    rail deflection "
              f"under the load at the end: OpenSees {o['w_end_opensees_m'] * 1e3:.5f} mm, ours "
              f"{o['w_end_ours_m'] * 1e3:.5f} mm (rel. diff {o['w_end_rel_diff']:.1e})")
    else:
        print(f"  OpenSeesPy: skipped ({o['skipped']})")
    print(f"  work per step: {e['flops_per_step'] / 1e3:.1f} kflop ({e['nnz_rhs_pattern']} CSR entries, "
          f"{e['envelope_entries']} envelope entries); data touched per step: "
          f"{(e['operator_bytes'] + e['state_bytes']) / 1024:.0f} KiB "
          f"-> {e['flops_per_step'] / e['us_per_step'] / 1e3:.2f} Gflop/s")
    for row in out.get("scan", []):
        print(f"  scan: {row['sleepers']:5d} sleepers {row['n_dof']:6d} DOFs  {row['us_per_step']:8.2f} us/step  "
              f"{row['ns_per_dof']:.1f} ns/DOF  RTF {row['rtf']:.2f} (CPU-time {row['rtf_cpu']:.2f})")


if __name__ == "__main__":
    main()
