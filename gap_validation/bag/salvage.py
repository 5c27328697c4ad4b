"""Salvage of damaged rosbag2 storage files: what a recording cut short or a broken index still holds.

rosbags refuses an mcap without its footer (a recording cut short) and a sqlite3 file whose index is broken.
:class:`gap_validation.bag.reader.Bag` then falls back to :func:`salvage`, a linear scan
(:class:`_McapSalvage`: records and chunks up to the first one that is cut off or does not decompress;
:class:`_SqliteSalvage`: rows in insertion order up to the first unreadable page) whose :attr:`damage` says
where the file stopped, so replay validates what was recorded and reports the rest.
"""
from __future__ import annotations

import sqlite3
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gap_validation.core.errors import one_line

__all__ = ["salvage", "Damage"]

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


class Damage(Exception):
    """Where a linear scan of a damaged file stopped: byte offset and why (``text``: the one-line message).

    Parameters
    ----------
    offset : int
        Byte offset where the scan stopped.
    reason : str
        Why.
    where : str
        Where, in words (default: the byte offset).
    """

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
            raise Damage(0, "not an mcap file (bad magic)")
        self.data_start = 9 + 8 + _U64.unpack(self._fh.read(8))[0]
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self.channels: dict[int, tuple[str, str]] = {}
        self.counts: dict[int, int] = {}
        self.first_ns = self.last_ns = None
        self.damage: Damage | None = None
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
            self.damage = Damage(offset, reason, f"byte {offset} of {self.size}")
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
        self.damage: Damage | None = None
        self._con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            topics = self._con.execute("SELECT id, name, type FROM topics").fetchall()
        except sqlite3.Error as err:
            self._con.close()
            raise Damage(0, f"the topic table is unreadable ({one_line(err)})") from None
        self.counts: dict[int, int] = {}
        self.first_ns = self.last_ns = None
        self._rows = -1
        for tid, t_ns, _ in self._scan(None):
            self.counts[tid] = self.counts.get(tid, 0) + 1
            self.first_ns = t_ns if self.first_ns is None else min(self.first_ns, t_ns)
            self.last_ns = t_ns if self.last_ns is None else max(self.last_ns, t_ns)
        self._rows = sum(self.counts.values())
        self.connections = [
            _SalvagedConnection(tid, name, msgtype, self.counts.get(tid, 0), _MsgDef(None, ""))
            for tid, name, msgtype in topics
        ]
        self.start_time = self.first_ns or 0

    def _scan(self, wanted):
        done = 0
        try:
            for tid, t_ns, data in self._con.execute(
                "SELECT topic_id, timestamp, data FROM messages ORDER BY id"
            ):
                done += 1
                if 0 <= self._rows < done:
                    return
                if wanted is None or tid in wanted:
                    yield tid, t_ns, data
        except sqlite3.Error as err:
            if self.damage is None:
                self.damage = Damage(done, one_line(err), f"message row {done + 1}")

    def messages(self, connections=None):
        by_id = {c.id: c for c in self.connections}
        wanted = None if connections is None else {c.id for c in connections}
        for tid, t_ns, data in self._scan(wanted):
            if tid in by_id:
                yield by_id[tid], t_ns, data

    def close(self) -> None:
        self._con.close()


def salvage(path: Path) -> "_McapSalvage | _SqliteSalvage | None":
    """A reader of what a damaged ``.mcap`` / ``.db3`` file still holds, or None when nothing can be
    recovered.

    Parameters
    ----------
    path : Path
        The storage file (not a rosbag2 directory).

    Returns
    -------
    reader or None
        With ``connections``, ``start_time``, ``messages(connections)``, ``close()`` and ``damage`` (a
        :class:`Damage` saying where the scan stopped, None if it did not), as rosbags' reader offers.
    """
    try:
        reader = (_McapSalvage if path.suffix == ".mcap" else _SqliteSalvage)(path)
    except (Damage, OSError, sqlite3.Error, struct.error):
        return None
    if reader.first_ns is None:
        reader.close()
        return None
    return reader
