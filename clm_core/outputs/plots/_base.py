"""Figure plumbing of :mod:`clm_core.outputs.plots`: Agg figures without pyplot, the house style, legend placement.

Every figure is made by :func:`new_figure` inside :func:`style` and written
by :func:`save`, which lays it out, moves any legend that would hide a curve
or a peak label (:func:`_place_legends`), tells :data:`figure_observers` and
writes the PNG.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Literal, cast
from weakref import WeakKeyDictionary

import matplotlib as mpl
import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from matplotlib.transforms import Bbox
from numpy.typing import NDArray

from clm_core.arrays import Array, CArray

#: Called with every figure and its file just before the file is written
#: (after the layout): the test suite checks every figure it renders this way.
figure_observers: list[Callable[[Figure, Path], None]] = []

#: Most wheels drawn as panels of a wheel-load figure (spread along the train beyond that).
MAX_WHEEL_PANELS = 8

_DPI = 150
_STYLE: dict[str, Any] = {
    "font.size": 9,
    "axes.titlesize": 9.5,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "lines.linewidth": 1.1,
    "legend.framealpha": 0.92,
    "figure.facecolor": "white",
    "savefig.facecolor": "white",
}
_Loc = Literal["upper right", "upper left", "lower right", "lower left", "center right", "center left",
               "upper center", "lower center"]
_LOCS: tuple[_Loc, ...] = ("upper right", "upper left", "lower right", "lower left", "center right", "center left",
                           "upper center", "lower center")
_PREFERRED: WeakKeyDictionary[Legend, _Loc] = WeakKeyDictionary()


# ----------------------------------------------------------------------------- figure plumbing


@contextmanager
def style() -> Iterator[None]:
    with mpl.rc_context(cast(Any, _STYLE)):
        yield


def new_figure(nrows: int, ncols: int, figsize: tuple[float, float], **kw: Any) -> tuple[Figure, NDArray[Any]]:
    """A Figure with its own Agg canvas (no pyplot) and a (nrows, ncols) array of axes."""
    fig = Figure(figsize=figsize, dpi=_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axs = fig.subplots(nrows, ncols, squeeze=False, **kw)
    return fig, axs


def legend(ax: Axes, loc: _Loc = "upper right", **kw: Any) -> Legend:
    """A legend on ``ax`` at ``loc``; :func:`save` moves it if it hides a curve or a label."""
    leg = ax.legend(loc=loc, **kw)
    _PREFERRED[leg] = loc
    return leg


def _line_points(fig: Figure) -> tuple[Array, Array]:
    """Display points of the data curves: (extremes, samples every few pixels along every curve).

    The extremes are the largest and smallest value of every curve (what a
    legend must never hide); reference lines (axhline, axvline) are left out.
    """
    ext: list[Array] = []
    samples: list[Array] = []
    for ax in fig.axes:
        frame = ax.get_window_extent()
        for line in ax.get_lines():
            if not line.get_visible() or line.get_transform() is not ax.transData:
                continue  # reference lines span the axes
            xy = np.column_stack([np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)])
            xy = xy[np.all(np.isfinite(xy), axis=1)]
            if xy.size == 0:
                continue
            disp = ax.transData.transform(xy)
            ok = np.all(np.isfinite(disp), axis=1) & (disp[:, 0] >= frame.x0 - 0.5) & (disp[:, 0] <= frame.x1 + 0.5)
            ok &= (disp[:, 1] >= frame.y0 - 0.5) & (disp[:, 1] <= frame.y1 + 0.5)
            if not ok.any():
                continue
            y = xy[ok, 1]
            ext.append(disp[ok][[int(np.argmax(y)), int(np.argmin(y))]])
            d = disp[ok]
            if line.get_linestyle() in ("None", "", " ") or len(d) < 2:
                samples.append(d)
                continue
            s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(d, axis=0).T))])
            n = int(min(max(s[-1] / 3.0, len(d)), 20000))
            u = np.linspace(0.0, s[-1], n)
            samples.append(np.column_stack([np.interp(u, s, d[:, 0]), np.interp(u, s, d[:, 1])]))
    return _stack(ext), _stack(samples)


def _stack(parts: list[Array]) -> Array:
    return np.concatenate(parts) if parts else np.zeros((0, 2))


def _text_boxes(fig: Figure) -> list[Bbox]:
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    return [t.get_window_extent(renderer) for ax in fig.axes for t in ax.texts if t.get_visible()]


def _inside(b: Bbox, pts: Array) -> int:
    return int(np.count_nonzero((pts[:, 0] >= b.x0) & (pts[:, 0] <= b.x1) & (pts[:, 1] >= b.y0) & (pts[:, 1] <= b.y1)))


def _outside_right(fig: Figure, ax: Axes, leg: Legend) -> None:
    """Anchor ``leg`` to the right of ``ax``, beyond any right-hand axis (twinx) drawn there."""
    frame = ax.get_window_extent()
    right = frame.x1
    for other in fig.axes:  # a twin at the same place has its axis on the right
        tb = other.yaxis.get_tightbbox()
        if tb is not None and np.allclose(other.get_position().bounds, ax.get_position().bounds):
            right = max(right, tb.x1)
    leg.set_bbox_to_anchor(((right - frame.x0) / frame.width + 0.01, 1.0), transform=ax.transAxes)
    leg.set_loc("upper left")


def _free_loc(leg: Legend, cands: Sequence[_Loc], ext: Array, samples: Array, boxes: list[Bbox]) -> _Loc | None:
    """The first of ``cands`` where ``leg`` hides no curve (6 px clearance) and no label; None if none."""
    for loc in cands:
        leg.set_loc(loc)
        b = leg.get_window_extent().padded(6.0)
        if not (_inside(b, ext) or _inside(b, samples) or any(b.overlaps(t) for t in boxes)):
            return loc
    return None


def _has_twin(fig: Figure, ax: Axes) -> bool:
    return any(o is not ax and np.allclose(o.get_position().bounds, ax.get_position().bounds) for o in fig.axes)


def _raise_top(ax: Axes, fraction: float) -> None:
    """Move the upper edge of the plot (whatever the axis direction or scale) away by ``fraction`` of the span."""
    lo, hi = ax.get_ylim()
    if ax.get_yscale() == "log" and lo > 0 and hi > 0:
        ax.set_ylim(lo, hi * (hi / lo) ** fraction)
    else:
        ax.set_ylim(lo, hi + fraction * (hi - lo))


def _place_legends(fig: Figure) -> None:
    """Put every legend where it hides no curve and no peak label.

    Candidates are the corners and edge centres of its axes, the one chosen
    by the plotting code first. If none is free, the axes gets headroom
    above the curves (up to 45 % more span, a single axes only) for an upper
    corner; failing that the legend goes outside, right of the axes.
    """
    for _ in range(4):
        fig.draw_without_rendering()
        ext, samples = _line_points(fig)
        boxes = _text_boxes(fig)
        moved = False
        for ax in fig.axes:
            leg = ax.get_legend()
            if leg is None or _anchored_outside(leg, ax):
                continue
            first = _PREFERRED.get(leg, "upper right")
            loc = _free_loc(leg, [first, *(c for c in _LOCS if c != first)], ext, samples, boxes)
            if loc is None and not _has_twin(fig, ax):
                uppers: list[_Loc] = [c for c in (first, "upper right", "upper left", "upper center")
                                      if c.startswith("upper")]
                limits = ax.get_ylim()
                for _k in range(3):
                    _raise_top(ax, 0.15)
                    ext, samples = _line_points(fig)
                    loc = _free_loc(leg, list(dict.fromkeys(uppers)), ext, samples, boxes)
                    if loc is not None:
                        break
                else:
                    ax.set_ylim(limits)
                    ext, samples = _line_points(fig)
                moved = True
            if loc is None:
                _outside_right(fig, ax, leg)
                moved = True
            else:
                leg.set_loc(loc)
                if loc != first:
                    _PREFERRED[leg] = loc
                    moved = True
        if not moved:
            return


def _anchored_outside(leg: Legend, ax: Axes) -> bool:
    b = leg.get_window_extent()
    f = ax.get_window_extent()
    return bool(b.x0 >= f.x1 - 1 or b.x1 <= f.x0 + 1 or b.y0 >= f.y1 - 1 or b.y1 <= f.y0 + 1)


def save(fig: Figure, path: str | Path) -> Path:
    """Lay out, place the legends (a figure without axes legends is laid out once, by savefig, unless observers
    look at it), tell the observers, write the PNG."""
    p = Path(path)
    if any(ax.get_legend() is not None for ax in fig.axes):
        _place_legends(fig)
    elif figure_observers:  # they look at a laid-out figure; savefig lays it out itself
        fig.draw_without_rendering()
    for observe in figure_observers:
        observe(fig, p)
    fig.savefig(p, dpi=_DPI)
    return p


#: Most points drawn per curve of a long record (:func:`decimate`): a figure is 1350 px wide.
MAX_POINTS = 2400


def decimate(x: Array, y: Array, most: int = MAX_POINTS, log: bool = False) -> tuple[Array, Array]:
    """Fewer points of a long curve that draw the same picture: the smallest and the largest value of each bin.

    ``most // 2`` bins of equal width in x (in log x with ``log``); each keeps its minimum and maximum in
    their order, so every extreme of the curve, and its global maximum and minimum, stay drawn exactly.
    Curves of at most ``most`` points are returned as they are; longer ones lose their NaN points
    (and, with ``log``, those at x <= 0).
    """
    xa, ya = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if xa.size <= most:
        return xa, ya
    ok = np.isfinite(xa) & np.isfinite(ya) & ((xa > 0) if log else True)
    xa, ya = xa[ok], ya[ok]
    if xa.size <= most:
        return xa, ya
    u = np.log(xa) if log else xa
    nb = max(1, most // 2)
    edges = np.linspace(u[0], u[-1], nb + 1) if u[-1] > u[0] else np.array([u[0], u[0] + 1.0])
    b = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, edges.size - 2)
    starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
    keep = np.zeros(xa.size, dtype=bool)
    for s0, e0 in zip(starts, np.r_[starts[1:], xa.size], strict=True):
        seg = ya[s0:e0]
        keep[s0 + int(np.argmax(seg))] = True
        keep[s0 + int(np.argmin(seg))] = True
    keep[0] = keep[-1] = True
    return xa[keep], ya[keep]


def pick_wheels(n_wheels: int, most: int = MAX_WHEEL_PANELS) -> list[int]:
    """Every wheel, or ``most`` of them spread from the first to the last."""
    if n_wheels <= most:
        return list(range(n_wheels))
    return sorted({int(i) for i in np.linspace(0, n_wheels - 1, most).round()})


def wheel_panels(axs: Sequence[Axes], t: Array, P: Array, wheels: list[int], static: Array | None) -> None:
    """One panel per wheel, same load scale: load [kN] over time, static load dashed, max/min and the dynamic
    factor (max / static) in the title."""
    for ax, i in zip(axs, wheels, strict=True):
        if ax is not axs[0]:
            ax.sharey(axs[0])
        p = P[:, i]
        ax.plot(*decimate(t, p / 1e3), color="C0", lw=0.8, label="wheel load")
        if static is not None:
            ax.axhline(static[i] / 1e3, color="0.25", ls="--", lw=0.8, label="static wheel load")
        ax.set_ylabel(f"wheel {i}\n[kN]")
        if np.isfinite(p).any():
            df = (f", dynamic factor max/static {np.nanmax(p) / static[i]:.3f}"
                  if static is not None and static[i] > 0 else "")
            ax.set_title(f"max {np.nanmax(p) / 1e3:.1f} kN, min {np.nanmin(p) / 1e3:.1f} kN{df}", loc="right",
                         fontsize=7.5, pad=2)


def figure_legend(fig: Figure, axs: Sequence[Axes]) -> None:
    """One legend for the figure, below the panels (outside every axes), entries of ``axs`` once each."""
    handles: list[Any] = []
    labels: list[str] = []
    for ax in axs:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="outside lower center", ncol=min(4, len(labels)), frameon=False)


def receptance_lines(amplitude: Axes, phase: Axes, f: Array, H: CArray, *, db: bool = False,
                     unwrap: bool = False, label: str | None = None, **line: Any) -> None:
    """One receptance H(f) [m/N]: its amplitude on ``amplitude``, its phase [deg] on ``phase``, the same line style.

    Parameters
    ----------
    amplitude, phase : Axes
        The amplitude panel (log scale, or dB re 1 m/N when ``db``) and the phase panel.
    f : (n_f,) array
        Frequencies [Hz].
    H : (n_f,) complex array
        The receptance [m/N].
    db : bool
        Amplitude as 20 log10 |H| [dB re 1 m/N] on a linear axis instead of |H| on a log axis.
    unwrap : bool
        Unwrap the phase (no 360-degree jumps).
    label : str, optional
        Legend entry (of the amplitude line only).
    **line
        Line style of both lines (color, ls, lw, ...).
    """
    if db:
        amplitude.plot(f, 20.0 * np.log10(np.abs(H)), label=label, **line)
    else:
        amplitude.semilogy(f, np.abs(H), label=label, **line)
    angle = np.unwrap(np.angle(H)) if unwrap else np.angle(H)
    phase.plot(f, np.degrees(angle), **line)


def label_receptance_axes(amplitude: Axes, phase: Axes, amplitude_label: str) -> None:
    """Axis labels of an amplitude panel above a phase panel [deg] over frequency [Hz]."""
    amplitude.set_ylabel(amplitude_label)
    phase.set_ylabel("phase [deg]")
    phase.set_xlabel("frequency [Hz]")
