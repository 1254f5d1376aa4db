"""The ROS 1 master fixture for the live tests."""

from tests.live.rosmaster import ros_env  # noqa: F401
