"""PX4 ULog (gap_validation.logs.ulog): written in PX4's layouts, read back by pyulog (PX4's own reader) value
for value, read by ours exactly as pyulog reads it, damaged files read up to the damage, one-line errors.

Files the writer cannot make (nested types, padding, appended data, every data-section message type) are built
here from raw bytes, by the spec, independently of the module.
"""
import struct

import numpy as np
import pytest
import pyulog

from gap_validation.core.errors import DataError
from gap_validation.logs import ulog as ulog_module
from gap_validation.logs.base import WriteTopic
from gap_validation.logs.formats import open_log
from gap_validation.logs.ulog import ULogFile, write_ulog

MAGIC = b"ULog\x01\x12\x35"


# ------------------------------------------------------------------------------------------- helpers
def _msg(kind, payload):
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def _walk(raw, start=16):
    """(offset, type, size) of every whole message from ``start`` (an independent walk of the spec)."""
    out, pos = [], start
    while pos + 3 <= len(raw):
        size, kind = struct.unpack_from("<HB", raw, pos)
        if pos + 3 + size > len(raw):
            break
        out.append((pos, chr(kind), size))
        pos += 3 + size
    return out


def _data_start(raw):
    return next(pos for pos, kind, _ in _walk(raw) if kind in "ALC")


def _one_line(err, *needles):
    message = str(err.value) if hasattr(err, "value") else str(err)
    assert "\n" not in message
    for needle in needles:
        assert str(needle) in message, (needle, message)
    return message


def _pyulog_topics(ulog):
    return {d.name if d.multi_id == 0 else f"{d.name}:{d.multi_id}": d for d in ulog.data_list}


def _read_all(log):
    return log.read({name: topic.fields for name, topic in log.topics.items()})


def _assert_same_as_pyulog(log, path):
    """Ours reads exactly what pyulog reads: topics, fields (padding aside), counts, values and times."""
    ref = _pyulog_topics(pyulog.ULog(str(path)))
    assert set(log.topics) >= set(ref)
    assert all(log.topics[name].count == 0 for name in set(log.topics) - set(ref))
    series = _read_all(log)
    for name, d in ref.items():
        fields = tuple(f for f in d.data if not f.rsplit(".", 1)[-1].startswith("_padding"))
        assert log.topics[name].fields == fields, name
        assert log.topics[name].count == len(d.data["timestamp"])
        time = d.data["timestamp_sample"] if "timestamp_sample" in d.data else d.data["timestamp"]
        np.testing.assert_array_equal(series[name].t_s, time / 1e6)
        for j, field in enumerate(fields):
            np.testing.assert_array_equal(series[name].values[:, j], d.data[field].astype(np.float64),
                                          err_msg=f"{name} {field}")
    return series


# ------------------------------------------------------------------------------------------- a flight
def _flight():
    """PX4's real layouts (as in its msg/ files), 2 s; times in us."""
    rng = np.random.default_rng(7)
    t_gyro = 1_000_000 + 4000 * np.arange(500, dtype=np.int64)
    t_servo = 1_001_000 + 20000 * np.arange(100, dtype=np.int64)
    t_rates = 1_000_500 + 10000 * np.arange(200, dtype=np.int64)
    t_gps = 1_000_000 + 200000 * np.arange(10, dtype=np.int64)

    def f32(n):
        return rng.standard_normal(n).astype(np.float32)

    def sensor_gyro(t):
        n = len(t)
        return {"timestamp_sample": t - 120, "device_id": np.full(n, 2293768, np.uint32), "x": f32(n),
                "y": f32(n), "z": f32(n), "temperature": np.float32(41.5) + f32(n),
                "error_count": np.arange(n, dtype=np.uint32), **{f"clip_counter[{i}]": np.zeros(n, np.uint8)
                                                                for i in range(3)},
                "samples": np.full(n, 4, np.uint8)}

    return [
        WriteTopic("vehicle_angular_velocity", t_gyro, {
            "timestamp_sample": t_gyro - 300, **{f"xyz[{i}]": f32(500) for i in range(3)},
            **{f"xyz_derivative[{i}]": f32(500) for i in range(3)}}),
        WriteTopic("actuator_servos", t_servo, {
            "timestamp_sample": t_servo - 50, **{f"control[{i}]": f32(100) for i in range(8)}}),
        WriteTopic("sensor_gyro", t_gyro + 10, sensor_gyro(t_gyro + 10)),
        WriteTopic("sensor_gyro:1", t_gyro + 20, sensor_gyro(t_gyro + 20)),
        WriteTopic("vehicle_rates_setpoint", t_rates, {
            "roll": f32(200), "pitch": f32(200), "yaw": f32(200),
            **{f"thrust_body[{i}]": f32(200) for i in range(3)},
            "reset_integral": np.arange(200) % 3 == 0}),
        WriteTopic("vehicle_global_position", t_gps, {
            "lat": 47.397742 + 1e-7 * np.arange(10), "lon": np.full(10, 8.545594), "alt": f32(10),
            "lat_lon_reset_counter": np.arange(10, dtype=np.uint8), "alt_ellipsoid": f32(10)}),
    ]


