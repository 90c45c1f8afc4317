"""An HTML index of an output tree: every figure and summary of a run, one page.

:func:`write_index` scans a directory (``clm demo``, ``clm report`` or a
whole ``results/`` tree), and writes ``index.html`` at its top: one section
per directory that holds outputs, with

- the figures (``*.png``) as thumbnails linking to the full image;
- every ``summary.json`` (and ``index.json``) as a link, with a table of its
  scalar entries (names carry their units, e.g. ``peak_wheel_load_N``);
- Markdown reports (``*.md``) and data files (``*.csv``, ``*.npz``,
  ``*.yaml``) as links; a rosbag2 bag directory as one link.

Links are relative, so the tree can be moved, zipped or served as it is.
No matplotlib: the thumbnails are the PNG files scaled by the browser.

``python -m clm_core.io.report_index DIR [TITLE]`` writes ``DIR/index.html``
(``scripts/demo.sh`` does so for ``results/``).
"""

from __future__ import annotations

import html
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Name of the page written at the top of the tree.
INDEX_NAME = "index.html"
_FIGURES = (".png", ".svg")
_SUMMARIES = ("summary.json", "index.json")
_DATA = (".csv", ".npz", ".yaml", ".yml", ".md", ".log", ".json")
_MAX_ROWS = 24

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 1.5em 2em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; border-bottom: 1px solid #ccc; padding-bottom: .2em; margin-top: 2em; }
.figs { display: flex; flex-wrap: wrap; gap: 14px; }
figure { margin: 0; width: 360px; } figure img { width: 360px; border: 1px solid #ddd; }
figcaption { font-size: .85em; font-family: monospace; }
table { border-collapse: collapse; font-size: .85em; margin: .4em 0 .8em 0; }
td { border-bottom: 1px solid #eee; padding: 1px 10px 1px 0; } td.k { font-family: monospace; }
.files a { font-family: monospace; margin-right: 1.2em; font-size: .9em; }
.toc a { margin-right: 1em; }
"""


@dataclass
class _Section:
    rel: str
    figures: list[str] = field(default_factory=list)
    summaries: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)


def _is_bag(d: Path) -> bool:
    return (d / "metadata.yaml").is_file()


def _scan(root: Path) -> list[_Section]:
    sections: dict[Path, _Section] = {}

    def sec(d: Path) -> _Section:
        if d not in sections:
            sections[d] = _Section(f"{root.resolve().name}/" if d == root else d.relative_to(root).as_posix() + "/")
        return sections[d]

    def walk(d: Path) -> None:
        for p in sorted(d.iterdir(), key=lambda q: q.name):
            if p.name.startswith("."):
                continue
            rel = p.relative_to(root).as_posix()
            if p.is_dir():
                if _is_bag(p):
                    sec(d).files.append(rel + "/")
                else:
                    walk(p)
            elif p.name == INDEX_NAME and d == root:
                continue
            elif p.suffix.lower() in _FIGURES:
                sec(d).figures.append(rel)
            elif p.name in _SUMMARIES:
                sec(d).summaries.append(rel)
            elif p.suffix.lower() in _DATA or p.name == INDEX_NAME:
                sec(d).files.append(rel)

    walk(root)
    return [sections[k] for k in sorted(sections, key=lambda q: (q != root, q.relative_to(root).as_posix()))]


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return str(v).lower() if isinstance(v, bool) else "null"
    if isinstance(v, float):
        return f"{v:.6g}" if math.isfinite(v) else str(v)
    if isinstance(v, list) and len(v) <= 6 and all(isinstance(x, (int, float)) for x in v):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def _summary_table(path: Path) -> str:
    """Scalar entries of a JSON summary as an HTML table ('' if none or unreadable)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return ""
    if not isinstance(data, dict):
        return ""
    rows = [(k, v) for k, v in data.items()
            if isinstance(v, (int, float, str, bool)) or v is None
            or (isinstance(v, list) and len(v) <= 6 and all(isinstance(x, (int, float)) for x in v))]
    if not rows:
        return ""
    body = "".join(f'<tr><td class="k">{html.escape(str(k))}</td><td>{html.escape(_fmt(v))}</td></tr>'
                   for k, v in rows[:_MAX_ROWS])
    more = f"<tr><td colspan=2>... {len(rows) - _MAX_ROWS} more in the file</td></tr>" if len(rows) > _MAX_ROWS else ""
    return f"<table>{body}{more}</table>"


def _href(rel: str) -> str:
    return html.escape(rel.replace(" ", "%20"), quote=True)


def render_index(root: str | Path, title: str | None = None) -> str:
    """The HTML text of the index of ``root`` (see :func:`write_index`)."""
    r = Path(root)
    sections = [s for s in _scan(r) if s.figures or s.summaries or s.files]
    t = html.escape(title or f"Results in {r.resolve().name}")
    n_fig = sum(len(s.figures) for s in sections)
    n_sum = sum(len(s.summaries) for s in sections)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{t}</title><style>{_CSS}</style></head><body>",
        f"<h1>{t}</h1>",
        f"<p>{n_fig} figure(s), {n_sum} summar{'y' if n_sum == 1 else 'ies'} in {len(sections)} "
        f"director{'y' if len(sections) == 1 else 'ies'}; click a figure for the full-size image.</p>",
    ]
    if len(sections) > 1:
        parts.append('<p class="toc">' + "".join(
            f'<a href="#s{i}">{html.escape(s.rel)}</a>' for i, s in enumerate(sections)) + "</p>")
    for i, s in enumerate(sections):
        parts.append(f'<h2 id="s{i}">{html.escape(s.rel)}</h2>')
        for rel in s.summaries:
            parts.append(f'<p class="files"><a href="{_href(rel)}">{html.escape(rel)}</a></p>')
            parts.append(_summary_table(r / rel))
        if s.figures:
            parts.append('<div class="figs">')
            for rel in s.figures:
                parts.append(f'<figure><a href="{_href(rel)}"><img src="{_href(rel)}" loading="lazy" '
                             f'alt="{html.escape(rel)}"></a><figcaption>{html.escape(Path(rel).name)}'
                             "</figcaption></figure>")
            parts.append("</div>")
        if s.files:
            parts.append('<p class="files">' + "".join(
                f'<a href="{_href(rel)}">{html.escape(Path(rel.rstrip("/")).name + ("/" if rel.endswith("/") else ""))}'
                "</a>" for rel in s.files) + "</p>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_index(root: str | Path, title: str | None = None) -> Path:
    """Write ``root/index.html`` linking every figure and summary below ``root``.

    Parameters
    ----------
    root : path
        Top of the output tree (an existing directory).
    title : str, optional
        Page title (default: "Results in <directory name>").

    Returns
    -------
    Path
        The page written.
    """
    r = Path(root)
    p = r / INDEX_NAME
    p.write_text(render_index(r, title), encoding="utf-8")
    return p


def main(argv: list[str] | None = None) -> int:
    """``python -m clm_core.io.report_index DIR [TITLE]``: write ``DIR/index.html``; print its path."""
    args = sys.argv[1:] if argv is None else argv
    if not args or not Path(args[0]).is_dir():
        print("usage: python -m clm_core.io.report_index DIR [TITLE] (DIR an existing directory)", file=sys.stderr)
        return 2
    print(write_index(args[0], " ".join(args[1:]) or None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
