"""``clm`` sub-commands of the ROS layer (discovered by :mod:`clm_core.cli`).

Modules here must not import rclpy at import time: ``clm --help`` stays fast
and works without a middleware.
"""