@pytest.fixture(scope="module")
def flight():
    return _flight()


@pytest.fixture(scope="module")
def ulg(tmp_path_factory, flight):
    path = tmp_path_factory.mktemp("ulog") / "FLIGHT.ulg"
    write_ulog(path, flight, start_us=123, info={"ver_hw": "SITL", "ver_sw_release": 0x010E00FF})
    return path


@pytest.fixture(scope="module")
def full(ulg):
    with ULogFile(ulg) as log:
        return log.topics, _read_all(log)


# ------------------------------------------------------------------------------------------- writer
def test_pyulog_reads_back_every_value_and_time(ulg, flight):
    ulog = pyulog.ULog(str(ulg))
    assert ulog.start_timestamp == 123
    assert ulog.msg_info_dict["sys_name"] == "gap_validation"
    assert ulog.msg_info_dict["ver_hw"] == "SITL" and ulog.msg_info_dict["ver_sw_release"] == 0x010E00FF
    assert not ulog.file_corruption
    ref = _pyulog_topics(ulog)
    assert set(ref) == {t.name for t in flight}
    for topic in flight:
        d = ref[topic.name]
        np.testing.assert_array_equal(d.data["timestamp"], topic.t_us)
        assert d.data["timestamp"].dtype == np.uint64
        for name, values in topic.fields.items():
            np.testing.assert_array_equal(d.data[name], np.asarray(values).astype(d.data[name].dtype),
                                          err_msg=f"{topic.name} {name}")
            assert np.array_equal(d.data[name].astype(np.float64), np.asarray(values, dtype=np.float64))


def test_writer_uses_px4_layouts(ulg):
    formats = pyulog.ULog(str(ulg), parse_header_only=True).message_formats
    assert formats["vehicle_angular_velocity"].fields == [
        ("uint64_t", 0, "timestamp"), ("uint64_t", 0, "timestamp_sample"), ("float", 3, "xyz"),
        ("float", 3, "xyz_derivative")]
    assert formats["actuator_servos"].fields == [
        ("uint64_t", 0, "timestamp"), ("uint64_t", 0, "timestamp_sample"), ("float", 8, "control")]
    assert ("uint32_t", 0, "device_id") in formats["sensor_gyro"].fields
    assert ("uint8_t", 3, "clip_counter") in formats["sensor_gyro"].fields
    assert ("bool", 0, "reset_integral") in formats["vehicle_rates_setpoint"].fields
    assert formats["vehicle_global_position"].fields[1] == ("double", 0, "lat")
    # one format for both instances of sensor_gyro; subscriptions carry the multi_id
    subs = [(raw[0], raw[3:].decode()) for raw in _payloads(ulg.read_bytes(), "A")]
    assert subs.count((0, "sensor_gyro")) == 1 and subs.count((1, "sensor_gyro")) == 1
    assert [p.decode().split(":")[0] for p in _payloads(ulg.read_bytes(), "F")].count("sensor_gyro") == 1


