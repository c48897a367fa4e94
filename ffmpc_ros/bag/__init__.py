"""MCAP bags of ffmpc runs: the same format rosbag2's MCAP storage writes.

ROS-free core (no rclpy import; usable with only ``mcap`` installed):

* :mod:`ffmpc_ros.bag.schema` — the ``ros2msg`` definitions of installed ``.msg`` files,
  concatenated with their dependencies as rosbag2 does, and rosbag2's QoS YAML;
* :mod:`ffmpc_ros.bag.writer` — :class:`~ffmpc_ros.bag.writer.BagWriter`, a context manager that
  writes raw CDR into chunked, compressed MCAP, refuses to overwrite and closes a chunk at least
  every ``flush_interval`` seconds, so a killed writer loses at most that much;
* :mod:`ffmpc_ros.bag.reader` — :class:`~ffmpc_ros.bag.reader.BagReader` (complete bags through
  their summary, truncated ones up to their last complete chunk, with a recovery report) and
  :func:`~ffmpc_ros.bag.reader.recover_bag`.

Thin rclpy adapters: :mod:`~ffmpc_ros.bag.recorder` (record topics and every node's parameters),
:mod:`~ffmpc_ros.bag.player` (republish with the original timing), :mod:`~ffmpc_ros.bag.rerun`
(feed one node the recorded inputs, compare its outputs), :mod:`~ffmpc_ros.bag.analysis`
(metrics and plots from a bag) and :mod:`~ffmpc_ros.bag.cli` (``ffmpc bag``).
"""
