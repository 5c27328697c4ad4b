"""Message types of the node's topics (gap_validation.ros.message_types): from the config, checked on the
classes."""
import dataclasses

import pytest
from _messages import make_config

from gap_validation.core.config import SignalSpec, ValidationConfig
from gap_validation.core.errors import ConfigError
from gap_validation.core.layouts import FLOAT64, IMU
from gap_validation.ros.message_types import TopicType, message_class, resolve_types, topic_types

pytest.importorskip("sensor_msgs.msg")


def test_types_from_the_config_and_their_conflicts():
    config = make_config()
    assert resolve_types(config) == {"/control_surfaces": None, "/imu": None}
    pitch = config.channels["pitch"]
    pitch = dataclasses.replace(pitch, output=SignalSpec("/imu", "angular_velocity.y", type=IMU))
    roll = dataclasses.replace(
        pitch, name="roll", output=SignalSpec("/imu", "angular_velocity.x", type=FLOAT64)
    )
    assert resolve_types(ValidationConfig({"pitch": pitch}))["/imu"] == IMU
    with pytest.raises(ConfigError, match="cfg.yaml: topic /imu: conflicting types"):
        resolve_types(ValidationConfig({"pitch": pitch, "roll": roll}, source="cfg.yaml"))


def test_a_type_must_be_installed_and_carry_the_fields():
    assert message_class("sensor_msgs/Imu").__name__ == "Imu"
    with pytest.raises(ConfigError, match="is not installed"):
        message_class("nope_msgs/msg/Nothing")
    pitch = make_config().channels["pitch"]
    wrong = dataclasses.replace(pitch, output=SignalSpec("/imu", "angular_velocity.w", type=IMU))
    with pytest.raises(ConfigError, match="channels.pitch.output: topic /imu"):
        resolve_types(ValidationConfig({"pitch": wrong}))


def test_topics_are_subscribed_at_once_with_the_type_their_fields_imply():
    """No ``type:`` in the config: angular_velocity.* is an Imu, position[...] a JointState, data a Float64; a
    field that implies nothing waits for the graph; the config's type wins."""
    config = make_config()
    assert topic_types(config) == {"/control_surfaces": TopicType("sensor_msgs/msg/JointState", "fields"),
                                   "/imu": TopicType(IMU, "fields")}
    pitch = config.channels["pitch"]
    scalar = dataclasses.replace(pitch, input=SignalSpec("/elevator", "data"),
                                 output=SignalSpec("/rates", "twist.angular.y"))
    types = topic_types(ValidationConfig({"pitch": scalar}))
    assert types == {"/elevator": TopicType(FLOAT64, "fields"), "/rates": TopicType(None)}
    named = dataclasses.replace(pitch, output=SignalSpec("/imu", "angular_velocity.y", type=IMU))
    assert topic_types(ValidationConfig({"pitch": named}))["/imu"] == TopicType(IMU, "config")