def _payloads(raw, kind):
    return [raw[pos + 3:pos + 3 + size] for pos, k, size in _walk(raw) if k == kind]


def test_writer_interleaves_data_in_time_order(ulg, flight):
    raw = ulg.read_bytes()
    stamps = [struct.unpack_from("<Q", p, 2)[0] for p in _payloads(raw, "D")]
    assert len(stamps) == sum(len(t.t_us) for t in flight)
    assert all(a <= b for a, b in zip(stamps, stamps[1:]))
    kinds = [k for _, k, _ in _walk(raw)]
    assert kinds[0] == "B" and kinds.index("D") > max(i for i, k in enumerate(kinds) if k in "FAI")


def test_writer_refuses_what_ulog_cannot_hold(tmp_path):
    t = np.arange(3, dtype=np.int64)
    bad = [WriteTopic("a", t, {"x": np.zeros(2)}),                                  # length
           WriteTopic("a", t, {"v[0]": np.zeros(3), "v[2]": np.zeros(3)}),          # array gap
           WriteTopic("a", t, {"x": np.zeros(3, np.float16)}),                      # no ULog type
           WriteTopic("a b", t, {"x": np.zeros(3)}),                                # name
           WriteTopic("a", t[::-1].copy(), {"x": np.zeros(3)})]                     # decreasing time
    for topic in bad:
        with pytest.raises(ValueError):
            write_ulog(tmp_path / "bad.ulg", [topic])
    with pytest.raises(ValueError, match="different fields"):
        write_ulog(tmp_path / "bad.ulg", [WriteTopic("g", t, {"x": np.zeros(3)}),
                                          WriteTopic("g:1", t, {"y": np.zeros(3)})])
    assert not list(tmp_path.iterdir())                     # nothing left behind
    path = write_ulog(tmp_path / "ok.ulg", [WriteTopic("a", t, {"x": np.ones(3)})])
    assert [p.name for p in tmp_path.iterdir()] == ["ok.ulg"] and path == tmp_path / "ok.ulg"


# ------------------------------------------------------------------------------------------- reader
def test_reads_what_pyulog_reads(ulg, full):
    with open_log(ulg) as log:
        assert isinstance(log, ULogFile) and log.format == "ulog"
        series = _assert_same_as_pyulog(log, ulg)
        assert log.damage is None
        assert log.info["sys_name"] == "gap_validation" and log.start_us == 123
    topics, _ = full
    assert list(topics) == ["vehicle_angular_velocity", "actuator_servos", "sensor_gyro", "sensor_gyro:1",
                            "vehicle_rates_setpoint", "vehicle_global_position"]
    assert topics["vehicle_angular_velocity"].fields == (
        "timestamp",
        "timestamp_sample",
        "xyz[0]",
        "xyz[1]",
        "xyz[2]",
        "xyz_derivative[0]",
        "xyz_derivative[1]",
        "xyz_derivative[2]",
    )
    assert series["vehicle_rates_setpoint"].values[:4, -1].tolist() == [1.0, 0.0, 0.0, 1.0]   # bool -> 0/1


def test_time_is_timestamp_sample_where_there_is_one(ulg, flight):
    with ULogFile(ulg) as log:
        got = log.read({"vehicle_angular_velocity": ["xyz[1]"], "vehicle_rates_setpoint": ["yaw"],
                        "actuator_servos": []})
    gyro, rates, servos = flight[0], flight[4], flight[1]
    # sample time
    np.testing.assert_array_equal(got["vehicle_angular_velocity"].t_s, (gyro.t_us - 300) / 1e6)
    np.testing.assert_array_equal(got["vehicle_rates_setpoint"].t_s, rates.t_us / 1e6)            # timestamp
    np.testing.assert_array_equal(got["vehicle_angular_velocity"].values[:, 0], gyro.fields["xyz[1]"])
    assert got["actuator_servos"].values.shape == (100, 0)
    np.testing.assert_array_equal(got["actuator_servos"].t_s, (servos.t_us - 50) / 1e6)


