"""CSV flight logs (gap_validation.logs.csvlog): one file per topic, read back exactly, checked against the
``csv`` module and hand-computed values; time columns and their units; bad cells, cut files and missing
columns as one line each, never a traceback."""
import csv
import math

import numpy as np
import pytest

from gap_validation.core.config import parse_config
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.logs.base import WriteTopic
from gap_validation.logs.csvlog import TIME_COLUMNS, CsvFile, time_scale, write_csv
from gap_validation.logs.formats import open_log


def _one_line(err, *needles):
    text = str(err.value) if hasattr(err, "value") else str(err)
    assert "\n" not in text
    for needle in needles:
        assert str(needle) in text, (needle, text)
    return text


def _reference(path):
    """The file as the ``csv`` module reads it (comments skipped): header and rows of floats (NaN where not a
    number)."""
    with open(path, newline="", encoding="utf-8-sig") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]

    def num(cell):
        try:
            return float(cell)
        except ValueError:
            return math.nan
    return rows[0], np.array([[num(c) for c in r] for r in rows[1:]])


@pytest.fixture
def topics():
    rng = np.random.default_rng(7)
    n = 257
    imu = WriteTopic(
        "imu",
        np.cumsum(rng.integers(3000, 5000, n)).astype(np.int64) + 60_000_000,
        {"p": rng.standard_normal(n), "q": rng.standard_normal(n) * 1e-9, "r": rng.standard_normal(n) * 1e6},
        {"p": "rad/s", "q": "rad/s"},
    )
    surfaces = WriteTopic("control_surfaces", np.arange(40, dtype=np.int64) * 20_000 + 60_001_000,
                          {"elevator": np.linspace(-0.1, 0.1, 40)})
    return [imu, surfaces]


def test_written_files_read_back_exactly(tmp_path, topics):
    paths = write_csv(tmp_path / "flight", topics)
    assert [p.name for p in paths] == ["imu.csv", "control_surfaces.csv"]
    assert paths[0].read_text().splitlines()[0] == "# units: TimeUS [us], p [rad/s], q [rad/s]"
    for path, topic in zip(paths, topics):
        log = open_log(path)
        assert isinstance(log, CsvFile) and log.time_column == "TimeUS" and log.damage is None
        info = log.topics[topic.name]
        assert info.fields == tuple(topic.fields) and info.count == topic.t_us.size
        series = log.read({topic.name: list(topic.fields)})[topic.name]
        assert np.array_equal(series.t_s, topic.t_us * 1e-6)                  # TimeUS: whole microseconds
        for j, name in enumerate(topic.fields):
            assert np.array_equal(series.values[:, j], topic.fields[name])    # repr: float64 to the bit
        header, rows = _reference(path)                                       # and as the csv module reads it
        assert header == ["TimeUS", *topic.fields]
        assert np.array_equal(rows[:, 1:], series.values)


def test_one_topic_to_a_csv_path_and_what_write_csv_refuses(tmp_path, topics):
    assert write_csv(tmp_path / "roll.csv", topics[1:]) == [tmp_path / "roll.csv"]
    assert open_log(tmp_path / "roll.csv").topics["roll"].fields == ("elevator",)
    with pytest.raises(DataError) as err:
        write_csv(tmp_path / "two.csv", topics)
    _one_line(err, "two.csv", "one topic")
    back = WriteTopic("x", np.array([2, 1]), {"a": np.zeros(2)})
    with pytest.raises(DataError) as err:
        write_csv(tmp_path / "d", [back])
    _one_line(err, "x.csv", "go back")
    short = WriteTopic("y", np.array([1, 2]), {"a": np.zeros(3)})
    with pytest.raises(DataError) as err:
        write_csv(tmp_path / "d", [short])
    _one_line(err, "y.csv", "field a", "3 values for 2 times")


@pytest.mark.parametrize("column, scale", [("time", 1.0), ("t", 1.0), ("TimeUS", 1e-6), ("timestamp", 1e-6)])
def test_the_default_time_columns_and_their_units(tmp_path, column, scale):
    path = tmp_path / "rates.csv"
    path.write_text(f"q,{column}\n0.5,1000\n0.25,3000\n")
    log = open_log(path)
    assert log.time_column == column and log.topics["rates"].fields == ("q",)
    series = log.read({"rates": ["q"]})["rates"]
    assert np.array_equal(series.t_s, np.array([1000.0, 3000.0]) * scale)
    assert np.array_equal(series.values[:, 0], [0.5, 0.25])


