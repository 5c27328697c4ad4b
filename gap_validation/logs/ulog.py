"""PX4 ULog (``.ulg``): read (:class:`ULogFile`) and written (:func:`write_ulog`).

The format is PX4's published spec (https://docs.px4.io/main/en/dev_log/ulog_file_format.html): a 16-byte
header (magic ``ULog\\x01\\x12\\x35``, version, start time [us]), then messages, each ``uint16 size, uint8
type, payload``: the *definitions* (``B`` flag bits first, ``F`` formats, ``I``/``M`` information, ``P``/``Q``
parameters) up to the first ``A``, ``L`` or ``C`` message, then the *data* (``A`` subscriptions ``multi_id,
msg_id, name``; ``D`` data ``msg_id, payload``; ``L``/``C`` log text, ``S`` sync, ``O`` dropouts, ``R``
unsubscriptions, ``I``/``M``/``P``/``Q`` again). Names follow pyulog, PX4's own reader: a topic is the message
name, a multi-instance one ``name:K`` (``multi_id`` K > 0; ``name:0`` is accepted for ``name``); fields are
flattened as pyulog flattens them (``xyz[0]``, ``a.b``, ``a[0].b``), ``_padding`` fields are not fields. A
sample's time is its ``timestamp_sample`` where the message has one, else its ``timestamp`` [us -> s].

Why a reader of our own and not pyulog (measured, ``benchmarks/bench_ulog.py``: a 10-minute, 57 MB log of 1.08
million data messages in 12 topics at PX4 rates, 15 % of its bytes in the two wanted topics): ``pyulog.ULog``
spends ~1.6 us of Python on every message (1.7-1.9 s), and ``message_name_filter_list`` saves only the final
copy of the unwanted topics, not the per-message work: 1.2-1.4 s, 0.7 times the full read, not the several
times faster a replay wants. This reader walks the message headers in one tight Python loop (``uint16 size``
-> next message, ~0.2 us per message), over the file in 1 MiB blocks, and does everything else per block with
numpy: types and ids are gathered at the found offsets, and each wanted field of each wanted topic is gathered
from all its ``D`` messages of the block at once (a strided view of the block as that field's type, indexed by
``message offset + field offset``: what ``np.frombuffer`` of the gathered payloads with the format's
structured dtype gives, without copying the payloads first). Measured on that log: :meth:`ULogFile.read`
0.20-0.24 s (0.11- 0.14 times ``pyulog.ULog``), :attr:`ULogFile.topics` then ``read`` (two passes) 0.47-0.53 s
(0.25-0.29 times); peak memory 10.7 MB (the wanted fields as float64 are 6 MB of it) against pyulog's 56 MB (8
MB filtered). The tests check this reader against pyulog value for value. ``topics`` needs a pass over the
file (the samples are counted); :meth:`ULogFile.read` before ``topics`` does both in that one pass.

Replay streams instead (:meth:`ULogFile.blocks`): one pass gives the topics and notes where the wanted
messages are in each 1 MiB block (4 bytes per message: the only memory that grows with the log), then each
block is read again and its messages gathered as above, a block at a time. On the same log, in the same run:
blocks 0.29 s (0.17 times ``pyulog.ULog``; the topics come with it), the whole read 0.23 s (0.13 times),
``topics`` then ``read`` 0.46 s; peak 6.1 MB against 10.7 MB (``benchmarks/bench_ulog.py``, variant *ours,
blocks*).

What is skipped as the spec says: information, parameters, log text, dropouts, sync and unsubscription
messages, and message types this reader does not know (skipped by their size). Appended data (flag bit
``DATA_APPENDED``, up to three ``appended_offsets``) is read as part of the data section, each part up to the
next offset (a message broken off before an offset is dropped, as the spec says). A log with an incompatible
flag bit this reader does not know is refused.

Damage: a file cut in the middle of a message, or a message that cannot be right (type 0, size 0, an unknown
type larger than 10000 bytes as pyulog judges it, a data message of an unsubscribed id or of the wrong size, a
subscription that cannot be resolved), stops the read there: what came before is returned and
:attr:`ULogFile.damage` says where (one line). The sync messages would allow skipping to the next good
message; this reader does not (the house rule: a damaged file is read up to the damage). Not a ULog (bad
magic), or a file that ends within the header or the definitions, is a :class:`DataError` at open.

Where it differs from pyulog 1.3 (both by the spec): a message that still logs its trailing padding is read
(pyulog drops it as the wrong size); the subscriptions hold in appended data (pyulog forgets them at an
appended offset); and a damaged message ends the read where pyulog skips it and goes on. On pyulog's own
sample logs from PX4 (its ``test/*.ulg``, appended data included) both read the same topics, fields, times and
values.

:func:`write_ulog` writes version-1 logs in PX4's layout (``uint64_t timestamp`` first, ``timestamp_sample``
as ``uint64_t``, ``xyz[0..2]`` as ``float xyz[3]`` when the arrays are float32): the simulator's flights,
checked by reading them back with pyulog.
"""
from __future__ import annotations

import array
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from gap_validation.core.atomic import atomic_open
from gap_validation.core.errors import DataError
from gap_validation.logs.base import LogBlocks, LogFile, LogSeries, LogTopic, WriteTopic

__all__ = ["ULogFile", "write_ulog", "ULOG_MAGIC"]

#: The first 7 bytes of every ULog file.
ULOG_MAGIC = b"ULog\x01\x12\x35"

