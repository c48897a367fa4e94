"""Test-wide environment: ROS 2 from PyPI needs a writable log directory, discovery stays on this
machine, and each pytest process gets its own ROS domain so parallel runs never see each other."""

import os
import tempfile

os.environ.setdefault("HOME", tempfile.gettempdir())
os.environ.setdefault("ROS_LOG_DIR", os.path.join(tempfile.gettempdir(), "ffmpc_ros_log"))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# Domain ids 1..100 (valid for every RMW port range); one per pytest process.
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
