"""Fast CDR field decoders (gap_validation.messages.cdr) against rosbags' full deserialisation."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from gap_validation.core.fields import FieldPath
from gap_validation.messages.cdr import FastDecodeError, Records, batch_decoder, fast_decoder
from gap_validation.messages.router import stamp_seconds

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types


def _imu(frame_id, values, sec, nanosec):
    vec, quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    return T["sensor_msgs/msg/Imu"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                        frame_id=frame_id),
        orientation=quat(x=values[0], y=values[1], z=values[2], w=values[3]),
        orientation_covariance=np.arange(9.0), angular_velocity=vec(x=values[4], y=values[5], z=values[6]),
        angular_velocity_covariance=np.arange(9.0) + 10, linear_acceleration=vec(x=values[7], y=values[8],
                                                                               z=values[9]),
        linear_acceleration_covariance=np.arange(9.0) + 20)


IMU_FIELDS = [
    "orientation.x",
    "orientation.w",
    "angular_velocity.x",
    "angular_velocity.y",
    "angular_velocity.z",
    "linear_acceleration.z",
]
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=80, deadline=None)
@given(st.text(max_size=13), st.lists(finite, min_size=10, max_size=10), st.integers(0, 2**31 - 1),
       st.integers(0, 999_999_999), st.lists(st.sampled_from(IMU_FIELDS), min_size=1, max_size=4))
def test_fast_imu_decoder_matches_rosbags(frame_id, values, sec, nanosec, fields):
    msg = _imu(frame_id, values, sec, nanosec)
    raw = TS.serialize_cdr(msg, "sensor_msgs/msg/Imu")
    paths = [FieldPath.parse(f) for f in fields]
    stamp, got = fast_decoder("sensor_msgs/msg/Imu", paths)(raw)
    full = TS.deserialize_cdr(raw, "sensor_msgs/msg/Imu")
    assert got == [p.extract(full) for p in paths]
    assert stamp == stamp_seconds(full)


@settings(max_examples=80, deadline=None)
@given(st.lists(st.text(alphabet="abcdefghijklmnop_", min_size=1, max_size=11), min_size=1, max_size=5,
                unique=True), st.text(max_size=6), st.data())
def test_fast_joint_state_decoder_matches_rosbags(names, frame_id, data):
    n = len(names)
    arrays = {k: np.array(data.draw(st.lists(finite, min_size=n, max_size=n))) for k in ("position",)}
    for k in ("velocity", "effort"):
        arrays[k] = np.array(data.draw(st.lists(finite, min_size=0, max_size=n) | st.just([])), dtype=float)
    msg = T["sensor_msgs/msg/JointState"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=3, nanosec=7),
                                        frame_id=frame_id), name=names, **arrays)
    raw = TS.serialize_cdr(msg, "sensor_msgs/msg/JointState")
    full = TS.deserialize_cdr(raw, "sensor_msgs/msg/JointState")
    fields = [
        f"position[{data.draw(st.sampled_from(names))}]",
        f"position[{data.draw(st.integers(0, n - 1))}]",
    ]
    for array in ("velocity", "effort"):
        if len(arrays[array]):
            fields.append(f"{array}[{names[len(arrays[array]) - 1]}]")
    paths = [FieldPath.parse(f) for f in fields]
    decode = fast_decoder("sensor_msgs/msg/JointState", paths)
    for _ in range(2):  # second call uses the cached name table
        stamp, got = decode(raw)
        assert got == [p.extract(full) for p in paths]
        assert stamp == stamp_seconds(full)


def test_fast_joint_state_missing_joint_falls_back():
    decode = fast_decoder("sensor_msgs/msg/JointState", [FieldPath.parse("position[elevator]")])
    good = T["sensor_msgs/msg/JointState"](header=T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id=""), name=["elevator"],
        position=np.array([0.5]), velocity=np.zeros(0), effort=np.zeros(0))
    assert decode(TS.serialize_cdr(good, "sensor_msgs/msg/JointState"))[1] == [0.5]
    good.name = ["aileron"]
    with pytest.raises(FastDecodeError):
        decode(TS.serialize_cdr(good, "sensor_msgs/msg/JointState"))


@pytest.mark.parametrize("msgtype, value", [("std_msgs/msg/Float64", -2.25), ("std_msgs/msg/Float32", 0.5),
                                            ("std_msgs/msg/Bool", True)])
def test_fast_scalar_decoders(msgtype, value):
    raw = TS.serialize_cdr(T[msgtype](data=value), msgtype)
    stamp, got = fast_decoder(msgtype, [FieldPath.parse("data")])(raw)
    assert stamp is None and got == [float(value)]


def test_big_endian_and_unknown_layouts_are_not_fast():
    msg = _imu("imu", list(range(10)), 1, 2)
    raw = TS.serialize_cdr(msg, "sensor_msgs/msg/Imu", little_endian=False)
    with pytest.raises(FastDecodeError):
        fast_decoder("sensor_msgs/msg/Imu", [FieldPath.parse("angular_velocity.y")])(raw)
    assert fast_decoder("sensor_msgs/msg/Imu", [FieldPath.parse("orientation_covariance[0]")]) is None
    assert fast_decoder("geometry_msgs/msg/Vector3Stamped", [FieldPath.parse("vector.y")]) is None


# ------------------------------------------------------------------------------------ many records at once
def _batch_agrees(msgtype, paths, raws):
    """Batch-decode ``raws``: every record it reads has the per-record decoder's stamp and values to the bit.
    Returns which records it read."""
    stamps, values, ok = batch_decoder(msgtype, paths)(Records.from_raws(raws))
    record = fast_decoder(msgtype, paths)
    for raw, stamp, row, read in zip(raws, stamps, values, ok):
        if read:
            want_stamp, want = record(raw)
            assert row.tolist() == want and np.array_equal(row, np.asarray(want), equal_nan=True)
            assert (math.isnan(stamp) if want_stamp is None else stamp == want_stamp)
    return ok


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["", "imu", "imu_link", "a" * 9]),
            st.lists(finite, min_size=10, max_size=10),
            st.integers(0, 2**31 - 1),
            st.integers(0, 999_999_999),
            st.sampled_from(["le", "le", "le", "be", "short"]),
        ),
        min_size=1,
        max_size=25,
    ),
    st.lists(st.sampled_from(IMU_FIELDS), min_size=1, max_size=4),
)
def test_batch_imu_decoder_reads_what_the_record_decoder_reads(records, fields):
    raws = []
    for frame_id, values, sec, nanosec, kind in records:
        unset = sec % 3 == 0                               # a zero stamp: none
        raw = bytes(TS.serialize_cdr(_imu(frame_id, values, 0 if unset else sec, 0 if unset else nanosec),
                                     "sensor_msgs/msg/Imu", little_endian=kind != "be"))
        raws.append(raw[:60] if kind == "short" else raw)
    ok = _batch_agrees("sensor_msgs/msg/Imu", [FieldPath.parse(f) for f in fields], raws)
    assert not any(read for read, r in zip(ok, records) if r[4] != "le")
    if records[0][4] == "le":  # the first record is the template: every record laid out like it is read
        assert all(read for read, r in zip(ok, records) if r[4] == "le" and len(r[0]) == len(records[0][0]))


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.sampled_from([("elevator", "aileron"), ("aileron", "elevator"), ("elevator",), ("rudder",)]),
        min_size=1,
        max_size=20,
    ),
    st.data(),
)
def test_batch_joint_state_decoder_reads_what_the_record_decoder_reads(name_sets, data):
    raws, shapes = [], []
    for names in name_sets:
        n = len(names)
        position = np.array(data.draw(st.lists(finite, min_size=n, max_size=n)))
        velocity = np.array(data.draw(st.lists(finite, min_size=n, max_size=n) | st.just([])), dtype=float)
        msg = T["sensor_msgs/msg/JointState"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=5, nanosec=data.draw(
                st.integers(0, 10))), frame_id=""), name=list(names), position=position, velocity=velocity,
            effort=np.zeros(0))
        raws.append(bytes(TS.serialize_cdr(msg, "sensor_msgs/msg/JointState")))
        shapes.append((names, velocity.size))
    paths = [FieldPath.parse(f) for f in ("position[elevator]", "position[0]", "velocity[elevator]")]
    ok = _batch_agrees("sensor_msgs/msg/JointState", paths, raws)
    record = fast_decoder("sensor_msgs/msg/JointState", paths)
    readable = []
    for raw in raws:
        try:
            record(raw)
            readable.append(True)
        except FastDecodeError:
            readable.append(False)
    assert not any(o and not r for o, r in zip(ok, readable))
    # the first record is the template: every record with its names and lengths is read
    if readable[0]:
        assert all(read for read, shape in zip(ok, shapes) if shape == shapes[0])


@pytest.mark.parametrize("msgtype, value", [("std_msgs/msg/Float64", -2.25), ("std_msgs/msg/Float32", 0.1),
                                            ("std_msgs/msg/Bool", True), ("std_msgs/msg/Bool", False)])
def test_batch_scalar_decoders(msgtype, value):
    raws = [TS.serialize_cdr(T[msgtype](data=value), msgtype)] * 3 + [b"\x00\x01\x00"]
    ok = _batch_agrees(msgtype, [FieldPath.parse("data")] * 2, raws)
    assert ok.tolist() == [True, True, True, False]


def test_records_in_one_buffer():
    records = Records.from_raws([b"abc", b"", b"de"])
    assert len(records) == 3 and [records.raw(i) for i in range(3)] == [b"abc", b"", b"de"]
    assert records.take(np.array([2, 0])).raw(0) == b"de"
    assert len(Records.from_raws([])) == 0
