"""The report of an output tree: ``index.html``, a short page an engineer can read and pass on.

:func:`write_index` scans a directory (``clm simulate``, ``clm demo``,
``clm report`` or a whole ``results/`` tree) and writes ``index.html`` at its
top: one section per directory that holds outputs, with

- a headline table of the run's ``summary.json``: the figures that matter
  (peak sleeper soil force, rail deflection, wheel loads and their dynamic
  part, dynamic factor, tensile ballast forces, real-time factors, lags),
  each with a label, its unit and the key it comes from (:data:`HEADLINES`);
  a summary without any of those gets a table of its scalar entries;
- the figures (``*.png``), full width, each with a caption saying what it
  shows (:data:`CAPTIONS`), linking to the full-size image;
- a link to every summary and data file (``*.csv``, ``*.npz``, ``*.yaml``,
  ``*.md``) and a rosbag2 bag directory as one link.

Links are relative, so the tree can be moved, zipped or served as it is.
No matplotlib. ``scripts/screenshot-report.sh DIR`` renders the page in
headless Chromium to a PNG.

``python -m clm_core.outputs.report_index DIR [TITLE]`` writes ``DIR/index.html``
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
.figs { display: flex; flex-wrap: wrap; gap: 18px; }
figure { margin: 0; width: 640px; } figure img { width: 640px; border: 1px solid #ddd; }
figcaption { font-size: .85em; line-height: 1.35; margin-top: .3em; } figcaption b { font-family: monospace; }
table { border-collapse: collapse; font-size: .9em; margin: .4em 0 .8em 0; }
th { text-align: left; border-bottom: 2px solid #bbb; padding: 2px 14px 2px 0; }
td { border-bottom: 1px solid #eee; padding: 2px 14px 2px 0; }
td.k { font-family: monospace; color: #777; font-size: .85em; }
td.v { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
.note { font-size: .85em; color: #a04000; }
.files a { font-family: monospace; margin-right: 1.2em; font-size: .85em; }
.toc a { margin-right: 1em; }
"""

#: Headline entries of a summary: (key, label, unit shown, factor from the key's SI unit).
HEADLINES: tuple[tuple[str, str, str, float], ...] = (
    ("peak_sleeper_soil_force_N", "Peak sleeper soil force (ballast on soil)", "kN", 1e-3),
    ("peak_sleeper_index", "Sleeper of the peak soil force (global index)", "", 1.0),
    ("peak_sleeper_global_index", "Sleeper of the peak soil force (global index)", "", 1.0),
    ("envelope_min_soil_force_N", "Smallest sleeper soil force (negative: tensile)", "kN", 1e-3),
    ("tensile_sleepers", "Sleepers with a tensile (negative) soil force", "", 1.0),
    ("max_rail_deflection_m", "Largest rail deflection", "mm", 1e3),
    ("peak_wheel_load_N", "Peak wheel load", "kN", 1e-3),
    ("min_wheel_load_N", "Smallest wheel load", "kN", 1e-3),
    ("wheel_load_static_N", "Static wheel load", "kN", 1e-3),
    ("wheel_load_dynamic_std_N", "Dynamic part of the wheel load (std about the static load)", "kN", 1e-3),
    ("dynamic_factor", "Dynamic factor (peak / static wheel load)", "", 1.0),
    ("unloading_factor", "Unloading factor (smallest / static wheel load)", "", 1.0),
    ("rms_wheel_load_N", "RMS of the wheel load, static load included (not its dynamic part)", "kN", 1e-3),
    ("contact_loss_events", "Wheel-rail contact losses (events)", "", 1.0),
    ("speed_m_per_s", "Train speed", "km/h", 3.6),
    ("sleeper_passing_frequency_Hz", "Sleeper-passing frequency V/d", "Hz", 1.0),
    ("simulated_time_s", "Simulated time", "s", 1.0),
    ("real_time_factor", "Real-time factor of the computation (simulated / stepping wall time)", "", 1.0),
    ("real_time_factor_command", "Real-time factor of the command (simulated / wall time, writing included)", "",
     1.0),
    ("lag_median_s", "Response lag, median", "ms", 1e3),
    ("lag_p99_s", "Response lag, 99th percentile", "ms", 1e3),
)

