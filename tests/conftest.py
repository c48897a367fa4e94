"""Test-wide environment: ROS 2 from PyPI needs a writable log directory, discovery stays on this
machine, and each pytest process gets its own ROS domain so parallel runs never see each other."""

import os
import tempfile

import pytest

os.environ.setdefault("HOME", tempfile.gettempdir())
os.environ.setdefault("ROS_LOG_DIR", os.path.join(tempfile.gettempdir(), "ffmpc_ros_log"))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# Domain ids 1..100 (valid for every RMW port range); one per pytest process.
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))


@pytest.fixture
def ros():
    """A :class:`ros_helpers.RosHarness` (its own rclpy Context and executor), closed after."""
    from ros_helpers import RosHarness

    harness = RosHarness()
    yield harness
    harness.close()


@pytest.fixture(scope="module")
def robot():
    """The iiwa model (``ffmpc_core.robots.load_robot("iiwa")``), one per test module."""
    from ffmpc_core.robots import load_robot

    return load_robot("iiwa")
