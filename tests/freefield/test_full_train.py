"""A full train with receivers: the automatic window holds the 10-car Thalys at every alignment (issue 23 review)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clm_core.errors import ParameterError
from clm_core.params import load_model
from clm_core.vehicle.coupled import CoupledSimulation, window_size
from clm_core.vehicle.multibody import build_train
from clm_core.vehicle.presets import load_vehicle
from tests.clitools import run_clm


def test_automatic_window_holds_the_span_at_any_alignment() -> None:
    """The window's free zone holds the span plus one bay (wheels anywhere within a bay)."""
    for span in (0.0, 10.0, 99.5, 325.04, 325.99, 326.0):
        n = window_size(span)
        assert n - 1 - n // 3 - max(2, min(10, n // 6)) >= span + 1
        m = n - 2
        if m >= 61:  # the next smaller window would not
            assert m - 1 - m // 3 - max(2, min(10, m // 6)) < span + 1


@pytest.mark.parametrize("start", [0.0, 0.0083, 0.3, 0.5999])
def test_ten_car_thalys_runs_with_the_automatic_window(start: float) -> None:
    """The 10-car Thalys (wheelbase 195 m = 325.1 bays) starts at any position within a bay (was refused at 0.0083)."""
    params = load_model("mevergnies", "mevergnies", "clm")
    train = build_train(load_vehicle("thalys").cars(10))
    sim = CoupledSimulation(train, params, 83.33, 1e-4, x_start=start, duration_hint=0.003)
    res = sim.run(0.003)
    assert sim.n_sleepers == window_size(train.wheelbase / params.track.spacing)
    assert np.all(np.isfinite(res.wheel_load)) and res.wheel_load.shape[1] == train.n_wheels
    too_small = sim.n_sleepers - 2
    with pytest.raises(ParameterError, match=f"use at least {sim.n_sleepers}"):
        CoupledSimulation(train, params, 83.33, 1e-4, x_start=start, n_sleepers=too_small)


def test_simulate_ten_car_thalys_with_receivers(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = run_clm(["simulate", "--vehicle", "thalys", "--cars", "10", "--duration", "0.3", "--out", str(out),
                 "--receivers", "8,16"])
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert [q["y_m"] for q in s["receivers"]["receivers"]] == [8.0, 16.0]
    assert all(q["ppv_mm_per_s"] > 0 for q in s["receivers"]["receivers"])