#: ULog basic type -> numpy dtype (little endian). bool and char as int8, as pyulog reads them.
_BASIC = {
    "int8_t": np.dtype("i1"),
    "uint8_t": np.dtype("u1"),
    "int16_t": np.dtype("<i2"),
    "uint16_t": np.dtype("<u2"),
    "int32_t": np.dtype("<i4"),
    "uint32_t": np.dtype("<u4"),
    "int64_t": np.dtype("<i8"),
    "uint64_t": np.dtype("<u8"),
    "float": np.dtype("<f4"),
    "double": np.dtype("<f8"),
    "bool": np.dtype("i1"),
    "char": np.dtype("i1"),
}

_D, _A = ord("D"), ord("A")
#: Message types of the data section this reader knows (all but A and D are skipped); minimum payload sizes.
_KNOWN_MIN = {ord("A"): 4, ord("D"): 2, ord("R"): 2, ord("L"): 9, ord("C"): 11, ord("S"): 1, ord("O"): 2,
              ord("I"): 1, ord("M"): 2, ord("P"): 1, ord("Q"): 2, ord("F"): 1, ord("B"): 16}
#: pyulog's judgement of an unknown message type: larger than this is a corrupt header, not a new message.
_MAX_UNKNOWN_SIZE = 10000
#: Bytes of the file handled per block in a pass (the loop over headers; numpy for the rest).
_BLOCK = 1 << 20
_HEADER = struct.Struct("<7sBQ")
_MSG = struct.Struct("<HB")
_TOPIC_NAME = re.compile(r"^[A-Za-z0-9_\-/]+$")
_FIELD_NAME = re.compile(r"^[A-Za-z0-9_]+$")
_ARRAY_ELEMENT = re.compile(r"^([A-Za-z0-9_]+)\[(\d+)\]$")


# ------------------------------------------------------------------------------------------------ layouts


@dataclass(frozen=True)
class _Field:
    """One flattened field of a message: pyulog's name, basic type, byte offset in the payload."""

    name: str
    type: str
    offset: int


@dataclass(frozen=True)
class _Layout:
    """A subscribed message's flattened fields and sizes (pyulog's rules)."""

    fields: tuple[_Field, ...]          # every flattened field, padding included, in payload order
    min_size: int                       # payload size without the trailing padding (may be left out)
    max_size: int                       # the full payload size
    time: _Field | None                 # timestamp_sample where there is one, else timestamp

    def public(self) -> tuple[str, ...]:
        """The field names a user sees (no padding)."""
        return tuple(f.name for f in self.fields if not _is_padding(f.name))


def _is_padding(name: str) -> bool:
    return name.rsplit(".", 1)[-1].startswith("_padding")


def _parse_format(text: str) -> tuple[str, list[tuple[str, int, str]]]:
    """``name:type field;type[n] field;`` -> (name, [(type, array size or 0, field)]); ValueError when
    malformed."""
    name, sep, body = text.partition(":")
    if not sep or not name:
        raise ValueError("no message name")
    fields = []
    for part in body.split(";"):
        if not part:
            continue
        words = part.split(" ")
        if len(words) != 2 or not words[0] or not words[1]:
            raise ValueError(f"malformed field {part!r}")
        type_str, field_name = words
        size = 0
        if "[" in type_str:
            base, _, rest = type_str.partition("[")
            if not rest.endswith("]") or not rest[:-1].isdigit():
                raise ValueError(f"malformed array type {type_str!r}")
            size = int(rest[:-1])
            if size > 0xFFFF:
                raise ValueError(f"array size {size} too large")
            type_str = base
        fields.append((type_str, size, field_name))
    return name, fields


def _layout(name: str, formats: Mapping[str, list[tuple[str, int, str]]]) -> _Layout:
    """Flatten message ``name`` as pyulog does; ValueError for an unknown type or a circular definition."""
    out: list[_Field] = []
    offset = 0

    def flatten(prefix: str, type_name: str, depth: int) -> None:
        nonlocal offset
        if depth > 32:
            raise ValueError(f"circular or too deep nesting at {type_name}")
        if type_name not in formats:
            raise ValueError(f"unknown type {type_name}")
        for type_str, size, field_name in formats[type_name]:
            if type_str in _BASIC:
                width = _BASIC[type_str].itemsize
                for i in range(size) if size else (None,):
                    out.append(
                        _Field(prefix + field_name + ("" if i is None else f"[{i}]"), type_str, offset)
                    )
                    offset += width
            else:
                for i in range(size) if size else (None,):
                    flatten(prefix + field_name + ("." if i is None else f"[{i}]."), type_str, depth + 1)

    flatten("", name, 0)
    full = offset
    kept = list(out)
    while kept and kept[-1].name.startswith("_padding"):
        kept.pop()
    min_size = kept[-1].offset + _BASIC[kept[-1].type].itemsize if kept else 0
    by_name = {f.name: f for f in out}
    time = by_name.get("timestamp_sample") or by_name.get("timestamp")
    return _Layout(tuple(out), min_size, full, time)


def _canonical(topic: str) -> str:
    """``name:0`` is ``name``."""
    return topic[:-2] if topic.endswith(":0") else topic


# ------------------------------------------------------------------------------------------------ reading


class _Stop(Exception):
    """Where a pass stopped: absolute byte offset and the reason (the words in the damage line)."""

    def __init__(self, offset: int, reason: str):
        super().__init__(reason)
        self.offset, self.reason = offset, reason


