"""Message-type layouts (gap_validation.core.layouts): the fields of the types the package reads and
writes."""
import pytest

from gap_validation.core.fields import FieldPath
from gap_validation.core.layouts import BOOL, FLOAT64, IMU, JOINT_STATE, LAYOUTS, infer_type


@pytest.mark.parametrize(
    "field, stream, expected",
    [
        ("angular_velocity.y", "output", IMU),
        ("orientation.w", "output", IMU),
        ("position[elevator]", "input", JOINT_STATE),
        ("effort[2]", "input", JOINT_STATE),
        ("data", "input", FLOAT64),
        ("data", "trigger", BOOL),
        ("position", "input", None),
        ("wrench.x", "output", None),
    ],
)
def test_type_inferred_from_the_field(field, stream, expected):
    assert infer_type(FieldPath.parse(field), stream) == expected


def test_layouts_hold_the_imu_vectors_and_joint_arrays():
    assert ("angular_velocity", "z") in LAYOUTS[IMU] and ("orientation", "w") in LAYOUTS[IMU]
    assert LAYOUTS[JOINT_STATE] == {("position",), ("velocity",), ("effort",)}
    assert list(LAYOUTS)[:2] == [IMU, JOINT_STATE]
