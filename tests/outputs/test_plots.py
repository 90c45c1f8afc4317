"""Figures (clm_core.outputs.plots) as an engineer puts them in a report, and the HTML index.

Every figure the commands write is rendered here from real runs into
``tmp_path`` (receptance, soil chain, moving loads, vehicle, calibration,
soil calibration; the demo plots of clm_ros: tests/ros/test_launcher.py) and
checked: axes labelled with units, legends off the curve extremes, valid
non-blank PNGs (tests/outputs/figure_checks.py), plus the specific points of
issue 13 item 8. The root conftest applies the same checks to every figure
any other test renders.
"""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from clm_core.cli import main
from clm_core.outputs import plots
from clm_core.outputs.plots import _base
from clm_core.outputs.report_index import write_index
from clm_core.params import load_soil
from clm_core.synthetic import add_noise, simulate_impact, write_bag
from tests.outputs.figure_checks import curve_extremes, figure_problems, png_problems

REPO = Path(__file__).resolve().parents[2]

#: Every figure file of the suite (clm_core.outputs.plots module docstring).
CORE_FIGURES = {"receptance.png", "chain.png", "simulate.png", "wheel_loads.png", "soil_forces.png", "spectra.png",
                "third_octave.png", "transfer_functions.png", "sums.png", "time_histories.png", "receptances.png"}
DEMO_FIGURES = set(plots.DEMO_FIGURES)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, list[tuple[Path, Figure]]]]:
    """Run every command that draws, small; yield (output root, [(file, figure)])."""
    record: list[tuple[Path, Figure]] = []

    def observe(fig: Figure, path: Path) -> None:
        record.append((path, fig))

    root = tmp_path_factory.mktemp("figures")
    plots.figure_observers.append(observe)
    try:
        assert main(["receptance", "--sleepers", "21", "--df", "1", "--out", str(root / "receptance")]) == 0
        assert main(["soil-chain", "--areas", "21", "--df", "1", "--out", str(root / "chain")]) == 0
        assert main(["simulate", "--load", "100e3", "--axles", "0,2.5", "--speed", "30", "--duration", "0.3",
                     "--dt", "2e-4", "--out", str(root / "simulate")]) == 0
        assert main(["simulate", "--vehicle", "tram", "--speed", "20", "--duration", "0.2", "--start", "10",
                     "--irregularity", "fra5", "--out", str(root / "vehicle")]) == 0
        rec = add_noise(simulate_impact(load_soil("mevergnies"), n_areas=11, duration=0.8), 30.0, seed=11)
        bag = write_bag(rec, root / "impact_bag").path
        assert main(["calibrate", str(bag), "--method", "impact", "--fmax", "120", "--out",
                     str(root / "calibrate")]) == 0
        assert main(["soil-calibrate", "--profile", "medium", "--areas", "5", "--fmax", "40", "--sweep-max", "40",
                     "--df", "5", "--out", str(root / "soil-calibrate")]) == 0
        yield root, record
    finally:
        plots.figure_observers.remove(observe)


def _figure(record: list[tuple[Path, Figure]], rel: str) -> Figure:
    found = [fig for path, fig in record if path.as_posix().endswith(rel)]
    assert len(found) == 1, f"{rel}: rendered {len(found)} times"
    return found[0]


def test_every_figure_of_the_suite_is_rendered(rendered: tuple[Path, list[tuple[Path, Figure]]]) -> None:
    root, record = rendered
    names = {p.name for p, _ in record}
    assert CORE_FIGURES <= names
    # one observed figure per PNG file written, and nothing written without being observed
    assert sorted(p for p, _ in record) == sorted(p for p in root.rglob("*.png"))


def test_figures_label_units_and_keep_peaks_visible(rendered: tuple[Path, list[tuple[Path, Figure]]]) -> None:
    _, record = rendered
    problems = [f"{path.parent.name}/{path.name}: {p}" for path, fig in record for p in figure_problems(fig)]
    assert not problems, "\n".join(problems)


def test_png_files_are_valid_and_not_blank(rendered: tuple[Path, list[tuple[Path, Figure]]]) -> None:
    _, record = rendered
    problems = [p for path, _ in record for p in png_problems(path)]
    assert not problems, "\n".join(problems)


