"""Reading rosbag2 files (gap_validation.bag.reader): streaming, deserialising, one-line errors."""
import pytest

from gap_validation.bag.batches import BATCH
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


# ------------------------------------------------------------------------------------------- batches
def _flat(bag, topics, size=BATCH):
    """What record_batches yields, record by record, and the error that ended it (or None)."""
    out = []
    try:
        for batch in bag.record_batches(topics, size):
            assert 0 < len(batch) <= size
            out += [(batch.topics[batch.which[i]], int(batch.t_ns[i]), batch.records.raw(i))
                    for i in range(len(batch))]
    except DataError as err:
        return out, str(err)
    return out, None


def _records(bag, topics):
    out = []
    try:
        for topic, _, t_ns, raw in bag.records(topics):
            out.append((topic, t_ns, bytes(raw)))
    except DataError as err:
        return out, str(err)
    return out, None


def _same_records(path, topics=("/imu", "/control_surfaces"), size=BATCH):
    with open_bag(path) as bag:
        want = _records(bag, list(topics) if topics else None)
    with open_bag(path) as bag:
        got = _flat(bag, list(topics) if topics else None, size)
    assert got == want
    return want


@pytest.mark.parametrize("storage", ["mcap", "mcap uncompressed", "sqlite3", "bare.mcap", "bare.db3"])
def test_batches_hold_the_records_in_the_same_order(tmp_path, flight, storage):
    from gap_validation.bag.writer import write_flight

    kind = storage.split()[0]
    path = write_flight(flight, tmp_path / kind.replace("bare.", "f."), None if "." in kind else kind,
                        compress="uncompressed" not in storage)
    for topics, size in (((), 100), (("/imu",), BATCH), (("/control_surfaces", "/imu"), 7)):
        records, error = _same_records(path, topics, size)
        assert error is None and len(records) == sum(len(flight.topics[t]) for t in topics or flight.topics)


def test_a_chunk_its_index_does_not_describe_is_read_by_rosbags(mcap_bag, monkeypatch):
    from gap_validation.bag import batches

    calls = []
    monkeypatch.setattr(batches, "_indexed_chunk", lambda *args: calls.append(1))
    _same_records(mcap_bag)
    assert calls


def test_a_tampered_message_index_is_noticed(tmp_path, mcap_bag, monkeypatch):
    from rosbags.rosbag2 import Reader

    data = bytearray(next(mcap_bag.glob("*.mcap")).read_bytes())
    from gap_validation.bag import batches

    with Reader(mcap_bag) as reader:
        indexes = [sorted(c.message_index_offsets.values()) for c in reader.storage.storages[0].chunks]
    for k, offsets in enumerate(indexes):                  # per chunk, one entry's log time or offset
        entry = offsets[k % len(offsets)] + 15 + 16 * (k % 3)
        data[entry + 8 * (k % 2):entry + 8 * (k % 2) + 2] = b"\xff\x7f"
    bad = tmp_path / "tampered.mcap"
    bad.write_bytes(bytes(data))
    found = []
    read = batches._indexed_chunk
    monkeypatch.setattr(batches, "_indexed_chunk", lambda *args: found.append(read(*args)) or found[-1])
    records, error = _same_records(bad)
    assert error is None and records
    assert found and all(batch is None for batch in found)      # every tampered chunk read by rosbags instead


@pytest.mark.parametrize("damage", ["zeros", "cut"])
def test_damaged_files_give_the_same_records_and_error(tmp_path, mcap_bag, damage):
    data = bytearray(next(mcap_bag.glob("*.mcap")).read_bytes())
    if damage == "zeros":
        middle = len(data) // 3
        data[middle:middle + 64] = bytes(64)
    else:
        data = data[:len(data) // 2]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    try:
        records, error = _same_records(bad)
    except DataError:            # unreadable at open: nothing to compare
        return
    assert error is not None and "\n" not in error
