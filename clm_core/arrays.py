"""The array types of the annotations, one definition for the package.

``Array``: float64 arrays (SI values); ``IntArray``: int64 arrays (indices,
counts, steps); ``CArray``: complex128 arrays (receptances, impedances,
spectra). Shapes and units are given where the arrays are used.
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

Array: TypeAlias = NDArray[np.float64]
IntArray: TypeAlias = NDArray[np.int64]
CArray: TypeAlias = NDArray[np.complex128]

__all__ = ["Array", "CArray", "IntArray"]
