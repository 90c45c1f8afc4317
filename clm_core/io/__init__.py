"""Edges of the core: time base, messages, bags, history files and figures (no ROS middleware needed).

Modules (one home per concept):

- :mod:`clm_core.io.timebase`: ``NS`` and the stamp <-> integer-nanosecond helpers;
- :mod:`clm_core.io.messages`: ``clm_msgs`` <-> domain data (rosbags flavour), the
  type store built from the ``clm_msgs`` definitions, and a numpy CDR codec;
- :mod:`clm_core.io.bags`: the one rosbag2 reader and writer (format version 9, as
  ``ros2 bag record`` of ROS 2 Jazzy writes it);
- :mod:`clm_core.io.errors`: :class:`MessageError` and :class:`BagError`;
- :mod:`clm_core.io.history`: time-history files (NPZ, CSV, JSON);
- :mod:`clm_core.io.plots`: every matplotlib figure (import it only where a figure is drawn);
- :mod:`clm_core.io.report_index`: the HTML index of an output tree.

Submodules are imported on use: importing this package is cheap.
"""
