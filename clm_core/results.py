"""Time histories of the streaming simulator: recorders and writers (NPZ, CSV, PNG).

:meth:`clm_core.stepper.TrackSimulator.advance` hands its outputs to a
callback, one :class:`~clm_core.stepper.Block` per stretch of steps with the
window in one position. Two callbacks are provided:

- :class:`HistoryRecorder` keeps the blocks in memory and returns one
  :class:`TimeHistory` (for tests, notebooks, short runs);
- :class:`HistoryWriter` streams the blocks to disk with flat memory
  (memory-mapped ``.npy`` files packed into an NPZ at the end, CSV appended
  block by block) and keeps only what the summary and the plot need.

Both keep the running peak of every sleeper the window has held, by global
sleeper index (the block before a window shift carries the final peaks of
the sleepers dropped).

Sleeper fields are stored window-relative: row ``r`` column ``j`` is the
sleeper with global index ``first_sleeper[r] + j`` at ``x = (first_sleeper[r]
+ j) * spacing`` [m].

Files written by :class:`HistoryWriter` (units in the names or below):

``history.npz``
    ``t`` (k,) [s]; ``first_sleeper`` (k,) int; ``soil_force`` (k, N) [N];
    ``rail_deflection``, ``sleeper_displacement``, ``area_displacement``
    (k, N) [m]; ``wheel_position`` (k, W) [m]; ``wheel_force`` (k, W) [N];
    ``wheel_deflection`` (k, W) [m]; ``wheel_velocity`` (k, W) [m/s];
    ``peak_sleeper_index`` (m,) int; ``peak_soil_force`` (m,) [N];
    ``peak_rail_deflection`` (m,) [m]; ``spacing`` [m]; ``dt`` [s].
``sleepers.csv``
    long format, one row per output instant and window sleeper:
    ``t_s, sleeper_index, x_m, soil_force_N, rail_deflection_m,
    sleeper_displacement_m, area_displacement_m``.
``wheels.csv``
    ``t_s`` then per wheel ``x{i}_m, F{i}_N, w{i}_m, v{i}_m_per_s``.
``peaks.csv``
    ``sleeper_index, x_m, peak_soil_force_N, peak_rail_deflection_m``.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.lib.format import open_memmap, write_array
from numpy.typing import NDArray

from clm_core.errors import InputError
from clm_core.stepper import Block

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

SLEEPER_FIELDS = ("soil_force", "rail_deflection", "sleeper_displacement", "area_displacement")
WHEEL_FIELDS = (("wheel_position", "wheel_positions"), ("wheel_force", "wheel_forces"),
                ("wheel_deflection", "wheel_deflection"), ("wheel_velocity", "wheel_velocity"))


@dataclass(frozen=True)
class TimeHistory:
    """Recorded outputs of a run (see the module docstring for the layout).

    Attributes
    ----------
    t : (k,) array
        Output times [s].
    first_sleeper : (k,) int array
        Global index of column 0 of the sleeper fields at each output time.
    spacing : float
        Sleeper spacing [m].
    soil_force : (k, N) array
        Soil reaction force under each window sleeper [N].
    rail_deflection, sleeper_displacement, area_displacement : (k, N) arrays
        [m].
    wheel_position, wheel_force, wheel_deflection, wheel_velocity : (k, W) arrays
        [m], [N], [m], [m/s] (NaN for absent wheels).
    peak_sleeper_index : (m,) int array
        Every global sleeper the window has held, ascending.
    peak_soil_force, peak_rail_deflection : (m,) arrays
        Running maxima over every step [N], [m].
    """

    t: Array
    first_sleeper: IntArray
    spacing: float
    soil_force: Array
    rail_deflection: Array
    sleeper_displacement: Array
    area_displacement: Array
    wheel_position: Array
    wheel_force: Array
    wheel_deflection: Array
    wheel_velocity: Array
    peak_sleeper_index: IntArray
    peak_soil_force: Array
    peak_rail_deflection: Array

    def sleeper_series(self, global_index: int, field: str = "soil_force") -> Array:
        """Time series of one sleeper field for a global sleeper (NaN while outside the window)."""
        data = getattr(self, field)
        col = global_index - self.first_sleeper
        ok = (col >= 0) & (col < data.shape[1])
        out = np.full(self.t.shape, np.nan)
        out[ok] = data[np.nonzero(ok)[0], col[ok]]
        return out


class _Peaks:
    """Running peaks by global sleeper index (grows with the sleepers visited)."""

    def __init__(self) -> None:
        self.force: dict[int, float] = {}
        self.rail: dict[int, float] = {}

    def update(self, b: Block) -> None:
        for j, g in enumerate(range(b.first_sleeper, b.first_sleeper + len(b.sleeper_x))):
            f, r = float(b.peak_soil_force[j]), float(b.peak_rail_deflection[j])
            if f > self.force.get(g, -np.inf):
                self.force[g] = f
            if r > self.rail.get(g, -np.inf):
                self.rail[g] = r

    def arrays(self) -> tuple[IntArray, Array, Array]:
        idx = np.array(sorted(self.force), dtype=np.int64)
        return (idx, np.array([self.force[int(g)] for g in idx]), np.array([self.rail[int(g)] for g in idx]))


class HistoryRecorder:
    """In-memory callback for :meth:`TrackSimulator.advance`; see :meth:`history`."""

    def __init__(self, spacing: float) -> None:
        self.spacing = float(spacing)
        self.blocks: list[Block] = []
        self._peaks = _Peaks()
        self.max_wheel_deflection = -np.inf

    def __call__(self, block: Block) -> None:
        """Keep one block."""
        self._peaks.update(block)
        if block.peak_wheel_deflection.size:
            self.max_wheel_deflection = max(self.max_wheel_deflection, float(np.max(block.peak_wheel_deflection)))
        if block.t.size:
            self.blocks.append(block)

    def history(self) -> TimeHistory:
        """All recorded blocks as one :class:`TimeHistory` (wheel arrays padded with NaN)."""
        bl = self.blocks
        W = max((b.wheel_positions.shape[1] for b in bl), default=0)
        N = max((len(b.sleeper_x) for b in bl), default=0)

        def wheels(name: str) -> Array:
            rows = [np.pad(getattr(b, name), ((0, 0), (0, W - getattr(b, name).shape[1])), constant_values=np.nan)
                    for b in bl]
            return np.concatenate(rows) if rows else np.zeros((0, W))

        def sleepers(name: str) -> Array:
            rows = [getattr(b, name) for b in bl]
            return np.concatenate(rows) if rows else np.zeros((0, N))

        idx, pf, pr = self._peaks.arrays()
        return TimeHistory(
            t=np.concatenate([b.t for b in bl]) if bl else np.zeros(0),
            first_sleeper=np.concatenate([np.full(b.t.size, b.first_sleeper, dtype=np.int64) for b in bl])
            if bl else np.zeros(0, dtype=np.int64),
            spacing=self.spacing,
            soil_force=sleepers("soil_force"), rail_deflection=sleepers("rail_deflection"),
            sleeper_displacement=sleepers("sleeper_displacement"),
            area_displacement=sleepers("area_displacement"),
            wheel_position=wheels("wheel_positions"), wheel_force=wheels("wheel_forces"),
            wheel_deflection=wheels("wheel_deflection"), wheel_velocity=wheels("wheel_velocity"),
            peak_sleeper_index=idx, peak_soil_force=pf, peak_rail_deflection=pr,
        )


@dataclass(frozen=True)
class RunDigest:
    """What a summary and a plot need from a streamed run (small, fixed size).

    Attributes
    ----------
    n_rows : int
        Output instants written.
    peak_sleeper_index : (m,) int array
        Global sleepers the window held.
    peak_soil_force, peak_rail_deflection : (m,) arrays
        Their running maxima over every step [N], [m].
    max_wheel_deflection : float
        Largest rail deflection under any wheel over every step [m].
    t_max : float
        Time of the output instant with the largest rail deflection above a sleeper [s].
    profile_x, profile_rail : (N,) arrays
        Rail deflection above the window sleepers at ``t_max`` [m] and their positions [m].
    profile_wheels : (W,) array
        Wheel positions at ``t_max`` [m].
    """

    n_rows: int
    peak_sleeper_index: IntArray
    peak_soil_force: Array
    peak_rail_deflection: Array
    max_wheel_deflection: float
    t_max: float
    profile_x: Array
    profile_rail: Array
    profile_wheels: Array


class HistoryWriter:
    """Callback that streams a run's outputs to a directory with flat memory.

    Parameters
    ----------
    directory : path
        Output directory (created).
    max_rows : int
        Upper bound on the number of output instants (sizes the memory maps).
    n_sleepers, n_wheels : int
        Window size and number of wheels.
    spacing, dt : float
        Sleeper spacing [m] and time step [s] (stored in the NPZ).
    csv : bool
        Also write ``sleepers.csv`` and ``wheels.csv``.
    """

    def __init__(self, directory: str | Path, max_rows: int, n_sleepers: int, n_wheels: int,
                 spacing: float, dt: float, csv: bool = True) -> None:
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.N, self.W = int(n_sleepers), int(n_wheels)
        self.spacing, self.dt = float(spacing), float(dt)
        self.max_rows = int(max_rows)
        self._tmp = self.dir / ".history_tmp"
        self._tmp.mkdir(exist_ok=True)
        self._maps: dict[str, np.memmap[Any, Any]] = {}
        shapes: dict[str, tuple[int, ...]] = {"t": (self.max_rows,), "first_sleeper": (self.max_rows,)}
        shapes.update({f: (self.max_rows, self.N) for f in SLEEPER_FIELDS})
        shapes.update({f: (self.max_rows, self.W) for f, _ in WHEEL_FIELDS})
        for name, shape in shapes.items():
            dtype = np.int64 if name == "first_sleeper" else np.float64
            self._maps[name] = open_memmap(self._tmp / f"{name}.npy", mode="w+", dtype=dtype, shape=shape)
        self.rows = 0
        self._peaks = _Peaks()
        self._max_rail = -np.inf
        self._max_wheel = -np.inf
        self._profile: tuple[float, Array, Array, Array] = (0.0, np.zeros(self.N), np.zeros(self.N), np.zeros(self.W))
        self.csv = bool(csv)

    def __call__(self, b: Block) -> None:
        """Write one block."""
        self._peaks.update(b)
        if b.peak_wheel_deflection.size:
            self._max_wheel = max(self._max_wheel, float(np.max(b.peak_wheel_deflection)))
        k = b.t.size
        if k == 0:
            return
        if self.rows + k > self.max_rows:
            raise InputError(f"history writer: {self.rows + k} output rows exceed the {self.max_rows} planned")
        if len(b.sleeper_x) != self.N or b.wheel_positions.shape[1] > self.W:
            raise InputError(
                f"history writer: block with {len(b.sleeper_x)} sleepers and {b.wheel_positions.shape[1]} "
                f"wheels; planned {self.N} and {self.W}"
            )
        r0, r1 = self.rows, self.rows + k
        m = self._maps
        m["t"][r0:r1] = b.t
        m["first_sleeper"][r0:r1] = b.first_sleeper
        for f in SLEEPER_FIELDS:
            m[f][r0:r1] = getattr(b, f)
        for f, bf in WHEEL_FIELDS:
            a = getattr(b, bf)
            m[f][r0:r1, : a.shape[1]] = a
            m[f][r0:r1, a.shape[1]:] = np.nan
        self.rows = r1
        # moment of the largest rail deflection above a sleeper (for the plot)
        i = int(np.argmax(np.max(b.rail_deflection, axis=1)))
        if b.rail_deflection[i].max() > self._max_rail:
            self._max_rail = float(b.rail_deflection[i].max())
            wp = np.full(self.W, np.nan)
            wp[: b.wheel_positions.shape[1]] = b.wheel_positions[i]
            self._profile = (float(b.t[i]), b.sleeper_x.copy(), b.rail_deflection[i].copy(), wp)

    def _write_csv(self, rows: int, chunk: int = 1000) -> None:
        """sleepers.csv and wheels.csv from the memory maps, ``chunk`` rows at a time."""
        m, N, W = self._maps, self.N, self.W
        with open(self.dir / "sleepers.csv", "w", encoding="utf-8") as fs, \
                open(self.dir / "wheels.csv", "w", encoding="utf-8") as fw:
            fs.write("t_s,sleeper_index,x_m,soil_force_N,rail_deflection_m,"
                     "sleeper_displacement_m,area_displacement_m\n")
            fw.write(",".join(["t_s"] + [f"{c}{i + 1}_{u}" for i in range(W)
                                         for c, u in (("x", "m"), ("F", "N"), ("w", "m"), ("v", "m_per_s"))]) + "\n")
            for r0 in range(0, rows, chunk):
                r1 = min(rows, r0 + chunk)
                k = r1 - r0
                t = np.asarray(m["t"][r0:r1])
                g = (np.asarray(m["first_sleeper"][r0:r1])[:, None] + np.arange(N)[None, :]).ravel()
                block = np.column_stack([np.repeat(t, N), g, g * self.spacing]
                                        + [np.asarray(m[f][r0:r1]).ravel() for f in SLEEPER_FIELDS])
                np.savetxt(fs, block, delimiter=",", fmt=["%.7f", "%d", "%.4f", "%.6e", "%.6e", "%.6e", "%.6e"])
                wcols = np.stack([np.asarray(m[f][r0:r1]) for f, _ in WHEEL_FIELDS], axis=2).reshape(k, 4 * W)
                np.savetxt(fw, np.column_stack([t, wcols]), delimiter=",", fmt="%.9g")

    def close(self, extra: dict[str, Any] | None = None) -> RunDigest:
        """Flush: pack ``history.npz`` (streamed from the memory maps), ``peaks.csv``; return the digest."""
        idx, pf, pr = self._peaks.arrays()
        r = self.rows
        if self.csv:
            self._write_csv(r)
        with zipfile.ZipFile(self.dir / "history.npz", "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
            def put(name: str, arr: Any) -> None:
                with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                    write_array(fh, np.asanyarray(arr), allow_pickle=False)

            for name, mm in self._maps.items():
                put(name, mm[:r])
            put("peak_sleeper_index", idx)
            put("peak_soil_force", pf)
            put("peak_rail_deflection", pr)
            put("spacing", np.array(self.spacing))
            put("dt", np.array(self.dt))
            for k, v in (extra or {}).items():
                put(k, np.asarray(v))
        for name in list(self._maps):
            mm = self._maps.pop(name)
            del mm
            os.remove(self._tmp / f"{name}.npy")
        os.rmdir(self._tmp)
        np.savetxt(self.dir / "peaks.csv", np.column_stack([idx, idx * self.spacing, pf, pr]), delimiter=",",
                   header="sleeper_index,x_m,peak_soil_force_N,peak_rail_deflection_m", comments="",
                   fmt=["%d", "%.4f", "%.6e", "%.6e"])
        t_max, px, prl, pw = self._profile
        return RunDigest(n_rows=r, peak_sleeper_index=idx, peak_soil_force=pf, peak_rail_deflection=pr,
                         max_wheel_deflection=self._max_wheel, t_max=t_max, profile_x=px, profile_rail=prl,
                         profile_wheels=pw)


def load_history(path: str | Path) -> TimeHistory:
    """Read a ``history.npz`` written by :class:`HistoryWriter`."""
    with np.load(path) as z:
        return TimeHistory(
            t=z["t"], first_sleeper=z["first_sleeper"], spacing=float(z["spacing"]),
            soil_force=z["soil_force"], rail_deflection=z["rail_deflection"],
            sleeper_displacement=z["sleeper_displacement"], area_displacement=z["area_displacement"],
            wheel_position=z["wheel_position"], wheel_force=z["wheel_force"],
            wheel_deflection=z["wheel_deflection"], wheel_velocity=z["wheel_velocity"],
            peak_sleeper_index=z["peak_sleeper_index"], peak_soil_force=z["peak_soil_force"],
            peak_rail_deflection=z["peak_rail_deflection"],
        )


def plot_run(
    history_npz: str | Path, digest: RunDigest, sleepers: list[int], path: str | Path, title: str = ""
) -> None:
    """Sleeper soil forces over time for a few sleepers, and the rail deflection along the track at its maximum.

    Parameters
    ----------
    history_npz : path
        The run's ``history.npz``.
    digest : RunDigest
        From :meth:`HistoryWriter.close`.
    sleepers : list of int
        Global indices of the sleepers to plot.
    path : path
        PNG file.
    """
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 7))
    with np.load(history_npz, mmap_mode="r") as z:
        t = z["t"]
        first = z["first_sleeper"]
        sf = z["soil_force"]
        spacing = float(z["spacing"])
        for g in sleepers:
            col = g - first
            ok = np.nonzero((col >= 0) & (col < sf.shape[1]))[0]
            if ok.size:
                ax1.plot(t[ok], sf[ok, col[ok]] / 1e3, label=f"sleeper {g} (x = {g * spacing:.1f} m)")
    ax1.set_xlabel("time [s]")
    ax1.set_ylabel("soil force under sleeper [kN]")
    ax1.grid(True, alpha=0.3)
    if sleepers:
        ax1.legend(fontsize=8)
    ax2.plot(digest.profile_x, digest.profile_rail * 1e3, "o-", ms=3, label="rail above sleepers")
    for i, xw in enumerate(digest.profile_wheels[np.isfinite(digest.profile_wheels)]):
        ax2.axvline(xw, color="C3", lw=0.8, ls="--", label="wheels" if i == 0 else None)
    ax2.invert_yaxis()
    ax2.set_xlabel("position along the line [m]")
    ax2.set_ylabel("rail deflection [mm] (down)")
    ax2.set_title(f"at t = {digest.t_max:.4f} s (largest rail deflection)", fontsize=9)
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize=8)
    ax1.set_title(title or "Moving wheel loads")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
