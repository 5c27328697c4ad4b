"""Records of a bag in batches, for the vectorised decoding of replay.

:meth:`gap_validation.bag.reader.Bag.record_batches` yields the records
:meth:`~gap_validation.bag.reader.Bag.records` yields, in the same order, grouped as :class:`RecordBatch`
(topic per record, bag time, and the serialized messages as :class:`~gap_validation.messages.cdr.Records`).

For an indexed mcap file (what ``gap-validate simulate`` and ``ros2 bag record`` write) a batch is one
decompressed chunk as it is: the messages are found with the chunk's message indexes (read straight into numpy
arrays and checked: each indexed record is a message of its channel and log time, and whatever lies between
them is whole records none of which is a message, so no message is missed) and
ordered as rosbags orders them (by log time, stably, within a chunk; chunk after chunk), without a line of
Python per message. A chunk whose index does not tile it is read by rosbags' own chunk reader; a file whose
chunks overlap in time, an unindexed one, per-message compression, sqlite3 and salvaged files group the
records of :meth:`~gap_validation.bag.reader.Bag.records` (:func:`grouped`). Memory holds one chunk or one
batch.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from itertools import islice
from typing import Any, Iterable, Iterator, Sequence

import numpy as np
from rosbags.rosbag2.storage_mcap import McapReader, decompress, msgsrc, read_exact
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

from gap_validation.messages.cdr import Records

__all__ = ["RecordBatch", "BATCH", "grouped", "storage_batches"]

#: Records per batch (at most): bounded memory, and enough records to amortise the per-batch work.
BATCH = 4096

_U32 = struct.Struct("<I")
_INDEX_HEAD = struct.Struct("<BQHI")   # opcode 0x07, record length, channel id, byte length of the entries
_MESSAGE_HEAD = 9 + 22                 # opcode, record length; channel id, sequence, log time, publish time
_HEAD_DTYPE = np.dtype(
    {
        "names": ["opcode", "length", "channel", "log_time"],
        "formats": ["u1", "<u8", "<u2", "<u8"],
        "offsets": [0, 1, 9, 15],
        "itemsize": _MESSAGE_HEAD,
    }
)


@dataclass(frozen=True)
class RecordBatch:
    """Consecutive records of a bag: record ``i`` is of topic ``topics[which[i]]``, at bag time ``t_ns[i]``,
    with serialized message ``records.raw(i)``."""

    topics: tuple[str, ...]
    which: np.ndarray
    t_ns: np.ndarray
    records: Records

    def __len__(self) -> int:
        return int(self.t_ns.size)

    def split(self, size: int) -> Iterator["RecordBatch"]:
        """This batch in parts of at most ``size`` records."""
        if len(self) <= size:
            yield self
            return
        for start in range(0, len(self), size):
            part = slice(start, start + size)
            yield RecordBatch(self.topics, self.which[part], self.t_ns[part], Records(
                self.records.buffer, self.records.offsets[part], self.records.lengths[part]))


def grouped(records: Iterable[tuple[str, str, int, Any]], size: int = BATCH) -> Iterator[RecordBatch]:
    """``(topic, msgtype, t_ns, raw)`` records in batches of ``size``; on an error the records before it are
    yielded first, then the error is raised."""
    topics: dict[str, int] = {}
    which: list[int] = []
    times: list[int] = []
    raws: list[Any] = []

    def batch() -> RecordBatch:
        out = RecordBatch(tuple(topics), np.asarray(which, dtype=np.int64), np.asarray(times, dtype=np.int64),
                          Records.from_raws(raws))
        topics.clear(), which.clear(), times.clear(), raws.clear()
        return out

    try:
        for topic, _, t_ns, raw in records:
            which.append(topics.setdefault(topic, len(topics)))
            times.append(t_ns)
            raws.append(raw)
            if len(raws) >= size:
                yield batch()
    except Exception:
        if raws:
            yield batch()
        raise
    if raws:
        yield batch()


def storage_batches(
    storage: Any, topic_of: dict[int, str], size: int = BATCH
) -> Iterator[RecordBatch] | None:
    """The records of the channels ``topic_of`` (storage connection id -> topic) of one storage file of
    rosbags, in batches, in the order of its ``messages``; None when it cannot be read so (then group the
    records)."""
    names = tuple(dict.fromkeys(topic_of.values()))
    code = np.full(1 << 16, -1, dtype=np.int64)     # connection id -> index of its topic in names, or -1
    for cid, topic in topic_of.items():
        if not 0 <= cid < code.size:
            return None
        code[cid] = names.index(topic)
    if isinstance(storage, Sqlite3Reader) and storage.dbconn is not None:
        return _sqlite_batches(storage, topic_of, names, code, size)
    if not isinstance(storage, McapReader) or not storage.chunks or storage.bio is None:
        return None
    chunks = sorted((c for c in storage.chunks if any(c.channel_count.get(cid, 0) for cid in topic_of)),
                    key=lambda c: (c.message_start_time, c.chunk_start_offset))
    for a, b in zip(chunks, chunks[1:]):   # rosbags merges the chunks' messages by (log time, chunk offset)
        if not (
            a.message_end_time < b.message_start_time
            or (a.message_end_time == b.message_start_time and a.chunk_start_offset < b.chunk_start_offset)
        ):
            return None
    return _chunk_batches(storage, chunks, topic_of, names, code, size)


def _sqlite_batches(storage: Any, topic_of: dict[int, str], names: tuple[str, ...], code: np.ndarray,
                    size: int) -> Iterator[RecordBatch]:
    """rosbags' query of ``Sqlite3Reader.messages`` (same text, same order), its rows fetched ``size`` at a
    time."""
    ids = tuple(set(topic_of))
    query = (
        "SELECT topics.id,messages.timestamp,messages.data FROM messages JOIN topics ON "
        f"messages.topic_id=topics.id WHERE topics.id IN ({','.join('?' for _ in ids)}) ORDER BY timestamp"
    )
    cursor = storage.dbconn.execute(query, ids)
    while rows := list(islice(cursor, size)):
        cids, times, raws = zip(*rows)
        yield RecordBatch(names, code[np.asarray(cids, dtype=np.int64)], np.asarray(times, dtype=np.int64),
                          Records.from_raws(raws))


def _chunk_batches(storage: Any, chunks: Sequence[Any], topic_of: dict[int, str], names: tuple[str, ...],
                   code: np.ndarray, size: int) -> Iterator[RecordBatch]:
    connections = {c.id: c for c in storage.connections if c.id in topic_of}
    for chunk in chunks:
        try:
            batch = _indexed_chunk(storage.bio, chunk, names, code)
        except Exception:  # noqa: BLE001 - a damaged chunk: rosbags' reader says what is wrong with it
            batch = None
        if batch is None:
            messages = [
                m
                for m in msgsrc(
                    chunk, connections, chunk.message_start_time, chunk.message_end_time + 1, storage.bio
                )
                if m.offset
            ]
            batch = RecordBatch(names, code[np.asarray([m.connection.id for m in messages], dtype=np.int64)],
                                np.asarray([m.timestamp for m in messages], dtype=np.int64),
                                Records.from_raws([m.data for m in messages]))
        yield from batch.split(size)


def _no_message_between(data: bytes, start: int, stop: int) -> bool:
    """Whether ``data[start:stop]`` is whole records none of which is a message (schemas, channels ...)."""
    while start < stop:
        if data[start] == 0x05 or start + 9 > stop:
            return False
        (length,) = struct.unpack_from("<Q", data, start + 1)
        start += 9 + length
    return start == stop


def _indexed_chunk(bio: Any, chunk: Any, names: tuple[str, ...], code: np.ndarray) -> RecordBatch | None:
    """One chunk, its messages located by its message indexes; None unless the indexed records are messages of
    their channel and log time and every other record of the chunk is not a message."""
    start = chunk.chunk_start_offset
    bio.seek(start + 9 + 24)
    (crc,) = _U32.unpack(read_exact(bio, 4))
    bio.seek(start + 9 + 40 + len(chunk.compression))
    data = decompress(read_exact(bio, chunk.compressed_size), chunk.compression, chunk.uncompressed_size, crc)
    bio.seek(start + chunk.chunk_length)
    index = read_exact(bio, chunk.message_index_length)
    channels, times, offsets = [], [], []
    pos = 0
    while pos < len(index):
        opcode, length, channel, nbytes = _INDEX_HEAD.unpack_from(index, pos)
        if opcode != 0x07 or nbytes % 16 or 2 + 4 + nbytes != length:
            return None
        entries = np.frombuffer(index, dtype="<u8", count=nbytes // 8, offset=pos + 15).reshape(-1, 2)
        channels.append(np.full(len(entries), channel, dtype=np.int64))
        times.append(entries[:, 0].astype(np.int64))
        offsets.append(entries[:, 1].astype(np.int64))
        pos += 9 + length
    if not offsets:
        return None
    channel, t_ns, offset = (np.concatenate(x) for x in (channels, times, offsets))
    order = np.argsort(offset, kind="stable")           # record order
    channel, t_ns, offset = channel[order], t_ns[order], offset[order]
    buffer = np.frombuffer(data, dtype=np.uint8)
    if offset[-1] + _MESSAGE_HEAD > buffer.size:
        return None
    head = np.lib.stride_tricks.sliding_window_view(buffer, _MESSAGE_HEAD)[offset].view(_HEAD_DTYPE)[:, 0]
    length = head["length"].astype(np.int64)
    ends = offset + 9 + length
    if (np.any(head["opcode"] != 0x05) or np.any(length < 22) or np.any(head["channel"] != channel)
            or np.any(head["log_time"].astype(np.int64) != t_ns)):
        return None
    starts, stops = np.r_[0, ends], np.r_[offset, buffer.size]     # between the indexed messages
    for gap in np.flatnonzero(starts != stops):
        if not _no_message_between(data, int(starts[gap]), int(stops[gap])):
            return None
    wanted = (code[channel] >= 0) & (t_ns >= chunk.message_start_time) & (t_ns <= chunk.message_end_time)
    channel, t_ns, offset, length = channel[wanted], t_ns[wanted], offset[wanted], length[wanted]
    order = np.argsort(t_ns, kind="stable")             # rosbags sorts a chunk's messages by log time, stably
    return RecordBatch(names, code[channel[order]], t_ns[order],
                       Records(buffer, offset[order] + _MESSAGE_HEAD, length[order] - 22))