class _Pass:
    """The state of one pass over the data section: subscriptions, counts, time span, and either the gathered
    fields or (``index``) where the wanted topics' messages are: per block of the pass (``blocks``: file
    offset and length), each topic's message offsets in it, and each topic's earliest finite time."""

    def __init__(self, formats: Mapping[str, list], wanted: Mapping[str, Sequence[str]], index: bool = False,
                 block: int = 0):
        self.formats = formats
        self.wanted = wanted
        self.index = index
        self.block = block
        self.blocks: list[tuple[int, int]] = []
        self.offsets: dict[str, dict[int, np.ndarray]] = {t: {} for t in wanted}
        self.first_s: dict[str, float] = {}
        self.layouts: dict[int, _Layout] = {}
        self.topic_of: dict[int, str] = {}
        self.order: dict[str, list[int]] = {}           # topic -> its msg_ids, in subscription order
        self.fields: dict[str, tuple[str, ...]] = {}
        self.min_size = np.full(0x10000, 0x7FFFFFFF, np.int64)
        self.max_size = np.full(0x10000, -1, np.int64)
        self.time_off = np.full(0x10000, -1, np.int64)  # offset of a uint64 time field (for the time span)
        self.counts = np.zeros(0x10000, np.int64)
        self.t_min = self.t_max = None
        self.chunks: dict[str, dict[str, list[np.ndarray]]] = {t: {} for t in wanted}

    def subscribe(self, payload: bytes) -> int | None:
        """Parse an ``A`` message; returns its msg_id (None: a repeat). ValueError when it cannot be
        resolved."""
        multi_id, msg_id = struct.unpack_from("<BH", payload, 0)
        name = payload[3:].decode("utf-8")
        topic = name if multi_id == 0 else f"{name}:{multi_id}"
        if msg_id in self.layouts:
            if self.topic_of[msg_id] == topic:
                return None                 # the same subscription again (e.g. in appended data)
            raise ValueError(f"msg_id {msg_id} subscribed to {self.topic_of[msg_id]} and to {topic}")
        layout = _layout(name, self.formats)
        self.layouts[msg_id] = layout
        self.topic_of[msg_id] = topic
        self.order.setdefault(topic, []).append(msg_id)
        self.fields.setdefault(topic, layout.public())
        self.min_size[msg_id], self.max_size[msg_id] = layout.min_size, layout.max_size
        if layout.time is not None and layout.time.type == "uint64_t":
            self.time_off[msg_id] = layout.time.offset
        return msg_id

    def unsubscribe(self, msg_id: int) -> None:
        """Undo a subscription met after the damage."""
        topic = self.topic_of.pop(msg_id)
        self.layouts.pop(msg_id)
        self.order[topic].remove(msg_id)
        if not self.order[topic]:
            del self.order[topic], self.fields[topic]
        self.min_size[msg_id], self.max_size[msg_id], self.time_off[msg_id] = 0x7FFFFFFF, -1, -1


def _walk(data: bytes, limit: int) -> array.array:
    """Offsets of the messages of ``data`` from 0 while a header starts before ``limit`` (the hot loop)."""
    found = array.array("q")
    append = found.append
    pos = 0
    while pos < limit:
        append(pos)
        pos += 3 + data[pos] + (data[pos + 1] << 8)
    return found


def _view(data: bytes, dtype: np.dtype) -> np.ndarray:
    """``data`` as ``dtype`` at every byte offset (element i is the value whose bytes start at i)."""
    n = len(data) - dtype.itemsize + 1
    return np.ndarray((max(n, 0),), dtype=dtype, buffer=data, offset=0, strides=(1,))


