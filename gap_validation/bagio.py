"""Everything that touches rosbag2 files (through ``rosbags``): open, stream, decode, write.

Reading: :func:`open_bag` accepts a rosbag2 directory (with ``metadata.yaml``), a bare ``.mcap`` or ``.db3``
file, or a directory without metadata that holds exactly one storage file. :meth:`Bag.records` streams the raw
CDR records of the requested topics one by one (rosbags reads mcap chunk by chunk and sqlite3 through a
cursor), so an hour-long bag is never held in memory. Messages are decoded with the ``ROS2_JAZZY`` typestore
(types the store lacks are registered from the bag's own message definitions).

Fast decoding: decoding dominates replay time, and a validation needs only a few numbers per message. For
``sensor_msgs/msg/Imu``, ``sensor_msgs/msg/JointState`` and ``std_msgs/msg/Float64|Float32|Bool`` in
little-endian CDR, :func:`fast_decoder` reads exactly the configured fields at their CDR offsets with
``struct`` (XCDR1 alignment: relative to the end of the 4-byte encapsulation header, primitives aligned to their
size). Anything unexpected (big-endian data, short buffers, a missing joint) falls back to full deserialisation,
and replay checks the first messages of every topic against full deserialisation before trusting it.

Damaged files: rosbags refuses an mcap without its footer (a recording cut short) and a sqlite3 file whose
index is broken. :class:`Bag` then falls back to a linear scan (:class:`_McapSalvage`: records and chunks up to
the first one that is cut off or does not decompress; :class:`_SqliteSalvage`: rows in insertion order up to the
first unreadable page) and :meth:`Bag.records` ends with a :class:`DataError` saying where the file stopped
and how many seconds before it were read, so replay validates what was recorded and reports the rest.

Writing: :func:`write_flight` writes a :class:`~gap_validation.core.simulation.SimulatedFlight` as a rosbag2
(mcap with zstd chunk compression by default, or sqlite3).
"""
from __future__ import annotations

import json
import shutil
import sqlite3
import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

import numpy as np
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2.errors import ReaderError, WriterError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_idl, get_types_from_msg, get_typestore

from gap_validation.core.errors import ConfigError, DataError, one_line
from gap_validation.ingest import FieldPath

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.simulation import SimulatedFlight, TopicSeries

__all__ = ["Bag", "TopicInfo", "open_bag", "fast_decoder", "write_flight", "STORAGES", "BAG_SUFFIXES",
           "FastDecodeError"]

#: Storage plugins :func:`write_flight` can write.
STORAGES = ("mcap", "sqlite3")
#: Bare storage files :func:`open_bag` reads.
BAG_SUFFIXES = (".mcap", ".db3")
#: Typestore of the ROS distribution whose message definitions decode the bags.
TYPESTORE = Stores.ROS2_JAZZY

#: Errors rosbags and its storage backends raise on damaged files.
_READ_ERRORS = (ReaderError, SerdeError, TypesysError, sqlite3.Error, struct.error, OSError, EOFError,
                ValueError, KeyError, IndexError, AssertionError, TypeError, AttributeError)


@dataclass(frozen=True)
class TopicInfo:
    """A topic of a bag: message type and number of messages."""

    topic: str
    msgtype: str | None
    count: int


class FastDecodeError(Exception):
    """The fast decoder cannot read this record; decode it fully instead."""


# --------------------------------------------------------------------------------------------- reading
def _storage_path(path: Path) -> Path:
    """The path rosbags should open: the directory, the bare file, or the one file of a metadata-less dir."""
    if not path.exists():
        raise DataError(f"{path}: no such bag (file or directory not found)")
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return path
        files = sorted(p for p in path.iterdir() if p.suffix in BAG_SUFFIXES and p.is_file())
        if len(files) == 1:
            return files[0]
        what = "no" if not files else f"{len(files)}"
        raise DataError(f"{path}: not a rosbag2 directory (no metadata.yaml and {what} .mcap/.db3 files)")
    if path.suffix not in BAG_SUFFIXES:
        raise DataError(f"{path}: not a bag (expected a rosbag2 directory, a .mcap or a .db3 file)")
    return path


