"""The bottom layer of the edges: time base, message codec, bags and files (no ROS middleware needed).

It imports nothing of :mod:`clm_core` above :mod:`clm_core.errors` and
:mod:`clm_core.arrays`; what is written from results (history files, figures,
reports) is the outputs layer, :mod:`clm_core.outputs`. Modules (one home per concept):

- :mod:`clm_core.io.timebase`: ``NS`` and the stamp <-> integer-nanosecond helpers;
- :mod:`clm_core.io.messages`: ``clm_msgs`` <-> message arrays (rosbags flavour), the
  type store built from the ``clm_msgs`` definitions, and a numpy CDR codec;
- :mod:`clm_core.io.bags`: the one rosbag2 reader and writer (format version 9, as
  ``ros2 bag record`` of ROS 2 Jazzy writes it);
- :mod:`clm_core.io.files`: JSON and NPZ files written atomically;
- :mod:`clm_core.io.errors`: :class:`MessageError` and :class:`BagError`.

Submodules are imported on use: importing this package is cheap.
"""