class ULogFile(LogFile):
    """A PX4 ULog file (``.ulg``), read with this module's reader (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The log file.

    Raises
    ------
    DataError
        The file is missing, is not a ULog (bad magic), has an incompatible flag bit this reader does not
        know, or ends within the header or the definitions (one line naming the file).

    Attributes
    ----------
    info : dict
        The ``I`` information messages of the definitions (key -> str, int or float), e.g. ``sys_name``.
    start_us : int
        The header's start time [us].
    """

    format = "ulog"

    def __init__(self, path: str | Path):
        super().__init__(path)
        self.size = self.path.stat().st_size
        self.info: dict[str, object] = {}
        self._formats: dict[str, list[tuple[str, int, str]]] = {}
        self._appended: list[int] = []
        self._indexed: _Pass | None = None          # the last index pass (:meth:`blocks`)
        with self.path.open("rb") as fh:
            self.start_us = self._read_header(fh)
            self._data_start = self._read_definitions(fh)

    # -- header and definitions ------------------------------------------------------------------------------

    def _read_header(self, fh) -> int:
        head = fh.read(16)
        if not head:
            raise DataError(f"{self.path}: empty file, not a ULog")
        if head[:7] != ULOG_MAGIC[:min(7, len(head))]:
            raise DataError(f"{self.path}: not a ULog file (bad magic bytes at the start)")
        if len(head) < 16:
            raise DataError(f"{self.path}: cut short at byte {len(head)} of 16 of the ULog header")
        _, _version, start_us = _HEADER.unpack(head)
        return start_us

    def _read_definitions(self, fh) -> int:
        pos = 16
        while True:
            head = fh.read(3)
            if len(head) < 3:
                where = "at the end of" if not head else "inside"
                raise DataError(
                    f"{self.path}: cut short at byte {pos + len(head)} of {self.size} {where} the "
                    "definitions (no data section)"
                )
            size, kind = _MSG.unpack(head)
            if kind in (_A, ord("L"), ord("C")):
                return pos
            payload = fh.read(size)
            if len(payload) < size:
                raise DataError(f"{self.path}: cut short at byte {self.size} of {self.size} inside the "
                                f"definitions (a {chr(kind)!r} message at byte {pos} broken off)")
            try:
                self._definition(kind, size, payload, pos)
            except (ValueError, UnicodeDecodeError, struct.error) as err:
                raise DataError(
                    f"{self.path}: corrupt {chr(kind)!r} message at byte {pos} of the definitions ({err})"
                ) from None
            pos += 3 + size

    def _definition(self, kind: int, size: int, payload: bytes, pos: int) -> None:
        if kind == ord("F"):
            name, fields = _parse_format(payload.decode("utf-8"))
            self._formats[name] = fields
        elif kind == ord("B"):
            if size < 16:
                raise ValueError(f"flag bits of {size} bytes (at least 16)")
            incompat = payload[8:16]
            if incompat[0] & ~1 or any(incompat[1:]):
                raise DataError(f"{self.path}: the log uses incompatible ULog features (incompat flags "
                                f"{incompat.hex()}) this reader does not know")
            offsets = struct.unpack_from("<3Q", payload.ljust(40, b"\0"), 16)
            if incompat[0] & 1:
                self._appended = sorted(o for o in offsets if o)
        elif kind == ord("I") and size:     # information only: what cannot be read is left out
            key_len = payload[0]
            type_str, _, key = payload[1:1 + key_len].decode("utf-8", "replace").partition(" ")
            value = payload[1 + key_len:]
            if type_str.startswith("char["):
                self.info[key] = value.decode("utf-8", "replace")
            elif type_str in _BASIC and len(value) == _BASIC[type_str].itemsize:
                self.info[key] = np.frombuffer(value, _BASIC[type_str])[0].item()
        elif kind == 0 or size == 0 or (kind not in _KNOWN_MIN and size > _MAX_UNKNOWN_SIZE):
            raise ValueError(f"message type {kind}, size {size}")

    # -- the passes -----------------------------------------------------------------------------------------

    def _regions(self) -> list[tuple[int, int]]:
        """(start, end) of each part of the data section: the log, then each appended part."""
        bounds = [self._data_start] + [o for o in self._appended if o >= self._data_start]
        ends = bounds[1:] + [self.size]
        return [(a, min(b, self.size)) for a, b in zip(bounds, ends) if a < self.size]

    def _pass(
        self, wanted: Mapping[str, Sequence[str]], index: bool = False, block: int | None = None
    ) -> _Pass:
        """One pass over the data in blocks of ``block`` bytes (default :data:`_BLOCK`): counts every topic,
        gathers the wanted fields (or, with ``index``, notes where their messages are); sets
        :attr:`damage`."""
        state = _Pass(self._formats, wanted, index, int(block or _BLOCK))
        stop = None
        with self.path.open("rb") as fh:
            for start, end in self._regions():
                try:
                    self._region(fh, start, end, state)
                except _Stop as err:
                    stop = err
                    break
            else:
                missing = [o for o in self._appended if o > self.size]
                if missing:
                    stop = _Stop(
                        self.size,
                        f"cut short at byte {self.size} of {self.size} (the appended data at "
                        f"byte {missing[0]} is missing)",
                    )
        self.damage = None if stop is None else self._damage_line(stop, state)
        return state

    def _damage_line(self, stop: _Stop, state: _Pass) -> str:
        if state.t_min is None:
            span = "nothing read before it"
        else:
            span = f"read {state.t_min / 1e6:.1f}-{state.t_max / 1e6:.1f} s"
        return f"{self.path}: {stop.reason}; {span}"

    def _region(self, fh, start: int, end: int, state: _Pass) -> None:
        """Pass over the messages from ``start`` to ``end`` in blocks; a message broken off at ``end`` is the
        damage if ``end`` is the end of the file (else data was appended after a log cut there: dropped)."""
        pos, want = start, state.block
        while pos < end:
            fh.seek(pos)
            data = fh.read(min(want, end - pos))
            offsets = _walk(data, len(data) - 2)
            whole = len(offsets)
            if whole:
                tail = offsets[-1]
                tail_end = tail + 3 + data[tail] + (data[tail + 1] << 8)
                if tail_end > len(data):
                    whole -= 1
            self._block(data, np.frombuffer(offsets, np.int64, whole), pos, state)
            done = offsets[whole] if whole < len(offsets) else (tail_end if whole else 0)
            if pos + len(data) == end and done < len(data):
                if end < self.size:
                    return
                left = data[done:]
                if len(left) < 3:
                    what = "a message header broken off"
                elif left[2] == _D:
                    what = "a data message broken off"
                else:
                    what = f"a {chr(left[2])!r} message broken off"
                raise _Stop(pos + done, f"cut short at byte {pos + done} of {self.size} ({what})")
            # a block too small for one message (only with a block below 64 KiB): read more
            want = state.block if done else max(2 * want, 0x10003)
            pos += done

    def _block(self, data: bytes, offs: np.ndarray, base: int, state: _Pass) -> None:
        """Handle the whole messages at ``offs`` of ``data`` (which starts at file byte ``base``)."""
        if not len(offs):
            return
        u8 = np.frombuffer(data, np.uint8)
        u16 = _view(data, np.dtype("<u2"))
        sizes = u16[offs].astype(np.int64)
        kinds = u8[offs + 2]
        cut, what, why = len(offs), "", ""
        subscribed: list[tuple[int, int]] = []            # (index in the block, msg_id) of this block's A
        since = np.full(0x10000, -1, np.int64)            # msg_id -> index of its A in this block
        for i in np.flatnonzero(kinds != _D).tolist():
            kind, size, at = int(kinds[i]), int(sizes[i]), int(offs[i])
            if kind == 0 or size == 0 or (kind not in _KNOWN_MIN and size > _MAX_UNKNOWN_SIZE) \
                    or size < _KNOWN_MIN.get(kind, 0):
                cut, what, why = i, "corrupt message header", f"type {kind}, size {size}"
                break
            if kind == _A:
                try:
                    msg_id = state.subscribe(data[at + 3:at + 3 + size])
                except (ValueError, UnicodeDecodeError, struct.error) as err:
                    cut, what, why = i, "unreadable subscription", str(err)
                    break
                if msg_id is not None:
                    subscribed.append((i, msg_id))
                    since[msg_id] = i
        is_d = np.flatnonzero(kinds[:cut] == _D)
        at = offs[is_d]
        ids = u16[np.minimum(at + 3, len(u16) - 1)].astype(np.int64)
        length = sizes[is_d] - 2
        ok = (length >= state.min_size[ids]) & (length <= state.max_size[ids]) & (since[ids] < is_d)
        if not ok.all():
            first = int(np.argmin(ok))
            msg_id = int(ids[first])
            if msg_id not in state.layouts or since[msg_id] > is_d[first]:
                why = f"msg_id {msg_id} has no subscription"
            else:
                lay = state.layouts[msg_id]
                why = (f"{state.topic_of[msg_id]} with {int(length[first])} bytes, its format has "
                       f"{lay.min_size}-{lay.max_size}")
            cut, what = int(is_d[first]), "corrupt data message"
            keep = slice(0, first)
            is_d, at, ids = is_d[keep], at[keep], ids[keep]
        for i, msg_id in subscribed:
            if i >= cut:
                state.unsubscribe(msg_id)
        state.counts += np.bincount(ids, minlength=0x10000)
        self._time_span(data, at, ids, state)
        if state.index:
            self._note(data, at, ids, base, state)
        else:
            self._gather(data, at, ids, state)
        if cut < len(offs):
            at_byte = base + int(offs[cut])
            raise _Stop(at_byte, f"{what} at byte {at_byte} of {self.size} ({why})")

    @staticmethod
    def _time_span(data: bytes, at: np.ndarray, ids: np.ndarray, state: _Pass) -> None:
        t_off = state.time_off[ids]
        has = t_off >= 0
        if not has.any():
            return
        t = _view(data, np.dtype("<u8"))[at[has] + 5 + t_off[has]]
        lo, hi = int(t.min()), int(t.max())
        state.t_min = lo if state.t_min is None else min(state.t_min, lo)
        state.t_max = hi if state.t_max is None else max(state.t_max, hi)

    @staticmethod
    def _gather(data: bytes, at: np.ndarray, ids: np.ndarray, state: _Pass) -> None:
        views: dict[str, np.ndarray] = {}
        for topic, names in state.wanted.items():
            msg_ids = state.order.get(topic)
            if not msg_ids:
                continue
            mask = ids == msg_ids[0] if len(msg_ids) == 1 else np.isin(ids, msg_ids)
            if not mask.any():
                continue
            payload = at[mask] + 5
            layout = state.layouts[msg_ids[0]]
            by_name = {f.name: f for f in layout.fields}
            chunks = state.chunks[topic]
            for name in ("\0time",) + tuple(names):
                f = layout.time if name == "\0time" else by_name.get(name)
                if f is None:
                    continue
                if f.type not in views:
                    views[f.type] = _view(data, _BASIC[f.type])
                chunks.setdefault(name, []).append(views[f.type][payload + f.offset])   # float64 at the end

    @staticmethod
    def _note(data: bytes, at: np.ndarray, ids: np.ndarray, base: int, state: _Pass) -> None:
        """Index the wanted topics' messages of a block (offsets in it), and their earliest finite time."""
        block = len(state.blocks)
        state.blocks.append((base, len(data)))
        for topic in state.wanted:
            msg_ids = state.order.get(topic)
            if not msg_ids:
                continue
            mask = ids == msg_ids[0] if len(msg_ids) == 1 else np.isin(ids, msg_ids)
            if not mask.any():
                continue
            mine = at[mask]
            state.offsets[topic][block] = mine.astype(np.uint32)
            f = state.layouts[msg_ids[0]].time
            if f is not None:
                raw = _view(data, _BASIC[f.type])[mine + 5 + f.offset]
                t = (
                    float(raw.min())
                    if raw.dtype.kind in "iu"
                    else float(np.fmin.reduce(raw.astype(np.float64)))
                )
                if not np.isnan(t):
                    state.first_s[topic] = min(state.first_s.get(topic, np.inf), t / 1e6)

    # -- the LogFile interface
    # --------------------------------------------------------------------------------

    def _topics(self) -> dict[str, LogTopic]:
        return self._table(self._pass({}))

    @staticmethod
    def _table(state: _Pass) -> dict[str, LogTopic]:
        return {topic: LogTopic(topic, state.fields[topic], int(state.counts[ids].sum()))
                for topic, ids in state.order.items()}

    def read(self, wanted: Mapping[str, Sequence[str]]) -> dict[str, LogSeries]:
        """The samples of the ``wanted`` fields of each wanted topic (topic -> fields).

        A multi-instance topic is ``name:K``; ``name:0`` is ``name``. Topics the log does not have are left
        out; before :attr:`topics` was asked for, one pass over the file gives both.

        Parameters
        ----------
        wanted : dict
            Topic -> field names (pyulog's: ``xyz[0]``, ``a.b``).

        Returns
        -------
        dict
            Topic (as asked) -> :class:`LogSeries` (time [s] from ``timestamp_sample`` where the message has
            it, else ``timestamp``; values float64).

        Raises
        ------
        DataError
            A wanted field the topic does not have (naming the file, topic, field and the fields it has), or a
            wanted topic without a timestamp.
        """
        asked = {topic: (_canonical(topic), tuple(fields)) for topic, fields in wanted.items()}
        need: dict[str, list[str]] = {}
        for canon, fields in asked.values():
            need.setdefault(canon, [])
            need[canon] += [f for f in fields if f not in need[canon]]
        if self._topic_cache is None:
            state = self._pass({t: f for t, f in need.items() if t.split(":")[0] in self._formats})
            self._topic_cache = self._table(state)
        else:
            state = None
        present = {t: f for t, f in need.items() if t in self.topics}
        for topic, fields in present.items():
            have = set(self.topics[topic].fields)
            for name in fields:
                if name not in have:
                    raise self.missing_field(topic, name)
        if state is None:
            state = self._pass(present)
        out = {}
        left = [canon for canon, _ in asked.values()]
        for topic, (canon, fields) in asked.items():
            left.remove(canon)
            if canon in present:
                out[topic] = self._series(state, canon, fields)
                if canon not in left:
                    state.chunks.pop(canon, None)   # what the samples were gathered in: no longer needed
        return out

    def _read(self, wanted: dict[str, tuple[str, ...]]) -> dict[str, LogSeries]:
        return self.read(wanted)

    def blocks(self, wanted: Mapping[str, Sequence[str]], *, block_bytes: int | None = None) -> LogBlocks:
        """The samples of the ``wanted`` fields of each wanted topic (topic -> fields) per block of the file,
        in the file's order: joined, what :meth:`read` returns.

        A pass over the file (:attr:`topics` and :attr:`damage` are known after it) notes where the wanted
        topics' messages are in each block of ``block_bytes`` (4 bytes per message); iterating reads each
        block again and gathers them. Topics the log does not have are left out; ``name:0`` is ``name``.

        Parameters
        ----------
        wanted : dict
            Topic -> field names (pyulog's: ``xyz[0]``, ``a.b``).
        block_bytes : int, optional
            Bytes per block (default :data:`_BLOCK`, 1 MiB).

        Raises
        ------
        DataError
            A wanted field the topic does not have (naming the file, topic, field and the fields it has), or a
            wanted topic without a timestamp.
        """
        asked = {topic: (_canonical(topic), tuple(fields)) for topic, fields in wanted.items()}
        need = sorted({canon for canon, _ in asked.values() if canon.split(":")[0] in self._formats})
        state = self._indexed
        if state is None or state.block != int(block_bytes or _BLOCK) or not set(need) <= set(state.wanted):
            state = self._pass({t: () for t in need}, index=True, block=block_bytes)
            if self._topic_cache is None:
                self._topic_cache = self._table(state)
            self._indexed = state
        present = {topic: (canon, fields) for topic, (canon, fields) in asked.items() if canon in self.topics}
        for topic, (canon, fields) in present.items():
            have = set(self.topics[canon].fields)
            for name in fields:
                if name not in have:
                    raise self.missing_field(canon, name)
            if state.layouts[state.order[canon][0]].time is None:
                raise DataError(f"{self.path}: topic {canon} has no timestamp field")
        return _ULogBlocks(self, state, present)

    def _series(self, state: _Pass, topic: str, fields: tuple[str, ...]) -> LogSeries:
        chunks = state.chunks.get(topic, {})
        layout = state.layouts[state.order[topic][0]]
        if layout.time is None:
            raise DataError(f"{self.path}: topic {topic} has no timestamp field")
        count = int(state.counts[state.order[topic]].sum())

        def fill(name: str, out: np.ndarray) -> np.ndarray:
            parts = chunks.get(name) or [np.zeros(0)]
            return np.concatenate(parts, out=out)

        t_s = fill("\0time", np.empty(count))
        t_s /= 1e6
        values = np.empty((count, len(fields)))
        for j, name in enumerate(fields):
            fill(name, values[:, j])
        return LogSeries(t_s, values, fields)