def test_time_column_order_unit_by_name_and_the_config_key(tmp_path):
    path = tmp_path / "rates.csv"
    path.write_text("TimeUS,time,t_ms,q\n1000000,2.0,3000,1.5\n")
    assert TIME_COLUMNS.index("time") < TIME_COLUMNS.index("TimeUS")
    # the first of TIME_COLUMNS, not the first column
    assert CsvFile(path).time_column == "time"
    t_ms = CsvFile(path, time_column="t_ms")
    assert t_ms.read({"rates": ["q"]})["rates"].t_s[0] == pytest.approx(3.0)
    assert "time" in t_ms.topics["rates"].fields and "t_ms" not in t_ms.topics["rates"].fields
    assert [time_scale(c) for c in ("time", "TimeUS", "gps_us", "T_MS", "stamp_ns", "timestamp", "sec")] == \
        [1.0, 1e-6, 1e-6, 1e-3, 1e-9, 1e-6, 1.0]
    with pytest.raises(DataError) as err:
        CsvFile(path, time_column="clock")
    _one_line(err, "rates.csv", "'clock'", "TimeUS, time, t_ms, q")
    spec = parse_config({"channels": {"pitch": {
        "input": {"topic": "surfaces", "field": "elevator", "time_column": "t_ms"},
        "output": {"topic": "rates", "field": "q"},
        "model": {"numerator": [1.0], "denominator": [1.0, 1.0]}}}}, "c.yaml").channels["pitch"]
    assert spec.input.time_column == "t_ms" and spec.output.time_column is None
    assert spec.input.topic == "/surfaces"
    with pytest.raises(ConfigError) as err:
        parse_config({"channels": {"pitch": {
            "input": {"topic": "s", "field": "e", "time_column": 3}, "output": {"topic": "r", "field": "q"},
            "model": {"numerator": [1.0], "denominator": [1.0, 1.0]}}}}, "c.yaml")
    _one_line(err, "c.yaml", "channels.pitch.input.time_column")


def test_no_time_column_missing_field_and_empty_files_are_one_line(tmp_path):
    path = tmp_path / "rates.csv"
    path.write_text("p,q\n1,2\n")
    with pytest.raises(DataError) as err:
        open_log(path)
    _one_line(err, "rates.csv", "no time column", "time, t, TimeUS, timestamp", "it has: p, q", "time_column")
    path.write_text("time,p,q\n0,1,2\n")
    with pytest.raises(DataError) as err:
        open_log(path).read({"rates": ["r"]})
    _one_line(err, "rates.csv", "topic rates has no field r", "it has: p, q")
    empty = tmp_path / "empty.csv"
    empty.write_text("# only a comment\n\n")
    with pytest.raises(DataError) as err:
        open_log(empty)
    _one_line(err, "empty.csv", "no header")
    only_header = tmp_path / "header.csv"
    only_header.write_text("time,p\n")
    series = open_log(only_header).read({"header": ["p"]})["header"]
    assert series.t_s.size == 0 and series.values.shape == (0, 1)
    twice = tmp_path / "twice.csv"
    twice.write_text("time,p,p\n")
    with pytest.raises(DataError) as err:
        open_log(twice)
    _one_line(err, "twice.csv", "'p' twice")
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"time,p\n\xff\xfe\x00\n")
    with pytest.raises(DataError) as err:
        open_log(binary)
    _one_line(err, "binary.csv", "UTF-8")


