"""Generators of sample and test bags with known contents (above calibration and halfspace).

- :mod:`clm_core.synthetic.records`: synthetic impact, receptance and pass-by
  records from known parameters, and sensor noise (was
  ``clm_core.calibration.synthetic``, first half);
- :mod:`clm_core.synthetic.writer`: those records written as calibration bags
  with their channel map and truth (second half);
- :mod:`clm_core.synthetic.reference`: soil impact bags from the rigorous
  half-space reference (was ``clm_core.halfspace.impact_bag``).

Every bag is written by the one writer, :class:`clm_core.io.bags.BagWriter`.
Submodules are imported on use (the rigorous reference pulls in the
half-space solvers).
"""

from clm_core.synthetic.records import (
    SyntheticRecord,
    add_noise,
    hammer_pulse,
    simulate_impact,
    simulate_passby,
    simulate_receptance,
)
from clm_core.synthetic.writer import (
    T0_NS,
    SyntheticBag,
    channel_map_for,
    write_bag,
    write_simulated_bag,
)

__all__ = [
    "T0_NS",
    "SyntheticBag",
    "SyntheticRecord",
    "add_noise",
    "channel_map_for",
    "hammer_pulse",
    "simulate_impact",
    "simulate_passby",
    "simulate_receptance",
    "write_bag",
    "write_simulated_bag",
]