class _ULogBlocks(LogBlocks):
    """The wanted series of a ULog per block of its index pass (:meth:`ULogFile.blocks`)."""

    def __init__(self, log: ULogFile, state: _Pass, asked: dict[str, tuple[str, tuple[str, ...]]]):
        counts = {topic: int(state.counts[state.order[canon]].sum()) for topic, (canon, _) in asked.items()}
        super().__init__(log.path, {topic: fields for topic, (_, fields) in asked.items()}, counts)
        self.state, self.asked = state, asked
        self._start_s = min((state.first_s.get(canon, np.inf) for canon, _ in asked.values()), default=np.inf)

    def _blocks(self):
        state = self.state
        if not self.asked:
            return
        buffer = bytearray(max(length for _, length in state.blocks))     # one buffer for every block
        with self.path.open("rb", buffering=0) as fh:
            for block, (base, length) in enumerate(state.blocks):
                mine = [(topic, canon, fields, state.offsets[canon].get(block))
                        for topic, (canon, fields) in self.asked.items()]
                mine = [m for m in mine if m[3] is not None]
                if not mine:
                    continue
                fh.seek(base)
                data = memoryview(buffer)[:length]
                got = fh.readinto(data)
                if got != length:  # the file changed since the index pass
                    raise DataError(
                        f"{self.path}: {length - got} bytes fewer than when it was opened (at byte "
                        f"{base + got}); it changed while being read"
                    )
                views: dict[str, np.ndarray] = {}

                def column(f: _Field, payload: np.ndarray, out: np.ndarray) -> None:
                    if f.type not in views:
                        views[f.type] = _view(data, _BASIC[f.type])
                    out[:] = views[f.type][payload + f.offset]

                out = {}
                for topic, canon, fields, offsets in mine:
                    layout = state.layouts[state.order[canon][0]]
                    by_name = {f.name: f for f in layout.fields}
                    payload = offsets.astype(np.int64) + 5
                    t_s = np.empty(payload.size)
                    column(layout.time, payload, t_s)
                    t_s /= 1e6
                    values = np.empty((payload.size, len(fields)))
                    for j, name in enumerate(fields):
                        column(by_name[name], payload, values[:, j])
                    out[topic] = LogSeries(t_s, values, fields)
                views.clear()
                data.release()
                yield out


