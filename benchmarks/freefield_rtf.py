#!/usr/bin/env python3
"""Benchmark (issue 23.2): real-time factor of the streaming receiver velocities.

    OMP_NUM_THREADS=1 nice -n 10 .venv-core/bin/python benchmarks/freefield_rtf.py [--receivers 10] [--seconds 5]

10 receivers (x = 0, y = 4, 8, ..., 40 m) on the Mevergnies soil
(homogeneous half-space, Table 1 of Kouroussis et al. 2011), default model
(influence length 60 m, band 100 Hz, model rate 250 Hz); frames of 61
sleepers (the track node's window) at 1 kHz, the rate the track node
answers, with an 85 kN load moving at 80 m/s through the window; by default
the run lasts the window's transit through the receivers' zone of
influence, so that every frame carries the full load of the zone. Printed:
the model's size and build time (once per receiver set, not real time),
then the wall time of :meth:`ReceiverStream.push` over all frames, the
real-time factor (simulated time / wall time) for each of ``--repeat``
runs and the worst, and the stream-vs-offline difference on the same
frames (max |v_stream - v_offline| / max |v_offline|).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from clm_core.freefield import FreeFieldModel, ReceiverStream, receiver_velocity
from clm_core.profile import load_profile
from clm_core.synthetic.window import moving_window_forces


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--receivers", type=int, default=10)
    ap.add_argument("--sleepers", type=int, default=61)
    ap.add_argument("--seconds", type=float, default=None,
                    help="simulated time per run [s] (default: the window's transit of the receivers' zone)")
    ap.add_argument("--speed", type=float, default=80.0, help="load speed [m/s]")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--soil", default="mevergnies")
    a = ap.parse_args()
    dt, d, speed = 1e-3, 0.6, a.speed
    rec = np.column_stack([np.zeros(a.receivers), 4.0 * (1 + np.arange(a.receivers))])
    tic = time.perf_counter()
    model = FreeFieldModel(load_profile(a.soil), rec, d, dt)
    build = time.perf_counter() - tic
    print(f"model: {a.receivers} receivers, {model.n_zone} zone sleepers, FIR {model.n_fir} taps at "
          f"{1 / model.model_dt:g} Hz (decimation {model.decimation}), leakage {model.leakage:.2e}, "
          f"built in {build:.1f} s")
    # the whole window stays inside the receivers' zone of influence (every frame is a full-cost frame)
    N = a.sleepers
    half = 0.5 * (N - 1) * d
    x_start, x_end = model.sleeper_positions[0] + half, model.sleeper_positions[-1] - half
    seconds = a.seconds if a.seconds is not None else (x_end - x_start) / speed
    n = int(round(seconds / dt))
    t, first, F = moving_window_forces(n, dt, speed, N, d, x_start)
    idx = first[:, None] + np.arange(N)[None, :]
    rtfs = []
    for k in range(a.repeat):
        s = ReceiverStream(model)
        out = []
        tic = time.perf_counter()
        for i in range(n):
            r = s.push(float(t[i]), idx[i], F[i])
            if r is not None:
                out.append(r[1])
        wall = time.perf_counter() - tic
        rtfs.append(seconds / wall)
        print(f"run {k + 1}: {n} frames of {N} sleepers in {wall:.3f} s: real-time factor {rtfs[-1]:.2f}")
    off = receiver_velocity(model, t, first, F)
    v = np.array(out).T
    diff = float(np.max(np.abs(v - off.velocity)) / np.max(np.abs(off.velocity)))
    print(f"worst real-time factor {min(rtfs):.2f} (best {max(rtfs):.2f}); stream vs offline: {diff:.2e} of the peak; "
          f"PPV {np.max(np.abs(off.velocity), axis=1)[0] * 1e3:.3f} mm/s at y = {rec[0, 1]:g} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