def test_receptance_peaks_are_marked_and_labelled_in_hz(rendered: tuple[Path, list[tuple[Path, Figure]]]) -> None:
    import json

    root, record = rendered
    peaks = json.loads((root / "receptance" / "summary.json").read_text())["peaks_hz"]
    assert len(peaks) >= 2
    fig = _figure(record, "receptance/receptance.png")
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.texts]
    assert labels == [f"{p:.1f} Hz" for p in peaks]
    markers = [ln for ln in ax.get_lines() if ln.get_label() == "peaks of |H11|"]
    assert len(markers) == 1 and np.allclose(markers[0].get_xdata(), peaks)
    # each label sits next to its marker (within 40 px) and inside the figure
    fbox = fig.bbox
    for t, p, y in zip(ax.texts, markers[0].get_xdata(), markers[0].get_ydata(), strict=True):
        bx = t.get_window_extent()
        mx, my = ax.transData.transform((p, y))
        assert abs(bx.x0 - mx) < 40 and abs(bx.y0 - my) < 40
        assert fbox.x0 <= bx.x0 and bx.x1 <= fbox.x1 and bx.y1 <= fbox.y1


def test_wheel_loads_one_panel_per_wheel(rendered: tuple[Path, list[tuple[Path, Figure]]]) -> None:
    import json

    root, record = rendered
    n = json.loads((root / "vehicle" / "summary.json").read_text())["settings"]["n_wheels"]
    check_wheel_panels(_figure(record, "vehicle/wheel_loads.png"), n)


def check_wheel_panels(fig: Figure, expect: int) -> None:
    """One panel per wheel (``expect`` wheels), one load curve each, one load scale and one time axis."""
    panels = [ax for ax in fig.axes if ax.get_ylabel().startswith("wheel ") and "[kN]" in ax.get_ylabel()]
    assert [ax.get_ylabel().split("\n")[0] for ax in panels] == [f"wheel {i}" for i in range(expect)]
    assert all(len([ln for ln in ax.get_lines() if ln.get_label() == "wheel load"]) == 1 for ax in panels)
    assert len({ax.get_ylim() for ax in panels}) == 1 and len({ax.get_xlim() for ax in panels}) == 1


def test_many_wheels_are_spread_over_eight_panels(tmp_path: Path) -> None:
    """Twelve wheels: eight panels, first and last wheel included, the title says which."""
    t = np.linspace(0.0, 1.0, 400)
    W = 12
    loads = 80e3 + 10e3 * np.sin(2 * np.pi * (3 + np.arange(W))[None, :] * t[:, None])
    force = 30e3 * np.exp(-(((np.arange(30)[None, :] - 30 * t[:, None]) / 2.0) ** 2))
    x = 0.6 * np.arange(30.0)
    figs: dict[str, Figure] = {}

    def observe(fig: Figure, path: Path) -> None:
        figs[path.name] = fig

    plots.figure_observers.append(observe)
    try:
        written = plots.plot_demo(tmp_path, t, force, 100, t[200], x, force[200] / 30e6, force[200], t, loads)
    finally:
        plots.figure_observers.remove(observe)
    assert {p.name for p in written} == DEMO_FIGURES == set(figs)
    fig = figs["wheel_loads.png"]
    panels = [ax.get_ylabel().split("\n")[0] for ax in fig.axes]
    assert len(panels) == plots.MAX_WHEEL_PANELS == 8
    assert panels[0] == "wheel 0" and panels[-1] == f"wheel {W - 1}" and len(set(panels)) == 8
    assert f"of {W})" in fig.get_suptitle()


def test_chain_closed_forms_stay_visible_on_the_chain_curves(
    rendered: tuple[Path, list[tuple[Path, Figure]]],
) -> None:
    _, record = rendered
    fig = _figure(record, "chain/chain.png")
    for ax in fig.axes[:2]:
        lines = {ln.get_label(): ln for ln in ax.get_lines()}
        for chain, eq in (("chain: F / sum X_j", "Eq. (16)"), ("chain: F / sum (-1)^j X_j", "Eq. (18)")):
            c, m = lines[chain], lines[eq]
            # the curves coincide to within a line width (1 % of the axis range): the closed form needs its own look
            lo, hi = ax.get_ylim()
            assert np.max(np.abs(np.asarray(m.get_ydata()) - np.asarray(c.get_ydata()))) < 0.01 * (hi - lo)
            assert m.get_linestyle() != "-" and m.get_marker() not in ("None", "", None)
            assert m.get_markevery() is not None and m.get_zorder() > c.get_zorder()
            assert c.get_linewidth() > 2 * m.get_linewidth()
            # markers every few points: more than 5, fewer than a third of the points
            every = m.get_markevery()
            assert isinstance(every, tuple)
            n_marks = len(range(every[0], len(m.get_xdata()), every[1]))
            assert 5 < n_marks < len(m.get_xdata()) / 3


