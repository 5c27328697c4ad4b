"""rosbag2 I/O (gap_validation.bagio): writing simulated flights, streaming, fast decoding, one-line errors."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from _flights import SHORT, make_bag, ultrastick
from gap_validation.bag.reader import open_bag
from gap_validation.messages.cdr import FastDecodeError, fast_decoder
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.simulation import simulate_flight, with_options
from gap_validation.core.fields import FieldPath
from gap_validation.messages.router import stamp_seconds

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
TINY = with_options(SHORT, sweeps_per_channel=1, sweep_duration_s=10.0, quiet_s=1.0)


@pytest.fixture(scope="module")
def flight():
    return simulate_flight(ultrastick(), options=TINY, seed=4)


@pytest.fixture(scope="module")
def mcap_bag(tmp_path_factory, flight):
    from gap_validation.bag.writer import write_flight

    path = tmp_path_factory.mktemp("bags") / "flight"
    write_flight(flight, path)
    return path


# ------------------------------------------------------------------------------------------- round trip
def _check_contents(path, flight):
    ts_ns = {}
    with open_bag(path) as bag:
        info = bag.topics
        assert {t: (i.msgtype, i.count) for t, i in info.items()} == {
            t: (s.msgtype, len(s)) for t, s in flight.topics.items()}
        got = {t: {"t": [], "bag": [], **{k: [] for k in s.values}} for t, s in flight.topics.items()}
        for topic, msg, bag_time_s in bag.messages():
            row = got[topic]
            row["t"].append(stamp_seconds(msg))
            row["bag"].append(bag_time_s)
            for key in flight.topics[topic].values:
                row[key].append(FieldPath.parse(key).extract(msg))
            ts_ns.setdefault(topic, []).append(msg.header.stamp.nanosec)
    for topic, series in flight.topics.items():
        row = got[topic]
        np.testing.assert_allclose(row["t"], series.stamp_s, rtol=0, atol=2e-9)
        np.testing.assert_allclose(row["bag"], series.receive_s, rtol=0, atol=5e-7)  # 1 ulp at 1.7e9 s
        for key, values in series.values.items():
            np.testing.assert_array_equal(row[key], values)  # doubles are stored exactly


def test_mcap_round_trip_is_exact(mcap_bag, flight):
    assert (mcap_bag / "metadata.yaml").exists() and list(mcap_bag.glob("*.mcap"))
    _check_contents(mcap_bag, flight)


@pytest.mark.parametrize("name, storage", [("flight_sql", "sqlite3"), ("bare.mcap", None), ("bare.db3", None)])
def test_other_storages_round_trip(tmp_path, flight, name, storage):
    from gap_validation.bag.writer import write_flight

    out = write_flight(flight, tmp_path / name, storage)
    assert out.exists()
    _check_contents(out, flight)


def test_mcap_is_zstd_compressed_and_metadata_records_the_truth(tmp_path):
    path = tmp_path / "hidden"
    make_bag(path, hidden=["pitch:time_delay:seconds=0.04"], options=TINY)
    with Reader(path) as reader:
        custom = reader.storage.metadata.custom or {}
    assert '"seconds": 0.04' in custom["gap_validation.hidden"]
    data = next(path.glob("*.mcap")).read_bytes()
    assert b"zstd" in data


def test_same_seed_same_bytes(tmp_path):
    a, b = tmp_path / "a" / "flight", tmp_path / "b" / "flight"
    for path in (a, b):
        path.parent.mkdir()
        make_bag(path, seed=9, options=TINY)
    for name in ("flight.mcap", "metadata.yaml"):
        assert (a / name).read_bytes() == (b / name).read_bytes()


def test_refuses_to_overwrite(mcap_bag, flight):
    from gap_validation.bag.writer import write_flight

    with pytest.raises(ConfigError, match="exists already"):
        write_flight(flight, mcap_bag)
    with pytest.raises(ConfigError, match="does not match"):
        write_flight(flight, mcap_bag.parent / "x.mcap", "sqlite3")


def test_streams_only_requested_topics(mcap_bag, flight):
    with open_bag(mcap_bag) as bag:
        seen = {topic for topic, *_ in bag.records(["/imu"])}
        assert seen == {"/imu"}
        assert bag.message_count(["/imu", "/nope"]) == len(flight.topics["/imu"])


# ------------------------------------------------------------------------------------------- fast decoding
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


IMU_FIELDS = ["orientation.x", "orientation.w", "angular_velocity.x", "angular_velocity.y", "angular_velocity.z",
              "linear_acceleration.z"]
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
    fields = [f"position[{data.draw(st.sampled_from(names))}]", f"position[{data.draw(st.integers(0, n - 1))}]"]
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


# ------------------------------------------------------------------------------------------- errors
def _one_line(err, *needles):
    message = str(err.value)
    assert "\n" not in message
    for needle in needles:
        assert str(needle) in message


def test_missing_bag(tmp_path):
    with pytest.raises(DataError) as err:
        open_bag(tmp_path / "nope")
    _one_line(err, tmp_path / "nope", "not found")


def test_not_a_bag(tmp_path):
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(DataError) as err:
        open_bag(text)
    _one_line(err, text, "not a bag")
    with pytest.raises(DataError) as err:
        open_bag(tmp_path)
    _one_line(err, tmp_path, "metadata.yaml")


def test_junk_and_truncated_mcap(tmp_path, mcap_bag):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all" * 10)
    with pytest.raises(DataError) as err:
        open_bag(junk)
    _one_line(err, junk)
    data = next(mcap_bag.glob("*.mcap")).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError) as err:
        with open_bag(cut) as bag:
            list(bag.records())
    _one_line(err, cut)


def test_corrupted_chunk_reports_file_while_streaming(tmp_path, mcap_bag):
    data = bytearray(next(mcap_bag.glob("*.mcap")).read_bytes())
    middle = len(data) // 3
    data[middle:middle + 64] = bytes(64)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(DataError) as err:
        with open_bag(bad) as bag:
            for _ in bag.records():
                pass
    _one_line(err, bad)


def test_bag_directory_without_metadata_but_one_file(tmp_path, mcap_bag, flight):
    folder = tmp_path / "loose"
    folder.mkdir()
    (folder / "x.mcap").write_bytes(next(mcap_bag.glob("*.mcap")).read_bytes())
    with open_bag(folder) as bag:
        assert bag.message_count() == flight.message_count


def test_deserialize_mismatch_names_topic(mcap_bag):
    with open_bag(mcap_bag) as bag:
        topic, msgtype, _, raw = next(iter(bag.records(["/control_surfaces"])))
        with pytest.raises(DataError) as err:
            bag.deserialize(raw, "sensor_msgs/msg/Imu", topic)
    _one_line(err, "/control_surfaces", "sensor_msgs/msg/Imu")