def test_instances_and_their_alias(ulg, flight):
    with ULogFile(ulg) as log:
        got = log.read({"sensor_gyro:0": ["x", "error_count"], "sensor_gyro:1": ["x"], "sensor_gyro": ["z"],
                        "no_such_topic": ["x"]})
        assert "sensor_gyro:0" not in log.topics
    assert set(got) == {"sensor_gyro:0", "sensor_gyro:1", "sensor_gyro"}
    np.testing.assert_array_equal(got["sensor_gyro:0"].values[:, 0], flight[2].fields["x"])
    np.testing.assert_array_equal(got["sensor_gyro:0"].values[:, 1], np.arange(500))
    np.testing.assert_array_equal(got["sensor_gyro:1"].values[:, 0], flight[3].fields["x"])
    np.testing.assert_array_equal(got["sensor_gyro"].values[:, 0], flight[2].fields["z"])
    np.testing.assert_array_equal(got["sensor_gyro:1"].t_s, (flight[3].t_us - 120) / 1e6)


def test_read_before_and_after_topics_agree(ulg, full):
    wanted = {"actuator_servos": ["control[7]", "control[0]"], "sensor_gyro:1": ["temperature"]}
    with ULogFile(ulg) as first:                # one pass: read gives the topics too
        one = first.read(wanted)
        assert first.topics == full[0]
    with ULogFile(ulg) as second:               # topics first, then read
        assert second.topics == full[0]
        two = second.read(wanted)
    for name in wanted:
        assert one[name].fields == two[name].fields == tuple(wanted[name])
        np.testing.assert_array_equal(one[name].values, two[name].values)
        column = full[0][name].fields.index(wanted[name][0])
        np.testing.assert_array_equal(one[name].values[:, 0], full[1][name].values[:, column])


def test_missing_field_is_one_line_listing_the_fields(ulg):
    for first in (True, False):
        with ULogFile(ulg) as log:
            if first:
                log.topics
            with pytest.raises(DataError) as err:
                log.read({"actuator_servos": ["control[8]"]})
        _one_line(err, ulg, "actuator_servos", "control[8]", "control[0], control[1]", "timestamp_sample")