def test_a_legend_on_a_peak_is_moved(tmp_path: Path) -> None:
    """The legend asked for the upper right corner, where the curve peaks: it must move."""
    x = np.linspace(0.0, 10.0, 500)
    with _base.style():
        fig, axs = _base.new_figure(1, 1, (6.0, 4.0))
        ax = axs[0, 0]
        ax.plot(x, np.exp(-((x - 9.5) ** 2)), label="peak at the right")
        ax.plot(x, 0.2 * np.exp(-((x - 1.0) ** 2)), label="small bump at the left")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [N]")
        leg = _base.legend(ax, "upper right")
        fig.draw_without_rendering()
        b = leg.get_window_extent()
        assert any(b.x0 <= px <= b.x1 and b.y0 <= py <= b.y1 for _, px, py in curve_extremes(fig))
        _base.save(fig, tmp_path / "moved.png")
    assert figure_problems(fig) == []
    assert png_problems(tmp_path / "moved.png") == []


def test_html_index_links_every_figure_and_summary(rendered: tuple[Path, list[tuple[Path, Figure]]]) -> None:
    root, _ = rendered
    page = write_index(root, title="test run")
    text = page.read_text()
    hrefs = set(re.findall(r'href="([^"]+)"', text))
    srcs = set(re.findall(r'<img src="([^"]+)"', text))
    pngs = {p.relative_to(root).as_posix() for p in root.rglob("*.png")}
    summaries = {p.relative_to(root).as_posix() for p in root.rglob("summary.json")}
    assert pngs and srcs == pngs and pngs <= hrefs and summaries <= hrefs
    for link in hrefs:
        if link.startswith("#"):
            continue
        assert not link.startswith("/") and "://" not in link
        assert (root / link).exists(), link
    # a bag is one link, not its files; summary values are shown
    assert "impact_bag/" in hrefs and not any(h.startswith("impact_bag/") and h != "impact_bag/" for h in hrefs)
    assert "peak_sleeper_soil_force_N" in text and "<title>test run</title>" in text


def test_clm_report_writes_its_html_index(tmp_path: Path) -> None:
    out = tmp_path / "report"
    assert main(["report", "--out", str(out)]) == 0
    text = (out / "index.html").read_text()
    pngs = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.png"))
    assert len(pngs) == len(list(out.glob("*/summary.json"))) > 20
    assert all(f'<img src="{p}"' in text for p in pngs)