# ------------------------------------------------------------------------------------------------ writing


def _message(kind: str, payload: bytes) -> bytes:
    """One ULog message: ``uint16 size, uint8 type, payload``."""
    if len(payload) > 0xFFFF:
        raise ValueError(f"ULog {kind!r} message of {len(payload)} bytes (at most 65535)")
    return _MSG.pack(len(payload), ord(kind)) + payload


def _ulog_type(dtype: np.dtype) -> str:
    if dtype.kind == "b":
        return "bool"
    if dtype.kind == "f" and dtype.itemsize in (4, 8):
        return "float" if dtype.itemsize == 4 else "double"
    if dtype.kind in "iu" and dtype.itemsize in (1, 2, 4, 8):
        return f"{'u' if dtype.kind == 'u' else ''}int{8 * dtype.itemsize}_t"
    raise ValueError(f"no ULog type for {dtype}")


def _info(key: str, value: object) -> bytes:
    if isinstance(value, str):
        raw = value.encode("utf-8")
        type_key, body = f"char[{len(raw)}] {key}", raw
    elif isinstance(value, (bool, int, np.integer)) and -2**31 <= int(value) < 2**31:
        type_key, body = f"int32_t {key}", struct.pack("<i", int(value))
    elif isinstance(value, (int, np.integer)) and -2**63 <= int(value) < 2**63:
        type_key, body = f"int64_t {key}", struct.pack("<q", int(value))
    elif isinstance(value, (float, np.floating)):
        type_key, body = f"float {key}", struct.pack("<f", float(value))
    else:
        raise ValueError(f"info {key}: a str, int or float, not {type(value).__name__}")
    raw_key = type_key.encode("utf-8")
    return _message("I", bytes([len(raw_key)]) + raw_key + body)


