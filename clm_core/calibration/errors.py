"""Exception types of the calibration subpackage.

Both derive from :class:`clm_core.errors.InputError` (bad run-time input), so
the ``clm`` command prints them as one line and exits with code 2. Every
message says what was wrong, with which value, and which rule it broke.
:class:`BagError` is the one bag error of :mod:`clm_core.io.errors`: the bag
reader raises it for the calibration as for every other tool.
"""

from __future__ import annotations

from clm_core.errors import InputError
from clm_core.io.errors import BagError

__all__ = ["BagError", "CalibrationError"]


class CalibrationError(InputError):
    """The data cannot be fitted as asked.

    Raised for bad options (unknown norm, empty band), an unusable channel
    map (unknown unit or quantity, duplicate channel), records that are too
    short for the band, or a fit that cannot start (no first estimate).
    """