def test_importing_the_core_never_imports_matplotlib() -> None:
    """Every clm_core module but the clm_core.outputs.plots package, imported in a fresh interpreter: no matplotlib."""
    code = textwrap.dedent(
        """
        import importlib, os, pkgutil, sys
        import clm_core

        def walk(path, prefix):  # like pkgutil.walk_packages, without importing the packages
            for m in pkgutil.iter_modules([path]):
                yield prefix + m.name
                if m.ispkg:
                    yield from walk(os.path.join(path, m.name), prefix + m.name + ".")

        names = sorted(walk(clm_core.__path__[0], "clm_core."))
        assert "clm_core.outputs.plots" in names and len(names) > 50, names
        for name in names:
            if name != "clm_core.outputs.plots" and not name.startswith("clm_core.outputs.plots."):
                importlib.import_module(name)
        bad = sorted(m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib."))
        print(len(names), bad)
        sys.exit(1 if bad else 0)
        """
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert r.returncode == 0, r.stdout + r.stderr


def test_drawing_leaves_the_users_backend_and_pyplot_alone(tmp_path: Path) -> None:
    code = textwrap.dedent(
        f"""
        import sys
        import matplotlib
        matplotlib.use("svg")
        from clm_core.frequency import receptance
        from clm_core.outputs.plots import plot_receptance
        from clm_core.params import load_model
        from clm_core.track import assemble
        import numpy as np
        rec = receptance(assemble(load_model("mevergnies", "mevergnies", "clm"), 21), np.arange(1.0, 200.0, 2.0))
        plot_receptance(rec, {str(tmp_path / "r.png")!r})
        assert matplotlib.get_backend().lower() == "svg", matplotlib.get_backend()
        assert "matplotlib.pyplot" not in sys.modules
        """
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert r.returncode == 0, r.stdout + r.stderr
    assert png_problems(tmp_path / "r.png") == []


# ----------------------------------------------------------------------------- report-grade outputs (issue 23)


def _peak_lines(fig: Figure) -> list[str]:
    return [str(ln.get_label()) for ln in fig.axes[0].get_lines() if str(ln.get_label()).endswith(", peak")]


@pytest.mark.parametrize("run", ["simulate", "vehicle"])
def test_the_peak_sleeper_is_plotted_and_marked_on_the_envelope(
    rendered: tuple[Path, list[tuple[Path, Figure]]], run: str,
) -> None:
    import json

    root, record = rendered
    s = json.loads((root / run / "summary.json").read_text())
    fig = _figure(record, f"{run}/soil_forces.png")
    g = s["envelope_peak_sleeper_index"]
    # the peak sleeper's history is among those drawn, and it reaches the envelope's peak (recorded instants)
    assert len(_peak_lines(fig)) == 1 and _peak_lines(fig)[0].startswith(f"sleeper {g} ")
    line = next(ln for ln in fig.axes[0].get_lines() if str(ln.get_label()).endswith(", peak"))
    assert np.nanmax(np.asarray(line.get_ydata(), float)) <= s["envelope_peak_soil_force_N"] / 1e3 + 1e-9
    # the envelope's marker sits at the reported peak
    marker = next(ln for ln in fig.axes[1].get_lines() if str(ln.get_label()).startswith("peak: sleeper"))
    assert np.asarray(marker.get_ydata(), float)[0] == pytest.approx(s["envelope_peak_soil_force_N"] / 1e3)
    assert s["envelope_peak_soil_force_N"] == pytest.approx(s["peak_sleeper_soil_force_N"], rel=1e-12)
    assert s["envelope_peak_sleeper_index"] == s["peak_sleeper_index"]
    # tensile forces are flagged in the figure when there are any
    title = fig.axes[1].get_title()
    assert ("NOTE: tensile" in title) == (s["tensile_sleepers"] > 0)
    assert (s["envelope_min_soil_force_N"] < 0) == (s["tensile_sleepers"] > 0)


def test_wheel_loads_show_the_static_load_and_the_dynamic_factor(
    rendered: tuple[Path, list[tuple[Path, Figure]]],
) -> None:
    import json

    root, record = rendered
    s = json.loads((root / "vehicle" / "summary.json").read_text())
    fig = _figure(record, "vehicle/wheel_loads.png")
    panels = [ax for ax in fig.axes if ax.get_ylabel().startswith("wheel ") and "[kN]" in ax.get_ylabel()]
    for i, ax in enumerate(panels):
        static = [ln for ln in ax.get_lines() if ln.get_label() == "static wheel load"]
        assert len(static) == 1 and np.asarray(static[0].get_ydata(), float)[0] == pytest.approx(
            s["wheel_load_static_N"][i] / 1e3)
        load = next(ln for ln in ax.get_lines() if ln.get_label() == "wheel load")
        df = float(re.search(r"dynamic factor max/static ([0-9.]+)", ax.get_title("right")).group(1))  # type: ignore[union-attr]
        assert df == pytest.approx(np.nanmax(np.asarray(load.get_ydata(), float)) / (s["wheel_load_static_N"][i] / 1e3),
                                   abs=6e-4)
    # the summary names the dynamic part and keeps the rms of the load apart
    assert 0 < s["wheel_load_dynamic_std_N"] < 0.2 * s["rms_wheel_load_N"]
    static = s["wheel_load_static_N"]
    assert max(static) - min(static) < 1e-9 * max(static)  # one static load: the factor is the peak over it
    assert s["dynamic_factor"] == pytest.approx(s["peak_wheel_load_N"] / static[0], rel=1e-12)


def test_spectra_and_bands_have_units_and_the_ground_vibration_band(
    rendered: tuple[Path, list[tuple[Path, Figure]]],
) -> None:
    _, record = rendered
    fig = _figure(record, "vehicle/spectra.png")
    left = [ax for ax in fig.axes if ax.get_xlim() == (0.0, 80.0)]
    assert [ax.get_ylabel().split("\n")[0] for ax in left] == ["wheel load", "soil force", "rail deflection"]
    assert [ax.get_ylabel().split("[")[1] for ax in left] == ["kN]", "kN]", "mm]"]
    bands = _figure(record, "vehicle/third_octave.png")
    for ax in bands.axes:
        assert "band rms [" in ax.get_ylabel() and "centre frequency [Hz]" in ax.get_xlabel()
        labels = [t.get_text() for t in ax.get_xticklabels()]
        assert labels[:4] == ["1", "2", "4", "8"] and "63" in labels  # nominal centres, every third band


def test_the_report_page_has_headlines_with_units_and_captioned_figures(
    rendered: tuple[Path, list[tuple[Path, Figure]]],
) -> None:
    import json

    from clm_core.outputs.report_index import CAPTIONS

    root, _ = rendered
    text = (root / "vehicle" / "index.html").read_text()
    s = json.loads((root / "vehicle" / "summary.json").read_text())
    row = re.search(r"<tr><td>Dynamic part of the wheel load \(std about the static load\)</td>"
                    r'<td class="v">([^<]+)</td><td>kN</td><td class="k">wheel_load_dynamic_std_N</td></tr>', text)
    assert row is not None and float(row.group(1)) == pytest.approx(s["wheel_load_dynamic_std_N"] / 1e3, rel=1e-3)
    assert re.search(r"<td>Peak sleeper soil force \(ballast on soil\)</td><td class=\"v\">[0-9.]+</td><td>kN</td>",
                     text)
    for name in ("wheel_loads.png", "soil_forces.png", "spectra.png", "third_octave.png"):
        assert f'<img src="{name}"' in text
        assert f"<figcaption><b>{name}</b>: {CAPTIONS[name]}" in text.replace("&#x27;", "'")
    # the figures come before the data files, and CSV files are not written by default
    assert text.index("<figure>") < text.index("data: ")
    assert not (root / "vehicle" / "sleepers.csv").exists() and (root / "vehicle" / "peaks.csv").exists()


def test_screenshot_of_the_report_in_headless_chromium(
    rendered: tuple[Path, list[tuple[Path, Figure]]], tmp_path: Path,
) -> None:
    import shutil

    if not (shutil.which("chromium") or shutil.which("chromium-browser")):
        pytest.skip("chromium is not installed (Debian package chromium): the report's screenshot is not taken")
    root, _ = rendered
    shot = tmp_path / "report.png"
    r = subprocess.run(["bash", str(REPO / "scripts" / "screenshot-report.sh"), str(root / "vehicle"), str(shot),
                        "1200x1800"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    from matplotlib.image import imread

    img = imread(shot)[..., :3]
    assert img.shape[:2] == (1800, 1200) and png_problems(shot) == []
    # the page shows the figures, not only text: a share of coloured (non-grey) pixels as in the PNG figures
    colour = np.ptp(img, axis=2) > 0.15
    assert colour.mean() > 0.002
    r = subprocess.run(["bash", str(REPO / "scripts" / "screenshot-report.sh"), str(tmp_path / "none")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "no " in r.stderr and "index.html" in r.stderr


def test_demo_report_marks_the_peak_over_the_admitted_sleepers(tmp_path: Path) -> None:
    """plot_demo with the launcher's admitted sleepers marks the summary's peak sleeper, not a larger one outside."""
    t = np.linspace(0.0, 1.0, 500)
    x = 0.6 * np.arange(30.0)
    force = 30e3 * np.exp(-(((np.arange(30)[None, :] - 30 * t[:, None]) / 2.0) ** 2))
    force[:, 2] *= 2.0  # the largest force, at a sleeper outside the admitted ones
    loads = np.full((500, 2), 80e3) + 5e3 * np.sin(2 * np.pi * 40 * t)[:, None]
    admitted = np.zeros(30, bool)
    admitted[5:25] = True
    figs: dict[str, Figure] = {}
    plots.figure_observers.append(lambda fig, path: figs.__setitem__(path.name, fig))
    try:
        plots.plot_demo(tmp_path, t, force, 100, t[200], x, force[200] / 30e6, force[200], t, loads,
                        static_wheel_load=np.array([80e3, 80e3]), speed=30.0, admitted_sleepers=admitted)
    finally:
        plots.figure_observers.pop()
    fig = figs["soil_forces.png"]
    marker = next(ln for ln in fig.axes[1].get_lines() if str(ln.get_label()).startswith("peak: sleeper"))
    g = int(str(marker.get_label()).split()[2].rstrip(","))
    assert 105 <= g < 125 and np.asarray(marker.get_ydata(), float)[0] == pytest.approx(
        np.nanmax(force[:, 5:25]) / 1e3)
    assert _peak_lines(fig) and _peak_lines(fig)[0].startswith(f"sleeper {g} ")
    assert all(not figure_problems(f) for f in figs.values())
