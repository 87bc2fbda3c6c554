"""Bags on the pure-Python ``rosbags`` library, with typed errors.

- :mod:`.errors`: the :class:`~.errors.BagError` family (messages meant for people);
- :mod:`.types`: the message type names used here, the Jazzy typestore, header-stamp helpers;
- :mod:`.reader`: :class:`~.reader.BagReader` (rosbag2 sqlite3/mcap and ROS 1 ``.bag``);
- :mod:`.inputs`: which image topics feed the pipeline (``--left``/``--right``/``--image`` or
  picked from the bag);
- :mod:`.writer`: :class:`~.writer.BagWriter`, a writer that survives SIGKILL;
- :mod:`.crash_safety`: atomic files and the clean-up of what a killed writer left.
"""
