"""What happened in one train of the vehicle node (or, summed, in its life): :class:`Counts`."""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field, fields

import numpy as np


@dataclass
class Counts:
    """What happened in one train (or, summed, in the node's life)."""

    published: int = 0
    answered: int = 0
    used: int = 0
    stale: int = 0
    after_end: int = 0
    unmatched: int = 0
    malformed: int = 0
    late: int = 0
    publish_failed: int = 0
    contact_lost_steps: int = 0
    model_cpu_s: float = 0.0
    model_messages: int = 0
    lags: array[float] = field(default_factory=lambda: array("d"))

    def __add__(self, other: Counts) -> Counts:
        out = Counts()
        for f in fields(self):
            if f.name != "lags":
                setattr(out, f.name, getattr(self, f.name) + getattr(other, f.name))
        return out

    def lag_figures(self) -> dict[str, float]:
        """Median, 99th percentile and maximum of the answer lags [s] (NaN without answers)."""
        if not self.lags:
            return {"lag_median_s": float("nan"), "lag_p99_s": float("nan"), "lag_max_s": float("nan")}
        a = np.frombuffer(self.lags, dtype=np.float64)
        return {"lag_median_s": float(np.median(a)), "lag_p99_s": float(np.percentile(a, 99)),
                "lag_max_s": float(a.max())}

    def model_us(self) -> float:
        """CPU time of the vehicle model per message [us]."""
        return 1e6 * self.model_cpu_s / self.model_messages if self.model_messages else float("nan")