def test_a_cell_that_is_not_a_number_is_nan_and_the_rest_exact(tmp_path, topics):
    path = write_csv(tmp_path, topics[:1])[0]
    lines = path.read_text().splitlines(keepends=True)
    cells = lines[10].split(",")
    cells[2] = "n/a"                         # q of row 8
    lines[10] = ",".join(cells)
    lines[20] = lines[20].split(",")[0] + ",,1e6x," + "\n"       # row 18: p empty, q bad, r missing
    path.write_text("".join(lines))
    log = open_log(path)
    series = log.read({"imu": ["p", "q", "r"]})["imu"]
    header, reference = _reference(path)
    assert series.values.shape == (topics[0].t_us.size, 3) and log.damage is None
    bad = ~np.isfinite(series.values)
    assert np.flatnonzero(bad.any(axis=1)).tolist() == [8, 18]
    assert bad[8].tolist() == [False, True, False] and bad[18].tolist() == [True, True, True]
    good = ~bad
    expected = np.column_stack([topics[0].fields[n] for n in ("p", "q", "r")])
    assert np.array_equal(series.values[good], expected[good])
    assert np.array_equal(series.values[good], reference[:, 1:][good])
    assert np.array_equal(series.t_s, topics[0].t_us * 1e-6)


def test_the_fast_and_the_cell_by_cell_parser_agree(tmp_path, topics, monkeypatch):
    path = write_csv(tmp_path, topics[:1])[0]
    fast = open_log(path).read({"imu": ["r", "p"]})["imu"]
    monkeypatch.setattr(CsvFile, "_load_fast", lambda self, columns, lines: None)
    slow = open_log(path).read({"imu": ["r", "p"]})["imu"]
    assert fast.fields == slow.fields == ("r", "p")
    assert np.array_equal(fast.values, slow.values) and np.array_equal(fast.t_s, slow.t_s)


def test_a_file_cut_mid_row_is_read_up_to_the_damage(tmp_path, topics):
    path = write_csv(tmp_path, topics[:1])[0]
    text = path.read_text()
    cut = text[:text.rindex(",") - 3]          # inside the last row's second to last cell
    path.write_text(cut)
    log = open_log(path)
    series = log.read({"imu": ["p", "q"]})["imu"]
    n = topics[0].t_us.size
    assert series.t_s.size == n - 1
    assert np.array_equal(series.values[:, 0], topics[0].fields["p"][:n - 1])
    span = (topics[0].t_us[n - 2] - topics[0].t_us[0]) * 1e-6
    _one_line(log.damage, "imu.csv", f"row {n}", "cut short", f"{span:.1f} s read")
    # cut after "1,2" of "1,25": a whole row to look at, a wrong number
    whole = tmp_path / "whole.csv"
    whole.write_text("time,p\n0,1\n1,2")
    log = open_log(whole)
    assert log.read({"whole": ["p"]})["whole"].values[:, 0].tolist() == [1.0]
    _one_line(log.damage, "whole.csv", "without a line break after row 2", "left out", "0.0 s read")
    whole.write_text("time,p\n0,1\n1,2\n")
    log = open_log(whole)
    assert log.read({"whole": ["p"]})["whole"].values[:, 0].tolist() == [1.0, 2.0] and log.damage is None


def test_semicolons_tabs_byte_order_mark_and_comments(tmp_path):
    for name, text in (
        ("semi", "\ufefftime;p\n# a comment\n0;1.5\n1;2.5\n"),
        ("tab", "t\tp\n0\t1.5\n1\t2.5\n"),
    ):
        path = tmp_path / f"{name}.csv"
        path.write_text(text, encoding="utf-8")
        series = open_log(path).read({name: ["p"]})[name]
        assert series.t_s.tolist() == [0.0, 1.0] and series.values[:, 0].tolist() == [1.5, 2.5]


def test_a_large_file_reads_as_the_csv_module_reads_it(tmp_path):
    """20 000 rows, 4 columns, two of them wanted: numpy's parser gives exactly the csv module's values (its
    speed against the csv module is measured by ``benchmarks/bench_csv.py``, not here)."""
    n = 20_000
    rng = np.random.default_rng(1)
    t = WriteTopic("big", np.arange(n, dtype=np.int64) * 4000, {k: rng.standard_normal(n) for k in "abc"})
    path = write_csv(tmp_path, [t])[0]
    series = open_log(path).read({"big": ["a", "c"]})["big"]
    with open(path, newline="") as f:
        rows = csv.reader(f)
        next(rows)
        reference = np.array([[row[0], row[1], row[3]] for row in rows], dtype=float).T
    assert np.array_equal(series.values[:, 0], reference[1]) and np.array_equal(
        series.values[:, 1], reference[2]
    )
    assert np.array_equal(series.t_s, reference[0] * 1e-6)
