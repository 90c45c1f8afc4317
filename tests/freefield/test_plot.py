"""receivers.png passes the report rules (tests/outputs/figure_checks.py, applied by tests/conftest.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clm_core.freefield import FreeFieldResult, measures, receiver_velocity
from clm_core.freefield.model import FreeFieldModel
from clm_core.outputs.plots.receivers import plot_receivers
from clm_core.synthetic.window import moving_window_forces


def test_receivers_png(small_model: FreeFieldModel, tmp_path: Path) -> None:
    t, first, F = moving_window_forces(1500, small_model.dt)
    rec = receiver_velocity(small_model, t, first, F)
    res = FreeFieldResult(receivers=small_model.receivers, t=rec.t, velocity=rec.velocity,
                          measures=measures(rec.velocity, small_model.model_dt), model=small_model)
    path = tmp_path / "receivers.png"
    plot_receivers(res, path)
    assert path.stat().st_size > 10_000
    assert np.all(res.measures.ppv_mm_s > 0)