#: Caption of each figure file (what it shows); others are captioned by their name.
CAPTIONS: dict[str, str] = {
    "simulate.png": "Soil force under a few sleepers over time (top); rail deflection along the track at the moment "
                    "of its largest value, downwards positive, wheels dashed (bottom).",
    "soil_forces.png": "Top: soil force under sleepers over time, the peak sleeper in black among them. Bottom: the "
                       "envelope along the track, largest (red) and smallest (blue) force of every sleeper, the peak "
                       "sleeper marked; negative values are tensile ballast forces (the model's ballast spring "
                       "carries tension).",
    "spectra.png": "Single-sided amplitude spectra of the dynamic part (static or mean value removed): 0-80 Hz "
                   "(the band of ground-borne vibration, DIN 4150) and 80-500 Hz on its own scale; dashed: the "
                   "sleeper-passing frequency V/d.",
    "third_octave.png": "One-third-octave band rms of the dynamic part (base-10 bands from 1 Hz; shaded: 1-80 Hz).",
    "wheel_loads.png": "Wheel loads over time, one panel per wheel on one scale, static load dashed; each title gives "
                       "the largest and smallest load and the dynamic factor (largest / static).",
    "sleeper_soil_forces.png": "Soil force under sleepers passed while in the track node's window, over time.",
    "rail_deflection.png": "Rail deflection and soil force along the track at the moment of the peak soil force "
                           "(both downwards).",
    "receptance.png": "Track receptances H_i1 (rail above sleeper i over a force above sleeper 1): amplitude and "
                      "phase; peaks labelled.",
    "receivers.png": "Free-field vertical velocity at the receivers (two-step method: the sleeper soil forces on the "
                     "layered half-space), peak marked (top); one-third-octave velocity levels L_v, 1-80 Hz, dB re "
                     "5e-8 m/s (bottom). The table above gives PPV, KB_F,max (DIN 4150-2) and the levels.",
    "rail_deflection_spectra.png": "Amplitude spectra of the rail deflection (mean removed) under the first wheel "
                                   "and above the sleeper of the largest deflection.",
    "rail_deflection_third_octave.png": "One-third-octave band rms of the rail deflection (mean removed).",
    "chain.png": "Soil chain: its impedance against the closed forms of the paper (Eqs. 16, 18).",
}
_ORDER = ("wheel_loads.png", "soil_forces.png", "simulate.png", "spectra.png", "third_octave.png",
          "sleeper_soil_forces.png", "rail_deflection.png", "rail_deflection_spectra.png",
          "rail_deflection_third_octave.png", "receivers.png")


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


