"""ArduPilot DataFlash logs (:mod:`gap_validation.logs.dataflash`), checked against pymavlink's ``DFReader``.

The writer's logs are read back by ``DFReader`` (every value and time); the reader reads the same as
``DFReader`` from them, from hand-made messages with every scaled format character, from truncated files and
from files with junk inside (same messages, same offsets as ``DFReader``'s index); the fast walk equals the
sequential one with tiny blocks, junk, and FMT byte patterns inside payloads.
"""
from __future__ import annotations

import re
import struct

import numpy as np
import pytest

pytest.importorskip("pymavlink")
from pymavlink import DFReader  # noqa: E402

from gap_validation.core.errors import ConfigError, DataError  # noqa: E402
from gap_validation.logs import dataflash as df  # noqa: E402
from gap_validation.logs.base import WriteTopic  # noqa: E402
from gap_validation.logs.dataflash import DataFlashFile, write_dataflash  # noqa: E402
from gap_validation.logs.formats import open_log  # noqa: E402

RATE = "RDes,R,ROut,PDes,P,POut,YDes,Y,YOut,ADes,A,AOut,AOutSlew".split(",")   # AP_AHRS/LogStructure.h
SIDD = "Time,Targ,F,Gx,Gy,Gz,Ax,Ay,Az".split(",")                              # ArduCopter/Log.cpp
RCOU = [f"C{k}" for k in range(1, 15)]                                          # AP_Logger/LogStructure.h
IMU = "GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz".split(",")         # AP_InertialSensor
START_US = 7_000_123
DATA = ("RATE", "SIDD", "RCOU", "IMU")


def _flight(seconds: float = 2.0, seed: int = 0) -> list[WriteTopic]:
    """A copter system-identification flight: RATE and SIDD at 400 Hz, RCOU at 50 Hz, two IMUs at 400 Hz."""
    rng = np.random.default_rng(seed)
    t400 = np.arange(int(400 * seconds)) * 2500
    t50 = t400[::8] + 1000
    n, m = len(t400), len(t50)

    def f32(size):
        return rng.normal(scale=50.0, size=size).astype(np.float32)

    topics = [
        WriteTopic("RATE", t400, {c: f32(n) for c in RATE}, {c: "deg/s" for c in ("RDes", "R", "PDes")}),
        WriteTopic("SIDD", t400 + 200, {c: f32(n) for c in SIDD}, {"Time": "s", "Gx": "deg/s"}),
        WriteTopic("RCOU", t50, {c: 1500.0 + rng.uniform(-400, 400, m) for c in RCOU}, {"C1": "us"}),
    ]
    for k in (0, 1):
        fields = {c: f32(n) for c in IMU[:6]}
        fields.update(EG=rng.integers(0, 3, n).astype(np.uint32), EA=rng.integers(0, 3, n).astype(np.uint32),
                      T=f32(n), GH=np.ones(n, np.uint8), AH=np.ones(n, np.uint8),
                      GHz=np.full(n, 1000, np.uint16), AHz=np.full(n, 1000, np.uint16))
        topics.append(WriteTopic(f"IMU[{k}]", t400 + 100 + 7 * k, fields, {"GyrX": "rad/s", "AccX": "m/s/s"}))
    return topics


@pytest.fixture(scope="module")
def flight():
    return _flight()


@pytest.fixture(scope="module")
def log(tmp_path_factory, flight):
    path = tmp_path_factory.mktemp("df") / "FLIGHT.bin"
    write_dataflash(path, flight, start_us=START_US)
    return path


@pytest.fixture(scope="module")
def theirs(log):
    """DFReader's reading of ``log`` (reader, messages)."""
    return _dfreader(log)