# ------------------------------------------------------------------------------------------- damage
def test_cut_inside_the_header_or_the_definitions_is_one_line(tmp_path, ulg):
    raw = ulg.read_bytes()
    start = _data_start(raw)
    cuts = [0, 5, 7, 15, 16, 17, 18, 40, start // 2, start - 1, start]
    for cut in cuts:
        path = tmp_path / f"cut{cut}.ulg"
        path.write_bytes(raw[:cut])
        with pytest.raises(DataError) as err:
            ULogFile(path)
        message = _one_line(err, path)
        assert ("header" in message) if 0 < cut < 16 else True
        assert ("definitions" in message) if cut >= 16 else True


def test_garbage_is_one_line(tmp_path):
    rng = np.random.default_rng(3)
    junk = tmp_path / "junk.ulg"
    junk.write_bytes(rng.integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(DataError) as err:
        ULogFile(junk)
    _one_line(err, junk, "not a ULog")
    text = tmp_path / "text.ulg"
    text.write_text("timestamp,x\n0,1\n")
    with pytest.raises(DataError) as err:
        ULogFile(text)
    _one_line(err, text, "not a ULog")
    magic_then_junk = tmp_path / "magic.ulg"
    magic_then_junk.write_bytes(MAGIC + b"\x01" + bytes(8) + _msg("F", b"\xff\xfe:x") + bytes(50))
    with pytest.raises(DataError) as err:
        ULogFile(magic_then_junk)
    _one_line(err, magic_then_junk, "byte")


def _prefix_equal(part, whole):
    for name, series in part.items():
        n = len(series.t_s)
        np.testing.assert_array_equal(series.t_s, whole[name].t_s[:n])
        np.testing.assert_array_equal(series.values, whole[name].values[:n])


def test_cut_inside_the_data_reads_up_to_the_cut(tmp_path, ulg, full):
    raw = ulg.read_bytes()
    messages = _walk(raw)
    data = [(pos, size) for pos, kind, size in messages if kind == "D"]
    picks = [data[0], data[len(data) // 3], data[len(data) // 2], data[-1]]
    cuts = [(pos + 1, "message header") for pos, _ in picks[:2]] + \
           [(pos + 3 + size // 2, "data message") for pos, size in picks] + [(len(raw) - 1, "data message")]
    for cut, what in cuts:
        path = tmp_path / "FLIGHT.ulg"
        path.write_bytes(raw[:cut])
        with ULogFile(path) as log:
            part = _assert_same_as_pyulog(log, path)          # pyulog drops the broken message too
            before = sum(1 for pos, size in data if pos + 3 + size <= cut)
            assert sum(t.count for t in log.topics.values()) == before
            _prefix_equal(part, full[1])
            broken = max(pos for pos, _, size in messages if pos < cut)
            message = _one_line(log.damage, path, f"cut short at byte {broken} of {cut}", what)
            t = [s.t_s for s in part.values() if len(s.t_s)]
            if t:
                assert message.endswith(f"read {min(x[0] for x in t):.1f}-{max(x.max() for x in t):.1f} s")
            else:
                assert message.endswith("nothing read before it")


def test_cut_between_messages_is_a_shorter_log(tmp_path, ulg, full):
    raw = ulg.read_bytes()
    pos = [p for p, kind, _ in _walk(raw) if kind == "D"][700]
    path = tmp_path / "short.ulg"
    path.write_bytes(raw[:pos])
    with ULogFile(path) as log:
        part = _assert_same_as_pyulog(log, path)
        assert log.damage is None
    _prefix_equal(part, full[1])
    assert sum(len(s.t_s) for s in part.values()) == 700


@pytest.mark.parametrize("how", ["type 0", "size 0", "huge unknown", "unknown msg_id", "wrong size",
                                 "size past the end"])
def test_corrupt_header_stops_the_read_there(tmp_path, ulg, full, how):
    raw = bytearray(ulg.read_bytes())
    d = [(p, s) for p, kind, s in _walk(bytes(raw)) if kind == "D"]
    index = len(d) - 5 if how == "size past the end" else len(d) // 2
    at, size = d[index]
    if how == "type 0":
        raw[at + 2] = 0
    elif how == "size 0":
        raw[at:at + 3] = struct.pack("<HB", 0, ord("X"))
    elif how == "huge unknown":
        raw[at:at + 3] = struct.pack("<HB", 20000, ord("X"))
    elif how == "unknown msg_id":
        raw[at + 3:at + 5] = struct.pack("<H", 999)
    elif how == "wrong size":                  # one byte short: the message after it is read as shifted
        raw[at:at + 2] = struct.pack("<H", size - 1)
    else:                                      # a size running past the end of the file
        raw[at:at + 2] = struct.pack("<H", 0xFFFF)
    path = tmp_path / "bad.ulg"
    path.write_bytes(bytes(raw))
    with ULogFile(path) as log:
        part = _read_all(log)
        assert sum(t.count for t in log.topics.values()) == index
        if how == "size past the end":
            _one_line(log.damage, path, f"cut short at byte {at} of {len(raw)}")
        else:
            _one_line(log.damage, path, f"at byte {at} of {len(raw)}", "corrupt")
    _prefix_equal(part, full[1])


@pytest.mark.parametrize("block", [211, 997, 4096])
def test_blocks_of_any_size_read_the_same(tmp_path, monkeypatch, ulg, full, block):
    # real files are read in 4 MiB blocks; small ones make every message boundary case occur here
    monkeypatch.setattr(ulog_module, "_BLOCK", block)
    with ULogFile(ulg) as log:
        assert log.topics == full[0]
        got = _read_all(log)
    for name, series in got.items():
        np.testing.assert_array_equal(series.t_s, full[1][name].t_s)
        np.testing.assert_array_equal(series.values, full[1][name].values)
    raw = ulg.read_bytes()
    d = [(p, s) for p, kind, s in _walk(raw) if kind == "D"]
    for index in (len(d) // 4, len(d) - 2):
        at, size = d[index]
        path = tmp_path / "cut.ulg"
        path.write_bytes(raw[:at + 3 + size - 1])
        with ULogFile(path) as log:
            part = _read_all(log)
            assert sum(t.count for t in log.topics.values()) == index
            _one_line(log.damage, f"cut short at byte {at} of {at + 2 + size}", "data message broken off")
        _prefix_equal(part, full[1])


# ------------------------------------------------------------------------------------------- by hand
def _header(start_us=0):
    return MAGIC + b"\x01" + struct.pack("<Q", start_us)


def _flags(incompat0=0, offsets=(0, 0, 0)):
    return _msg("B", bytes(8) + bytes([incompat0]) + bytes(7) + struct.pack("<3Q", *offsets))


def _info(key, value: bytes):
    return _msg("I", bytes([len(key)]) + key.encode() + value)


def _nested_log(path, trailing_padding_logged):
    formats = [
        b"vec3:float x;float y;float z;uint8_t[3] _padding0;",
        b"nested_msg:uint64_t timestamp;vec3 pos;uint8_t[1] _padding1;vec3[2] pair;int16_t k;char[2] tag;"
        b"uint8_t[4] _padding0;",
    ]
    head = _header() + _flags() + _info("char[3] sys_name", b"PX4")
    head += b"".join(_msg("F", f) for f in formats)
    head += _msg("A", struct.pack("<BH", 0, 0) + b"nested_msg")
    vec = struct.Struct("<fff3x")
    rows = []
    for i in range(5):
        payload = struct.pack("<Q", 1000 * i) + vec.pack(i, 2 * i, 3 * i) + b"\0"
        payload += vec.pack(-i, 0.5, 7) + vec.pack(1, 2, -3.25) + struct.pack("<h2s", -i, b"ok")
        if trailing_padding_logged and i % 2:
            payload += bytes(4)
        rows.append(_msg("D", struct.pack("<H", 0) + payload))
    path.write_bytes(head + b"".join(rows))
    return path


def test_nested_types_and_padding_are_named_as_pyulog_names_them(tmp_path):
    path = _nested_log(tmp_path / "nested.ulg", trailing_padding_logged=False)
    names = list(_pyulog_topics(pyulog.ULog(str(path)))["nested_msg"].data)
    assert "pos._padding0[0]" in names and "_padding1[0]" in names and "pair[1].z" in names
    with ULogFile(path) as log:
        series = _assert_same_as_pyulog(log, path)
        assert log.topics["nested_msg"].fields == (
            "timestamp", "pos.x", "pos.y", "pos.z", "pair[0].x", "pair[0].y", "pair[0].z", "pair[1].x",
            "pair[1].y", "pair[1].z", "k", "tag[0]", "tag[1]")
    assert series["nested_msg"].t_s.tolist() == [0.0, 0.001, 0.002, 0.003, 0.004]


def test_trailing_padding_may_be_logged_or_not(tmp_path):
    # the spec: a trailing padding field "may not be logged", so both sizes are valid data messages
    path = _nested_log(tmp_path / "padded.ulg", trailing_padding_logged=True)
    with ULogFile(path) as log:
        got = log.read({"nested_msg": ["pos.z", "pair[1].z", "k", "tag[1]"]})["nested_msg"]
        assert log.damage is None
    np.testing.assert_array_equal(got.values[:, 0], 3.0 * np.arange(5))
    np.testing.assert_array_equal(got.values[:, 1], -3.25)
    np.testing.assert_array_equal(got.values[:, 2], -np.arange(5))
    np.testing.assert_array_equal(got.values[:, 3], ord("k"))


def _small_log(messages, incompat0=0, offsets=(0, 0, 0)):
    head = _header() + _flags(incompat0, offsets) + _msg("F", b"rate:uint64_t timestamp;float v;")
    head += _msg("F", b"other:uint64_t timestamp;uint16_t n;")
    return head + b"".join(messages)


def _rate(msg_id, t_us, v):
    return _msg("D", struct.pack("<HQf", msg_id, t_us, v))


def test_every_data_section_message_type_is_handled_or_skipped(tmp_path):
    body = [_msg("L", b"6" + struct.pack("<Q", 5) + b"Takeoff detected"),
            _msg("A", struct.pack("<BH", 0, 0) + b"rate"),
            _rate(0, 10, 1.5),
            _msg("S", bytes([0x2F, 0x73, 0x13, 0x20, 0x25, 0x0C, 0xBB, 0x12])),
            _msg("C", b"4" + struct.pack("<HQ", 3, 11) + b"tagged"),
            _msg("O", struct.pack("<H", 40)),
            _msg("P", bytes([11]) + b"float RATE1" + struct.pack("<f", 2.0)),
            _msg("Q", bytes([1, 11]) + b"float RATE1" + struct.pack("<f", 1.0)),
            _info("int32_t in_data", struct.pack("<i", 3)),
            _msg("M", bytes([0, 11]) + b"char[2] key" + b"ab"),
            _msg("X", b"a future message type"),
            _rate(0, 20, 2.5),
            _msg("A", struct.pack("<BH", 2, 1) + b"other"),
            _msg("D", struct.pack("<HQH", 1, 21, 9)),
            _msg("R", struct.pack("<H", 1)),
            _rate(0, 30, -1.0)]
    path = tmp_path / "types.ulg"
    path.write_bytes(_small_log(body))
    with ULogFile(path) as log:
        series = _assert_same_as_pyulog(log, path)
        assert log.damage is None
        assert set(log.topics) == {"rate", "other:2"}
    assert series["rate"].values[:, 1].tolist() == [1.5, 2.5, -1.0]
    assert series["other:2"].t_s.tolist() == [21e-6] and series["other:2"].values[:, 1].tolist() == [9.0]


def test_appended_data_is_read_as_part_of_the_data(tmp_path):
    log = [_msg("A", struct.pack("<BH", 0, 0) + b"rate")] + [_rate(0, 10 * i, i) for i in range(5)]
    cut = _rate(0, 50, 5.0)[:6]                              # the log was cut in the middle of a message
    offset = len(_small_log(log)) + len(cut)
    appended = [_rate(0, 100 + i, 100.0 + i) for i in range(3)]
    key = b"char[5] hardfault_plain_text"                   # what PX4's hardfault_log appends
    crash_dump = [_msg("M", bytes([i > 0, len(key)]) + key + b"dump!") for i in range(2)]
    path = tmp_path / "appended.ulg"
    path.write_bytes(_small_log(log + [cut] + appended + crash_dump, incompat0=1, offsets=(offset, 0, 0)))
    with ULogFile(path) as ours:
        got = ours.read({"rate": ["v"]})["rate"]
        assert ours.damage is None
    # the spec: appended data is part of the data section (the subscriptions hold; pyulog 1.3 forgets them
    # at an appended offset, so it is the reference for the part before the offset only)
    assert got.values[:, 0].tolist() == [0, 1, 2, 3, 4, 100, 101, 102]
    assert got.t_s.tolist() == [0, 10e-6, 20e-6, 30e-6, 40e-6, 100e-6, 101e-6, 102e-6]
    ref = pyulog.ULog(str(path)).get_dataset("rate")
    np.testing.assert_array_equal(got.values[:5, 0], ref.data["v"])


def test_unknown_incompatible_flag_is_refused(tmp_path):
    path = tmp_path / "future.ulg"
    path.write_bytes(_small_log([_msg("A", struct.pack("<BH", 0, 0) + b"rate"), _rate(0, 1, 1.0)],
                                incompat0=2))
    with pytest.raises(DataError) as err:
        ULogFile(path)
    _one_line(err, path, "incompat")
