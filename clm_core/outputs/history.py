"""Time-history files: one writer per format (NPZ, CSV, JSON), one layout per file.

:meth:`clm_core.solver.TrackSimulator.advance` hands its outputs to a
callback, one :class:`~clm_core.solver.Block` per stretch of steps with the
window in one position. Two callbacks are provided:

- :class:`HistoryRecorder` keeps the blocks in memory and returns one
  :class:`TimeHistory` (for tests, notebooks, short runs);
- :class:`HistoryWriter` streams the blocks to disk with flat memory
  (memory-mapped ``.npy`` files packed into an NPZ at the end, CSV appended
  block by block) and keeps only what the summary and the plot need.

Both keep the running peak of every sleeper the window has held, by global
sleeper index (the block before a window shift carries the final peaks of
the sleepers dropped). A coupled vehicle run
(:class:`clm_core.vehicle.coupled.CoupledResult`) is written by
:func:`write_coupled_history` with the same CSV layouts.

One writer per format: :func:`~clm_core.io.files.write_npz` (every NPZ),
:func:`append_wheel_rows`, :func:`append_sleeper_rows` and
:func:`write_peaks_csv` (every CSV), and
:func:`~clm_core.io.files.write_json` / :func:`~clm_core.io.files.dumps_json`
(every ``summary.json``, the calibration node's ``metrics_json``).

Sleeper fields of a :class:`TimeHistory` are stored window-relative: row
``r`` column ``j`` is the sleeper with global index ``first_sleeper[r] + j``
at ``x = (first_sleeper[r] + j) * spacing`` [m].

File layouts (units in the names or below; sign convention of the suite:
forces and displacements positive downwards):

``history.npz`` (moving-load run, :class:`HistoryWriter`)
    ``t`` (k,) [s]; ``first_sleeper`` (k,) int; ``soil_force`` (k, N) [N];
    ``rail_deflection``, ``sleeper_displacement``, ``area_displacement``
    (k, N) [m]; ``wheel_position`` (k, W) [m]; ``wheel_force`` (k, W) [N];
    ``wheel_deflection`` (k, W) [m]; ``wheel_velocity`` (k, W) [m/s];
    ``peak_sleeper_index`` (m,) int; ``peak_soil_force`` (m,) [N];
    ``peak_rail_deflection`` (m,) [m]; ``spacing`` [m]; ``dt`` [s].
``vehicle_history.npz`` (vehicle run, :func:`write_coupled_history`; uncompressed)
    every array of :class:`~clm_core.vehicle.coupled.CoupledResult` (``t``,
    ``wheel_position``, ``wheel_load``, ``static_wheel_load``,
    ``compression``, ``wheel_displacement``, ``rail_deflection``,
    ``irregularity``, ``vehicle_energy``, ``newton_iterations``, ``t_out``,
    ``sleeper_index``, ``sleeper_x``, ``peak_soil_force``) plus ``meta_json``;
    the sleeper fields ``soil_force`` and ``sleeper_rail_deflection`` are
    stored window-relative as in ``history.npz``: (n_o, N) with
    ``first_sleeper`` (n_o,), the global index of column 0 at each snapshot
    (the run's dense (n_o, n_s) arrays are NaN outside the engine's window:
    98 % NaN for a 20 s run; :func:`read_vehicle_history` expands them back).
``wheels.csv`` (both runs: ONE layout)
    ``t_s``, then for each wheel ``i = 0 .. W-1`` (front first) seven columns
    (:data:`WHEEL_CSV_COLUMNS`):

    ===============  ========================================================
    ``x{i}_m``       wheel position along the line
    ``P{i}_N``       wheel load: force of the wheel on the rail
    ``delta{i}_m``   Hertz compression (negative: contact lost)
    ``z{i}_m``       axle-centre displacement
    ``w{i}_m``       rail deflection under the wheel
    ``r{i}_m``       rail irregularity under the wheel
    ``v{i}_m_per_s`` rail velocity under the wheel
    ===============  ========================================================

    ``nan`` where the run does not compute the quantity (a moving-load run has
    no contact spring, axle or irregularity: ``delta``, ``z``, ``r``; a
    vehicle run does not record ``v``) or the wheel is not on the track.
    :func:`read_wheels_csv` reads this layout and the two earlier ones
    (moving-load ``x{i}_m, F{i}_N, w{i}_m, v{i}_m_per_s`` with ``i`` from 1;
    vehicle ``x{i}_m, P{i}_N, delta{i}_m, z{i}_m, w{i}_m, r{i}_m``).
The CSV files are written on request (``clm simulate --csv``): the NPZ files
hold the same numbers in a tenth of the space and time.

``sleepers.csv`` (both runs)
    long format, one row per output instant and sleeper in the window:
    ``t_s, sleeper_index, x_m, soil_force_N, rail_deflection_m,
    sleeper_displacement_m, area_displacement_m`` (:data:`SLEEPER_CSV_COLUMNS`;
    a vehicle run records the first two fields only: ``nan`` in the others).
``peaks.csv`` (both runs)
    ``sleeper_index, x_m, peak_soil_force_N, peak_rail_deflection_m``: running
    maxima over every step (``nan``: not recorded, the vehicle run's rail).
``summary.json`` (every command)
    strict JSON by :func:`~clm_core.io.files.write_json`: numpy values as plain numbers,
    non-finite numbers as ``null``.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np
from numpy.lib.format import open_memmap
from numpy.typing import ArrayLike

from clm_core.arrays import Array, IntArray
from clm_core.checks import integer
from clm_core.errors import InputError
from clm_core.io.files import dumps_json, write_npz

if TYPE_CHECKING:
    from clm_core.solver import Block
    from clm_core.vehicle.coupled import CoupledResult


#: Sleeper fields of a history, in the order of ``sleepers.csv``.
SLEEPER_FIELDS = ("soil_force", "rail_deflection", "sleeper_displacement", "area_displacement")
#: History wheel field -> :class:`~clm_core.solver.Block` attribute.
WHEEL_FIELDS = (("wheel_position", "wheel_positions"), ("wheel_force", "wheel_forces"),
                ("wheel_deflection", "wheel_deflection"), ("wheel_velocity", "wheel_velocity"))
#: Columns of ``sleepers.csv``.
SLEEPER_CSV_COLUMNS = ("t_s", "sleeper_index", "x_m", "soil_force_N", "rail_deflection_m",
                       "sleeper_displacement_m", "area_displacement_m")
_SLEEPER_FMT = ["%.7f", "%d", "%.4f", "%.6e", "%.6e", "%.6e", "%.6e"]
#: Per-wheel columns of ``wheels.csv``: (symbol, unit, quantity), in file order.
WHEEL_CSV_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("x", "m", "wheel position"),
    ("P", "N", "wheel load (force on the rail)"),
    ("delta", "m", "Hertz compression"),
    ("z", "m", "axle-centre displacement"),
    ("w", "m", "rail deflection under the wheel"),
    ("r", "m", "rail irregularity under the wheel"),
    ("v", "m_per_s", "rail velocity under the wheel"),
)
_WHEEL_SYMBOLS = tuple(s for s, _, _ in WHEEL_CSV_COLUMNS)
#: Columns of ``peaks.csv``.
PEAKS_CSV_COLUMNS = ("sleeper_index", "x_m", "peak_soil_force_N", "peak_rail_deflection_m")


# ----------------------------------------------------------------------------- CSV


def wheels_csv_header(n_wheels: int) -> str:
    """Header line of ``wheels.csv`` for ``n_wheels`` wheels (module docstring), without newline."""
    n_wheels = integer("n_wheels", n_wheels, 0)
    return ",".join(["t_s"] + [f"{s}{i}_{u}" for i in range(n_wheels) for s, u, _ in WHEEL_CSV_COLUMNS])


def append_wheel_rows(fh: IO[str], t: ArrayLike, n_wheels: int, columns: Mapping[str, ArrayLike]) -> None:
    """Append rows to an open ``wheels.csv``.

    Parameters
    ----------
    fh : text file
        Open for writing, after :func:`wheels_csv_header`.
    t : (k,) array
        Times [s].
    n_wheels : int
        W, as in the header.
    columns : mapping symbol -> (k, W) array
        Values by the symbols of :data:`WHEEL_CSV_COLUMNS` (``x``, ``P``,
        ``delta``, ``z``, ``w``, ``r``, ``v``), SI units; a symbol left out is
        written ``nan`` (the run does not compute it).
    """
    tt = np.asarray(t, dtype=np.float64).reshape(-1)
    k, W = tt.size, int(n_wheels)
    unknown = sorted(set(columns) - set(_WHEEL_SYMBOLS))
    if unknown:
        raise InputError(f"wheels.csv: unknown column symbol(s) {unknown}; known {list(_WHEEL_SYMBOLS)}")
    block = np.full((k, W, len(_WHEEL_SYMBOLS)), np.nan)
    for j, s in enumerate(_WHEEL_SYMBOLS):
        if s in columns:
            v = np.asarray(columns[s], dtype=np.float64)
            if v.shape != (k, W):
                raise InputError(f"wheels.csv: column {s!r} has shape {v.shape}; expected {(k, W)}")
            block[:, :, j] = v
    np.savetxt(fh, np.column_stack([tt, block.reshape(k, W * len(_WHEEL_SYMBOLS))]), delimiter=",", fmt="%.9g")


def append_sleeper_rows(
    fh: IO[str], t: ArrayLike, sleeper_index: ArrayLike, x: ArrayLike, fields: Mapping[str, ArrayLike]
) -> None:
    """Append long-format rows to an open ``sleepers.csv`` (header :data:`SLEEPER_CSV_COLUMNS`).

    Parameters
    ----------
    fh : text file
        Open for writing, after the header line.
    t, sleeper_index, x : (n,) arrays
        Time [s], global sleeper index, sleeper position [m] of each row.
    fields : mapping name -> (n,) array
        Values by the names of :data:`SLEEPER_FIELDS` [N], [m]; a field left
        out is written ``nan``.
    """
    tt = np.asarray(t, dtype=np.float64).reshape(-1)
    unknown = sorted(set(fields) - set(SLEEPER_FIELDS))
    if unknown:
        raise InputError(f"sleepers.csv: unknown field(s) {unknown}; known {list(SLEEPER_FIELDS)}")
    cols = [tt, np.asarray(sleeper_index).reshape(-1), np.asarray(x, dtype=np.float64).reshape(-1)]
    cols += [np.asarray(fields[f], dtype=np.float64).reshape(-1) if f in fields else np.full(tt.size, np.nan)
             for f in SLEEPER_FIELDS]
    if any(c.size != tt.size for c in cols):
        raise InputError(f"sleepers.csv: columns of sizes {[c.size for c in cols]}; expected {tt.size} each")
    np.savetxt(fh, np.column_stack(cols), delimiter=",", fmt=_SLEEPER_FMT)


def write_peaks_csv(
    path: str | Path, sleeper_index: ArrayLike, x: ArrayLike, peak_soil_force: ArrayLike,
    peak_rail_deflection: ArrayLike | None = None,
) -> Path:
    """Write ``peaks.csv`` (:data:`PEAKS_CSV_COLUMNS`; ``nan`` rail peaks when not given); return the path."""
    idx = np.asarray(sleeper_index).reshape(-1)
    pr = np.full(idx.size, np.nan) if peak_rail_deflection is None else np.asarray(peak_rail_deflection)
    p = Path(path)
    np.savetxt(p, np.column_stack([idx, np.asarray(x, dtype=np.float64).reshape(-1),
                                   np.asarray(peak_soil_force, dtype=np.float64).reshape(-1), pr.reshape(-1)]),
               delimiter=",", header=",".join(PEAKS_CSV_COLUMNS), comments="", fmt=["%d", "%.4f", "%.6e", "%.6e"])
    return p


@dataclass(frozen=True)
class WheelTable:
    """Contents of a ``wheels.csv``.

    Attributes
    ----------
    t : (k,) array
        Times [s].
    columns : dict symbol -> (k, W) array
        Every symbol of :data:`WHEEL_CSV_COLUMNS` [SI]; all ``nan`` when the
        file does not hold the quantity. Wheel ``i`` is column ``i`` (front first).
    """

    t: Array
    columns: dict[str, Array]

    @property
    def n_wheels(self) -> int:
        """Number of wheels W."""
        return int(self.columns["x"].shape[1])

    def __getitem__(self, symbol: str) -> Array:
        """The (k, W) array of one symbol (``x``, ``P``, ``delta``, ``z``, ``w``, ``r``, ``v``)."""
        return self.columns[symbol]


_WHEEL_HEAD = re.compile(r"^(x|P|F|delta|z|w|r|v)(\d+)_(m|N|m_per_s)$")


def read_wheels_csv(path: str | Path) -> WheelTable:
    """Read a ``wheels.csv``: the current layout and the two earlier ones (module docstring).

    Raises
    ------
    InputError
        The file cannot be read, the header is not a ``wheels.csv`` header
        (names the first bad column), or a row is not numbers.
    """
    p = Path(path)
    try:
        with p.open(encoding="utf-8") as fh:
            head = fh.readline().strip().split(",")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read the wheels.csv ({exc})") from None
    if not head or head[0] != "t_s":
        raise InputError(f"{p}: not a wheels.csv (first column {head[0] if head else ''!r}, expected 't_s')")
    parsed: list[tuple[str, int]] = []
    for name in head[1:]:
        m = _WHEEL_HEAD.match(name)
        if m is None:
            raise InputError(f"{p}: column {name!r} is not a wheels.csv column ({{x,P,delta,z,w,r,v}}{{i}}_unit)")
        parsed.append((m.group(1), int(m.group(2))))
    legacy_moving = any(s == "F" for s, _ in parsed)  # x{i}_m, F{i}_N, w{i}_m, v{i}_m_per_s with i from 1
    base = 1 if legacy_moving else 0
    parsed = [("P" if s == "F" else s, i - base) for s, i in parsed]
    W = max((i for _, i in parsed), default=-1) + 1
    with p.open(encoding="utf-8") as fh:
        lines = [ln for ln in fh.read().splitlines()[1:] if ln.strip()]
    try:
        data = np.loadtxt(lines, delimiter=",", ndmin=2) if lines else np.zeros((0, len(head)))
    except ValueError as exc:
        raise InputError(f"{p}: a row of the wheels.csv is not {len(head)} numbers ({exc})") from None
    k = data.shape[0]
    cols = {s: np.full((k, W), np.nan) for s in _WHEEL_SYMBOLS}
    for c, (s, i) in enumerate(parsed, start=1):
        cols[s][:, i] = data[:, c]
    return WheelTable(t=data[:, 0].copy(), columns=cols)


# ----------------------------------------------------------------------------- moving-load histories


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
            fs.write(",".join(SLEEPER_CSV_COLUMNS) + "\n")
            fw.write(wheels_csv_header(W) + "\n")
            for r0 in range(0, rows, chunk):
                r1 = min(rows, r0 + chunk)
                t = np.asarray(m["t"][r0:r1])
                g = (np.asarray(m["first_sleeper"][r0:r1])[:, None] + np.arange(N)[None, :]).ravel()
                append_sleeper_rows(fs, np.repeat(t, N), g, g * self.spacing,
                                    {f: np.asarray(m[f][r0:r1]).ravel() for f in SLEEPER_FIELDS})
                append_wheel_rows(fw, t, W, {"x": m["wheel_position"][r0:r1], "P": m["wheel_force"][r0:r1],
                                             "w": m["wheel_deflection"][r0:r1], "v": m["wheel_velocity"][r0:r1]})

    def close(self, extra: dict[str, Any] | None = None, on_file: Callable[[Path], None] | None = None) -> RunDigest:
        """Flush: pack ``history.npz`` (streamed from the memory maps), ``peaks.csv``; return the digest.

        ``on_file`` is called with each file once written (progress of the writing phase).
        """
        idx, pf, pr = self._peaks.arrays()
        r = self.rows
        tell = on_file or (lambda _p: None)
        if self.csv:
            self._write_csv(r)
            tell(self.dir / "sleepers.csv")
        items: list[tuple[str, Any]] = [(name, mm[:r]) for name, mm in self._maps.items()]
        items += [("peak_sleeper_index", idx), ("peak_soil_force", pf), ("peak_rail_deflection", pr),
                  ("spacing", np.array(self.spacing)), ("dt", np.array(self.dt))]
        items += [(k, np.asarray(v)) for k, v in (extra or {}).items()]
        write_npz(self.dir / "history.npz", items)
        tell(self.dir / "history.npz")
        del items
        for name in list(self._maps):
            mm = self._maps.pop(name)
            del mm
            os.remove(self._tmp / f"{name}.npy")
        os.rmdir(self._tmp)
        tell(write_peaks_csv(self.dir / "peaks.csv", idx, idx * self.spacing, pf, pr))
        t_max, px, prl, pw = self._profile
        return RunDigest(n_rows=r, peak_sleeper_index=idx, peak_soil_force=pf, peak_rail_deflection=pr,
                         max_wheel_deflection=self._max_wheel, t_max=t_max, profile_x=px, profile_rail=prl,
                         profile_wheels=pw)


def _open_npz(path: str | Path, what: str) -> np.lib.npyio.NpzFile:
    """``path`` opened as an ``.npz`` archive of plain arrays (no pickles), or an InputError naming ``what``."""
    try:
        z = np.load(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read a {what} ({exc})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise InputError(f"{path}: not a {what} (a single .npy array, not an .npz archive)")
    return z


def load_history(path: str | Path) -> TimeHistory:
    """Read a ``history.npz`` written by :class:`HistoryWriter`.

    Raises
    ------
    InputError
        The file cannot be read, is not an ``.npz`` archive of plain arrays,
        or lacks an array of the history.
    """
    z = _open_npz(path, "history.npz")
    names = [f.name for f in dataclasses.fields(TimeHistory)]  # a history.npz holds one array per field
    with z:
        missing = [k for k in names if k not in z.files]
        if missing:
            raise InputError(f"{path}: not a history.npz: no array {', '.join(missing)}")
        arrays: dict[str, Any] = {k: z[k] for k in names}
    arrays["spacing"] = float(arrays["spacing"])
    return TimeHistory(**arrays)


# ----------------------------------------------------------------------------- vehicle runs


def window_columns(dense: ArrayLike) -> tuple[IntArray, Array]:
    """Window-relative form of a dense (n_o, n_s) sleeper field that is NaN outside a window.

    Returns ``(first, compact)``: ``first[k]`` the column of the first finite value of row k (0 if none),
    ``compact[k, j] == dense[k, first[k] + j]`` (NaN beyond n_s), N the widest span of finite values.
    """
    a = np.asarray(dense, dtype=np.float64)
    if a.ndim != 2:
        raise InputError(f"window_columns: a (n_o, n_s) array expected, got shape {a.shape}")
    fin = np.isfinite(a)
    have = fin.any(axis=1)
    first = np.where(have, np.argmax(fin, axis=1), 0).astype(np.int64)
    last = np.where(have, a.shape[1] - 1 - np.argmax(fin[:, ::-1], axis=1), -1)
    width = int(max(1, int(np.max(last - first + 1, initial=1))))
    cols = first[:, None] + np.arange(width)[None, :]
    out = np.take_along_axis(a, np.minimum(cols, a.shape[1] - 1), axis=1)
    out[cols >= a.shape[1]] = np.nan
    return first, out


def read_vehicle_history(path: str | Path, dense: bool = True) -> dict[str, Any]:
    """Read a ``vehicle_history.npz``: every array by name, ``meta`` (dict) from ``meta_json``.

    ``dense``: the sleeper fields expanded to (n_o, n_s) over ``sleeper_index`` (NaN outside the window,
    as in :class:`~clm_core.vehicle.coupled.CoupledResult`); otherwise window-relative with ``first_sleeper``.

    Raises :class:`InputError` for a file that is not readable or not of this layout.
    """
    import json

    with _open_npz(path, "vehicle_history.npz") as z:
        missing = [k for k in ("wheel_load", "first_sleeper", "soil_force", "sleeper_index") if k not in z.files]
        if missing:
            raise InputError(f"{path}: not a vehicle_history.npz of this layout: no array {', '.join(missing)}")
        h: dict[str, Any] = {k: z[k] for k in z.files}
    h["meta"] = json.loads(str(h.pop("meta_json"))) if "meta_json" in h else {}
    if dense:
        n_s, k = h["sleeper_index"].size, h["t_out"].size
        lo = int(h["sleeper_index"][0]) if n_s else 0
        for name in ("soil_force", "sleeper_rail_deflection"):
            c = h[name]
            full = np.full((k, n_s), np.nan)
            cols = h["first_sleeper"][:, None] - lo + np.arange(c.shape[1])[None, :]
            ok = (cols >= 0) & (cols < n_s)
            rows = np.broadcast_to(np.arange(k)[:, None], cols.shape)
            full[rows[ok], cols[ok]] = c[ok]
            h[name] = full
    return h


def write_coupled_history(res: CoupledResult, out: str | Path, csv_files: bool = True,
                          on_file: Callable[[Path], None] | None = None,
                          window: tuple[IntArray, Array] | None = None) -> list[Path]:
    """Write a coupled vehicle run: ``vehicle_history.npz``, ``peaks.csv`` and, with ``csv_files``, the other CSVs.

    Parameters
    ----------
    res : CoupledResult
        The run (:meth:`clm_core.vehicle.coupled.CoupledSimulation.run`).
    out : path
        Output directory (must exist).
    csv_files : bool
        Also write ``wheels.csv`` (every ``meta['snapshot_every']``-th step) and
        ``sleepers.csv`` (the window's sleepers at each snapshot) (module docstring).
    on_file : callable, optional
        Called with each file once written (progress of the writing phase).
    window : (first, compact), optional - :func:`window_columns` of ``res.soil_force`` if the caller has it.

    Returns the files written (list of Path).
    """
    d = Path(out)
    tell = on_file or (lambda _p: None)
    first_col, sf = window if window is not None else window_columns(res.soil_force)
    lo = int(res.sleeper_index[0]) if res.sleeper_index.size else 0
    cols = np.minimum(first_col[:, None] + np.arange(sf.shape[1])[None, :], max(res.sleeper_index.size - 1, 0))
    rd = np.take_along_axis(np.asarray(res.sleeper_rail_deflection, dtype=np.float64), cols, axis=1)
    rd[np.isnan(sf)] = np.nan
    written = [write_npz(
        d / "vehicle_history.npz",
        {"t": res.t, "wheel_position": res.wheel_position, "wheel_load": res.wheel_load,
         "static_wheel_load": res.static_wheel_load, "compression": res.compression,
         "wheel_displacement": res.wheel_displacement, "rail_deflection": res.rail_deflection,
         "irregularity": res.irregularity, "vehicle_energy": res.vehicle_energy,
         "newton_iterations": res.newton_iterations, "t_out": res.t_out, "sleeper_index": res.sleeper_index,
         "sleeper_x": res.sleeper_x, "first_sleeper": first_col + lo, "soil_force": sf,
         "sleeper_rail_deflection": rd, "peak_soil_force": res.peak_soil_force,
         "meta_json": np.array(dumps_json(res.meta, indent=None))},
    )]
    tell(written[0])
    ok = np.nonzero(np.isfinite(res.peak_soil_force))[0]
    written.append(write_peaks_csv(d / "peaks.csv", res.sleeper_index[ok], res.sleeper_x[ok], res.peak_soil_force[ok]))
    tell(written[-1])
    if not csv_files:
        return written
    rows = np.arange(0, res.t.size, int(res.meta.get("snapshot_every", 1)))
    nw = res.wheel_load.shape[1]
    with (d / "wheels.csv").open("w", encoding="utf-8") as fh:
        fh.write(wheels_csv_header(nw) + "\n")
        append_wheel_rows(fh, res.t[rows], nw, {
            "x": res.wheel_position[rows], "P": res.wheel_load[rows], "delta": res.compression[rows],
            "z": res.wheel_displacement[rows], "w": res.rail_deflection[rows], "r": res.irregularity[rows],
        })
    tell(d / "wheels.csv")
    kk, jj = np.nonzero(np.isfinite(sf))
    g = first_col[kk] + jj
    with (d / "sleepers.csv").open("w", encoding="utf-8") as fh:
        fh.write(",".join(SLEEPER_CSV_COLUMNS) + "\n")
        append_sleeper_rows(fh, res.t_out[kk], res.sleeper_index[g], res.sleeper_x[g],
                            {"soil_force": sf[kk, jj], "rail_deflection": rd[kk, jj]})
    tell(d / "sleepers.csv")
    return [*written, d / "wheels.csv", d / "sleepers.csv"]
