"""clm_ros.launcher (``clm demo``): its defaults are the schema's, its plots pass the report rules.

The core side of both checks is in tests/test_settings.py (demo.yaml) and
tests/outputs/test_plots.py (every figure of clm_core.outputs.plots); the launcher
lives in clm_ros, hence here. The demo plots are drawn from the shipped demo
bag by :func:`clm_ros.launcher.analyse_bag`, no DDS involved.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from clm_ros.launcher import analyse_bag
from clm_ros.parameters import lookup
from clm_ros.run_settings import NAMES, RunSettings
from matplotlib.figure import Figure

from clm_core.errors import ParameterError
from clm_core.outputs import plots
from tests.outputs.figure_checks import figure_problems, png_problems
from tests.outputs.test_plots import DEMO_FIGURES, check_wheel_panels

REPO = Path(__file__).resolve().parents[2]
DEMO_BAG = REPO / "bags" / "demo" / "demo_bag"


def test_run_settings_defaults_are_the_schema_defaults() -> None:
    run = RunSettings()
    assert NAMES == ("vehicle", "speed", "duration", "track", "soil", "model", "rate", "dt", "n_sleepers",
                     "irregularity", "seed", "closed_loop", "storage", "domain_id", "realtime_priority")
    for name in NAMES:
        assert getattr(run, name) == lookup(name).default, name


def test_run_settings_are_checked_and_typed() -> None:
    assert RunSettings(speed=60, seed=3.0).speed == 60.0 and isinstance(RunSettings(speed=60).speed, float)
    assert isinstance(RunSettings(seed=3.0).seed, int)
    for kw, message in (({"speed": -5.0}, "speed = -5: must be 0 to 150 m/s"),
                        ({"model": "elastic"}, "model = 'elastic': must be one of"),
                        ({"domain_id": 300}, "domain_id = 300: must be 0 to 232")):
        with pytest.raises(ParameterError, match=message):
            RunSettings(**kw)


def test_run_settings_give_the_nodes_parameters() -> None:
    run = RunSettings(speed=44.4, seed=7, rate=500.0, duration=2.0, realtime_priority=3)
    assert run.messages == 1001
    assert run.track_parameters() == {"track": run.track, "soil": run.soil, "model": run.model, "dt": run.dt,
                                      "n_sleepers": run.n_sleepers, "diagnostics_period": 0.5,
                                      "realtime_priority": 3}
    v = run.vehicle_parameters(seed_offset=3, wait_for_subscribers=1)
    assert v["speed"] == 44.4 and v["seed"] == 10 and v["rate"] == 500.0 and v["wait_for_subscribers"] == 1
    assert v["trains"] == 1 and v["exit_when_done"] is False and v["realtime_priority"] == 3
    assert run.summary()["speed_m_per_s"] == 44.4 and run.summary()["rate_hz"] == 500.0
    assert run.summary()["realtime_priority"] == 3


@pytest.fixture(scope="module")
def demo_figures(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Figure]]:
    """The demo plots of the shipped demo bag: (output directory, {file name: figure})."""
    out = tmp_path_factory.mktemp("demo")
    record: list[tuple[Path, Figure]] = []

    def observe(fig: Figure, path: Path) -> None:
        record.append((path, fig))

    plots.figure_observers.append(observe)
    try:
        analyse_bag(DEMO_BAG, out)
    finally:
        plots.figure_observers.remove(observe)
    # one observed figure per PNG file written, and nothing written without being observed
    assert sorted(p for p, _ in record) == sorted(out.rglob("*.png"))
    return out, {p.name: fig for p, fig in record}


def test_demo_plots_follow_the_report_rules(demo_figures: tuple[Path, dict[str, Figure]]) -> None:
    out, figs = demo_figures
    assert set(figs) == DEMO_FIGURES
    problems = [f"{name}: {p}" for name, fig in figs.items() for p in figure_problems(fig)]
    problems += [f"{name}: {p}" for name in figs for p in png_problems(out / name)]
    assert not problems, "\n".join(problems)
    check_wheel_panels(figs["wheel_loads.png"], 4)


def test_soil_force_on_the_deflection_plot_has_its_own_axis_in_kn(
    demo_figures: tuple[Path, dict[str, Figure]],
) -> None:
    fig = demo_figures[1]["rail_deflection.png"]
    assert len(fig.axes) == 2
    host, twin = fig.axes
    assert np.allclose(host.get_position().bounds, twin.get_position().bounds)
    assert "[mm]" in host.get_ylabel() and "[kN]" in twin.get_ylabel()
    assert twin.yaxis.get_label_position() == "right"
    (force,) = twin.get_lines()
    (defl,) = host.get_lines()
    # unscaled: the soil force is in kN on its own axis (tens of kN), the deflection in mm
    assert 10.0 < np.nanmax(force.get_ydata()) < 100.0 and 0.3 < np.nanmax(defl.get_ydata()) < 5.0
    # zero of both axes at the same height (both drawn downwards, compression +)
    z_host = host.transData.transform((0.0, 0.0))[1]
    z_twin = twin.transData.transform((0.0, 0.0))[1]
    assert abs(z_host - z_twin) < 1.0 and host.yaxis_inverted() and twin.yaxis_inverted()


