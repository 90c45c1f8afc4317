"""The online per-frame path against the compiled kernel's cost for the same steps (prints, never asserts).

For each case (window of 61 or 401 sleepers, wheel-load frames at 1 or 2 kHz;
4 wheels at 83.33 m/s, 85 kN +- 5 kN, dt = 1e-4 s, Mevergnies CLM), in one
process, side by side:

- **kernel**: the bare compiled steps, :func:`clm_core.solver._kernels.run_steps`
  for the steps of one frame (10 at 1 kHz, 5 at 2 kHz) with the sleeper
  fields recorded at the last step, loads precomputed (no Python per step),
  window fixed: what one frame costs at the least;
- **process**: :meth:`clm_core.online.OnlineTrackModel.process` of one frame
  (validation, stamp policy, interpolation, Hermite weights, steps, window
  shifts, the response record), per frame over a stream; measured in blocks
  of 100 calls alternating with blocks of the kernel, so that both see the
  same load;
- **batch**: :meth:`~clm_core.online.OnlineTrackModel.process_batch` of a
  backlog of 5000 frames in one call, and its real-time factor (simulated
  time / time taken).

Every figure is CPU time of this process (``time.process_time``: the machine
is shared, wall-clock figures vary with the load) and wall time; each run is
repeated (``--runs``) and the median and the worst run are printed, with the
load average. Usage::

    python benchmarks/online_path.py [--runs 5] [--frames 3000] [--backlog 5000] [--cases 61:1000,401:2000]
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import numpy as np

from clm_core.online import OnlineTrackModel, WheelFrame
from clm_core.params import load_model
from clm_core.solver import _kernels as kern
from clm_core.solver.loads import load_weights

SPEED = 83.33
OFFSETS = np.array([0.0, 3.0, 12.5, 15.5])
DT = 1e-4
NS = 1_000_000_000


def stream(n: int, rate: float, t0_ns: int = 1_796_150_165_843_913_423) -> list[WheelFrame]:
    """n frames at ``rate`` Hz, wall-clock stamps (the demo's magnitude), 4 wheels moving at SPEED."""
    period = round(NS / rate)
    out = []
    for k in range(n):
        t = k * period / NS
        out.append(WheelFrame.of(t0_ns + k * period, [0, 1, 2, 3], 40.0 - OFFSETS + SPEED * t,
                                 85e3 + 5e3 * np.sin(2 * np.pi * 7.0 * t + np.arange(4))))
    return out


def cpu_wall(fn: Any) -> tuple[float, float]:
    c0, w0 = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - c0, time.perf_counter() - w0


class KernelCall:
    """The bare compiled steps of one frame: run_steps for ``steps`` steps, 4 wheels, output at the last step."""

    def __init__(self, params: Any, n_sleepers: int, steps: int) -> None:
        model = OnlineTrackModel.from_settings({"dt": DT, "n_sleepers": n_sleepers}, params=params)
        sim = model.sim
        sim.initialize(40.0 - OFFSETS, np.full(4, 85e3))
        s = sim._s
        # wheels sway by +-1 mm around their place (no shift): the same work per step as moving loads
        P = (40.0 - OFFSETS)[None, :] + 1e-3 * np.sin(np.arange(steps))[:, None]
        F = np.full((steps, 4), 85e3)
        ld, lw = load_weights(sim._layout, s.placement.first, P)
        N = sim.n_sleepers
        out = kern.StepOutputs(np.empty((steps, 4)), np.empty((steps, 4)), np.array([steps - 1], dtype=np.int64),
                               np.empty((1, N)), np.empty((1, N)), np.empty((1, N)), np.empty((1, N)))
        self.args = kern.StepArgs(s.op.kernel, sim._step_state(), kern.StepLoads(ld, lw, F), out)
        kern.run_steps(self.args)

    def __call__(self, calls: int) -> None:
        for _ in range(calls):
            kern.run_steps(self.args)


def side_by_side(params: Any, n_sleepers: int, steps: int, frames: list[WheelFrame], block: int = 100
                 ) -> tuple[float, float, float, float]:
    """CPU and wall time [s] per call of the bare kernel and per frame of ``process``, measured in alternating
    blocks of ``block`` calls (the same load on both)."""
    kernel = KernelCall(params, n_sleepers, steps)
    model = OnlineTrackModel.from_settings({"dt": DT, "n_sleepers": n_sleepers}, params=params)
    model.process(frames[0])
    kc = kw = pc = pw = 0.0
    n = 0
    for a in range(1, len(frames) - block + 1, block):
        c, w = cpu_wall(lambda: kernel(block))
        kc, kw = kc + c, kw + w
        chunk = frames[a:a + block]

        def run(chunk: list[WheelFrame] = chunk) -> None:
            for f in chunk:
                model.process(f)

        c, w = cpu_wall(run)
        pc, pw = pc + c, pw + w
        n += block
    assert model.stats.accepted == n + 1, model.stats
    return kc / n, kw / n, pc / n, pw / n


def batch(params: Any, n_sleepers: int, frames: list[WheelFrame]) -> tuple[float, float, float]:
    model = OnlineTrackModel.from_settings({"dt": DT, "n_sleepers": n_sleepers}, params=params)
    model.process(frames[0])
    c, w = cpu_wall(lambda: model.process_batch(frames[1:]))
    assert model.stats.accepted == len(frames), model.stats
    return c, w, model.stats.simulated_ns / NS


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--frames", type=int, default=3000, help="frames of the per-frame stream")
    ap.add_argument("--backlog", type=int, default=5000, help="frames of the backlog")
    ap.add_argument("--cases", default="61:1000,61:2000,401:1000,401:2000", help="SLEEPERS:RATE_HZ,...")
    a = ap.parse_args()
    params = load_model("mevergnies", "mevergnies", "clm")
    print(f"online path, 4 wheels at {SPEED} m/s, dt = {DT:g} s, Mevergnies CLM; {a.runs} runs; "
          f"load average {os.getloadavg()[0]:.2f} (2 vCPUs shared); CPU time [wall time]")
    for case in a.cases.split(","):
        n_s, rate = (float(x) for x in case.split(":"))
        N, steps = int(n_s), round(1.0 / (rate * DT))
        frames = stream(a.frames, rate)
        backlog = stream(a.backlog + 1, rate)
        kc, kw, pc, pw, bc, bw = [], [], [], [], [], []
        sim_s = 0.0
        for _ in range(a.runs):
            c1, w1, c2, w2 = side_by_side(params, N, steps, frames)
            kc.append(c1)
            kw.append(w1)
            pc.append(c2)
            pw.append(w2)
            c, w, sim_s = batch(params, N, backlog)
            bc.append(c)
            bw.append(w)
        us = 1e6
        ratio = np.array(pc) / np.array(kc)
        print(f"\n{N} sleepers, {rate:g} Hz frames ({steps} steps each), load {os.getloadavg()[0]:.2f}")
        print(f"  kernel, {steps} steps    median {np.median(kc) * us:7.1f} us  worst {max(kc) * us:7.1f} us"
              f"   [wall median {np.median(kw) * us:7.1f} us]")
        print(f"  process, one frame  median {np.median(pc) * us:7.1f} us  worst {max(pc) * us:7.1f} us"
              f"   [wall median {np.median(pw) * us:7.1f} us]")
        print(f"  process / kernel    median {np.median(ratio):7.2f}     worst {max(ratio):7.2f}  (same run)")
        rtf_c = sim_s / np.array(bc)
        rtf_w = sim_s / np.array(bw)
        print(f"  backlog of {a.backlog} frames ({sim_s:.2f} s simulated) in one process_batch: "
              f"{np.median(bc) * 1e3 / a.backlog * 1e3:.1f} us/frame; real-time factor median {np.median(rtf_c):.1f}, "
              f"worst {min(rtf_c):.1f} [wall: median {np.median(rtf_w):.1f}, worst {min(rtf_w):.1f}]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
