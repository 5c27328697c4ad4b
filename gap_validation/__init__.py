"""gap_validation: validate linear aircraft models against flight data in the nu-gap metric.

The math lives in :mod:`gap_validation.core` (numpy/scipy only); replay (rosbags), the ROS 2 node (rclpy),
the CLI and the report are thin front ends around :class:`gap_validation.core.validator.OnlineValidator`.
"""

__version__ = "0.1.0"
