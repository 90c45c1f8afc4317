#!/usr/bin/env python3
"""Regenerate the rigorous reference impact bag of bags/halfspace/ (deterministic: fixed seed).

    .venv/bin/python bags/halfspace/regenerate.py [--storage mcap|sqlite3] [--out DIR]

Writes ``impact_mevergnies_rigorous/``: the response of 41 contact areas
(0.6 m apart) on the Mevergnies half-space (paper Table 1 soil) to the Eq. (1)
pulse, from the rigorous half-space model (clm_core.halfspace), as a soil
impact test bag in the calibration-bag format, with ``channels.yaml`` and
``reference.yaml``. The same bag comes out of
``clm soil-calibrate --profile mevergnies --out DIR --impact-bag`` (in
``DIR/reference_impact_bag``). See README.md here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from clm_core.synthetic.reference import ReferenceImpactBag, rigorous_reference, write_reference_impact_bag
from clm_core.synthetic.shipped import regenerate

HERE = Path(__file__).resolve().parent


def impact_mevergnies_rigorous(path: Path, *, storage: Any) -> ReferenceImpactBag:
    """The shipped bag: the rigorous sweep and direct CLM fit, then the record written with noise."""
    reference = rigorous_reference(
        "mevergnies", n_areas=41, spacing=0.6, sweep_max=150.0, df=1.0, fmin=0.0, fmax=80.0, norm="ls"
    )
    return write_reference_impact_bag(
        path,
        reference=reference,
        storage=storage,
        quantity="velocity",
        fs=1000.0,
        amplitude=10e3,
        t0=0.2,
        td=0.001,
        shaping="gaussian",
        snr_db=30.0,
        seed=1,
    )


#: What is shipped: name -> the function writing it.
BAGS = {"impact_mevergnies_rigorous": impact_mevergnies_rigorous}


def main() -> int:
    return regenerate(__doc__ or "", HERE, BAGS)


if __name__ == "__main__":
    raise SystemExit(main())
