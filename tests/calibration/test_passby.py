"""Pass-by calibration: output-error fit through the time-domain engine, from clm_msgs bags.

The bag holds ``clm_msgs/msg/WheelLoads`` (a bogie at 25 m/s, 80 kN wheels
with a 9 Hz load fluctuation) and ``clm_msgs/msg/SleeperResponse`` (rail and
sleeper displacements of two instrumented sleepers, 30 dB noise), generated
by :class:`clm_core.solver.TrackSimulator` at dt = 0.1 ms; the fit runs the
same engine at 0.5 ms from another starting point.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clm_core.calibration import CalibrationError, calibrate
from clm_core.params import load_model
from clm_core.synthetic import simulate_passby, write_simulated_bag


@pytest.fixture(scope="module")
def passby_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("passby") / "passby"
    write_simulated_bag(simulate_passby, path, snr_db=30.0, seed=2, storage="mcap")
    return path


def test_passby_bag_uses_the_suites_messages(passby_bag: Path) -> None:
    meta = (passby_bag / "metadata.yaml").read_text()
    assert "clm_msgs/msg/WheelLoads" in meta and "clm_msgs/msg/SleeperResponse" in meta
    text = (passby_bag / "channels.yaml").read_text()
    assert "field: rail_deflection" in text and "loads:" in text


def test_passby_recovers_pad_and_ballast_stiffness(passby_bag: Path) -> None:
    truth = load_model("mevergnies", "mevergnies", "clm")
    res = calibrate(passby_bag, "passby", {"fit": ["kp", "kb"], "initial": {"kp": 80e6, "kb": 70e6}})
    assert res.method == "passby" and res.norm == "weighted"
    for p in res.parameters:
        true = getattr(truth.track, p.name)
        assert abs(p.value / true - 1) < 0.05, (p.name, p.value, true)
        assert p.contains(true), (p.name, p.ci_low, p.value, p.ci_high, true)
    assert 0.8 < res.stats.rms < 1.2
    assert res.time_model is not None and res.time_model.shape == res.recording.responses.shape
    assert np.isfinite(res.time_model).any()


def test_passby_needs_the_loads_topic(passby_bag: Path, tmp_path: Path) -> None:
    text = (passby_bag / "channels.yaml").read_text()
    bad = tmp_path / "map.yaml"
    bad.write_text(text.replace("loads:\n  topic: /clm/wheel_loads\n", ""))
    with pytest.raises(CalibrationError, match="no 'loads' entry"):
        calibrate(passby_bag, "passby", {"channels": str(bad)})