@dataclass
class _Topic:
    """A topic to write: its message name, instance, columns in the message's order."""

    name: str
    multi_id: int
    t_us: np.ndarray
    columns: list[tuple[str, str, int, list[np.ndarray]]]   # (field, ULog type, array size or 0, arrays)

    def format_text(self) -> str:
        parts = ["uint64_t timestamp"]
        for field_name, type_str, size, _ in self.columns:
            parts.append(f"{type_str}[{size}] {field_name}" if size else f"{type_str} {field_name}")
        return f"{self.name}:" + "".join(p + ";" for p in parts)

    def records(self, msg_id: int) -> np.ndarray:
        """The ``D`` messages, header included, as an ``(n, size)`` uint8 array."""
        spec = [("size", "<u2"), ("kind", "u1"), ("msg_id", "<u2"), ("timestamp", "<u8")]
        for field_name, type_str, size, _ in self.columns:
            dtype = _BASIC[type_str]
            spec.append((field_name, dtype, (size,)) if size else (field_name, dtype))
        rec = np.zeros(len(self.t_us), np.dtype(spec))
        rec["size"] = rec.dtype.itemsize - 3
        rec["kind"] = _D
        rec["msg_id"] = msg_id
        rec["timestamp"] = self.t_us
        for field_name, _, size, arrays in self.columns:
            if size:
                rec[field_name] = np.stack(arrays, axis=1)
            else:
                rec[field_name] = arrays[0]
        return rec.view(np.uint8).reshape(len(rec), rec.dtype.itemsize)


