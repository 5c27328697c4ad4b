"""Message-type layouts: the ROS message types the package reads and writes without ROS, and their fields.

One definition of what ``sensor_msgs/msg/Imu``, ``sensor_msgs/msg/JointState`` and ``std_msgs/msg/Float64 |
Float32 | Bool`` carry, read by the simulator (which topics a config's fields imply), the fast CDR decoders of
:mod:`gap_validation.messages.cdr` and the bag writer of :mod:`gap_validation.bag.writer`. It lives in the
core, below :mod:`gap_validation.messages`, because the core's simulator needs it. No ROS import.
"""
from __future__ import annotations

from gap_validation.core.fields import FieldPath

__all__ = ["IMU", "JOINT_STATE", "FLOAT64", "FLOAT32", "BOOL", "IMU_VECTORS", "JOINT_ARRAYS", "SCALAR_TYPES",
           "STAMPED_TYPES", "LAYOUTS", "infer_type"]

IMU = "sensor_msgs/msg/Imu"
JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
FLOAT32 = "std_msgs/msg/Float32"
BOOL = "std_msgs/msg/Bool"

#: Imu vectors and their components, in message order (``orientation`` is a quaternion).
IMU_VECTORS = (("orientation", "xyzw"), ("angular_velocity", "xyz"), ("linear_acceleration", "xyz"))
#: JointState arrays read as ``array[joint name]`` or ``array[index]``, in message order.
JOINT_ARRAYS = ("position", "velocity", "effort")
#: Types with one field ``data``.
SCALAR_TYPES = (FLOAT64, FLOAT32, BOOL)
#: Types with a ``header`` (their samples are stamped with ``header.stamp``).
STAMPED_TYPES = (IMU, JOINT_STATE)

#: Message type -> the attribute paths of its numeric fields (JointState: the arrays, indexed by name or
#: index).
LAYOUTS: dict[str, set[tuple[str, ...]]] = {
    IMU: {(vector, c) for vector, components in IMU_VECTORS for c in components},
    JOINT_STATE: {(array,) for array in JOINT_ARRAYS},
    **{kind: {("data",)} for kind in SCALAR_TYPES},
}


def infer_type(path: FieldPath, stream: str) -> str | None:
    """The message type a field path implies, or None when it does not say.

    ``angular_velocity.*``, ``linear_acceleration.*``, ``orientation.*`` -> Imu; ``position[name]`` (velocity,
    effort, or an index) -> JointState; ``data`` -> Float64, or Bool for a sweep trigger.

    Parameters
    ----------
    path : FieldPath
        A parsed field path.
    stream : {"input", "output", "trigger"}
        The stream the field feeds.
    """
    attrs = path.attributes
    if not attrs:
        return None
    if stream == "trigger" and attrs == ("data",):
        return BOOL
    if attrs[0] in dict(IMU_VECTORS):
        return IMU
    if attrs[0] in JOINT_ARRAYS and (path.key is not None or path.index is not None):
        return JOINT_STATE
    if attrs == ("data",):
        return FLOAT64
    return None