def _dfreader(path, types=DATA, sequential=False):
    """What DFReader gives: (name, instance label or None, TimeUS, _timestamp, {column: value}) per message.

    ``recv_match`` over ``types`` (the usual way; it follows DFReader's index), or with ``sequential`` every
    message of ``recv_msg`` (its parser, which resynchronises after junk; the index stops at the first header
    of an undefined type, since pymavlink's commit 93489bcf of March 2026)."""
    reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
    out = []
    while True:
        m = reader.recv_msg() if sequential else reader.recv_match(type=list(types))
        if m is None:
            break
        if m.get_type() not in types:
            continue
        inst = m.fmt.instance_field
        label = None if inst is None else str(getattr(m, inst))
        out.append(
            (m.get_type(), label, m.TimeUS, m._timestamp, {c: getattr(m, c) for c in m.get_fieldnames()})
        )
    return reader, out


def _ours(path, topics=DATA):
    """Our read of every column of ``topics`` (and their instances)."""
    with DataFlashFile(path) as log:
        names = [t for t in log.topics if t in topics or t.split("[")[0] in topics]
        data = log.read({t: [f for f in log.topics[t].fields] for t in names})
        return data, dict(log.topics), log.damage, log.bad_bytes


def _compare(ours: dict, theirs: list):
    """Every message of ``theirs`` (DFReader) equals ours, topic by topic, in the same order."""
    by_topic: dict[str, list] = {}
    for name, label, time_us, stamp, values in theirs:
        by_topic.setdefault(name, []).append((time_us, stamp, values))
        if label is not None:
            by_topic.setdefault(f"{name}[{label}]", []).append((time_us, stamp, values))
    assert set(by_topic) <= set(ours)
    for topic, series in ours.items():
        rows = by_topic.get(topic, [])
        assert len(series.t_s) == len(rows), topic
        if not rows:
            continue
        assert np.array_equal(series.t_s, np.array([r[0] for r in rows], float) / 1e6), topic
        assert np.allclose(series.t_s, [r[1] for r in rows], rtol=1e-15, atol=0), topic
        expect = np.array([[float(r[2][f]) for f in series.fields] for r in rows])
        assert np.array_equal(series.values, expect, equal_nan=True), topic


# -- the writer, read back by DFReader
# -------------------------------------------------------------------------


def test_dfreader_reads_back_every_value_and_time(theirs, flight):
    reader, msgs = theirs
    for topic in flight:
        name, _, inst = topic.name.partition("[")
        rows = [m for m in msgs if m[0] == name and (not inst or m[1] == inst.rstrip("]"))]
        assert [r[2] for r in rows] == (topic.t_us + START_US).tolist(), topic.name
        assert np.array_equal([r[3] for r in rows], (topic.t_us + START_US) * 1e-6)
        for col, values in topic.fields.items():
            got = np.array([r[4][col] for r in rows], float)
            want = np.rint(values) if name == "RCOU" else values.astype(float)
            assert np.array_equal(got, want), (topic.name, col)
    # ArduPilot's own layouts (LogStructure.h): the formats DFReader sees
    fmts = {f.name: f for f in reader.formats.values()}
    assert fmts["RATE"].format == "Q" + "f" * 13 and fmts["SIDD"].format == "Qfffffffff"
    assert fmts["RCOU"].format == "Q" + "H" * 14
    assert fmts["IMU"].format.startswith("QBffffff") and fmts["IMU"].instance_field == "I"
    assert fmts["RATE"].columns == ["TimeUS"] + RATE and fmts["IMU"].columns == ["TimeUS", "I"] + IMU
    assert reader.messages.keys() >= {"IMU[0]", "IMU[1]"}
    assert fmts["IMU"].get_unit("GyrX") == "rad/s" and fmts["RATE"].get_unit("TimeUS") == "µs"


def test_messages_in_time_order_as_ardupilot_writes(log, theirs):
    _, msgs = theirs
    times = [m[2] for m in msgs]
    assert times == sorted(times)
    head = open(log, "rb").read(89)
    assert head[:3] == b"\xa3\x95\x80" and head[3] == 128 and head[4] == 89 and head[5:8] == b"FMT"