def _topic(wt: WriteTopic) -> _Topic:
    name, _, instance = wt.name.partition(":")
    if not _TOPIC_NAME.match(name) or (instance and not instance.isdigit()) or int(instance or 0) > 255:
        raise ValueError(
            f"ULog topic {wt.name!r}: a message name [A-Za-z0-9_-/], with ':K' (0-255) for an instance"
        )
    t_us = np.asarray(wt.t_us)
    if t_us.ndim != 1 or t_us.dtype.kind not in "iu" or (len(t_us) and t_us.min() < 0):
        raise ValueError(f"ULog topic {wt.name}: t_us must be non-negative integers [us]")
    if np.any(np.diff(t_us) < 0):
        raise ValueError(f"ULog topic {wt.name}: t_us must not decrease")
    groups: dict[str, dict[int, np.ndarray]] = {}
    order: list[str] = []
    for field_name, values in wt.fields.items():
        arr = np.asarray(values)
        if arr.shape != t_us.shape:
            raise ValueError(
                f"ULog topic {wt.name}: field {field_name} has {arr.shape} values for {t_us.shape} times"
            )
        match = _ARRAY_ELEMENT.match(field_name)
        base, index = (match.group(1), int(match.group(2))) if match else (field_name, -1)
        if not _FIELD_NAME.match(base) or base == "timestamp":
            raise ValueError(f"ULog topic {wt.name}: field name {field_name!r} (timestamp is t_us; names "
                             "[A-Za-z0-9_], arrays as name[i])")
        if base not in groups:
            groups[base] = {}
            order.append(base)
        if groups[base] and (index in groups[base] or index == -1 or -1 in groups[base]):
            raise ValueError(f"ULog topic {wt.name}: field {field_name} clashes with another field {base}")
        groups[base][index] = arr
    columns = []
    for base in order:
        elements = groups[base]
        if base == "timestamp_sample":
            if -1 not in elements:
                raise ValueError(f"ULog topic {wt.name}: timestamp_sample must be a single field")
            arr = elements[-1]
            if arr.dtype.kind not in "iuf" or (len(arr) and arr.min() < 0):
                raise ValueError(f"ULog topic {wt.name}: timestamp_sample must be non-negative numbers [us]")
            if arr.dtype.kind == "f":
                arr = np.round(arr)
            columns.append((base, "uint64_t", 0, [arr.astype(np.uint64)]))
            continue
        if -1 in elements:
            columns.append((base, _ulog_type(elements[-1].dtype), 0, [elements[-1]]))
            continue
        if sorted(elements) != list(range(len(elements))):
            raise ValueError(f"ULog topic {wt.name}: array {base} must have the elements 0..n-1 "
                             f"(it has {sorted(elements)})")
        arrays = [elements[i] for i in range(len(elements))]
        types = {_ulog_type(a.dtype) for a in arrays}
        if len(types) != 1:
            raise ValueError(f"ULog topic {wt.name}: array {base} mixes types {sorted(types)}")
        columns.append((base, types.pop(), len(arrays), arrays))
    return _Topic(name, int(instance or 0), t_us.astype(np.uint64), columns)


def write_ulog(path: str | Path, topics: Sequence[WriteTopic], *, start_us: int = 0,
               info: Mapping[str, object] | None = None) -> Path:
    """Write ``topics`` as a ULog file (version 1, PX4's layout), atomically.

    The file holds the header, a flag-bits message (no flags), the information messages, one format per
    message name, one subscription per topic (``msg_id`` 0, 1, ... in the order given, ``multi_id`` from the
    ``:K`` suffix), then the data messages of all topics in time order (ties in the order of ``topics``).
    Every message starts with ``uint64_t timestamp`` (``t_us``); a field ``timestamp_sample`` is ``uint64_t``
    (rounded if given as floats); a field's ULog type follows its array's dtype (float64 ``double``, float32
    ``float``, intN/uintN ``[u]intN_t``, bool ``bool``); fields ``xyz[0]``, ``xyz[1]``, ``xyz[2]`` are one
    array field ``float xyz[3]`` (their dtypes must agree). The instances of a topic (``name``, ``name:1``)
    share its format, so they must have the same fields.

    Parameters
    ----------
    path : str or Path
        The ``.ulg`` file to write (replaced atomically: a temporary file in the same directory, renamed).
    topics : sequence of WriteTopic
        The topics: ``name`` (``name:K`` for instance K), ``t_us`` (int, non-decreasing), ``fields`` (name ->
        array, one value per time). ``units`` is not kept (ULog has none).
    start_us : int
        The header's start time [us].
    info : dict, optional
        Information messages (key -> str, int or float), added to ``sys_name``
        (``"gap_validation"`` unless given).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        A topic or field name ULog cannot hold, a dtype without a ULog type, mismatched lengths, decreasing
        times, instances of one message with different fields.
    """
    built = [_topic(t) for t in topics]
    formats: dict[str, str] = {}
    for t in built:
        text = t.format_text()
        if formats.setdefault(t.name, text) != text:
            raise ValueError(
                f"ULog topic {t.name}: its instances have different fields ({formats[t.name]!r} vs {text!r})"
            )
    seen = set()
    for t in built:
        if (t.name, t.multi_id) in seen:
            raise ValueError(f"ULog topic {t.name}:{t.multi_id} given twice")
        seen.add((t.name, t.multi_id))
    head = [_HEADER.pack(ULOG_MAGIC, 1, int(start_us)), _message("B", bytes(40))]
    head += [_info(k, v) for k, v in {"sys_name": "gap_validation", **dict(info or {})}.items()]
    head += [_message("F", text.encode("utf-8")) for text in formats.values()]
    head += [
        _message("A", struct.pack("<BH", t.multi_id, i) + t.name.encode("utf-8")) for i, t in enumerate(built)
    ]
    data = _interleave([t.records(i) for i, t in enumerate(built)], [t.t_us for t in built])
    with atomic_open(path, "wb") as fh:
        fh.write(b"".join(head))
        fh.write(data)
    return Path(path)


def _interleave(records: list[np.ndarray], times: list[np.ndarray]) -> memoryview:
    """The rows of every topic's records in time order (stable: ties keep the topics' order), as one
    buffer."""
    if not records:
        return memoryview(b"")
    t_all = np.concatenate(times)
    which = np.concatenate([np.full(len(t), k, np.int64) for k, t in enumerate(times)])
    order = np.argsort(t_all, kind="stable")
    widths = np.array([r.shape[1] for r in records], np.int64)
    sorted_width = widths[which[order]]
    starts = np.empty(len(order), np.int64)
    starts[order] = np.cumsum(sorted_width) - sorted_width
    out = np.empty(int(sorted_width.sum()), np.uint8)
    first = 0
    for rows in records:
        n, width = rows.shape
        mine = starts[first:first + n]
        step = max(1, (1 << 22) // max(width, 1))
        for a in range(0, n, step):
            out[mine[a:a + step, None] + np.arange(width)] = rows[a:a + step]
        first += n
    return memoryview(out)
