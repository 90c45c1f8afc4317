"""Exception types of the calibration subpackage.

Both derive from :class:`clm_core.errors.InputError` (bad run-time input), so
the ``clm`` command prints them as one line and exits with code 2. Every
message says what was wrong, with which value, and which rule it broke.
"""

from __future__ import annotations

from clm_core.errors import InputError


class CalibrationError(InputError):
    """The data cannot be fitted as asked.

    Raised for bad options (unknown norm, empty band), an unusable channel
    map (unknown unit or quantity, duplicate channel), records that are too
    short for the band, or a fit that cannot start (no first estimate).
    """


class BagError(InputError):
    """A bag cannot be read or holds unusable records.

    Raised for missing, truncated or corrupt bag files, missing topics,
    messages without the expected field, clipped records (flat tops at the
    sensor limit) and inconsistent sampling (jittered or gappy stamps).
    The message names the bag path or the topic and the offending value.
    """
