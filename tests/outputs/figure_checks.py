"""Checks every figure of the suite must pass (an engineer puts them in reports).

Written independently of :mod:`clm_core.outputs.plots` (which places the legends):
these functions only look at a laid-out figure and at the PNG file.

- every axes has an x and a y label with a unit in brackets, ``[...]`` (the
  x label may sit on an axes sharing the x-axis, as under stacked panels);
- no legend covers the largest or the smallest point of any data curve
  (legend box against the curve extremes, in display coordinates);
- the PNG decodes, is not tiny and not blank.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

UNIT = re.compile(r"\[[^\]]+\]")


def _shared_x_label(ax: Axes) -> str:
    if ax.get_xlabel().strip():
        return ax.get_xlabel()
    for other in ax.get_shared_x_axes().get_siblings(ax):
        if other.get_xlabel().strip():
            return other.get_xlabel()
    return ""


def label_problems(fig: Figure) -> list[str]:
    """Axes without a labelled x or y axis with a unit in brackets."""
    out = []
    for n, ax in enumerate(fig.axes):
        if not ax.get_visible() or not ax.axison:
            continue
        for which, text in (("x", _shared_x_label(ax)), ("y", ax.get_ylabel())):
            if not text.strip():
                out.append(f"axes {n} ({ax.get_title() or ax.get_ylabel()!r}): no {which} label")
            elif not UNIT.search(text):
                out.append(f"axes {n}: {which} label {text!r} has no unit in brackets")
    return out


def curve_extremes(fig: Figure) -> list[tuple[str, float, float]]:
    """(curve label, x, y) in display pixels of the max and min of every visible data curve in view."""
    out = []
    for ax in fig.axes:
        box = ax.get_window_extent()
        for line in ax.get_lines():
            if not line.get_visible() or line.get_transform() is not ax.transData:
                continue
            x = np.asarray(line.get_xdata(), float)
            y = np.asarray(line.get_ydata(), float)
            ok = np.isfinite(x) & np.isfinite(y)
            if not ok.any():
                continue
            pts = ax.transData.transform(np.column_stack([x[ok], y[ok]]))
            view = (pts[:, 0] >= box.x0 - 1) & (pts[:, 0] <= box.x1 + 1) & (pts[:, 1] >= box.y0 - 1)
            view &= pts[:, 1] <= box.y1 + 1
            if not view.any():
                continue
            yv = y[ok][view]
            for k in (int(np.argmax(yv)), int(np.argmin(yv))):
                px, py = pts[view][k]
                out.append((str(line.get_label()), float(px), float(py)))
    return out


def legend_problems(fig: Figure) -> list[str]:
    """Legends whose box holds the max or min point of a curve."""
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None] + list(fig.legends)
    out = []
    ext = curve_extremes(fig)
    for leg in legends:
        b = leg.get_window_extent()
        for name, x, y in ext:
            if b.x0 <= x <= b.x1 and b.y0 <= y <= b.y1:
                out.append(f"legend ({', '.join(t.get_text() for t in leg.get_texts())[:60]}) covers an extreme "
                           f"of curve {name!r} at ({x:.0f}, {y:.0f}) px")
    return out


def figure_problems(fig: Figure) -> list[str]:
    """Every rule above that ``fig`` (laid out) breaks."""
    return label_problems(fig) + legend_problems(fig)


def png_problems(path: Path) -> list[str]:
    """A PNG that does not decode, is tiny, or is (nearly) blank."""
    from matplotlib.image import imread

    try:
        img = imread(path)
    except Exception as exc:  # any decoder error is the finding
        return [f"{path.name}: does not decode ({exc})"]
    rgb = img[..., :3]
    h, w = rgb.shape[:2]
    out = []
    if h < 300 or w < 400:
        out.append(f"{path.name}: {w} x {h} px, too small for a report")
    ink = np.mean(np.any(rgb < 0.9, axis=2))
    if ink < 0.01 or float(rgb.std()) < 0.02:
        out.append(f"{path.name}: nearly blank ({100 * ink:.2f} % non-white pixels)")
    q = (rgb[::3, ::3].reshape(-1, 3) * 15).round().astype(np.int64)
    colours = len(np.unique(q[:, 0] * 256 + q[:, 1] * 16 + q[:, 2]))
    if colours < 4:
        out.append(f"{path.name}: only {colours} colours")
    return out
