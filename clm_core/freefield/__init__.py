"""Free-field ground vibration at receivers from the sleeper soil forces (two-step method).

Step 1 is the CLM track model (:mod:`clm_core.solver`, the ballast forces on
the sleepers' contact areas); step 2 (this package) propagates them through
the layered half-space (:mod:`clm_core.halfspace.green`) to surface
receivers: transfer functions per (area, receiver), causal FIR filters
(:mod:`.model`), offline and streaming convolution (:mod:`.convolve`), PPV,
KB_F,max (DIN 4150-2) and one-third-octave levels (:mod:`.metrics`).
Independent references for the validation are in :mod:`.reference`.
See ``docs/freefield.md``.
"""

from clm_core.freefield.api import FreeFieldResult, free_field
from clm_core.freefield.convolve import ReceiverStream, VelocityRecord, receiver_velocity, zone_forces
from clm_core.freefield.metrics import VibrationMeasures, kb_f, measures, third_octave_levels
from clm_core.freefield.model import FreeFieldModel, receivers_from_distances

__all__ = [
    "FreeFieldModel",
    "FreeFieldResult",
    "ReceiverStream",
    "VelocityRecord",
    "VibrationMeasures",
    "free_field",
    "kb_f",
    "measures",
    "receiver_velocity",
    "receivers_from_distances",
    "third_octave_levels",
    "zone_forces",
]
