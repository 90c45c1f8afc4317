"""Streaming simulator: API contract, refusals, two-phase stepping, load tables, ``clm simulate``."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from clm_core.cli import main
from clm_core.errors import InputError, ParameterError, StabilityError
from clm_core.outputs.history import HistoryRecorder, load_history
from clm_core.params import ModelParams, SleeperOverride, load_model, save_params_file
from clm_core.solver import LoadTable, Snapshot, TrackSimulator

F0 = 100e3


@pytest.fixture(scope="module")
def mev() -> ModelParams:
    return load_model("mevergnies", "mevergnies", "clm")


def _same(a: Snapshot, b: Snapshot) -> bool:
    return a.t == b.t and all(
        np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True)
        for f in ("sleeper_index", "soil_force", "rail_deflection", "sleeper_displacement",
                  "area_displacement", "wheel_positions", "wheel_forces", "wheel_deflection", "wheel_velocity")
    )


@pytest.fixture
def running(mev: ModelParams) -> TrackSimulator:
    sim = TrackSimulator(mev, 2e-4, 31)
    sim.initialize([0.0, -2.5], [F0, F0])
    sim.advance(0.02, ([0.6, -1.9], [F0, F0]))
    return sim


# ------------------------------------------------------------------ refusals leave the state unchanged


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda s: s.step([0.61, -1.89], [F0, np.nan]), "force nan"),
        (lambda s: s.step([0.61, -1.89], [F0]), "one force per wheel"),
        (lambda s: s.step([[0.61, -1.89]], [[F0, F0]]), "1-D"),
        (lambda s: s.advance(0.03, ([0.9, -1.6], [F0, np.inf])), "must be finite"),
        (lambda s: s.advance(0.03, ([0.9], [F0])), "wheels at t_end"),
        (lambda s: s.advance(0.01, ([0.9, -1.6], [F0, F0])), "time going backwards"),
        (lambda s: s.advance(0.03, lambda t: ([0.6, -1.9], [F0, np.nan if t > 0.025 else F0])), "force nan"),
        (lambda s: s.advance(0.03, ([0.9, -40.0], [F0, F0])), "span"),  # longer than the window holds
        (lambda s: s.step([0.61, np.nan], [F0, 5e3]), "position NaN"),
        (lambda s: s.initialize([0.0], [F0], state="moving"), "state"),  # type: ignore[arg-type]
        (lambda s: s.finish_step([F0, F0]), "no pending step"),
    ],
)
def test_bad_input_is_refused_and_state_unchanged(running: TrackSimulator, call, match: str) -> None:  # type: ignore[no-untyped-def]
    before = running.snapshot()
    window = running.window
    with pytest.raises(InputError, match=match):
        call(running)
    assert _same(running.snapshot(), before)
    assert running.window == window
    # and it still steps normally afterwards
    running.advance(0.021, ([0.63, -1.87], [F0, F0]))
    assert running.t == pytest.approx(0.021)


def test_wheels_outside_a_fixed_window_are_refused(mev: ModelParams) -> None:
    sim = TrackSimulator(mev, 1e-4, 31, follow=False)  # sleepers -15..15, margin 5 -> wheels in [-6, 6] m
    assert sim.allowed_range() == pytest.approx((-6.0, 6.0))
    sim.initialize([5.0], [F0])
    before = sim.snapshot()
    with pytest.raises(InputError, match="outside the allowed part"):
        sim.advance(0.1, ([8.0], [F0]))  # would cross 6 m after 0.033 s: nothing is stepped
    assert _same(sim.snapshot(), before)
    with pytest.raises(InputError, match="outside the allowed part"):
        sim.initialize([-7.0], [F0])
    assert _same(sim.snapshot(), before)


def test_following_window_never_hits_the_edge(mev: ModelParams) -> None:
    """The window shifts (whole bays) before the foremost wheel comes within lead_sleepers of its front."""
    sim = TrackSimulator(mev, 1e-4, 31, lead_sleepers=10)
    sim.initialize([0.0, -3.0], [F0, F0])
    fronts = []

    def cb(b) -> None:  # type: ignore[no-untyped-def]
        last = (b.first_sleeper + 30) * sim.spacing
        fronts.append(np.min(last - np.max(b.wheel_positions, axis=1)))

    sim.advance(0.5, ([25.0, 22.0], [F0, F0]), callback=cb)
    assert min(fronts) >= 10 * sim.spacing - 1e-9
    assert sim.window[0] == int(np.ceil(25.0 / 0.6 - 20))


def test_unstable_parameter_set_refused_before_stepping(mev: ModelParams) -> None:
    """A per-sleeper d_c that makes C indefinite, even 1 km ahead of the start, is refused at construction."""
    bad = replace(mev, overrides=(SleeperOverride(tuple(range(1700, 1720)), {"dc": -400e3}),))
    with pytest.raises(StabilityError, match="not positive semi-definite"):
        TrackSimulator(bad, 1e-4, 31)
    bad_here = replace(mev, overrides=(SleeperOverride((0, 1, 2), {"dc": -400e3}),))
    with pytest.raises(StabilityError):
        TrackSimulator(bad_here, 1e-4, 31)
    with pytest.raises(ParameterError, match="kb"):
        TrackSimulator(replace(mev, overrides=(SleeperOverride((900,), {"kb": -1.0}),)), 1e-4, 31)
    for kwargs, match in (({"dt": 0.0}, "dt"), ({"dt": float("nan")}, "dt"),
                          ({"dt": 1e-4, "n_sleepers": 3}, "n_sleepers"),
                          ({"dt": 1e-4, "lead_sleepers": 1, "margin_sleepers": 3}, "lead_sleepers"),
                          ({"dt": 1e-4, "elements_per_bay": 1}, "elements_per_bay")):
        with pytest.raises(ParameterError, match=match):
            TrackSimulator(mev, **kwargs)  # type: ignore[arg-type]


# ------------------------------------------------------------------ two-phase step (vehicle coupling)


def test_begin_finish_step_equals_step_and_compliance_is_exact(mev: ModelParams) -> None:
    a = TrackSimulator(mev, 2e-4, 31)
    b = TrackSimulator(mev, 2e-4, 31)
    for s in (a, b):
        s.initialize([2.4, -0.1], [F0, 0.8 * F0])  # front wheel 0.6 m before the shift point (3 m)
    P = np.array([1.1 * F0, 0.7 * F0])
    x = np.array([2.77, 0.27])
    for k in range(60):  # crosses a window shift
        xk = x + 30 * 2e-4 * (k + 1)
        w_free, v_free, G = a.begin_step(xk)
        assert np.allclose(G, G.T, rtol=1e-10) and np.all(np.linalg.eigvalsh(G) > 0)
        a.finish_step(P)
        b.step(xk, P)
        sa = a.snapshot()
        np.testing.assert_allclose(sa.wheel_deflection, w_free + G @ P, rtol=1e-9)
        np.testing.assert_allclose(sa.wheel_velocity, v_free + (2 / 2e-4) * G @ P, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(a.snapshot().soil_force, b.snapshot().soil_force, rtol=1e-10, atol=1e-6)
    assert a.window == b.window == (-15 + 1, 31)  # one shift on the way


# ------------------------------------------------------------------ loads: callables, tables, files


def test_load_table_and_callable_and_tuple_agree(mev: ModelParams, tmp_path: Path) -> None:
    csv = tmp_path / "loads.csv"
    csv.write_text("# two wheels, constant speed, second wheel enters at 0.01 s\n"
                   "t,x1,F1,x2,F2\n0.0,0.0,100e3,,\n0.01,0.3,100e3,-2.2,50e3\n0.05,1.5,100e3,-1.0,50e3\n")
    table = LoadTable.read_csv(str(csv))
    assert table.n_wheels == 2
    P, F = table(np.array([0.0, 0.005, 0.01, 0.03]))
    assert np.isnan(P[1, 1]) and F[1, 1] == 0.0 and P[2, 1] == pytest.approx(-2.2)
    sims = [TrackSimulator(mev, 1e-3, 31) for _ in range(3)]
    for s in sims:
        s.initialize([0.0, np.nan], [F0, np.nan])
    sims[0].advance(0.05, table)
    sims[1].advance(0.01, table)
    sims[1].advance(0.05, lambda t: table(t))
    sims[2].advance(0.01, lambda t: table(t))
    sims[2].advance(0.05, ([1.5, -1.0], [F0, 50e3]))
    for s in sims[1:]:
        np.testing.assert_allclose(s.snapshot().soil_force, sims[0].snapshot().soil_force, rtol=1e-12, atol=1e-6)
    with pytest.raises(InputError, match="covers t"):
        sims[0].advance(0.06, table)
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x1,F1\n0.0,0,1\n0.0,1,1\n")
    with pytest.raises(InputError, match="increase strictly"):
        LoadTable.read_csv(str(bad))
    bad.write_text("t,x1,F1,x2\n0.0,0,1,2\n0.1,1,1,2\n")
    with pytest.raises(InputError, match="columns"):
        LoadTable.read_csv(str(bad))


def test_recorder_blocks_cover_every_output_step(mev: ModelParams) -> None:
    sim = TrackSimulator(mev, 1e-4, 31)
    sim.initialize([0.0], [F0])
    rec = HistoryRecorder(sim.spacing)
    sim.advance(0.1, ([3.0], [F0]), callback=rec, output_every=7)
    sim.advance(0.2, ([6.0], [F0]), callback=rec, output_every=7)
    h = rec.history()
    k = np.round(h.t / 1e-4).astype(int)
    np.testing.assert_array_equal(k, np.arange(7, 2001, 7))  # global step count, across calls and shifts
    assert len(np.unique(h.first_sleeper)) > 5
    np.testing.assert_allclose(h.wheel_position[:, 0], 30.0 * h.t, atol=1e-9)


# ------------------------------------------------------------------ command line


def test_cli_simulate_moving_loads(tmp_path: Path) -> None:
    out = tmp_path / "run"
    code = main(["simulate", "--track", "mevergnies", "--soil", "mevergnies", "--model", "clm",
                 "--load", "100e3", "--axles", "0,2.5", "--speed", "30", "--duration", "0.3",
                 "--dt", "2e-4", "--csv", "--out", str(out)])  # --csv: the CSV files are on request (issue 23)
    assert code == 0
    for name in ("history.npz", "sleepers.csv", "wheels.csv", "peaks.csv", "simulate.png", "summary.json"):
        assert (out / name).is_file(), name
    s = json.loads((out / "summary.json").read_text())
    assert 30e3 < s["peak_sleeper_soil_force_N"] < 60e3
    assert 1e-3 < s["max_rail_deflection_m"] < 2e-3
    assert s["real_time_factor"] > 0
    h = load_history(out / "history.npz")
    assert h.t[0] == 0.0 and h.t[-1] == pytest.approx(0.3)
    assert h.wheel_position.shape[1] == 2
    # the summary's peak is the largest running peak over the sleepers both loads have passed
    passed = (h.peak_sleeper_index * 0.6 >= 3.0) & (h.peak_sleeper_index * 0.6 <= 9.0 - 2.5 - 3.0)
    assert s["peak_sleeper_soil_force_N"] == pytest.approx(h.peak_soil_force[passed].max())
    header = (out / "sleepers.csv").read_text().splitlines()[0]
    assert header.startswith("t_s,sleeper_index,x_m,soil_force_N")


def test_cli_simulate_params_file_and_loads_file(tmp_path: Path, mev: ModelParams, capsys) -> None:  # type: ignore[no-untyped-def]
    pf = tmp_path / "p.yaml"
    save_params_file(replace(mev, overrides=(SleeperOverride((5,), {"kb": 4.7e6}),)), pf)
    lf = tmp_path / "loads.csv"
    lf.write_text("t,x1,F1\n0.0,0.0,80e3\n0.2,6.0,120e3\n")
    out = tmp_path / "run2"
    assert main(["simulate", "--params", str(pf), "--set", "kp=150e6", "--loads-file", str(lf),
                 "--dt", "5e-4", "--sleepers", "41", "--no-csv", "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["window_sleepers"] == 41 and s["n_overrides"] == 1 and s["factorisations"] > 1
    assert not (out / "sleepers.csv").exists()
    # a bad time step is one readable error line, exit code 2
    assert main(["simulate", "--dt", "-1", "--out", str(tmp_path / "x")]) == 2
    assert "--dt" in capsys.readouterr().err
