"""``clm`` sub-commands of the ROS layer.

Registered with the core's ``clm`` command through the entry-point group
``clm.commands`` (setup.py): the core never imports this package, it loads the
``register`` functions the installed distributions declare.

Modules here must not import rclpy at import time: ``clm --help`` stays fast
and works without a middleware.
"""
