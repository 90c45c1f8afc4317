"""``clm simulate`` outputs sized for their use (issue 23 item 5): NPZ by default, CSV on request, a progress bar on
the writing phase, both real-time factors named, and a report page in the output folder."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from clm_core.outputs.history import load_history, read_wheels_csv
from tests.clitools import CLM, run_clm, run_in_pty


def test_npz_by_default_csv_on_request_with_the_same_numbers(tmp_path: Path) -> None:
    args = ["simulate", "--load", "100e3", "--axles", "0,2.5", "--speed", "30", "--duration", "0.2", "--dt", "2e-4"]
    r = run_clm([*args, "--out", str(tmp_path / "npz")])
    assert r.returncode == 0, r.stderr
    names = {p.name for p in (tmp_path / "npz").iterdir()}
    assert {"history.npz", "peaks.csv", "summary.json", "index.html", "simulate.png", "soil_forces.png",
            "spectra.png", "third_octave.png"} <= names
    assert not names & {"sleepers.csv", "wheels.csv"}
    r = run_clm([*args, "--csv", "--out", str(tmp_path / "csv")])
    assert r.returncode == 0, r.stderr
    h = load_history(tmp_path / "csv" / "history.npz")
    np.testing.assert_array_equal(h.soil_force, load_history(tmp_path / "npz" / "history.npz").soil_force)
    # the CSV holds the NPZ's numbers (to its printed digits)
    rows = np.loadtxt(tmp_path / "csv" / "sleepers.csv", delimiter=",", skiprows=1)
    k, n = h.soil_force.shape
    assert rows.shape == (k * n, 7)
    np.testing.assert_allclose(rows[:, 3].reshape(k, n), h.soil_force, rtol=1e-6, atol=1e-3)
    np.testing.assert_allclose(read_wheels_csv(tmp_path / "csv" / "wheels.csv")["P"], h.wheel_force, rtol=1e-8)
    # both real-time factors, named, in the summary and on the console
    s = json.loads((tmp_path / "npz" / "summary.json").read_text())
    assert s["real_time_factor_command"] <= s["real_time_factor"]
    assert s["command_wall_time_s"] >= s["stepping_wall_time_s"] + s["writing_wall_time_s"] - 1e-6
    assert s["real_time_factor_command"] == s["simulated_time_s"] / s["command_wall_time_s"]
    assert re.search(r"compute real-time factor [0-9.]+ \(simulated / stepping wall time\), command real-time factor "
                     r"[0-9.]+ \(simulated / wall time of clm simulate, writing included\)", r.stdout), r.stdout


def test_vehicle_run_names_the_dynamic_part_and_both_real_time_factors(tmp_path: Path) -> None:
    r = run_clm(["simulate", "--vehicle", "tram", "--speed", "20", "--duration", "0.3", "--start", "10",
                 "--irregularity", "fra5", "--out", str(tmp_path / "v")])
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "v" / "summary.json").read_text())
    m = re.search(r"dynamic part of the wheel load ([0-9.]+) (k?)N \(std about the static load\)", r.stdout)
    assert m is not None, r.stdout
    shown = float(m.group(1)) * (1e3 if m.group(2) else 1.0)
    assert shown == pytest.approx(s["wheel_load_dynamic_std_N"], rel=5e-4)
    assert "rms wheel load" not in r.stdout and "compute real-time factor" in r.stdout
    assert "command real-time factor" in r.stdout
    assert s["compute_wall_time_s"] <= s["command_wall_time_s"]
    names = {p.name for p in (tmp_path / "v").iterdir()}
    assert "sleepers.csv" not in names and {"vehicle_history.npz", "peaks.csv", "index.html"} <= names


def test_writing_phase_shows_progress_in_a_terminal(tmp_path: Path) -> None:
    code, text = run_in_pty([*CLM, "simulate", "--speed", "30", "--duration", "0.2", "--dt", "2e-4", "--csv",
                             "--out", str(tmp_path / "m")])
    assert code == 0, text
    assert re.search(r"clm simulate: writing: +\d+%\|", text), text
    code, text = run_in_pty([*CLM, "simulate", "--vehicle", "tram", "--speed", "20", "--duration", "0.2", "--start",
                             "10", "--out", str(tmp_path / "v")])
    assert code == 0, text
    assert re.search(r"clm simulate: writing: +\d+%\|", text), text
