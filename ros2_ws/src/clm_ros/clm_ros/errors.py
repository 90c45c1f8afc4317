"""Exceptions of the clm_ros package."""

from clm_core.errors import ClmError


class ClmRosError(ClmError):
    """Raised when the ROS layer cannot do what was asked; the message says why and where.

    A :class:`clm_core.errors.ClmError`, so the ``clm`` command prints it as one
    line and exits with code 2.
    """
