"""ROS 2 layer of the CLM track-soil suite.

Thin nodes that convert messages to arrays at the edge and call ``clm_core``;
no physics lives here. ``clm_ros.msg_types`` gives a rosbags typestore with
the ``clm_msgs`` interfaces, usable without rclpy.
"""
