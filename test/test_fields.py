"""Field paths (gap_validation.core.fields) on rosbags and rclpy message objects."""
import pytest
from _messages import T, imu, joints
from hypothesis import given, settings
from hypothesis import strategies as st

from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.fields import FieldError, FieldPath
from gap_validation.messages.router import stamp_seconds


# ------------------------------------------------------------------------------------------- parsing
@pytest.mark.parametrize("text, attrs, key, index", [
    ("angular_velocity.y", ("angular_velocity", "y"), None, None),
    ("data", ("data",), None, None),
    ("position[elevator]", ("position",), "elevator", None),
    ("position[2]", ("position",), None, 2),
    ("[2]", (), None, 2),
    ("position[-1]", ("position",), None, -1),
    ("position['2']", ("position",), "2", None),
    ("position[left aileron]", ("position",), "left aileron", None),
    ("a.b[0].c", ("a", "b", "c"), None, 0),
])
def test_parse_valid_paths(text, attrs, key, index):
    path = FieldPath.parse(text)
    assert path.attributes == attrs and path.key == key and path.index == index
    assert path.text == text


@pytest.mark.parametrize("text, part", [
    ("", None), ("angular_velocity..y", "''"), ("angular velocity.y", "angular velocity"),
    ("1abc", "1abc"), ("position[]", "[]"), ("[elevator]", "[elevator]"), ("a.[2]", "[2]"),
    ("position[elev", "position[elev"), ("a-b", "a-b"),
])
def test_parse_bad_paths_one_line_error(text, part):
    with pytest.raises(ConfigError) as err:
        FieldPath.parse(text)
    message = str(err.value)
    assert "\n" not in message and repr(text) in message
    if part is not None:
        assert part.strip("'") in message


# ------------------------------------------------------------------------------------------- extraction
def test_extract_rosbags_imu_and_stamp():
    msg = imu(x=0.5, y=-0.25, z=2.0, sec=12, nanosec=250_000_000)
    assert FieldPath.parse("angular_velocity.x").extract(msg) == 0.5
    assert FieldPath.parse("angular_velocity.y").extract(msg) == -0.25
    assert FieldPath.parse("angular_velocity.z").extract(msg) == 2.0
    assert FieldPath.parse("orientation_covariance[8]").extract(msg) == 0.0
    assert stamp_seconds(msg) == pytest.approx(12.25, abs=1e-12)


def test_extract_joint_state_by_name_index_and_negative_index():
    msg = joints(["aileron", "elevator", "rudder"], [0.1, -0.2, 0.3])
    assert FieldPath.parse("position[elevator]").extract(msg) == -0.2
    assert FieldPath.parse("position[2]").extract(msg) == 0.3
    assert FieldPath.parse("position[-3]").extract(msg) == 0.1


def test_name_lookup_follows_reordered_names():
    path = FieldPath.parse("position[elevator]")
    assert path.extract(joints(["aileron", "elevator"], [1.0, 2.0])) == 2.0
    assert path.extract(joints(["elevator", "aileron"], [3.0, 4.0])) == 3.0  # cached index is re-checked
    assert path.extract(joints(["rudder", "aileron", "elevator"], [5.0, 6.0, 7.0])) == 7.0


def test_float64_and_bool_data():
    assert FieldPath.parse("data").extract(T["std_msgs/msg/Float64"](data=-1.5)) == -1.5
    assert FieldPath.parse("data").extract(T["std_msgs/msg/Bool"](data=True)) == 1.0


def test_missing_joint_is_per_message_error_naming_the_joint():
    with pytest.raises(FieldError) as err:
        FieldPath.parse("position[elevator]").extract(joints(["aileron", "rudder"], [0.1, 0.2]))
    assert isinstance(err.value, DataError)
    assert "elevator" in str(err.value) and "aileron" in str(err.value)
    assert err.value.reason == "missing joint" and not err.value.structural


def test_short_position_array_and_index_out_of_range():
    with pytest.raises(FieldError) as err:
        FieldPath.parse("position[rudder]").extract(joints(["aileron", "rudder"], [0.1]))
    assert err.value.reason == "wrong length" and not err.value.structural
    with pytest.raises(FieldError) as err:
        FieldPath.parse("position[5]").extract(joints(["aileron"], [0.1]))
    assert err.value.reason == "index out of range"


def test_missing_attribute_is_structural_and_named():
    with pytest.raises(FieldError) as err:
        FieldPath.parse("angular_velocity.w").extract(imu())
    assert err.value.structural and "angular_velocity.w" in str(err.value)
    with pytest.raises(FieldError) as err:
        FieldPath.parse("position[elevator]").extract(imu())
    assert err.value.structural


def test_field_that_is_not_a_number():
    with pytest.raises(FieldError) as err:
        FieldPath.parse("angular_velocity").extract(imu())
    assert err.value.reason == "not a number"


def test_rclpy_messages_same_values():
    """The node hands rclpy objects (array.array positions, numpy covariances) to the same extractor."""
    pytest.importorskip("rclpy")
    from sensor_msgs.msg import Imu, JointState
    from std_msgs.msg import Float64

    js = JointState()
    js.name = ["aileron", "elevator", "rudder"]
    js.position = [0.1, -0.2, 0.3]
    js.header.stamp.sec, js.header.stamp.nanosec = 7, 5
    assert FieldPath.parse("position[elevator]").extract(js) == -0.2
    assert FieldPath.parse("position[0]").extract(js) == 0.1
    assert stamp_seconds(js) == pytest.approx(7.000000005)
    msg = Imu()
    msg.angular_velocity.y = 0.75
    assert FieldPath.parse("angular_velocity.y").extract(msg) == 0.75
    assert FieldPath.parse("orientation_covariance[4]").extract(msg) == 0.0
    assert stamp_seconds(msg) is None  # zero stamp: unset, use the receive time
    assert FieldPath.parse("data").extract(Float64(data=2.5)) == 2.5


@settings(max_examples=60, deadline=None)
@given(st.lists(st.text(alphabet="abcdefghij_", min_size=1, max_size=6), min_size=1, max_size=6, unique=True),
       st.data())
def test_name_lookup_property(names, data):
    """position[name] is the value at name's index, whatever the order of the names."""
    order = data.draw(st.permutations(names))
    values = data.draw(st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=len(order),
                                max_size=len(order)))
    msg = joints(order, values)
    for name in names:
        path = FieldPath.parse(f"position[{name}]")
        assert path.extract(msg) == values[order.index(name)]
