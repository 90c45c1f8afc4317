"""Exceptions of the clm_ros package."""


class ClmRosError(Exception):
    """Raised when the ROS layer cannot do what was asked; the message says why and where."""