# -- the reader against DFReader
# -----------------------------------------------------------------------------------


def test_reads_the_same_as_dfreader(log, theirs):
    reader, msgs = theirs
    ours, topics, damage, bad = _ours(log)
    assert damage is None and bad == 0
    _compare(ours, msgs)
    names = {k for k in reader.messages if k not in ("MAV", "__MAV__")}
    assert names <= set(topics) and {"IMU[0]", "IMU[1]"} <= set(topics)
    assert topics["IMU"].count == topics["IMU[0]"].count + topics["IMU[1]"].count == 1600
    assert topics["RATE"].fields == ("TimeUS", *RATE)
    assert open_log(log).format == "dataflash"


def _message(tid: int, fmt: str, *values) -> bytes:
    codes = {
        "Q": "Q",
        "c": "h",
        "C": "H",
        "e": "i",
        "E": "I",
        "L": "i",
        "M": "b",
        "b": "b",
        "g": "e",
        "q": "q",
        "h": "h",
        "H": "H",
        "i": "i",
        "I": "I",
        "B": "B",
        "f": "f",
        "d": "d",
        "n": "4s",
        "Z": "64s",
        "N": "16s",
    }
    return bytes([0xA3, 0x95, tid]) + struct.pack("<" + "".join(codes[c] for c in fmt), *values)


def _fmt(tid: int, name: str, fmt: str, columns: str) -> bytes:
    length = 3 + sum(df.FORMATS[c][0].itemsize for c in fmt)
    return _message(128, "BBnNZ", tid, length, name.encode(), fmt.encode(), columns.encode())


TYP1, TYP1_COLS, TYP1_RAW = "QcCeELMbg", "TimeUS,c,C,e,E,L,M,b,g", (
    5_000_000, -1234, 65000, -987654, 4000000000, 473977418, 5, -7, 1.5)
TYP2, TYP2_COLS, TYP2_RAW = "QqhHiIBfdn", "TimeUS,q,h,H,i,I,B,f,d,n", (
    5_000_100, -2**40, -300, 60000, -70000, 3_000_000_000, 250, 0.1, -2.5, b"abc")


def test_format_characters_scaled_as_dfreader(tmp_path):
    path = tmp_path / "types.bin"
    body = (
        _fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")
        + _fmt(140, "TYP1", TYP1, TYP1_COLS)
        + _fmt(142, "TYP2", TYP2, TYP2_COLS)
        + _fmt(141, "NOTI", "BB", "A,B")
        + _message(140, TYP1, *TYP1_RAW)
        + _message(142, TYP2, *TYP2_RAW)
        + _message(141, "BB", 1, 2)
    )
    path.write_bytes(body)
    _, msgs = _dfreader(path, ["TYP1", "TYP2"])
    with DataFlashFile(path) as log:
        cols1, cols2 = TYP1_COLS.split(","), TYP2_COLS.split(",")[:-1]
        got = log.read({"TYP1": cols1, "TYP2": cols2})
        _compare(got, msgs)
        # by hand: c C e E are x0.01, L x1e-7 (divided, as DFReader divides), the rest as logged
        row = dict(zip(cols1, got["TYP1"].values[0])) | dict(zip(cols2, got["TYP2"].values[0]))
        assert row["c"] == -12.34 and row["C"] == 650.0 and row["e"] == -9876.54 and row["E"] == 40000000.0
        assert row["L"] == 47.3977418 and row["M"] == 5 and row["b"] == -7 and row["g"] == 1.5
        assert row["q"] == -2**40 and row["h"] == -300 and row["H"] == 60000 and row["i"] == -70000
        assert row["I"] == 3e9 and row["B"] == 250 and row["f"] == float(np.float32(0.1)) and row["d"] == -2.5
        assert got["TYP1"].t_s[0] == 5.0 and got["TYP2"].t_s[0] == 5.0001
        with pytest.raises(DataError, match=r"field n of topic TYP2 is not a number") as err:
            log.read({"TYP2": ["n"]})
        assert "\n" not in str(err.value)
        with pytest.raises(DataError, match=r"types.bin: topic NOTI has no TimeUS column") as err:
            log.read({"NOTI": ["A"]})
        with pytest.raises(DataError, match=r"topic FMT has no TimeUS"):
            log.read({"FMT": ["Type"]})