def _read_summary(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _headline_value(v: Any, factor: float) -> str | None:
    if isinstance(v, bool) or v is None:
        return None
    if isinstance(v, list):
        nums = [x for x in v if isinstance(x, (int, float)) and not isinstance(x, bool)]
        if not nums or len(nums) != len(v):
            return None
        lo, hi = min(nums) * factor, max(nums) * factor
        return f"{lo:.4g}" if math.isclose(lo, hi, rel_tol=1e-9) else f"{lo:.4g} .. {hi:.4g}"
    if isinstance(v, int):
        return f"{v * factor:.4g}" if factor != 1.0 else str(v)
    if isinstance(v, float):
        return f"{v * factor:.4g}" if math.isfinite(v) else str(v)
    return None


def _summary_table(path: Path) -> str:
    """The headline table of a summary (:data:`HEADLINES`); its scalar entries if it has no headline ('' if none)."""
    data = _read_summary(path)
    if data is None:
        return ""
    rows = []
    for key, label, unit, factor in HEADLINES:
        if key in data:
            text = _headline_value(data[key], factor)
            if text is not None:
                rows.append(f'<tr><td>{html.escape(label)}</td><td class="v">{html.escape(text)}</td>'
                            f'<td>{html.escape(unit)}</td><td class="k">{html.escape(key)}</td></tr>')
    if rows:
        note = data.get("tensile_note") if data.get("tensile_sleepers") else None
        return ("<table><tr><th>quantity</th><th>value</th><th>unit</th><th>key in summary.json</th></tr>"
                + "".join(rows) + "</table>"
                + (f'<p class="note">Note: {html.escape(str(note))}.</p>' if note else ""))
    scalars = [(k, v) for k, v in data.items()
               if isinstance(v, (int, float, str, bool)) or v is None
               or (isinstance(v, list) and len(v) <= 6 and all(isinstance(x, (int, float)) for x in v))]
    if not scalars:
        return ""
    body = "".join(f'<tr><td class="k">{html.escape(str(k))}</td><td>{html.escape(_fmt(v))}</td></tr>'
                   for k, v in scalars[:_MAX_ROWS])
    more = (f"<tr><td colspan=2>... {len(scalars) - _MAX_ROWS} more in the file</td></tr>"
            if len(scalars) > _MAX_ROWS else "")
    return f"<table>{body}{more}</table>"


def _receivers_table(data: dict[str, Any]) -> str:
    """The free-field receivers of a summary (its ``receivers`` entry): PPV, KB_F,max, dominant band, L_v per band."""
    entry = data.get("receivers")
    if not isinstance(entry, dict):
        return ""
    rows = entry.get("receivers")
    if not isinstance(rows, list) or not rows or not all(isinstance(r, dict) for r in rows):
        return ""
    bands = list(rows[0].get("lv_db_re_5e-8_m_per_s", {}))
    head = ("<tr><th>receiver x [m]</th><th>y [m]</th><th>PPV [mm/s]</th><th>KB<sub>F,max</sub> [mm/s]</th>"
            "<th>dominant 1/3-octave band [Hz]</th></tr>")
    body = "".join(
        f'<tr><td class="v">{_fmt(r.get("x_m"))}</td><td class="v">{_fmt(r.get("y_m"))}</td>'
        f'<td class="v">{_headline_value(r.get("ppv_mm_per_s"), 1.0)}</td>'
        f'<td class="v">{_headline_value(r.get("kb_fmax_mm_per_s"), 1.0)}</td>'
        f'<td class="v">{_fmt(r.get("dominant_third_octave_hz"))}</td></tr>' for r in rows)
    lv_head = "<tr><th>L<sub>v</sub> [dB re 5e-8 m/s], band [Hz]</th>" + "".join(
        f"<th>{html.escape(b)}</th>" for b in bands) + "</tr>"
    lv_body = "".join(
        f'<tr><td>y = {_fmt(r.get("y_m"))} m</td>' + "".join(
            f'<td class="v">{"" if v is None else f"{v:.1f}"}</td>'
            for v in r.get("lv_db_re_5e-8_m_per_s", {}).values()) + "</tr>" for r in rows)
    return (f"<p>Free-field receivers (soil {html.escape(str(entry.get('soil', '?')))}; "
            f"{html.escape(str(entry.get('kb_filter', '')))}):</p>"
            f"<table>{head}{body}</table><table>{lv_head}{lv_body}</table>")


def _caption(rel: str) -> str:
    name = Path(rel).name
    text = CAPTIONS.get(name)
    return f"<b>{html.escape(name)}</b>" + (f": {html.escape(text)}" if text else "")


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
        f"director{'y' if len(sections) == 1 else 'ies'}: headline figures with their units, then the figures with "
        "captions (click one for the full-size image), then the data files. Forces and displacements are positive "
        "downwards (compression of the ballast positive).</p>",
    ]
    if len(sections) > 1:
        parts.append('<p class="toc">' + "".join(
            f'<a href="#s{i}">{html.escape(s.rel)}</a>' for i, s in enumerate(sections)) + "</p>")
    for i, s in enumerate(sections):
        parts.append(f'<h2 id="s{i}">{html.escape(s.rel)}</h2>')
        for rel in s.summaries:
            parts.append(_summary_table(r / rel))
            parts.append(_receivers_table(_read_summary(r / rel) or {}))
            parts.append(f'<p class="files">every value: <a href="{_href(rel)}">{html.escape(rel)}</a></p>')
        if s.figures:
            parts.append('<div class="figs">')
            rank = {n: i for i, n in enumerate(_ORDER)}
            for rel in sorted(s.figures, key=lambda q: (rank.get(Path(q).name, len(rank)), q)):
                parts.append(f'<figure><a href="{_href(rel)}"><img src="{_href(rel)}" '
                             f'alt="{html.escape(rel)}"></a><figcaption>{_caption(rel)}</figcaption></figure>')
            parts.append("</div>")
        if s.files:
            parts.append('<p class="files">data: ' + "".join(
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
    """``python -m clm_core.outputs.report_index DIR [TITLE]``: write ``DIR/index.html``; print its path."""
    args = sys.argv[1:] if argv is None else argv
    if not args or not Path(args[0]).is_dir():
        print("usage: python -m clm_core.outputs.report_index DIR [TITLE] (DIR an existing directory)", file=sys.stderr)
        return 2
    print(write_index(args[0], " ".join(args[1:]) or None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
