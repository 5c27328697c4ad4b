"""Message objects (rosbags) and a recording validator for the message-path tests (test helper, not a test
module)."""
import numpy as np
from rosbags.typesys import Stores, get_typestore

from gap_validation.core.config import ChannelConfig, SignalSpec, ValidationConfig
from gap_validation.core.models import LinearModel

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types


def header(sec=0, nanosec=0):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                    frame_id="imu")


def imu(x=0.1, y=0.2, z=0.3, sec=10, nanosec=500_000_000):
    vec, quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    return T["sensor_msgs/msg/Imu"](
        header=header(sec, nanosec), orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.zeros(9), angular_velocity=vec(x=x, y=y, z=z),
        angular_velocity_covariance=np.zeros(9), linear_acceleration=vec(x=0.0, y=0.0, z=9.81),
        linear_acceleration_covariance=np.zeros(9))


def joints(names, positions, sec=10, nanosec=0):
    return T["sensor_msgs/msg/JointState"](header=header(sec, nanosec), name=list(names),
                                           position=np.asarray(positions, dtype=float),
                                           velocity=np.zeros(0), effort=np.zeros(0))


class FakeValidator:
    def __init__(self):
        self.batches = []
        self.bad = []

    def add_samples(self, channel, stream, t_s, values):
        self.batches.append((channel, stream, np.asarray(t_s), np.asarray(values)))

    def count_bad(self, channel, stream, reason, count=1):
        self.bad.extend([(channel, stream, reason)] * count)

    def samples(self, channel, stream):
        rows = [(t, v) for c, s, t, v in self.batches if (c, s) == (channel, stream)]
        if not rows:
            return np.zeros(0), np.zeros(0)
        return np.concatenate([r[0] for r in rows]), np.concatenate([r[1] for r in rows])


def make_config(input_field="position[elevator]", output_field="angular_velocity.y", output_scale=1.0,
                trigger=False):
    model = LinearModel.from_tf([1.0], [1.0, 1.0])
    channel = ChannelConfig(
        name="pitch", input=SignalSpec("/control_surfaces", input_field),
        output=SignalSpec("/imu", output_field, scale=output_scale), model=model, model_spec={},
        trigger=SignalSpec("/sweep", "data") if trigger else None)
    return ValidationConfig(channels={"pitch": channel})
