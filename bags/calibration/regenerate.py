#!/usr/bin/env python3
"""Regenerate the shipped calibration bags of bags/calibration/ (deterministic: fixed seeds).

    .venv/bin/python bags/calibration/regenerate.py [--storage mcap|sqlite3] [--out DIR]

Writes ``impact_mevergnies/`` (soil impact test, 41 areas, Mevergnies CLM soil
of Table 1) and ``receptance_mevergnies/`` (hammer on the rail, Mevergnies
track of Table 2 on that soil), each a rosbag2 directory with its
``channels.yaml`` and ``truth.yaml``. See README.md here and docs/calibration.md.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

from clm_core.synthetic import simulate_impact, simulate_receptance, write_simulated_bag
from clm_core.synthetic.shipped import regenerate

HERE = Path(__file__).resolve().parent

#: What is shipped: name -> writer with its keyword arguments (called with the directory and ``storage``).
BAGS = {
    "impact_mevergnies": partial(
        write_simulated_bag,
        simulate_impact,
        n_areas=41, quantity="velocity", fs=1000.0, duration=1.0, hit_times=(0.2,), pulse="half-sine",
        pulse_duration=0.003, amplitude=10e3, snr_db=30.0, seed=1,
    ),
    "receptance_mevergnies": partial(
        write_simulated_bag,
        simulate_receptance,
        n_sleepers=41, rail_sleepers=(0, 1, 2, 3, 4), sleeper_sleepers=(0,), quantity="acceleration",
        fs=2000.0, duration=0.6, hit_times=(0.1,), pulse="half-sine", pulse_duration=0.0008, amplitude=20e3,
        snr_db=30.0, seed=1,
    ),
}


def main() -> int:
    return regenerate(__doc__ or "", HERE, BAGS)


if __name__ == "__main__":
    raise SystemExit(main())
