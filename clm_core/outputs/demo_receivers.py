"""Free-field receivers and the rail-deflection spectra of a recorded demo (``scripts/demo.sh``).

``python -m clm_core.outputs.demo_receivers OUT [--receivers 8,16,32] [--receiver-x X] [--influence 60]`` reads
the bag ``OUT/demo_bag`` of ``clm demo`` (the track node's
``/sleeper_response``: sleeper indices, soil forces, rail deflections above
the sleepers; ``/wheel_rail_response``: rail deflection under the wheels)
and adds to ``OUT``:

- the receiver outputs of :func:`clm_core.outputs.receivers.write_receiver_outputs`
  (``receivers.npz``, ``receivers.csv``, ``receivers.png``, the ``receivers``
  entry of ``summary.json``: PPV, KB_F,max, one-third-octave levels L_v per
  receiver), receivers at the given distances from the track axis at
  ``--receiver-x`` (default: the middle of the sleepers the run recorded),
  on the soil profile and with the contact area of the run's ``soil`` and
  ``track`` (from ``summary.json``);
- ``rail_deflection_spectra.png``: amplitude spectra and one-third-octave
  band rms of the rail deflection under the first wheel and above the
  sleeper of the largest deflection (:mod:`clm_core.spectra`);
- ``index.html`` rewritten with them.

The sleeper forces are placed on the global sleeper grid (sleepers outside
the track node's window carry no force, as for the receiver node); the
responses are the 1-kHz frames of the track node, one per wheel-load
message. A frame missing from the bag (none in a healthy run) is
interpolated linearly in time and counted (``frames_interpolated``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from clm_core.arrays import Array
from clm_core.errors import ClmError, InputError

__all__ = ["DemoRecord", "demo_receivers", "read_demo_bag"]


@dataclass(frozen=True)
class DemoRecord:
    """The track node's responses of a demo bag on a uniform time grid.

    Attributes
    ----------
    t : (n,) array
        Times from the first wheel-load message [s], uniform step ``dt``.
    dt : float
        Frame interval [s].
    first_sleeper : int
        Global index of column 0 of the grids.
    soil_force, rail_deflection : (n, J) arrays
        Ballast force on the soil [N] and rail deflection above each global sleeper [m]; NaN outside the window.
    spacing : float
        Sleeper spacing [m].
    wheel_t, wheel_deflection : (p,) arrays
        Times [s] and rail deflection under the first wheel [m] (``/wheel_rail_response``; empty if not recorded).
    interpolated : int
        Frames missing from the bag, interpolated in time.
    """

    t: Array
    dt: float
    first_sleeper: int
    soil_force: Array
    rail_deflection: Array
    spacing: float
    wheel_t: Array
    wheel_deflection: Array
    interpolated: int


def read_demo_bag(bag: str | Path) -> DemoRecord:
    """Read ``/sleeper_response`` (and ``/wheel_rail_response``) of a demo bag (:class:`DemoRecord`)."""
    from clm_core.io.bags import BagReader
    from clm_core.io.timebase import stamp_ns

    s_t: list[int] = []
    s_idx: list[Array] = []
    s_x: list[Array] = []
    s_F: list[Array] = []
    s_w: list[Array] = []
    w_t: list[int] = []
    w_d: list[float] = []
    t0: int | None = None
    with BagReader(bag) as reader:
        topics = [t for t in ("/wheel_loads", "/sleeper_response", "/wheel_rail_response") if t in reader.topics]
        for bm in reader.messages(topics):
            m = reader.deserialize(bm.data, bm.msgtype)
            if bm.topic == "/wheel_loads":
                if t0 is None:
                    t0 = stamp_ns(m.header)
            elif bm.topic == "/sleeper_response":
                s_t.append(stamp_ns(m.header))
                s_idx.append(np.asarray(m.sleeper_index, dtype=np.int64))
                s_x.append(np.asarray(m.position, dtype=float))
                s_F.append(np.asarray(m.soil_force, dtype=float))
                s_w.append(np.asarray(m.rail_deflection, dtype=float))
            elif len(m.rail_deflection):
                w_t.append(stamp_ns(m.header))
                w_d.append(float(m.rail_deflection[0]))
    if len(s_t) < 2:
        raise InputError(f"bag {bag}: {len(s_t)} sleeper response(s); need a recorded run")
    order = np.argsort(s_t, kind="stable")
    st = np.asarray(s_t, dtype=np.int64)[order]
    base = int(t0) if t0 is not None else int(st[0])
    step = int(np.median(np.diff(st)))
    if step <= 0:
        raise InputError(f"bag {bag}: sleeper responses with equal stamps; cannot place them in time")
    slot = np.rint((st - st[0]) / step).astype(np.int64)
    if np.any(np.abs(st - st[0] - slot * step) > 0.01 * step) or np.any(np.diff(slot) == 0):
        raise InputError(f"bag {bag}: sleeper response stamps are not on a uniform {step} ns grid")
    gmin = min(int(i.min()) for i in s_idx)
    gmax = max(int(i.max()) for i in s_idx)
    n = int(slot[-1]) + 1
    F = np.full((n, gmax - gmin + 1), np.nan)
    W = np.full_like(F, np.nan)
    xg = np.full(gmax - gmin + 1, np.nan)
    for k, j in enumerate(order):
        cols = s_idx[j] - gmin
        F[slot[k], cols] = s_F[j]
        W[slot[k], cols] = s_w[j]
        xg[cols] = s_x[j]
    have = np.zeros(n, dtype=bool)
    have[slot] = True
    if not have.all():  # interpolate missing frames column by column (NaN = outside the window stays NaN)
        for grid in (F, W):
            for c in range(grid.shape[1]):
                ok = have & np.isfinite(grid[:, c])
                if ok.sum() >= 2:
                    lo, hi = np.flatnonzero(ok)[[0, -1]]
                    miss = ~have & (np.arange(n) > lo) & (np.arange(n) < hi)
                    grid[miss, c] = np.interp(np.flatnonzero(miss), np.flatnonzero(ok), grid[ok, c])
    dx = np.diff(xg)
    spacing = round(float(np.nanmedian(dx)), 9) if np.isfinite(dx).any() else 0.6
    dt = step * 1e-9
    wt = np.asarray((np.asarray(w_t, dtype=np.int64) - base) * 1e-9, dtype=np.float64)
    return DemoRecord(t=(st[0] - base) * 1e-9 + dt * np.arange(n), dt=dt, first_sleeper=gmin, soil_force=F,
                      rail_deflection=W, spacing=spacing, wheel_t=wt,
                      wheel_deflection=np.asarray(w_d), interpolated=int(n - have.sum()))


def _rail_spectra(rec: DemoRecord, out: Path) -> Path | None:
    """``rail_deflection_spectra.png``: spectra and one-third-octave band rms of the rail deflection."""
    from clm_core.outputs.plots.report import Quantity, Record, plot_spectra, plot_third_octave, uniform

    records = []
    if rec.wheel_deflection.size:
        u = uniform(rec.wheel_t, rec.wheel_deflection)
        if u is not None:
            records.append(Record("rail under wheel 0 (mean removed)", *u))
    cover = np.isfinite(rec.rail_deflection).sum(axis=0)
    full = np.flatnonzero(cover >= 0.9 * max(1, int(cover.max())))
    if full.size:
        j = int(full[np.argmax(np.nanmax(rec.rail_deflection[:, full], axis=0))])
        u = uniform(rec.t, rec.rail_deflection[:, j])
        if u is not None:
            records.append(Record(f"rail above sleeper {rec.first_sleeper + j} (largest deflection; mean removed)",
                                  *u))
    if not records:
        return None
    q = [Quantity("rail deflection", "mm", 1e3, records)]
    title = "clm demo: rail deflection"
    path = plot_spectra(out / "rail_deflection_spectra.png", q, title)
    plot_third_octave(out / "rail_deflection_third_octave.png", q, title)
    return path


def demo_receivers(out: str | Path, distances: tuple[float, ...] = (8.0, 16.0, 32.0), *,
                   receiver_x: float | None = None, influence_length: float = 60.0) -> dict[str, Any]:
    """Add the receivers and the rail-deflection spectra to the demo output ``out`` (module docstring).

    Returns
    -------
    dict
        The ``receivers`` entry written to ``summary.json`` (plus ``build_s``, ``wall_s``, ``frames_interpolated``).
    """
    from clm_core.freefield import free_field, receivers_from_distances
    from clm_core.io.files import write_json
    from clm_core.outputs.receivers import receiver_soil, write_receiver_outputs
    from clm_core.outputs.report_index import write_index
    from clm_core.params import load_track

    tic = time.perf_counter()
    d = Path(out)
    s_path = d / "summary.json"
    summary = json.loads(s_path.read_text(encoding="utf-8")) if s_path.exists() else {}
    rec = read_demo_bag(d / "demo_bag")
    _, track = load_track(str(summary.get("track") or "mevergnies"))
    soil = receiver_soil(None, str(summary.get("soil") or "mevergnies"))
    x_mid = (rec.first_sleeper + 0.5 * (rec.soil_force.shape[1] - 1)) * rec.spacing
    receivers = receivers_from_distances(distances, x=x_mid if receiver_x is None else float(receiver_x))
    F = np.where(np.isfinite(rec.soil_force), rec.soil_force, 0.0)
    first = np.full(rec.t.size, rec.first_sleeper, dtype=np.int64)
    t_build = time.perf_counter()
    res = free_field(soil, receivers, rec.t, first, F, rec.spacing, contact_length=track.contact_length,
                     contact_width=track.contact_width, influence_length=influence_length)
    build = time.perf_counter() - t_build
    title = f"clm demo: free-field vertical velocity, soil '{soil.name}' (two-step method)"
    entry = write_receiver_outputs(res, soil.name, d, title=title)
    _rail_spectra(rec, d)
    entry.update({"frames_interpolated": rec.interpolated, "free_field_s": round(build, 3),
                  "wall_s": round(time.perf_counter() - tic, 3)})
    if s_path.exists():
        summary = json.loads(s_path.read_text(encoding="utf-8"))
        summary["receivers"] = entry
        write_json(s_path, summary)
    title = (f"clm demo: {summary.get('vehicle', '?')} at {summary.get('speed_m_per_s', '?')} m/s on "
             f"{summary.get('track', '?')} / {summary.get('soil', '?')} ({summary.get('model', '?')})")
    write_index(d, title=title)
    return entry


def main(argv: list[str] | None = None) -> int:
    """``python -m clm_core.outputs.demo_receivers OUT [--receivers 8,16,32] [--receiver-x X] [--influence 60]``."""
    ap = argparse.ArgumentParser(prog="python -m clm_core.outputs.demo_receivers",
                                 description="Free-field receivers and rail-deflection spectra of a clm demo output.")
    ap.add_argument("out", help="the demo's output directory (holds demo_bag/ and summary.json)")
    ap.add_argument("--receivers", default="8,16,32", help="distances from the track axis [m], comma-separated")
    ap.add_argument("--receiver-x", type=float, default=None, help="position along the track [m]")
    ap.add_argument("--influence", type=float, default=60.0, help="influence length along the track [m]")
    a = ap.parse_args(argv)
    try:
        dist = tuple(float(s) for s in a.receivers.split(",") if s.strip())
    except ValueError:
        print(f"--receivers {a.receivers!r}: need distances [m], comma-separated", file=sys.stderr)
        return 2
    if not (Path(a.out) / "demo_bag").is_dir():
        print(f"error: {a.out}: no demo_bag/ (the output of clm demo)", file=sys.stderr)
        return 2
    try:
        entry = demo_receivers(a.out, dist, receiver_x=a.receiver_x, influence_length=a.influence)
    except ClmError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"demo receivers: free field in {entry['free_field_s']:.1f} s (filters "
          f"{'from the cache' if entry['filters_from_cache'] else 'built'}), {entry['wall_s']:.1f} s in all")
    return 0


if __name__ == "__main__":
    sys.exit(main())