def test_instances_named_as_dfreader_names_them(tmp_path):
    # a text instance (as NVF's name) and a scaled one: DFReader's "%s[%s]" % (name, value) of the decoded
    # value
    fmtu = "TimeUS,FmtType,UnitIds,MultIds"
    body = [_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"), _fmt(150, "FMTU", "QBNN", fmtu),
            _fmt(143, "NVF", "QnB", "TimeUS,Name,Value"), _fmt(144, "FIN", "Qcf", "TimeUS,Inst,V"),
            _fmt(145, "EMPT", "Qf", "TimeUS,V"), _message(150, "QBNN", 0, 143, b"s#-", b"F--"),
            _message(150, "QBNN", 0, 144, b"s#-", b"F--")]
    for k in range(30):
        body += [_message(143, "QnB", 10 * k, [b"abc", b"de\0x"][k % 2], k),
                 _message(144, "Qcf", 10 * k + 1, [150, -25, 150][k % 3], k / 3)]
    path = tmp_path / "inst.bin"
    path.write_bytes(b"".join(body))
    reader, msgs = _dfreader(path, ("NVF", "FIN"))
    with DataFlashFile(path) as f:
        names = {t for t in f.topics if "[" in t}
        assert names == {k for k in reader.messages if "[" in k} == {"NVF[abc]", "NVF[de]", "FIN[1.5]",
                                                                     "FIN[-0.25]"}
        assert f.topics["FIN[1.5]"].count == 20 and f.topics["NVF[de]"].count == 15
        got = f.read({t: ["Value" if t.startswith("NVF") else "V"] for t in names | {"EMPT", "NVF", "FIN"}})
        assert got["EMPT"].values.shape == (0, 1) and got["EMPT"].t_s.shape == (0,)
        del got["EMPT"]
        _compare(got, msgs)
        assert got["NVF[de]"].values[:, 0].tolist() == list(range(1, 30, 2))


def test_a_type_that_cannot_be_decoded_is_listed_and_refused(tmp_path):
    body = (_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns") + _fmt(140, "AA", "Qf", "TimeUS,x")
            + _message(128, "BBnNZ", 141, 12, b"ODD", b"QX", b"TimeUS,y") + _message(140, "Qf", 1, 1.0)
            + bytes([0xA3, 0x95, 141]) + bytes(9) + _message(140, "Qf", 2, 2.0))
    path = tmp_path / "odd.bin"
    path.write_bytes(body)
    with DataFlashFile(path) as f:
        assert f.topics["ODD"].count == 1 and f.topics["AA"].count == 2
        with pytest.raises(
            DataError, match=r"odd.bin: topic ODD cannot be decoded: unknown format characters 'X'"
        ):
            f.read({"ODD": ["y"]})
        assert f.read({"AA": ["x"]})["AA"].values[:, 0].tolist() == [1.0, 2.0]


def test_missing_field_is_one_line_listing_the_fields(log):
    with DataFlashFile(log) as f:
        with pytest.raises(DataError) as err:
            f.read({"RATE": ["ROut", "Rout"]})
    assert str(err.value) == f"{log}: topic RATE has no field Rout (it has: TimeUS, {', '.join(RATE)})"


