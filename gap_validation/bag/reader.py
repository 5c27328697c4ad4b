"""Reading rosbag2 files (through ``rosbags``): open, list topics, stream records, deserialise.

:func:`open_bag` accepts a rosbag2 directory (with ``metadata.yaml``), a bare ``.mcap`` or ``.db3`` file, or a
directory without metadata that holds exactly one storage file. :meth:`Bag.records` streams the raw CDR
records of the requested topics one by one (rosbags reads mcap chunk by chunk and sqlite3 through a cursor),
so an hour-long bag is never held in memory. Messages are decoded with the ``ROS2_JAZZY`` typestore (types the
store lacks are registered from the bag's own message definitions); replay reads most of them with the fast
field decoders of :mod:`gap_validation.messages.cdr` instead.

A damaged file (a recording cut short, a broken index) is read by :func:`gap_validation.bag.salvage.salvage`
up to the damage, and :meth:`Bag.records` ends with a :class:`DataError` saying where the file stopped and how
many seconds before it were read.
"""
from __future__ import annotations

import sqlite3
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.reader import DirectoryReader
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_idl, get_types_from_msg, get_typestore

from gap_validation.bag.batches import BATCH, RecordBatch, grouped, storage_batches
from gap_validation.bag.salvage import Damage, salvage
from gap_validation.core.errors import DataError, one_line

__all__ = ["Bag", "TopicInfo", "open_bag", "BAG_SUFFIXES", "TYPESTORE"]

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
        self.damage: Damage | None = None
        self._last_ns: int | None = None
        try:
            self._reader = Reader(self._storage)
            self._reader.open()
        except Exception as err:  # noqa: BLE001 - any failure to open means "not a readable bag"
            self._reader = _salvage(self._storage)
            if self._reader is None:
                raise DataError(
                    f"{self.path}: cannot read bag ({one_line(err)}; nothing recoverable)"
                ) from None
            self.damage = self._reader.damage or Damage(0, one_line(err), "the index")
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
        """Messages in ``topics`` (all topics when None).

        Parameters
        ----------
        topics : sequence of str, optional
            Topics to count (None: all).
        """
        info = self.topics
        names = info.keys() if topics is None else [t for t in topics if t in info]
        return sum(info[t].count for t in names)

    def _connections(self, topics: Sequence[str] | None):
        wanted = None if topics is None else set(topics)
        return [c for c in self._reader.connections if wanted is None or c.topic in wanted]

    def ensure_type(self, msgtype: str) -> None:
        """Make ``msgtype`` decodable: register it from the bag's definition if the typestore lacks it.

        Parameters
        ----------
        msgtype : str
            The message type, e.g. ``sensor_msgs/msg/Imu``.

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

        Parameters
        ----------
        topics : sequence of str, optional
            Topics to stream (None: all).

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

    def record_batches(self, topics: Sequence[str] | None = None, size: int = BATCH) -> Iterator[RecordBatch]:
        """The records of :meth:`records`, in the same order, as
        :class:`~gap_validation.bag.batches.RecordBatch` of at most ``size`` records (an indexed mcap file:
        straight from its chunks; sqlite3: rows fetched many at a time; see
        :mod:`gap_validation.bag.batches`).

        Parameters
        ----------
        topics : sequence of str, optional
            Topics to stream (None: all).
        size : int
            Most records per batch.

        Raises
        ------
        DataError
            On a damaged file, naming the bag (the batches before it stay valid).
        """
        conns = self._connections(topics)
        if not conns:
            return
        sources = self._batch_sources(conns, size)
        if sources is None:
            yield from grouped(self.records(topics), size)
            return
        try:
            for source in sources:
                for batch in source:
                    self._last_ns = int(batch.t_ns[-1]) if len(batch) else self._last_ns
                    yield batch
        except Exception as err:  # noqa: BLE001 - as records(): rosbags, zstd, lz4 raise many kinds on damage
            if isinstance(err, DataError):
                raise
            raise DataError(f"{self.path}: corrupted or unreadable data ({one_line(err)}){self._before()}") \
                from None

    def _batch_sources(self, conns: Sequence[Any], size: int) -> list[Iterator[RecordBatch]] | None:
        """Per storage file, its batches (:func:`~gap_validation.bag.batches.storage_batches`), in the order
        rosbags reads the files; None when one of them cannot be read so (then :meth:`records` is grouped)."""
        if self.damage is not None or not isinstance(self._reader, Reader):
            return None
        storage = self._reader.storage
        if isinstance(storage, DirectoryReader):
            if self._reader.compression_mode == "message":
                return None
            # as DirectoryReader.messages
            parts = [(part, {x.id: y.topic for x in part.connections for y in conns
                             if y.topic == x.topic and y.msgtype == x.msgtype and y.ext == x.ext
                             and (not x.digest or not y.digest or y.digest == x.digest)})
                     for part in storage.storages]
        else:
            parts = [(storage, {c.id: c.topic for c in conns})]
        sources = []
        for part, topic_of in parts:
            if topic_of:
                source = storage_batches(part, topic_of, size)
                if source is None:
                    return None
                sources.append(source)
        return sources

    def _before(self) -> str:
        """``; validated the X s before (up to bag time T)`` for what was read before a damage."""
        if self._last_ns is None:
            return "; nothing before it was read"
        span_s = (self._last_ns - self._reader.start_time) * 1e-9
        return f"; validated the {span_s:.1f} s before it (bag time up to {self._last_ns * 1e-9:.3f} s)"

    def deserialize(self, raw: Any, msgtype: str, topic: str = "") -> Any:
        """Fully decode one CDR record into a rosbags message object.

        Parameters
        ----------
        raw : bytes-like
            The CDR record.
        msgtype : str
            Its message type.
        topic : str
            Its topic, for the message of an error.

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
        """Stream ``(topic, message object, bag_time_s)`` (full deserialisation).

        Parameters
        ----------
        topics : sequence of str, optional
            Topics to stream (None: all).
        """
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
    """Open a rosbag2 directory, ``.mcap`` or ``.db3`` file for streaming (see :class:`Bag`).

    Parameters
    ----------
    path : str or Path
        The bag directory, or one ``.mcap`` / ``.db3`` file.
    """
    return Bag(path)


def _salvage(storage: Path) -> Any:
    """A reader of what a damaged bag (its one storage file) still holds, or None (:func:`salvage`)."""
    files = (
        [storage] if storage.is_file() else sorted(p for p in storage.iterdir() if p.suffix in BAG_SUFFIXES)
    )
    return salvage(files[0]) if len(files) == 1 else None
