"""Reading rosbag2 files (gap_validation.bag.reader): streaming, deserialising, one-line errors."""
import pytest

from gap_validation.bag.reader import open_bag
from gap_validation.core.errors import DataError


def test_streams_only_requested_topics(mcap_bag, flight):
    with open_bag(mcap_bag) as bag:
        seen = {topic for topic, *_ in bag.records(["/imu"])}
        assert seen == {"/imu"}
        assert bag.message_count(["/imu", "/nope"]) == len(flight.topics["/imu"])


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
