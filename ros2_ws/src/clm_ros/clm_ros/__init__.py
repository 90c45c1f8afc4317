"""ROS 2 layer of the CLM track-soil suite.

Thin nodes that convert messages to arrays at the edge and call ``clm_core``;
no physics lives here. Messages, bags and the clm_msgs type store (usable
without rclpy) are in :mod:`clm_core.io`; ``clm_ros.conversions`` is the rclpy
flavour of the message conversions.
"""
