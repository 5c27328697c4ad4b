"""ROS-free core of gap_validation: models, effects, metrics, margins, estimator, validator, diagnosis.

Imports numpy and scipy only (never rclpy, rosbags, matplotlib or yaml), so it is usable as a plain library
and testable without ROS.
"""