class Bag:
    """An open bag (context manager): topics, message counts and a streaming record iterator.

    Parameters
    ----------
    path : str or Path
        rosbag2 directory, ``.mcap`` or ``.db3`` file.

    Raises
    ------
    DataError
        One line naming the file: not found, not a bag, or unreadable (corrupted, truncated).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._storage = _storage_path(self.path)
        self.typestore = get_typestore(TYPESTORE)
        #: Where a damaged file stops being readable (None for an intact bag); see :meth:`records`.
        self.damage: _Damage | None = None
        self._last_ns: int | None = None
        try:
            self._reader = Reader(self._storage)
            self._reader.open()
        except Exception as err:  # noqa: BLE001 - any failure to open means "not a readable bag"
            self._reader = _salvage(self._storage)
            if self._reader is None:
                raise DataError(f"{self.path}: cannot read bag ({one_line(err)}; nothing recoverable)") from None
            self.damage = self._reader.damage or _Damage(0, one_line(err), "the index")
        self._closed = False

    def __enter__(self) -> "Bag":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the underlying reader (idempotent)."""
        if not self._closed:
            self._closed = True
            try:
                self._reader.close()
            except _READ_ERRORS:  # pragma: no cover - closing a damaged file
                pass

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Topic -> :class:`TopicInfo` (type and message count from the bag's index or metadata)."""
        out: dict[str, TopicInfo] = {}
        for conn in self._reader.connections:
            info = out.get(conn.topic)
            if info is None:
                out[conn.topic] = TopicInfo(conn.topic, conn.msgtype, int(conn.msgcount))
            else:
                msgtype = info.msgtype if info.msgtype == conn.msgtype else None
                out[conn.topic] = TopicInfo(conn.topic, msgtype, info.count + int(conn.msgcount))
        return out

    @property
    def start_time_s(self) -> float:
        """Bag time of the first message [s]."""
        return self._reader.start_time * 1e-9

    def message_count(self, topics: Sequence[str] | None = None) -> int:
        """Messages in ``topics`` (all topics when None)."""
        info = self.topics
        names = info.keys() if topics is None else [t for t in topics if t in info]
        return sum(info[t].count for t in names)

    def _connections(self, topics: Sequence[str] | None):
        wanted = None if topics is None else set(topics)
        return [c for c in self._reader.connections if wanted is None or c.topic in wanted]

    def ensure_type(self, msgtype: str) -> None:
        """Make ``msgtype`` decodable: register it from the bag's definition if the typestore lacks it.

        Raises
        ------
        DataError
            When the type is unknown and the bag carries no usable definition.
        """
        if msgtype in self.typestore.fielddefs:
            return
        for conn in self._reader.connections:
            if conn.msgtype != msgtype or not conn.msgdef.data:
                continue
            try:
                fmt = getattr(conn.msgdef.format, "name", str(conn.msgdef.format)).upper()
                types = (get_types_from_idl(conn.msgdef.data) if fmt == "IDL"
                         else _types_from_msgdef(conn.msgdef.data, msgtype))
                self.typestore.register(types)
                return
            except (TypesysError, ValueError, KeyError) as err:
                raise DataError(f"{self.path}: cannot use the definition of {msgtype} in the bag "
                                f"({one_line(err)})") from None
        raise DataError(f"{self.path}: unknown message type {msgtype} (not in the {TYPESTORE.name} typestore "
                        "and no definition in the bag)")

    def records(self, topics: Sequence[str] | None = None) -> Iterator[tuple[str, str, int, Any]]:
        """Stream ``(topic, msgtype, bag_time_ns, raw_cdr)`` of ``topics`` in bag-time order.

        Raises
        ------
        DataError
            On a damaged file, naming the bag (already yielded records stay valid).
        """
        conns = self._connections(topics)
        if not conns:
            return
        try:
            for conn, timestamp, raw in self._reader.messages(connections=conns):
                self._last_ns = timestamp
                yield conn.topic, conn.msgtype, timestamp, raw
        except Exception as err:  # noqa: BLE001 - rosbags, zstd, lz4 and sqlite3 raise many kinds on damage
            if isinstance(err, DataError):
                raise
            raise DataError(f"{self.path}: corrupted or unreadable data ({one_line(err)}){self._before()}") \
                from None
        if self.damage is not None:
            where = getattr(self._reader, "path", self.path)      # the damaged file itself
            raise DataError(f"{where}: {self.damage.text}{self._before()}")

    def _before(self) -> str:
        """``; validated the X s before (up to bag time T)`` for what was read before a damage."""
        if self._last_ns is None:
            return "; nothing before it was read"
        span_s = (self._last_ns - self._reader.start_time) * 1e-9
        return f"; validated the {span_s:.1f} s before it (bag time up to {self._last_ns * 1e-9:.3f} s)"

    def deserialize(self, raw: Any, msgtype: str, topic: str = "") -> Any:
        """Fully decode one CDR record into a rosbags message object.

        Raises
        ------
        DataError
            Naming the bag and topic when the record does not decode as ``msgtype``.
        """
        try:
            return self.typestore.deserialize_cdr(raw, msgtype)
        except KeyError:
            self.ensure_type(msgtype)
            return self.deserialize(raw, msgtype, topic)
        except (SerdeError, struct.error, ValueError, IndexError, AssertionError, TypeError,
                UnicodeDecodeError) as err:
            raise DataError(f"{self.path}: topic {topic}: message does not decode as {msgtype} "
                            f"({one_line(err)})") from None

    def messages(self, topics: Sequence[str] | None = None) -> Iterator[tuple[str, Any, float]]:
        """Stream ``(topic, message object, bag_time_s)`` (full deserialisation)."""
        for topic, msgtype, t_ns, raw in self.records(topics):
            yield topic, self.deserialize(raw, msgtype, topic), t_ns * 1e-9


def _types_from_msgdef(text: str, msgtype: str) -> dict:
    """Types of a concatenated ros2msg definition (main type, then ``MSG: pkg/Name`` sections)."""
    sep = "=" * 80 + "\n"
    sections = text.split(sep)
    types = dict(get_types_from_msg(sections[0], msgtype))
    for section in sections[1:]:
        header, _, body = section.partition("\n")
        name = header.replace("MSG:", "").strip()
        if "/" in name and "/msg/" not in name:
            pkg, _, base = name.partition("/")
            name = f"{pkg}/msg/{base}"
        types.update(get_types_from_msg(body, name))
    return types


def open_bag(path: str | Path) -> Bag:
    """Open a rosbag2 directory, ``.mcap`` or ``.db3`` file for streaming (see :class:`Bag`)."""
    return Bag(path)


# --------------------------------------------------------------------------------------------- damaged bags
_MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class _MsgDef:
    """Stand-in for rosbags' MessageDefinition: ``format.name`` (MSG or IDL) and the definition text."""

    format: Any
    data: str


@dataclass(frozen=True)
class _SalvagedConnection:
    """What :class:`Bag` reads of a rosbags Connection (topic, type, count, definition)."""

    id: int
    topic: str
    msgtype: str
    msgcount: int
    msgdef: _MsgDef


class _Damage(Exception):
    """Where a linear scan of a damaged file stopped: byte offset and why."""

    def __init__(self, offset: int, reason: str, where: str = ""):
        super().__init__(reason)
        self.offset, self.reason = offset, reason
        self.where = where or f"byte {offset}"
        self.text = f"damaged at {self.where} ({reason})"


class _McapSalvage:
    """Linear scan of an mcap file without a usable footer or summary (a recording cut short, a damaged tail).

    rosbags refuses such a file whole (it needs the footer). The data section is a plain sequence of records
    (``opcode u8, length u64, content``); chunks hold schemas, channels and messages, compressed with zstd or
    lz4 (rosbags' own decompressors, CRC checked). Everything up to the first record that is cut off or does
    not decode is recovered; :attr:`damage` says where the scan stopped. Two passes: the first counts
    messages per channel (for progress and the topic table), the second streams them; nothing is held.
    """

    def __init__(self, path: Path):
        self.path = path
        self.size = path.stat().st_size
        self._fh = path.open("rb")
        head = self._fh.read(9)
        if head[:8] != _MCAP_MAGIC or head[8:9] != b"\x01":
            self._fh.close()
            raise _Damage(0, "not an mcap file (bad magic)")
        self.data_start = 9 + 8 + _U64.unpack(self._fh.read(8))[0]
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self.channels: dict[int, tuple[str, str]] = {}
        self.counts: dict[int, int] = {}
        self.first_ns = self.last_ns = None
        self.damage: _Damage | None = None
        self._counting = True
        for _ in self._messages(None):
            pass
        self._counting = False
        ids = sorted(self.channels)
        self.connections = [
            _SalvagedConnection(cid, self.channels[cid][0], self.schemas.get(self.channels[cid][1], ("",))[0],
                                self.counts.get(cid, 0), _msgdef(self.schemas.get(self.channels[cid][1])))
            for cid in ids]
        self.start_time = self.first_ns or 0

    def close(self) -> None:
        self._fh.close()

    def messages(self, connections=None):
        """``(connection, log_time_ns, data)`` of the wanted connections, up to the damage."""
        by_id = {c.id: c for c in self.connections}
        wanted = None if connections is None else {c.id for c in connections}
        for cid, t_ns, data in self._messages(wanted):
            yield by_id[cid], t_ns, data

    def _messages(self, wanted):
        fh, pos = self._fh, self.data_start
        end = self.size if self.damage is None else self.damage.offset
        while pos + 9 <= end:
            fh.seek(pos)
            op, length = _OP.unpack(fh.read(9))
            if op in (0x02, 0x0F):                       # footer, data end: the data section is complete
                return
            if op == 0x00 or pos + 9 + length > end:
                self._stop(pos, "record cut off" if op else "zeroed bytes")
                return
            content = fh.read(length)
            try:
                records = _chunk_records(content) if op == 0x06 else [(op, content)]
                out = [self._record(o, c) for o, c in records]
            except Exception as err:  # noqa: BLE001 - damaged content: stop here, keep what came before
                self._stop(pos, f"damaged record ({one_line(err)})")
                return
            for item in out:
                if item is not None and (wanted is None or item[0] in wanted):
                    yield item
            pos += 9 + length
        if pos < end:
            self._stop(pos, "record cut off")

    def _stop(self, offset: int, reason: str) -> None:
        if self.damage is None:
            self.damage = _Damage(offset, reason, f"byte {offset} of {self.size}")
            if reason == "record cut off":
                self.damage.text = f"truncated at byte {offset} of {self.size} (the recording was cut short)"

    def _record(self, op: int, c: bytes):
        if op == 0x03:                                   # schema: id, name, encoding, data
            sid, pos = _U16.unpack_from(c, 0)[0], 2
            name, pos = _mcap_string(c, pos)
            encoding, pos = _mcap_string(c, pos)
            data, _ = _mcap_string(c, pos)
            self.schemas[sid] = (name, encoding, data)
        elif op == 0x04:                                 # channel: id, schema id, topic, ...
            cid, sid = struct.unpack_from("<HH", c, 0)
            topic, _ = _mcap_string(c, 4)
            self.channels[cid] = (topic, sid)
        elif op == 0x05:                                 # message: channel, sequence, log time, publish, data
            cid, _, t_ns = struct.unpack_from("<HIQ", c, 0)
            if cid not in self.channels:
                raise ValueError(f"message of unknown channel {cid}")
            if self._counting:
                self.counts[cid] = self.counts.get(cid, 0) + 1
                self.first_ns = t_ns if self.first_ns is None else min(self.first_ns, t_ns)
                self.last_ns = t_ns if self.last_ns is None else max(self.last_ns, t_ns)
            return cid, t_ns, c[22:]
        return None


_OP = struct.Struct("<BQ")
_U64 = struct.Struct("<Q")
_U16 = struct.Struct("<H")


def _mcap_string(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    if pos + 4 + n > len(buf):
        raise ValueError("string beyond the record")
    return bytes(buf[pos + 4:pos + 4 + n]).decode(), pos + 4 + n


def _chunk_records(content: bytes) -> list[tuple[int, bytes]]:
    """The records inside an mcap chunk (decompressed, CRC checked by rosbags' decompressor)."""
    from rosbags.rosbag2.storage_mcap import decompress

    _, _, usize, crc = struct.unpack_from("<QQQI", content, 0)
    compression, pos = _mcap_string(content, 28)
    (csize,) = _U64.unpack_from(content, pos)
    data = content[pos + 8:pos + 8 + csize]
    if len(data) != csize:
        raise ValueError("chunk shorter than its header says")
    raw = decompress(data, compression, usize, crc)
    out, pos = [], 0
    while pos < len(raw):
        op, length = _OP.unpack_from(raw, pos)
        if pos + 9 + length > len(raw):
            raise ValueError("record beyond the chunk")
        out.append((op, raw[pos + 9:pos + 9 + length]))
        pos += 9 + length
    return out


def _msgdef(schema) -> _MsgDef:
    name, encoding, data = schema if schema else ("", "", "")
    fmt = type("Format", (), {"name": "IDL" if encoding == "ros2idl" else "MSG"})()
    return _MsgDef(fmt, data)


class _SqliteSalvage:
    """Reads what a damaged rosbag2 sqlite3 file still gives (rows in insertion order up to the damage)."""

    def __init__(self, path: Path):
        self.path = path
        self.damage: _Damage | None = None
        self._con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            topics = self._con.execute("SELECT id, name, type FROM topics").fetchall()
        except sqlite3.Error as err:
            self._con.close()
            raise _Damage(0, f"the topic table is unreadable ({one_line(err)})") from None
        self.counts: dict[int, int] = {}
        self.first_ns = self.last_ns = None
        self._rows = -1
        for tid, t_ns, _ in self._scan(None):
            self.counts[tid] = self.counts.get(tid, 0) + 1
            self.first_ns = t_ns if self.first_ns is None else min(self.first_ns, t_ns)
            self.last_ns = t_ns if self.last_ns is None else max(self.last_ns, t_ns)
        self._rows = sum(self.counts.values())
        self.connections = [_SalvagedConnection(tid, name, msgtype, self.counts.get(tid, 0), _MsgDef(None, ""))
                            for tid, name, msgtype in topics]
        self.start_time = self.first_ns or 0

    def _scan(self, wanted):
        done = 0
        try:
            for tid, t_ns, data in self._con.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id"):
                done += 1
                if 0 <= self._rows < done:
                    return
                if wanted is None or tid in wanted:
                    yield tid, t_ns, data
        except sqlite3.Error as err:
            if self.damage is None:
                self.damage = _Damage(done, one_line(err), f"message row {done + 1}")

    def messages(self, connections=None):
        by_id = {c.id: c for c in self.connections}
        wanted = None if connections is None else {c.id for c in connections}
        for tid, t_ns, data in self._scan(wanted):
            if tid in by_id:
                yield by_id[tid], t_ns, data

    def close(self) -> None:
        self._con.close()


def _salvage(storage: Path):
    """A reader of what a damaged ``.mcap`` / ``.db3`` still holds, or None when nothing can be recovered."""
    files = [storage] if storage.is_file() else sorted(p for p in storage.iterdir() if p.suffix in BAG_SUFFIXES)
    if len(files) != 1:
        return None
    try:
        reader = (_McapSalvage if files[0].suffix == ".mcap" else _SqliteSalvage)(files[0])
    except (_Damage, OSError, sqlite3.Error, struct.error):
        return None
    if reader.first_ns is None:
        reader.close()
        return None
    return reader


# --------------------------------------------------------------------------------------------- fast decoding
_HEAD = struct.Struct("<iII")       # header.stamp.sec, header.stamp.nanosec, frame_id length
_U32 = struct.Struct("<I")
_F64 = struct.Struct("<d")
_F32 = struct.Struct("<f")
_STAMP = struct.Struct("<iI")

#: Offsets [bytes] of Imu doubles after the 8-aligned start of ``orientation``.
_IMU_OFFSETS = {
    ("orientation", "x"): 0, ("orientation", "y"): 8, ("orientation", "z"): 16, ("orientation", "w"): 24,
    ("angular_velocity", "x"): 104, ("angular_velocity", "y"): 112, ("angular_velocity", "z"): 120,
    ("linear_acceleration", "x"): 200, ("linear_acceleration", "y"): 208, ("linear_acceleration", "z"): 216,
}
_IMU_SIZE = 296  # 4 + 9 + 3 + 9 + 3 + 9 doubles


def _check_le(raw) -> None:
    if len(raw) < 8 or raw[0] != 0 or raw[1] != 1:
        raise FastDecodeError("not little-endian CDR")


def _stamp(sec: int, nanosec: int) -> float | None:
    return None if sec == 0 and nanosec == 0 else sec + nanosec * 1e-9


def _imu_decoder(paths: Sequence[FieldPath]) -> Callable | None:
    keys = []
    for path in paths:
        if any(s.kind != "attr" for s in path.steps) or path.attributes not in _IMU_OFFSETS:
            return None
        keys.append(path.attributes)
    offsets = sorted({_IMU_OFFSETS[k] for k in keys})
    fmt, pos = "<", 0
    for off in offsets:
        fmt += (f"{off - pos}x" if off > pos else "") + "d"
        pos = off + 8
    reader = struct.Struct(fmt)
    order = [offsets.index(_IMU_OFFSETS[k]) for k in keys]

    def decode(raw):
        _check_le(raw)
        sec, nanosec, slen = _HEAD.unpack_from(raw, 4)
        base = 4 + ((12 + slen + 7) & ~7)  # frame_id ends at 16 + slen; align 8 relative to offset 4
        if len(raw) < base + _IMU_SIZE:
            raise FastDecodeError("short Imu record")
        got = reader.unpack_from(raw, base)
        return _stamp(sec, nanosec), [got[i] for i in order]

    return decode


class _JointStateDecoder:
    """``position|velocity|effort[name|index]`` of JointState records; the name table is cached while the
    serialized names do not change."""

    ARRAYS = ("position", "velocity", "effort")

    def __init__(self, paths: Sequence[FieldPath]):
        self.wants = []
        for path in paths:
            if len(path.steps) != 2 or path.steps[0].kind != "attr" or path.steps[0].value not in self.ARRAYS \
                    or path.steps[1].kind not in ("key", "index"):
                raise FastDecodeError("unsupported JointState path")
            self.wants.append((self.ARRAYS.index(path.steps[0].value), path.steps[1].kind, path.steps[1].value))
        self.last_arrays = max(a for a, _, _ in self.wants)
        self.cached_block = b""
        self.cached_names: dict[str, int] = {}
        self.cached_end = 0

    def _names(self, raw, start: int) -> tuple[dict[str, int], int]:
        block = self.cached_block
        if block and raw[start:start + len(block)] == block:
            return self.cached_names, start + len(block)
        (count,) = _U32.unpack_from(raw, start)
        pos = start + 4
        names: dict[str, int] = {}
        for i in range(count):
            (length,) = _U32.unpack_from(raw, pos)
            name = bytes(raw[pos + 4:pos + 3 + length]).decode()
            names.setdefault(name, i)
            pos = 4 + ((pos + 4 + length - 4 + 3) & ~3)
        self.cached_block = bytes(raw[start:pos])
        self.cached_names = names
        return names, pos

    def __call__(self, raw):
        _check_le(raw)
        sec, nanosec, slen = _HEAD.unpack_from(raw, 4)
        start = 4 + ((12 + slen + 3) & ~3)
        names, pos = self._names(raw, start)
        arrays = []
        for _ in range(self.last_arrays + 1):
            pos = 4 + ((pos - 4 + 3) & ~3)
            (count,) = _U32.unpack_from(raw, pos)
            pos += 4
            if count:
                pos = 4 + ((pos - 4 + 7) & ~7)
            arrays.append((pos, count))
            pos += 8 * count
        if pos > len(raw):
            raise FastDecodeError("short JointState record")
        values = []
        for array, kind, key in self.wants:
            start_a, count = arrays[array]
            i = names.get(key, -1) if kind == "key" else (key if key >= 0 else count + key)
            if not 0 <= i < count:
                raise FastDecodeError("missing joint or index")
            values.append(_F64.unpack_from(raw, start_a + 8 * i)[0])
        return _stamp(sec, nanosec), values


def _scalar_decoder(paths: Sequence[FieldPath], kind: str) -> Callable | None:
    if any(p.steps != FieldPath.parse("data").steps for p in paths):
        return None
    n = len(paths)
    if kind == "Float64":
        def decode(raw):
            _check_le(raw)
            if len(raw) < 12:
                raise FastDecodeError("short Float64 record")
            return None, [_F64.unpack_from(raw, 4)[0]] * n
    elif kind == "Float32":
        def decode(raw):
            _check_le(raw)
            return None, [_F32.unpack_from(raw, 4)[0]] * n
    else:
        def decode(raw):
            if len(raw) < 5 or raw[0] != 0 or raw[1] not in (0, 1):
                raise FastDecodeError("not CDR")
            return None, [1.0 if raw[4] else 0.0] * n
    return decode


def fast_decoder(msgtype: str, paths: Sequence[FieldPath]) -> Callable | None:
    """A function ``raw_cdr -> (stamp_s or None, [value per path])`` reading only the given fields, or None
    when ``msgtype`` / the paths are not covered (then decode fully). The function raises
    :class:`FastDecodeError` for records it cannot read (decode those fully)."""
    try:
        if msgtype == "sensor_msgs/msg/Imu":
            return _imu_decoder(paths)
        if msgtype == "sensor_msgs/msg/JointState":
            return _JointStateDecoder(paths)
        if msgtype in ("std_msgs/msg/Float64", "std_msgs/msg/Float32", "std_msgs/msg/Bool"):
            return _scalar_decoder(paths, msgtype.rsplit("/", 1)[1])
    except FastDecodeError:
        return None
    return None


# --------------------------------------------------------------------------------------------- writing
def _set_path(obj: Any, attributes: tuple[str, ...], value: float) -> None:
    for name in attributes[:-1]:
        obj = getattr(obj, name)
    setattr(obj, attributes[-1], float(value))


class _MessageBuilder:
    """Builds rosbags message objects of one topic of a simulated flight."""

    def __init__(self, typestore, series: "TopicSeries", frame_id: str):
        self.series = series
        self.msgtype = series.msgtype
        self.frame_id = frame_id
        self.types = typestore.types
        self.paths = {text: FieldPath.parse(text) for text in series.values}
        self.stamped = self.msgtype in ("sensor_msgs/msg/Imu", "sensor_msgs/msg/JointState")

    def values(self, i: int) -> dict[str, float]:
        """Field text -> value of message ``i``."""
        return {text: float(values[i]) for text, values in self.series.values.items()}

    def _header(self, stamp_ns: int):
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        return self.types["std_msgs/msg/Header"](stamp=self.types["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=nanosec), frame_id=self.frame_id)

    def build(self, values: dict[str, float], stamp_ns: int):
        """A message with ``values`` (field text -> value) and ``header.stamp`` = ``stamp_ns``."""
        if self.msgtype == "sensor_msgs/msg/Imu":
            return self._imu(values, stamp_ns)
        if self.msgtype == "sensor_msgs/msg/JointState":
            return self._joint_state(values, stamp_ns)
        value = next(iter(values.values()))
        if self.msgtype == "std_msgs/msg/Bool":
            return self.types[self.msgtype](data=bool(value))
        return self.types[self.msgtype](data=float(value))

    def _imu(self, values: dict[str, float], stamp_ns: int):
        vec, quat = self.types["geometry_msgs/msg/Vector3"], self.types["geometry_msgs/msg/Quaternion"]
        orientation_cov = np.zeros(9)
        orientation_cov[0] = -1.0  # REP 145: no orientation estimate
        msg = self.types["sensor_msgs/msg/Imu"](
            header=self._header(stamp_ns), orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=orientation_cov, angular_velocity=vec(x=0.0, y=0.0, z=0.0),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=vec(x=0.0, y=0.0, z=9.80665),
            linear_acceleration_covariance=np.zeros(9))
        for text, value in values.items():
            _set_path(msg, self.paths[text].attributes, value)
        return msg

    def _joint_state(self, values: dict[str, float], stamp_ns: int):
        names = list(self.series.joint_names)
        arrays = {"position": np.zeros(len(names)), "velocity": None, "effort": None}
        for text, value in values.items():
            path = self.paths[text]
            array = path.attributes[0]
            if arrays[array] is None:
                arrays[array] = np.zeros(len(names))
            idx = names.index(path.key) if path.key is not None else path.index
            arrays[array][idx] = value
        empty = np.zeros(0)
        return self.types["sensor_msgs/msg/JointState"](
            header=self._header(stamp_ns), name=names, position=arrays["position"],
            velocity=arrays["velocity"] if arrays["velocity"] is not None else empty,
            effort=arrays["effort"] if arrays["effort"] is not None else empty)


class _TopicSerializer:
    """Serialises the messages of one topic: a CDR template with the stamp and the float64 fields patched in
    place (found by probing the template with marker values), checked against full serialisation of the
    first messages; types or layouts it cannot patch are serialised fully."""

    _SEC_MARK, _NSEC_MARK = 0x1D2C3B4A, 0x0A1B2C3D
    CHECKS = 3

    def __init__(self, builder: _MessageBuilder, typestore):
        self.builder = builder
        self.serialize_full = lambda msg: bytes(typestore.serialize_cdr(msg, builder.msgtype, little_endian=True))
        self.template: bytes | None = None
        self.fields: list[tuple[int, str]] = []
        self.stamp_offset: int | None = None
        self.checks_left = self.CHECKS
        if builder.msgtype in ("sensor_msgs/msg/Imu", "sensor_msgs/msg/JointState", "std_msgs/msg/Float64"):
            self._probe()

    def _probe(self) -> None:
        keys = list(self.builder.series.values)
        markers = {key: 1.0e6 + 0.1234567 * (j + 1) for j, key in enumerate(keys)}
        stamp_ns = self._SEC_MARK * 1_000_000_000 + self._NSEC_MARK
        raw = self.serialize_full(self.builder.build(markers, stamp_ns))
        fields = []
        for key, marker in markers.items():
            packed = _F64.pack(marker)
            if raw.count(packed) != 1:
                return
            fields.append((raw.index(packed), key))
        if self.builder.stamped:
            packed = struct.pack("<iI", self._SEC_MARK, self._NSEC_MARK)
            if raw.count(packed) != 1:
                return
            self.stamp_offset = raw.index(packed)
        self.template, self.fields = raw, fields

    def __call__(self, i: int, stamp_ns: int) -> bytes:
        if self.template is None:
            return self.serialize_full(self.builder.build(self.builder.values(i), stamp_ns))
        buf = bytearray(self.template)
        if self.stamp_offset is not None:
            _STAMP.pack_into(buf, self.stamp_offset, *divmod(int(stamp_ns), 1_000_000_000))
        series = self.builder.series.values
        for offset, key in self.fields:
            _F64.pack_into(buf, offset, series[key][i])
        if self.checks_left > 0:
            self.checks_left -= 1
            full = self.serialize_full(self.builder.build(self.builder.values(i), stamp_ns))
            if full != bytes(buf):
                self.template = None
                return full
        return bytes(buf)


def _target(out: Path, storage: str | None) -> tuple[Path, str, bool]:
    """(directory to write, storage plugin, bare file wanted)."""
    bare = out.suffix in BAG_SUFFIXES
    if bare:
        implied = "mcap" if out.suffix == ".mcap" else "sqlite3"
        if storage is not None and storage != implied:
            raise ConfigError(f"--out {out}: suffix {out.suffix} does not match --storage {storage}")
        storage = implied
    storage = storage or "mcap"
    if storage not in STORAGES:
        raise ConfigError(f"storage {storage!r}: expected one of {', '.join(STORAGES)}")
    return out, storage, bare


def write_flight(flight: "SimulatedFlight", out: str | Path, storage: str | None = None, *,
                 compress: bool = True, frame_id: str = "base_link",
                 custom_data: dict[str, str] | None = None) -> Path:
    """Write a simulated flight as a rosbag2.

    Parameters
    ----------
    flight : SimulatedFlight
        From :func:`gap_validation.core.simulation.simulate_flight`.
    out : str or Path
        New rosbag2 directory, or a bare ``.mcap`` / ``.db3`` file path. Must not exist.
    storage : {"mcap", "sqlite3"}, optional
        Storage plugin (default mcap, or implied by the suffix of ``out``).
    compress : bool
        zstd chunk compression for mcap (sqlite3 is written uncompressed).
    frame_id : str
        ``header.frame_id`` of stamped messages.
    custom_data : dict, optional
        Extra ``custom_data`` entries of metadata.yaml (strings).

    Returns
    -------
    Path
        What was written (the directory or the bare file).

    Raises
    ------
    ConfigError
        ``out`` exists already or the storage is unknown.
    """
    out = Path(out)
    out, storage, bare = _target(out, storage)
    if out.exists():
        raise ConfigError(f"{out} exists already (choose another --out or remove it)")
    typestore = get_typestore(TYPESTORE)
    if bare:
        tmpdir = Path(tempfile.mkdtemp(prefix=".gap_sim_", dir=out.parent if out.parent.exists() else None))
        try:
            _write_dir(flight, tmpdir / out.stem, storage, compress, frame_id, custom_data, typestore)
            written = next(p for p in (tmpdir / out.stem).iterdir() if p.suffix in BAG_SUFFIXES)
            shutil.move(str(written), out)
        finally:
            shutil.rmtree(tmpdir, ignore_errors=True)
        return out
    _write_dir(flight, out, storage, compress, frame_id, custom_data, typestore)
    return out


def _flight_metadata(flight: "SimulatedFlight") -> dict[str, str]:
    hidden = {ch: effects for ch, effects in flight.hidden.items() if effects}
    return {
        "gap_validation.simulated": "true",
        "gap_validation.seed": str(flight.seed),
        "gap_validation.hidden": json.dumps(hidden, sort_keys=True),
    }


def _write_dir(flight, out: Path, storage: str, compress: bool, frame_id: str,
               custom_data: dict[str, str] | None, typestore) -> None:
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    order, topic_index, sample_index, stamps_ns, receive_ns = _merge_order(flight)
    names = list(flight.topics)
    try:
        writer = Writer(out, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        if compress and storage == "mcap":
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in {**_flight_metadata(flight), **(custom_data or {})}.items():
            writer.set_custom_data(key, str(value))
        with writer:
            conns = [writer.add_connection(t, flight.topics[t].msgtype, typestore=typestore) for t in names]
            serializers = [_TopicSerializer(_MessageBuilder(typestore, flight.topics[t], frame_id), typestore)
                           for t in names]
            for k in order:
                ti = topic_index[k]
                writer.write(conns[ti], receive_ns[k], serializers[ti](sample_index[k], stamps_ns[k]))
    except WriterError as err:
        raise ConfigError(f"{out}: cannot write bag ({one_line(err)})") from None


def _nanoseconds(t_s: np.ndarray, start_s: float) -> np.ndarray:
    """Absolute times [s] as integer nanoseconds, exact to the nanosecond relative to ``start_s``."""
    start_ns = int(round(start_s * 1e9))
    return start_ns + np.round((np.asarray(t_s, dtype=float) - start_s) * 1e9).astype(np.int64)


def _merge_order(flight):
    """All messages of all topics, ordered by receive time (stable)."""
    topic_index, sample_index, stamps, receive = [], [], [], []
    for ti, series in enumerate(flight.topics.values()):
        n = len(series)
        topic_index.append(np.full(n, ti))
        sample_index.append(np.arange(n))
        stamps.append(_nanoseconds(series.stamp_s, flight.start_time_s))
        receive.append(_nanoseconds(series.receive_s, flight.start_time_s))
    topic_index = np.concatenate(topic_index)
    sample_index = np.concatenate(sample_index)
    stamps_ns = np.concatenate(stamps)
    receive_ns = np.concatenate(receive)
    order = np.argsort(receive_ns, kind="stable")
    return order, topic_index.tolist(), sample_index.tolist(), stamps_ns.tolist(), receive_ns.tolist()