def test_a_second_read_walks_again_and_reads_the_same(log):
    wanted = {"RATE": ["ROut", "TimeUS"], "IMU[0]": ["GyrZ"], "IMU": ["I", "AccX"], "RCOU": ["C14"]}
    with DataFlashFile(log) as f:
        first = f.read(wanted)                 # from the offsets the topics walk kept
        assert f._index is None                # dropped: only the fields stay
        second = f.read(wanted)                # a walk keeping the wanted types only
        mm = f._mm
    assert mm.closed                           # no view of the memory map outlives the reads
    for topic in wanted:
        assert np.array_equal(first[topic].t_s, second[topic].t_s)
        assert np.array_equal(first[topic].values, second[topic].values) and len(first[topic].t_s)
    assert first["IMU"].values[:4, 0].tolist() == [0, 1, 0, 1]


def test_unknown_topics_are_left_out_and_empty_reads_work(log):
    with DataFlashFile(log) as f:
        got = f.read({"XXXX": ["a"], "IMU[1]": ["GyrX"], "IMU[7]": ["GyrX"]})
        assert set(got) == {"IMU[1]"} and got["IMU[1]"].values.shape == (800, 1)


# -- damaged files
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("content", [b"", b"hello world, not a log\n" * 100, bytes(range(256)) * 300,
                                     b"\xa3\x95\x80" + bytes(200)])
