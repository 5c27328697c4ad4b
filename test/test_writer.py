"""Writing rosbag2 files (gap_validation.bag.writer): simulated flights round-trip exactly, in every
storage."""
import numpy as np
import pytest
from _flights import TINY, make_bag
from rosbags.rosbag2 import Reader

from gap_validation.bag.reader import open_bag
from gap_validation.core.errors import ConfigError
from gap_validation.core.fields import FieldPath
from gap_validation.messages.router import stamp_seconds


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


@pytest.mark.parametrize(
    "name, storage", [("flight_sql", "sqlite3"), ("bare.mcap", None), ("bare.db3", None)]
)
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
