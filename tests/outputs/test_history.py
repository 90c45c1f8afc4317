"""History files (clm_core.outputs.history): one writer per format, one wheels.csv layout."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from clm_core.errors import InputError, ParameterError
from clm_core.outputs.history import (
    PEAKS_CSV_COLUMNS,
    SLEEPER_CSV_COLUMNS,
    HistoryRecorder,
    HistoryWriter,
    append_wheel_rows,
    load_history,
    read_vehicle_history,
    read_wheels_csv,
    wheels_csv_header,
    window_columns,
    write_coupled_history,
)
from clm_core.params import load_model
from clm_core.solver import TrackSimulator


@pytest.fixture(scope="module")
def mev():  # type: ignore[no-untyped-def]
    return load_model("mevergnies", "mevergnies", "clm")


def _moving_run(out: Path, params, csv: bool = True):  # type: ignore[no-untyped-def]
    """Two 100 kN loads at 30 m/s for 0.1 s through the writer and a recorder (the ``clm simulate`` path)."""
    d = params.track.spacing
    P0, F0 = np.array([6.0, 3.5]), np.array([100e3, 100e3])
    sim = TrackSimulator(params, 2e-4, 41, start_position=0.0, lead_sleepers=13)
    sim.initialize(P0, F0, t0=0.0, state="static")
    writer = HistoryWriter(out, 200, 41, 2, d, 2e-4, csv=csv)
    rec = HistoryRecorder(d)

    def both(b):  # type: ignore[no-untyped-def]
        writer(b)
        rec(b)

    both(sim.block())
    sim.advance(0.1, (P0 + 30.0 * 0.1, F0), callback=both, output_every=5)
    return writer.close(), rec.history()


def test_moving_load_files_one_layout(tmp_path: Path, mev) -> None:  # type: ignore[no-untyped-def]
    digest, h = _moving_run(tmp_path, mev)
    on_disk = load_history(tmp_path / "history.npz")
    np.testing.assert_array_equal(on_disk.t, h.t)
    np.testing.assert_array_equal(on_disk.soil_force, h.soil_force)
    assert digest.n_rows == h.t.size
    head = (tmp_path / "wheels.csv").read_text().splitlines()[0]
    assert head == wheels_csv_header(2)
    assert head.startswith("t_s,x0_m,P0_N,delta0_m,z0_m,w0_m,r0_m,v0_m_per_s,x1_m,P1_N")
    tab = read_wheels_csv(tmp_path / "wheels.csv")
    assert tab.n_wheels == 2
    np.testing.assert_allclose(tab.t, h.t, rtol=1e-9)
    np.testing.assert_allclose(tab["x"], h.wheel_position, rtol=1e-8)
    np.testing.assert_allclose(tab["P"], h.wheel_force, rtol=1e-8)
    np.testing.assert_allclose(tab["w"], h.wheel_deflection, rtol=1e-8)
    np.testing.assert_allclose(tab["v"], h.wheel_velocity, rtol=1e-8, atol=1e-12)
    # quantities a moving load does not have: no contact spring, axle or irregularity
    assert all(np.isnan(tab[s]).all() for s in ("delta", "z", "r"))
    # the running peaks of every sleeper, both sleeper files in their one layout
    sl = np.loadtxt(tmp_path / "sleepers.csv", delimiter=",", skiprows=1)
    assert (tmp_path / "sleepers.csv").read_text().splitlines()[0] == ",".join(SLEEPER_CSV_COLUMNS)
    assert sl.shape == (h.t.size * 41, 7) and np.isfinite(sl).all()
    pk = np.loadtxt(tmp_path / "peaks.csv", delimiter=",", skiprows=1)
    assert (tmp_path / "peaks.csv").read_text().splitlines()[0] == ",".join(PEAKS_CSV_COLUMNS)
    np.testing.assert_array_equal(pk[:, 0], h.peak_sleeper_index)
    np.testing.assert_allclose(pk[:, 2], h.peak_soil_force, rtol=1e-6)
    # the stored peaks bound every output row of each sleeper (they are taken at every step)
    for g, f in zip(h.peak_sleeper_index[::7], h.peak_soil_force[::7], strict=True):
        series = h.sleeper_series(int(g))
        assert np.nanmax(series, initial=-np.inf) <= f + 1e-9


def test_vehicle_files_share_the_layout(tmp_path: Path, mev) -> None:  # type: ignore[no-untyped-def]
    from clm_core.vehicle.coupled import CoupledSimulation
    from clm_core.vehicle.multibody import build_train
    from clm_core.vehicle.presets import load_vehicle

    train = build_train(load_vehicle("tram").cars(1))
    res = CoupledSimulation(train, mev, 20.0, 1e-4, x_start=15.0, snapshot_every=5, duration_hint=0.05).run(0.05)
    written = write_coupled_history(res, tmp_path)
    assert [p.name for p in written] == ["vehicle_history.npz", "peaks.csv", "wheels.csv", "sleepers.csv"]
    W = res.wheel_load.shape[1]
    assert (tmp_path / "wheels.csv").read_text().splitlines()[0] == wheels_csv_header(W)
    tab = read_wheels_csv(tmp_path / "wheels.csv")
    rows = np.arange(0, res.t.size, 5)
    np.testing.assert_allclose(tab.t, res.t[rows], rtol=1e-9, atol=1e-12)
    for sym, arr in (("x", res.wheel_position), ("P", res.wheel_load), ("delta", res.compression),
                     ("z", res.wheel_displacement), ("w", res.rail_deflection), ("r", res.irregularity)):
        np.testing.assert_allclose(tab[sym], arr[rows], rtol=1e-8, atol=1e-15, err_msg=sym)
    assert np.isnan(tab["v"]).all()
    # the columns keep their meaning: P is the Hertz contact force C_H delta^1.5 of the same row
    d = tab["delta"]
    ok = d > 0
    assert ok.mean() > 0.9
    hertz = np.broadcast_to(np.asarray(res.meta["hertz_constant"])[None, :], d.shape)
    np.testing.assert_allclose(tab["P"][ok], hertz[ok] * d[ok] ** 1.5, rtol=1e-6)
    assert (tmp_path / "sleepers.csv").read_text().splitlines()[0] == ",".join(SLEEPER_CSV_COLUMNS)
    sl = np.loadtxt(tmp_path / "sleepers.csv", delimiter=",", skiprows=1)
    assert np.isfinite(sl[:, :5]).all() and np.isnan(sl[:, 5:]).all()
    assert sl.shape[0] == np.isfinite(res.soil_force).sum()
    with np.load(tmp_path / "vehicle_history.npz") as z:
        np.testing.assert_array_equal(z["wheel_load"], res.wheel_load)
        assert json.loads(str(z["meta_json"]))["speed"] == pytest.approx(20.0)
    # the NPZ round trip: the window-relative sleeper fields expand back to the run's arrays, bit for bit
    back = read_vehicle_history(tmp_path / "vehicle_history.npz")
    for name in ("soil_force", "sleeper_rail_deflection"):
        np.testing.assert_array_equal(back[name], getattr(res, name))
    for name in ("t", "wheel_load", "compression", "t_out", "sleeper_index", "peak_soil_force"):
        np.testing.assert_array_equal(back[name], getattr(res, name))
    assert back["meta"]["speed"] == pytest.approx(20.0)
    compact = read_vehicle_history(tmp_path / "vehicle_history.npz", dense=False)
    assert compact["soil_force"].shape[1] < res.soil_force.shape[1] and compact["first_sleeper"].size == res.t_out.size


def test_window_columns_keep_every_finite_value() -> None:
    rng = np.random.default_rng(2)
    dense = np.full((30, 50), np.nan)
    for k in range(30):
        a = int(rng.integers(0, 45))
        w = int(rng.integers(1, 9))
        dense[k, a: a + w] = rng.normal(size=min(w, 50 - a))
    dense[7] = np.nan  # a row without values
    first, compact = window_columns(dense)
    spans = [np.flatnonzero(np.isfinite(r)) for r in dense if np.isfinite(r).any()]
    assert compact.shape == (30, max(int(c[-1] - c[0] + 1) for c in spans))
    for k in range(30):
        for j in range(compact.shape[1]):
            c = first[k] + j
            want = dense[k, c] if c < 50 else np.nan
            assert (np.isnan(want) and np.isnan(compact[k, j])) or want == compact[k, j]
    assert np.isfinite(compact).sum() == np.isfinite(dense).sum()
    with pytest.raises(InputError, match="shape"):
        window_columns(np.zeros(3))


def test_read_wheels_csv_reads_the_earlier_layouts(tmp_path: Path) -> None:
    old_moving = tmp_path / "old_moving.csv"
    old_moving.write_text("t_s,x1_m,F1_N,w1_m,v1_m_per_s,x2_m,F2_N,w2_m,v2_m_per_s\n"
                          "0,10,1e5,0.001,0,7.5,9e4,0.0009,0\n0.1,13,1.02e5,0.0011,0.01,10.5,9.8e4,0.001,-0.01\n")
    t = read_wheels_csv(old_moving)
    assert t.n_wheels == 2
    np.testing.assert_array_equal(t["P"], [[1e5, 9e4], [1.02e5, 9.8e4]])
    np.testing.assert_array_equal(t["x"][:, 1], [7.5, 10.5])
    assert np.isnan(t["delta"]).all()
    old_vehicle = tmp_path / "old_vehicle.csv"
    old_vehicle.write_text("t_s,x0_m,P0_N,delta0_m,z0_m,w0_m,r0_m\n0,20,83385,9.2e-05,0.0012,0.0011,0\n")
    t = read_wheels_csv(old_vehicle)
    assert t.n_wheels == 1 and t["P"][0, 0] == 83385 and math.isnan(float(t["v"][0, 0]))
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,x0_m,Q0_N\n0,1,2\n")
    with pytest.raises(InputError, match="'Q0_N'"):
        read_wheels_csv(bad)
    with (tmp_path / "x.csv").open("w") as fh, pytest.raises(InputError, match="unknown column symbol"):
        append_wheel_rows(fh, [0.0], 1, {"F": [[1.0]]})


def test_readers_refuse_missing_and_foreign_files(tmp_path: Path) -> None:
    from clm_core.outputs.history import read_wheels_csv

    (tmp_path / "rows.csv").write_text("t_s,x0_m\n0.0,abc\n", encoding="utf-8")
    (tmp_path / "pickled.npz").write_text("not an archive", encoding="utf-8")
    np.savez(tmp_path / "other.npz", t=np.zeros(3))
    np.save(tmp_path / "single.npy", np.zeros(3))
    with pytest.raises(InputError, match=re.escape("cannot read the wheels.csv")):
        read_wheels_csv(tmp_path / "none.csv")
    with pytest.raises(InputError, match=re.escape("a row of the wheels.csv is not 2 numbers")):
        read_wheels_csv(tmp_path / "rows.csv")
    for name, fragment in [("none.npz", "cannot read a history.npz"), ("pickled.npz", "cannot read a history.npz"),
                           ("other.npz", "not a history.npz: no array first_sleeper"),
                           ("single.npy", "not a history.npz (a single .npy array")]:
        with pytest.raises(InputError, match=re.escape(fragment)):
            load_history(tmp_path / name)


@pytest.mark.parametrize("n", [-1, 2.0, "2"])
def test_wheels_csv_header_refuses_a_bad_wheel_count(n: object) -> None:
    with pytest.raises(ParameterError, match=r"^n_wheels = .*: must be an integer >= 0$"):
        wheels_csv_header(n)  # type: ignore[arg-type]
    assert wheels_csv_header(0) == "t_s"