def test_not_a_dataflash_log(tmp_path, content):
    path = tmp_path / "x.bin"
    path.write_bytes(content)
    with pytest.raises(DataError) as err:
        DataFlashFile(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def test_cut_inside_the_first_fmt(tmp_path, log):
    path = tmp_path / "cut.bin"
    path.write_bytes(log.read_bytes()[:50])
    with pytest.raises(DataError, match=r"cut short at byte 50 of 50 inside the first FMT message"):
        DataFlashFile(path)


def _full(log):
    data, topics, _, _ = _ours(log)
    return data


def _offsets(path):
    """Offsets of the data messages in DFReader's index (name -> list)."""
    reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
    return {n: reader.offsets[reader.name_to_id[n]] for n in DATA}, reader


@pytest.mark.parametrize(
    "where", ["boundary", "header+1", "header+2", "header+3", "header+4", "middle", "fmts"]
)
def test_truncated_reads_up_to_the_cut(tmp_path, log, where):
    full = _full(log)
    raw = log.read_bytes()
    rate = _offsets(log)[0]["RATE"]
    cut, start, what = {"boundary": (rate[300], None, None),
                        "header+1": (rate[700] + 1, rate[700], "a message broken off in its header"),
                        "header+2": (rate[700] + 2, rate[700], "a message broken off in its header"),
                        "header+3": (rate[700] + 3, rate[700], "a message broken off in its header"),
                        "header+4": (rate[700] + 4, rate[700], "a RATE message broken off"),
                        "middle": (rate[555] + 20, rate[555], "a RATE message broken off"),
                        "fmts": (400, 4 * 89, "a FMT message broken off")}[where]
    path = tmp_path / "CUT.bin"
    path.write_bytes(raw[:cut])
    part, topics, damage, bad = _ours(path)
    _, msgs = _dfreader(path)
    _compare(part, msgs)                                  # the same as DFReader on the cut file
    for topic, series in part.items():                    # and a prefix of the full read
        n = len(series.t_s)
        assert np.array_equal(series.t_s, full[topic].t_s[:n])
        assert np.array_equal(series.values, full[topic].values[:n])
    assert bad == 0
    if where == "boundary":
        assert damage is None and len(part["RATE"].t_s) == 300
        return
    span = "read no timed messages" if where == "fmts" else \
        f"read {START_US / 1e6:.1f}-{max(s.t_s[-1] for s in part.values() if len(s.t_s)):.1f} s"
    assert damage == f"{path}: cut short at byte {start} of {cut} ({what}); {span}"
    if where != "fmts":
        assert len(part["RATE"].t_s) == rate.index(start)
    else:
        assert not part and set(topics) == {"FMT", "UNIT", "FMTU", "MULT"}


def test_cut_header_positions_are_damage_not_junk(tmp_path, log):
    raw = log.read_bytes()
    rate = _offsets(log)[0]["RATE"]
    for extra in (1, 2, 3):
        path = tmp_path / f"c{extra}.bin"
        path.write_bytes(raw[:rate[500] + extra])
        with DataFlashFile(path) as f:
            assert f.topics["RATE"].count == 500
            assert f.damage is not None and f"at byte {rate[500]} of" in f.damage and f.bad_bytes == 0


# -- junk: resynchronisation as DFReader does it
# -----------------------------------------------------------------


def _with_junk(raw: bytes, places: list[tuple[int, bytes]]) -> bytes:
    out, last = [], 0
    for pos, junk in sorted(places):
        out += [raw[last:pos], junk]
        last = pos
    return b"".join(out + [raw[last:]])


@pytest.mark.parametrize("kind", ["plain", "unknown-type", "known-type", "fmt-pattern"])
def test_junk_is_skipped_as_dfreader_skips_it(tmp_path, log, kind, capfd):
    raw = log.read_bytes()
    rate = _offsets(log)[0]["RATE"]
    junk = {"plain": b"\x00\x11junk\x42" * 7,                        # no header pattern: 49 bytes skipped
            "unknown-type": b"\x01\xa3\x95\x07\x02" * 3,             # a header with a type never defined
            "known-type": b"\xa3\x95" + bytes([df._FIRST_ID + 3]) + b"\x05" * 20,   # a fake RATE start
            "fmt-pattern": b"\xa3\x95\x80\xf0\x10" + bytes(12)}[kind]
    inside = 0 if kind in ("plain", "unknown-type") else 7          # between messages, or inside one
    places = [(rate[100] + inside, junk), (rate[400], junk), (rate[750], junk), (len(raw), b"\x00" * 5)]
    path = tmp_path / "JUNK.bin"
    path.write_bytes(_with_junk(raw, places))
    ours, topics, damage, bad = _ours(path)
    reader, msgs = _dfreader(path, sequential=True)
    _compare(ours, msgs)
    if kind == "plain":          # the same messages as DFReader's index (recv_match), at the same offsets
        _compare(ours, _dfreader(path)[1])
        with DataFlashFile(path) as f:
            walk = f._walk(None)
            for name in DATA:
                tid = reader.name_to_id[name]
                assert walk.offsets[tid].tolist() == reader.offsets[tid], name
    if kind in ("plain", "unknown-type"):
        assert bad == 3 * len(junk) + 5 and damage is None
        with DataFlashFile(path) as f:
            f.topics
            assert (
                f.skipped
                == f"{path}: skipped {bad} bytes that are not messages (the first at byte {rate[100]})"
            )
        full = _full(log)
        for topic in full:
            assert np.array_equal(full[topic].values, ours[topic].values)
    else:
        assert bad > 0
    capfd.readouterr()


# -- the fast walk against the sequential one
# --------------------------------------------------------------------


def _spurious_fmt(tid: int, length: int) -> float:
    """A float64 whose bytes start with an FMT header defining ``tid`` with ``length``."""
    return float(np.frombuffer(bytes([0xA3, 0x95, 0x80, tid, length, 0, 0, 0x40]), "<f8")[0])


def _walks_agree(path, monkeypatch, block):
    monkeypatch.setattr(df, "_BLOCK", block)
    with DataFlashFile(path) as f:
        fast, _, table = df._index(f._mm, f._data, f._size, None)
        slow, _ = df._walk_sequential(f._mm, f._size, None)
        assert np.array_equal(fast.counts, slow.counts)
        assert fast.offsets.keys() == slow.offsets.keys()
        for tid in fast.offsets:
            assert np.array_equal(fast.offsets[tid], slow.offsets[tid]), tid
        assert (fast.bad_bytes, fast.first_bad, fast.cut, fast.cut_type) == \
            (slow.bad_bytes, slow.first_bad, slow.cut, slow.cut_type)
        return fast, table


@pytest.mark.parametrize("seed", range(6))
def test_fast_walk_equals_sequential_walk(tmp_path, monkeypatch, seed):
    rng = np.random.default_rng(seed)
    n = 300
    t = np.arange(n) * 1000
    x = rng.normal(size=n)
    # FMT patterns inside payloads: one redefining a used type with another length, one defining a new type
    x[rng.integers(0, n, 3)] = _spurious_fmt(df._FIRST_ID + 4, 31)
    x[rng.integers(0, n, 3)] = _spurious_fmt(0xF0, 9)
    topics = [WriteTopic("AAA", t, {"x": x, "y": rng.normal(size=n)}),
              WriteTopic("BB", t + 3, {"k": rng.integers(-5, 5, n).astype(np.int16)}),
              WriteTopic("CC[0]", t + 5, {"z": rng.normal(size=n).astype(np.float32)}),
              WriteTopic("CC[3]", t + 6, {"z": rng.normal(size=n).astype(np.float32)})]
    path = tmp_path / f"w{seed}.bin"
    write_dataflash(path, topics)
    raw = path.read_bytes()
    with DataFlashFile(path) as f:
        first_data = int(min(f._walk(None).offsets[df._FIRST_ID + 3]))
    junks = [bytes(rng.integers(0, 256, rng.integers(1, 40), dtype=np.uint8)) for _ in range(8)]
    junks += [b"\xa3\x95\xf0" + bytes(8), b"\xa3\x95", b"\xa3\x95\x85" + bytes(3), b"\xa3\x95\x80\x86\x02"]
    for lowest in (3, first_data):          # junk anywhere (also inside the definitions), junk among the data
        places = [(int(p), j) for p, j in zip(rng.integers(lowest, len(raw), len(junks)), junks)]
        path.write_bytes(_with_junk(raw, places)[:len(raw) - int(rng.integers(0, 60))])
        for block in (64, 1000, 1 << 24):
            _walks_agree(path, monkeypatch, block)
    _, msgs = _dfreader(path, ("AAA", "BB", "CC"), sequential=True)
    _compare(_ours(path, ("AAA", "BB", "CC"))[0], msgs)


def test_spurious_fmt_patterns_are_checked_against_the_path(tmp_path, monkeypatch):
    # AAA's values hold the bytes of an FMT giving BB 40 bytes, before BB's real FMT (13 bytes; defined late,
    # as ArduPilot defines types when first written): the table found by the bytes is wrong, the walk's is
    # right
    fake = _spurious_fmt(141, 40)
    body = [_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"), _fmt(140, "AAA", "Qd", "TimeUS,x")]
    body += [_message(140, "Qd", k, fake) for k in range(50)] + [_fmt(141, "BB", "Qh", "TimeUS,k")]
    body += [_message(140, "Qd", k, fake) + _message(141, "Qh", k, -k) for k in range(50, 100)]
    path = tmp_path / "s.bin"
    path.write_bytes(b"".join(body))
    with DataFlashFile(path) as f:
        table = df._Table.empty()
        df._grow(table, f._data, np.array([m.start() for m in re.finditer(b"\xa3\x95\x80", f._mm)]))
        assert table.lengths[141] == 40
    fast, table = _walks_agree(path, monkeypatch, 1 << 24)
    assert (
        table is not None and table.lengths[141] == 13 and fast.counts[140] == 100 and fast.counts[141] == 50
    )
    data, _, _, bad = _ours(path, ("AAA", "BB"))
    assert bad == 0 and np.array_equal(data["AAA"].values[:, 1], np.full(100, fake))
    assert np.array_equal(data["BB"].values[:, 1], -np.arange(50, 100))
    _compare(data, _dfreader(path, ("AAA", "BB"))[1])


def test_a_type_redefined_with_another_length_uses_the_sequential_walk(tmp_path):
    body = (_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns") + _fmt(140, "AA", "Qf", "TimeUS,x")
            + _fmt(142, "OK", "Qh", "TimeUS,y") + _message(140, "Qf", 1, 1.0) + _message(142, "Qh", 1, -1)
            + _fmt(140, "AA", "Qd", "TimeUS,x") + _message(140, "Qd", 2, 2.0) + _message(142, "Qh", 2, -2))
    path = tmp_path / "r.bin"
    path.write_bytes(body)
    with DataFlashFile(path) as f:
        assert f.topics["AA"].count == 2 and f._sequential
        with pytest.raises(DataError, match="defined twice with different layouts"):
            f.read({"AA": ["x"]})
        assert f.read({"OK": ["y"]})["OK"].values[:, 0].tolist() == [-1, -2]


# -- the writer's rules
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("topic, error", [
    (WriteTopic("RATES", np.arange(3), {"x": np.zeros(3)}), ConfigError),
    (WriteTopic("FMTU", np.arange(3), {"x": np.zeros(3)}), ConfigError),
    (WriteTopic("IMU[300]", np.arange(3), {"x": np.zeros(3)}), ConfigError),
    (WriteTopic("BIG", np.arange(3), {f"x{k}": np.zeros(3) for k in range(16)}), ConfigError),
    (WriteTopic("AB", np.arange(3), {"TimeUS": np.zeros(3)}), ConfigError),
    (WriteTopic("AB[1]", np.arange(3), {"I": np.zeros(3)}), ConfigError),
    (WriteTopic("AB", np.arange(3), {"a,b": np.zeros(3)}), ConfigError),
    (WriteTopic("AB", np.array([0, 2, 1]), {"x": np.zeros(3)}), DataError),
    (WriteTopic("AB", np.arange(3), {"x": np.zeros(2)}), DataError),
    (WriteTopic("RCOU", np.arange(3), {"C1": np.array([1500.0, np.nan, 1500.0])}), DataError),
    (WriteTopic("RCOU", np.arange(3), {"C1": np.array([1500, 70000, 1500])}), DataError),
])
def test_writer_refuses_what_dataflash_cannot_hold(tmp_path, topic, error):
    path = tmp_path / "bad.bin"
    path.write_bytes(b"old")
    with pytest.raises(error) as err:
        write_dataflash(path, [topic])
    assert "\n" not in str(err.value) and str(path) in str(err.value)
    assert path.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["bad.bin"]


def test_writer_instances_must_match(tmp_path):
    t = np.arange(3)
    with pytest.raises(ConfigError, match="same fields"):
        write_dataflash(tmp_path / "i.bin", [WriteTopic("IMU[0]", t, {"a": np.zeros(3)}),
                                             WriteTopic("IMU[1]", t, {"b": np.zeros(3)})])
    with pytest.raises(ConfigError, match="same fields"):
        write_dataflash(tmp_path / "i.bin", [WriteTopic("IMU[0]", t, {"a": np.zeros(3)}),
                                             WriteTopic("IMU", t, {"a": np.zeros(3)})])


def test_writer_integer_formats_fit_the_values(tmp_path):
    t = np.arange(4)
    fields = {"a": np.array([0, 1, 2, 255]), "b": np.array([-1, 0, 1, 2]), "c": np.array([0, 1, 2, 60000]),
              "d": np.array([0, -70000, 0, 1]), "e": np.array([True, False, True, True]),
              "f": np.zeros(4, np.float32), "g": np.zeros(4)}
    path = write_dataflash(tmp_path / "ints.bin", [WriteTopic("INT", t, fields)])
    reader = DFReader.DFReader_binary(str(path))
    assert reader.formats[reader.name_to_id["INT"]].format == "QBhHiBfd"
    m = [reader.recv_match(type="INT") for _ in range(4)][-1]
    assert (m.a, m.b, m.c, m.d, m.e) == (255, 2, 60000, 1, True)
