"""The critical-speed figure of ``clm study``: speed in km/h with m/s above, every soil's shear-wave and Rayleigh
speed marked, the peak of each curve marked, a caption that says what was varied; it passes the suite's figure
checks (:mod:`tests.outputs.figure_checks`). And the Rayleigh speed it marks, against closed forms."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from matplotlib.figure import Figure

from clm_core.outputs import plots
from clm_core.outputs.plots.studies import KMH, plot_critical_speed, soil_wave_speeds
from clm_core.profile import Layer, load_profile
from tests.outputs.figure_checks import figure_problems, png_problems

ROOT = Path(__file__).resolve().parents[2]


def test_rayleigh_speed_against_closed_forms() -> None:
    # nu = 1/4 (c_p^2 = 3 c_s^2): x = 2 - 2/sqrt(3) exactly (Rayleigh 1885)
    layer = Layer(thickness=None, E=10.0e6, rho=1540.0, nu=0.25)
    assert layer.cr / layer.cs == pytest.approx(math.sqrt(2.0 - 2.0 / math.sqrt(3.0)), rel=1e-12)
    # tabulated roots (e.g. Graff, Wave Motion in Elastic Solids, Fig. 6.7): nu = 0, 1/3, -> 1/2
    for nu, ratio in ((0.0, 0.87403), (1.0 / 3.0, 0.93252), (0.49999, 0.95531)):
        lay = Layer(thickness=None, E=50.0e6, rho=1800.0, nu=nu)
        assert lay.cr / lay.cs == pytest.approx(ratio, abs=2e-5), nu
        assert lay.cr < lay.cs  # slower than shear waves, always


def _rows(soils: list[str], peak_of: dict[str, float]) -> list[dict[str, Any]]:
    """Rows of a speed x soil x seed study; each soil's deflection peaks at ``peak_of[soil]`` m/s."""
    rng = np.random.default_rng(3)
    rows = []
    for v in np.linspace(10.0, 150.0, 15):
        for soil in soils:
            for seed in (1, 2, 3):
                defl = 1.0e-3 * (1.0 + np.exp(-(((v - peak_of[soil]) / 15.0) ** 2)))
                rows.append({"speed": float(v), "soil": soil, "seed": seed, "status": "ok",
                             "peak_sleeper_soil_force_N": 5.0e4 * (1.0 + v / 100.0) * (1.0 + 0.03 * rng.normal()),
                             "max_rail_deflection_m": defl * (1.0 + 0.01 * rng.normal())})
    rows.append({"speed": 50.0, "soil": "soft", "seed": 9, "status": "error", "peak_sleeper_soil_force_N": None,
                 "max_rail_deflection_m": None})
    return rows


@pytest.fixture
def drawn(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Figure, Path, list[dict[str, Any]]]:
    monkeypatch.chdir(tmp_path)
    data = yaml.safe_load((ROOT / "clm_core" / "presets" / "soils" / "soft.yaml").read_text())
    data["profile"]["layers"][0]["E"] = 40.0e6  # c_s = 102 m/s: inside the speed range
    Path("site.yaml").write_text(yaml.safe_dump(data))
    rows = _rows(["soft", "site.yaml", "stiff"], {"soft": 60.0, "site.yaml": 100.0, "stiff": 150.0})
    seen: list[Figure] = []
    plots.figure_observers.append(lambda fig, _p: seen.append(fig))
    try:
        path = plot_critical_speed(rows, ["speed", "soil", "seed"], tmp_path / "critical_speed.png", "test",
                                   {"vehicle": "thalys", "duration": 2.0})
    finally:
        plots.figure_observers.pop()
    assert path is not None and len(seen) == 1
    return seen[0], path, rows


def test_figure_passes_the_suites_checks(drawn: tuple[Figure, Path, list[dict[str, Any]]]) -> None:
    fig, path, _ = drawn
    assert figure_problems(fig) == []
    assert png_problems(path) == []


def test_speed_axes_in_kmh_and_ms(drawn: tuple[Figure, Path, list[dict[str, Any]]]) -> None:
    fig, _, _ = drawn
    ax1, ax2 = fig.axes[:2]
    assert ax2.get_xlabel() == "train speed [km/h]"
    top = [c for c in ax1.child_axes if "[m/s]" in c.xaxis.get_label().get_text()]
    assert len(top) == 1  # the secondary axis above, in m/s
    # the curves are drawn in km/h: the fastest run (150 m/s) at 540 km/h
    xs = np.concatenate([np.asarray(ln.get_xdata(), float) for ln in ax2.get_lines() if len(ln.get_xdata()) > 2])
    assert xs.max() == pytest.approx(150.0 * KMH)


def test_wave_speeds_and_peaks_are_marked(drawn: tuple[Figure, Path, list[dict[str, Any]]]) -> None:
    fig, _, rows = drawn
    ax1, ax2 = fig.axes[:2]
    vlines = {round(float(ln.get_xdata()[0]), 6): ln.get_linestyle() for ln in ax2.get_lines()
              if ln.get_transform() is not ax2.transData}
    for soil in ("soft", "site.yaml"):  # inside the range: a dashed c_s and a dotted c_R line each
        cs, cr = soil_wave_speeds(soil) or (0.0, 0.0)
        assert vlines[round(KMH * cs, 6)] == "--" and vlines[round(KMH * cr, 6)] == ":"
    cs_site = load_profile("site.yaml").layers[0].cs
    assert cs_site == pytest.approx(math.sqrt(40.0e6 / 2.5 / 1540.0))
    # the stiff soil's (441 m/s) lie beyond 150 m/s: named in the caption instead
    caption = fig.get_supxlabel()
    assert "c_s of stiff = 441 m/s (1589 km/h)" in caption.replace("\n", " ")
    assert "Varied: speed 10-150 m/s (15 values); soil (site.yaml, soft, stiff)" in caption.replace("\n", " ")
    assert "Fixed: vehicle = thalys, duration = 2.0 s" in caption.replace("\n", " ")
    # a star at the peak of every mean curve, at its largest value
    for ax, metric, scale in ((ax1, "peak_sleeper_soil_force_N", 1e-3), (ax2, "max_rail_deflection_m", 1e3)):
        stars = [ln for ln in ax.get_lines() if ln.get_marker() == "*" and len(ln.get_xdata()) == 1]
        assert len(stars) == 3
        for soil in ("soft", "site.yaml", "stiff"):
            ok = [r for r in rows if r["soil"] == soil and r["status"] == "ok"]
            speeds = sorted({r["speed"] for r in ok})
            mean = [np.mean([r[metric] for r in ok if r["speed"] == v]) * scale for v in speeds]
            k = int(np.argmax(mean))
            assert any(float(s.get_xdata()[0]) == pytest.approx(KMH * speeds[k])
                       and float(s.get_ydata()[0]) == pytest.approx(mean[k]) for s in stars), (soil, metric)
            if metric == "max_rail_deflection_m":  # the legend gives it, in km/h and m/s
                text = f"soil = {soil}: deflection peak {mean[k]:.3g} mm at {KMH * speeds[k]:.0f} km/h " \
                       f"({speeds[k]:.0f} m/s)"
                assert speeds[k] == {"soft": 60.0, "site.yaml": 100.0, "stiff": 150.0}[soil]
                labels = [t.get_text() for t in ax2.get_legend().get_texts()]
                assert text + (" (the fastest run)" if soil == "stiff" else "") in labels
