"""ArduPilot DataFlash logs (``.bin``): :class:`DataFlashFile` reads one, :func:`write_dataflash` writes one.

The format (ArduPilot's ``libraries/AP_Logger/LogStructure.h``; pymavlink's ``DFReader``): a log is a sequence
of messages, each ``0xA3 0x95``, a type byte and a payload of the length the type's ``FMT`` message gives.
``FMT`` is type 128, 89 bytes, columns ``Type,Length,Name,Format,Columns`` (``BBnNZ``); a message type has a
name of at most 4 characters, up to 16 columns and one format character per column (:data:`FORMATS`). ``FMTU``
gives each type's unit and multiplier characters (``UNIT``, ``MULT`` define them); a ``#`` unit marks the
*instance* column (IMU's ``I``).

Names and numbers are what pymavlink gives (so what MAVExplorer shows):

* **Topics** are message names (``RATE``, ``SIDD``, ``RCOU``). A type with an instance column is also a topic
  per instance, named as ``DFReader`` names them in its ``messages`` dict: ``"%s[%s]" % (name, value)``, so
  ``IMU[0]``, ``IMU[1]``; plain ``IMU`` is every instance, interleaved as logged (what
  ``recv_match(type="IMU")`` returns). Where two type ids carry the same name, the last defined one is the
  topic, as in ``DFReader.name_to_id``.
* **Fields** are the columns, scaled by their format character's multiplier as ``DFReader`` scales them:
  ``c C e E`` are divided by 100, ``L`` (latitude, longitude) by 1e7; every other number is as logged. FMTU's
  multipliers are *not* applied: pymavlink (by default, and MAVExplorer) only uses them to name the unit. So
  ``RCOU.C1`` is PWM in microseconds, ``ATT.Roll`` degrees, ``SIDD.Gx`` and ``RATE.ROut`` as logged. Text
  columns (``n N Z``) and ``a`` arrays are no numbers and cannot be read as fields.
* **Time** is ``TimeUS / 1e6`` s (``DFReader``'s clock without a GPS time base is ``TimeUS * 1e-6``: the same
  to the last bit or one unit in it). A type without a ``TimeUS`` column (``FMT``, some very old types) is
  listed but cannot be read.

How a file is read (the reason for a reader of our own is speed: ``DFReader`` decodes every message in Python,
some 10 us each):

1. **The walk** finds the messages by the rules of pymavlink's index (``dfindexer``): at a position, ``0xA3
   0x95`` and a type that an ``FMT`` before it defined make a message of that type's length; anything else is
   skipped one byte at a time, so the walk resynchronises to the next ``0xA3 0x95`` with a known type, as
   ``DFReader``'s parser (``recv_msg``) does. (pymavlink's index, which ``recv_match`` follows, skips bytes
   that are no header but has stopped at the first header of an undefined type since March 2026, against
   false messages from payload bytes; the index of earlier versions skipped that too.) The skipped bytes are
   counted (:attr:`DataFlashFile.bad_bytes`, :attr:`DataFlashFile.skipped`), trailing ones too (a
   block-based log may end in up to 249 bytes of padding, which pymavlink passes over in silence).

   As every type has a fixed length, the walk is vectorised (numpy, in 4 MiB blocks): all header candidates of
   a block, where each message ends against where the next candidate starts, and Python only where the chain
   is not straight (junk, a header pattern inside a payload). The lengths come from the file's ``FMT``
   messages, first found by their bytes (block by block, before each block's walk), then checked against the
   ``FMT`` messages the walk itself went through; where they differ (an ``FMT`` pattern inside a payload
   before a type's real ``FMT``) the walk is redone with the checked table, and where a type is redefined with
   another length by a plain sequential walk (the reference, checked against the fast one by the tests).
2. **The decoding** gathers the wanted types' messages from the memory-mapped file a window of the file (1
   MiB) at a time (:meth:`DataFlashFile.blocks`; :meth:`DataFlashFile.read` joins the windows): a numpy
   structured dtype per ``FMT`` over the file with a stride of one byte, indexed by the messages' offsets;
   only the wanted columns become float64.

Memory: the file is memory-mapped, and the pages of each block of the walk and each window of the decoding are
given back to the kernel once done with (``madvise(MADV_DONTNEED)``: a mapped page counts in the process's
resident memory until then). :attr:`DataFlashFile.topics` walks once and keeps the counts, instances and
definitions, and the offsets of the messages (4 bytes each, 8 for a file over 4 GiB) until the first
:meth:`DataFlashFile.blocks` or :meth:`DataFlashFile.read`, which keeps those of the wanted types only and
decodes from them (a later one walks again, keeping the offsets of the wanted types only). What stays is those
offsets: 4 bytes per wanted message.

Damage: a message broken off by the end of the file ends the read there: :meth:`DataFlashFile.read` returns
the messages before it and :attr:`DataFlashFile.damage` is one line (``FLIGHT.bin: cut short at byte 123456 of
123500 (a RATE message broken off); read 0.0-61.2 s``). A file that is not a DataFlash log (no ``FMT`` message
in its first 64 KiB) raises :class:`~gap_validation.core.errors.DataError` at open.
"""
from __future__ import annotations

import mmap
import re
import struct
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from gap_validation.core.atomic import atomic_open
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.logs.base import LogBlocks, LogFile, LogSeries, LogTopic, WriteTopic

__all__ = ["DataFlashFile", "write_dataflash", "FORMATS"]

#: Format character -> (numpy dtype, multiplier or None), as pymavlink's ``DFReader.FORMAT_TO_STRUCT`` (``M``
#: is a signed byte there; ``a`` is 32 int16; ``n N Z`` text of 4, 16, 64 bytes).
FORMATS: dict[str, tuple[np.dtype, float | None]] = {char: (np.dtype(spec), mult) for char, spec, mult in (
    ("a", ("<i2", (32,)), None), ("b", "i1", None), ("B", "u1", None), ("g", "<f2", None), ("h", "<i2", None),
    ("H", "<u2", None), ("i", "<i4", None), ("I", "<u4", None), ("f", "<f4", None), ("d", "<f8", None),
    ("n", "S4", None), ("N", "S16", None), ("Z", "S64", None), ("c", "<i2", 0.01), ("C", "<u2", 0.01),
    ("e", "<i4", 0.01), ("E", "<u4", 0.01), ("L", "<i4", 1.0e-7), ("M", "i1", None), ("q", "<i8", None),
    ("Q", "<u8", None))}
#: Format character -> :mod:`struct` code (the writer's header messages).
_STRUCT = {"b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d", "n": "4s",
           "N": "16s", "Z": "64s", "q": "q", "Q": "Q"}
_TEXT = frozenset("anNZ")
_HEAD = b"\xa3\x95"
_H1, _H2 = 0xA3, 0x95
FMT_TYPE = 128
FMT_LENGTH = 89
_FMT_PAYLOAD = np.dtype([("type", "u1"), ("length", "u1"), ("name", "S4"), ("format", "S16"),
                         ("columns", "S64")])
_BLOCK = 1 << 22            # bytes per block of the walk
_WINDOW = 1 << 20           # bytes per window of the decoding
_CHUNK = 1 << 16            # messages per chunk of the writing
_HEADER_WINDOW = 1 << 16    # an FMT message must be found within this many bytes at the start
_DONTNEED = getattr(mmap, "MADV_DONTNEED", None)


def _release(mm, lo: int, hi: int) -> None:
    """Give the mapped pages wholly inside file bytes ``[lo, hi)`` back to the kernel (read again from the
    page cache when touched later): without it every page of the file the walk or the decoding touched stays
    in the process's resident memory until the file is closed."""
    lo = max(lo, 0) // mmap.PAGESIZE * mmap.PAGESIZE
    hi = hi // mmap.PAGESIZE * mmap.PAGESIZE
    if _DONTNEED is None or hi <= lo:
        return
    try:
        mm.madvise(_DONTNEED, lo, hi - lo)
    except (OSError, ValueError):      # not supported here: the pages stay until the file is closed
        pass


def _null_term(raw: bytes) -> str:
    """Text of a fixed-size char field as ``DFReader.null_term`` gives it (up to the first NUL)."""
    text = raw.decode("utf-8", errors="backslashreplace")
    cut = text.find("\0")
    return text if cut < 0 else text[:cut]


def _field_size(char: str) -> int:
    return FORMATS[char][0].itemsize


@dataclass
class _Format:
    """One message type as its ``FMT`` defines it (``problem`` says why it cannot be decoded)."""

    type_id: int
    name: str
    length: int
    format: str
    columns: tuple[str, ...]
    problem: str | None = None
    offsets: tuple[int, ...] = ()          # byte offset of each column in the payload
    instance: int | None = None            # the instance column (FMTU's '#'), if any
    redefined: bool = False                # defined again with another length or layout

    @classmethod
    def parse(cls, type_id: int, length: int, name: bytes, fmt: bytes, columns: bytes) -> "_Format":
        """A type from the fields of its FMT message."""
        text = _null_term(columns)
        out = cls(type_id, _null_term(name), length, _null_term(fmt),
                  tuple(text.split(",")) if text else ())
        bad = sorted(set(c for c in out.format if c not in FORMATS))
        if bad:
            out.problem = f"unknown format characters {''.join(bad)!r} in {out.format!r}"
            return out
        if len(out.columns) != len(out.format):
            out.problem = f"{len(out.columns)} columns but {len(out.format)} format characters"
            return out
        sizes = [_field_size(c) for c in out.format]
        out.offsets = tuple(int(x) for x in np.cumsum([0] + sizes[:-1]))
        if 3 + sum(sizes) != length:
            out.problem = f"its FMT says {length} bytes but format {out.format!r} needs {3 + sum(sizes)}"
        return out

    def same_layout(self, other: "_Format") -> bool:
        return (self.length, self.format, self.columns) == (other.length, other.format, other.columns)

    def dtype(self, columns: Sequence[int]) -> np.dtype:
        """A structured dtype over the payload holding ``columns`` (indices)."""
        return np.dtype({"names": [f"c{i}" for i in columns],
                         "formats": [FORMATS[self.format[i]][0] for i in columns],
                         "offsets": [self.offsets[i] for i in columns], "itemsize": self.length - 3})

    def values(self, raw: np.ndarray, col: int) -> np.ndarray:
        """Column ``col`` of the decoded records as float64, scaled as ``DFReader`` scales it."""
        v = raw[f"c{col}"].astype(np.float64)
        mult = FORMATS[self.format[col]][1]
        if mult is not None:
            # DFReader divides by 1/mult (more accurate for 0.01 and 1e-7): the same operation, the same
            # numbers
            v = v / (1.0 / mult) if 0.0 < mult < 1.0 else v * mult
        return v

    def label(self, value) -> str:
        """The instance label ``DFReader`` puts between the brackets (``IMU[1]``) for a raw instance value."""
        char = self.format[self.instance]
        if char in "nNZ":
            return _null_term(bytes(value))
        mult = FORMATS[char][1]
        if mult is not None:
            return str(int(value) / (1.0 / mult))
        if char in "fdg":
            return str(float(value))
        return str(int(value))


# ------------------------------------------------------------------------------------------------------------
# The walk


@dataclass
class _Table:
    """Lengths of the types and where they become known (a type's messages count after its first FMT)."""

    lengths: np.ndarray          # int64[256], 0 = not defined
    known_from: np.ndarray       # int64[256], messages of the type are valid at offsets > known_from
    conflict: bool = False       # a type defined twice with different lengths

    @classmethod
    def from_fmts(cls, fmts: Sequence[tuple[int, int, int]]) -> "_Table":
        """From ``(offset, type, length)`` of FMT messages in file order (the first definition of a type
        wins)."""
        table = cls.empty()
        lengths, known = table.lengths, table.known_from
        conflict = False
        for pos, tid, length in fmts:
            if tid == FMT_TYPE:
                conflict |= length != FMT_LENGTH
            elif lengths[tid] == 0:
                lengths[tid], known[tid] = length, pos
            else:
                conflict |= lengths[tid] != length
        table.conflict = conflict
        return table

    @classmethod
    def empty(cls) -> "_Table":
        """Only FMT itself known (89 bytes, as pymavlink assumes before any FMT)."""
        lengths = np.zeros(256, np.int64)
        known = np.full(256, np.iinfo(np.int64).max, np.int64)
        lengths[FMT_TYPE], known[FMT_TYPE] = FMT_LENGTH, -1
        return cls(lengths, known)


@dataclass
class _Walk:
    """The messages a walk found."""

    counts: np.ndarray                          # int64[256] complete messages per type
    offsets: dict[int, np.ndarray]              # kept type -> offsets of its complete messages
    bad_bytes: int = 0
    first_bad: int | None = None
    cut: int | None = None                      # offset of the message broken off by the end of the file
    cut_type: int | None = None                 # its type (None when broken off inside its header)


def _grow(table: _Table, data: np.ndarray, fmts: np.ndarray) -> None:
    """Add the types the FMT byte patterns at ``fmts`` (sorted, length byte >= 3) define, the first one of a
    type winning (some may lie inside a payload: the walk's own FMT messages check them afterwards)."""
    tids, lens = data[fmts + 3], data[fmts + 4]
    new = (table.lengths[tids] == 0) & (tids != FMT_TYPE)
    tids, first = np.unique(tids[new], return_index=True)
    table.lengths[tids] = lens[new][first]
    table.known_from[tids] = fmts[new][first]


def _tail(mm, size: int, pos: int) -> tuple[int | None, int]:
    """After the last message, at ``pos``: where a message broken off in its header starts (or None), and the
    bytes skipped before it (the index stops where fewer than 4 bytes are left)."""
    if pos >= size:
        return None, 0
    if pos + 3 >= size:
        i = pos
    else:
        j = mm.find(_HEAD, max(pos + 1, size - 3))
        i = j if j >= 0 else size
    left = size - i
    if left > 0 and mm[i] == _H1 and (left < 2 or mm[i + 1] == _H2):
        return i, i - pos
    return None, size - pos


def _finish(walk: _Walk, mm, size: int, pos: int, last: tuple[int, int, int] | None) -> _Walk:
    """Close a walk at ``pos`` (after the last message ``last = (offset, type, length)``): the cut or the
    tail."""
    if last is not None and last[0] + last[2] > size:
        walk.cut, walk.cut_type = last[0], last[1]
        walk.counts[last[1]] -= 1
        kept = walk.offsets.get(last[1])
        if kept is not None and len(kept) and kept[-1] == last[0]:
            walk.offsets[last[1]] = kept[:-1]
        return walk
    cut, skipped = _tail(mm, size, pos)
    if skipped and walk.first_bad is None:
        walk.first_bad = pos
    walk.bad_bytes += skipped
    if cut is not None:
        walk.cut = cut
        walk.cut_type = None
    return walk


def _walk_sequential(mm, size: int, keep: set[int] | None) -> tuple[_Walk, list[int]]:
    """The walk one message at a time (pymavlink's ``dfindexer`` rules, with a table that FMT messages update
    as they come). Returns the walk and the offsets of the FMT messages it went through."""
    lengths = [0] * 256
    lengths[FMT_TYPE] = FMT_LENGTH
    counts = [0] * 256
    kept: dict[int, array] = {}
    fmts: list[int] = []
    walk = _Walk(np.zeros(256, np.int64), {})
    i, last = 0, None
    released = 0
    while i + 3 < size:
        if i - released >= 2 * _BLOCK:                   # walked: its pages back to the kernel
            _release(mm, released, i - _BLOCK)
            released = i - _BLOCK
        if mm[i] == _H1 and mm[i + 1] == _H2:
            tid = mm[i + 2]
            ok = True
            if tid == FMT_TYPE and i + 4 < size:
                ok = mm[i + 4] >= 3
                if ok:
                    lengths[mm[i + 3]] = mm[i + 4]
            length = lengths[tid] if ok else 0
            if length:
                counts[tid] += 1
                if tid == FMT_TYPE:
                    fmts.append(i)
                if keep is None or tid in keep:
                    kept.setdefault(tid, array("q")).append(i)
                last = (i, tid, length)
                i += length
                continue
        j = mm.find(_HEAD, i + 1)
        if j < 0 or j + 3 >= size:
            break
        if walk.first_bad is None:
            walk.first_bad = i
        walk.bad_bytes += j - i
        i = j
    walk.counts = np.array(counts, np.int64)
    walk.offsets = {t: np.frombuffer(a, np.int64).copy() for t, a in kept.items()}
    _finish(walk, mm, size, i, last)
    if walk.cut_type == FMT_TYPE and fmts and fmts[-1] == walk.cut:
        fmts.pop()
    return walk, fmts


def _candidates(mm, size: int, lo: int, hi: int) -> np.ndarray:
    """Offsets in ``[lo, hi)`` where ``0xA3 0x95`` starts (and at least 4 bytes are left in the file)."""
    if hi - lo < 2:
        return np.zeros(0, np.int64)
    pairs = np.ndarray((hi - lo - 1,), "<u2", buffer=mm, offset=lo, strides=(1,))
    found = np.flatnonzero(pairs == 0x95A3).astype(np.int64) + lo
    del pairs
    return found[found + 3 < size]


def _walk_blocks(mm, data: np.ndarray, size: int, table: _Table, keep: set[int] | None, grow: bool) -> _Walk:
    """The same walk as :func:`_walk_sequential` with a fixed ``table``, vectorised per block (see the module
    docstring); Python only steps where the chain of messages is not straight. With ``grow``, ``table`` starts
    empty and each block first adds the FMT byte patterns it holds (see :func:`_grow`)."""
    lengths, known = table.lengths, table.known_from
    walk = _Walk(np.zeros(256, np.int64), {})
    parts: dict[int, list[np.ndarray]] = {}
    small = _offset_type(size)
    pos, last = 0, None
    for b0 in range(0, size, _BLOCK):
        _release(mm, b0 - _BLOCK, b0)                    # the block before: walked
        b1 = min(b0 + _BLOCK, size)
        if pos >= b1 and not grow:
            continue
        cand = _candidates(mm, size, b0, min(b1 + 258, size))
        types = data[cand + 2]
        fmt = (types == FMT_TYPE) & (cand + 4 < size)
        fmt[fmt] = data[cand[fmt] + 4] >= 3
        if grow:
            _grow(table, data, cand[fmt])
        ok = (lengths[types] > 0) & (cand > known[types])
        ok[(types == FMT_TYPE) & (cand + 4 < size) & ~fmt] = False
        if pos >= b1:
            continue
        vc, vt = cand[ok], types[ok]
        n = len(vc)
        i = int(np.searchsorted(vc, pos))
        if i >= n or vc[i] >= b1:
            continue
        nxt = vc + lengths[vt]
        # straight: the next candidate is where this message ends (so it is the next message)
        breaks = np.flatnonzero(vc[1:] != nxt[:-1])
        breaks = np.append(breaks, n - 1)
        end_block = int(np.searchsorted(vc, b1))          # nodes [0, end_block) start in this block
        if vc[i] > pos:
            walk.first_bad = pos if walk.first_bad is None else walk.first_bad
            walk.bad_bytes += int(vc[i] - pos)
        segments = []
        while True:
            e = int(breaks[np.searchsorted(breaks, i)])
            m = min(e, end_block - 1)
            segments.append((i, m + 1))
            pos = int(nxt[m])
            if m < e:                                    # straight on into the next block
                break
            k = int(np.searchsorted(vc, pos))            # the first candidate at or after its end
            if k >= end_block:                           # the next message (if any) starts beyond this block
                break
            if vc[k] > pos:
                walk.first_bad = pos if walk.first_bad is None else walk.first_bad
                walk.bad_bytes += int(vc[k] - pos)
            i = k
        if len(segments) == 1:
            offs, tids = vc[segments[0][0]:segments[0][1]], vt[segments[0][0]:segments[0][1]]
        else:
            idx = np.concatenate([np.arange(a, b) for a, b in segments])
            offs, tids = vc[idx], vt[idx]
        walk.counts += np.bincount(tids, minlength=256)
        last = (int(offs[-1]), int(tids[-1]), int(lengths[tids[-1]]))
        if keep is None:
            order = np.argsort(tids, kind="stable")         # uint8: a radix sort
            bounds = np.concatenate([[0], np.cumsum(np.bincount(tids, minlength=256))])
            sorted_offs = offs[order]
            for tid in np.flatnonzero(bounds[1:] > bounds[:-1]):
                parts.setdefault(int(tid), []).append(sorted_offs[bounds[tid]:bounds[tid + 1]].astype(small))
        else:
            for tid in keep:
                sel = offs[tids == tid]
                if len(sel):
                    parts.setdefault(tid, []).append(sel.astype(small))
    _release(mm, size - size % _BLOCK - _BLOCK, size)
    walk.offsets = {t: np.concatenate(parts.pop(t)) for t in sorted(parts)}
    return _finish(walk, mm, size, pos, last)


def _offset_type(size: int) -> np.dtype:
    """The smallest type holding every offset of a file of ``size`` bytes (4 bytes up to 4 GiB)."""
    return np.dtype(np.uint32) if size < 2**32 else np.dtype(np.int64)


def _gather_windows(mm, size: int, offsets: np.ndarray, dtype: np.dtype, shift: int = 3) -> np.ndarray:
    """:func:`_gather` of ``offsets`` (ascending) a window of :data:`_WINDOW` bytes at a time, each window's
    pages given back once gathered."""
    out = np.empty(len(offsets), dtype)
    if not len(offsets):
        return out
    ends = np.arange(_WINDOW, int(offsets[-1]) + 1 + _WINDOW, _WINDOW, dtype=np.int64)
    cuts = np.searchsorted(offsets, np.minimum(ends, np.iinfo(offsets.dtype).max).astype(offsets.dtype))
    i = 0
    for w1, j in zip(ends.tolist(), cuts.tolist()):
        if j > i:
            out[i:j] = _gather(mm, size, offsets[i:j], dtype, shift)
            _release(mm, w1 - _WINDOW, w1)
            i = j
    return out


def _fmt_records(mm, size: int, offsets: Sequence[int]) -> np.ndarray:
    """The payloads of the FMT messages at ``offsets`` (complete ones)."""
    return _gather(mm, size, np.asarray(offsets, np.int64), _FMT_PAYLOAD)


def _gather(mm, size: int, offsets: np.ndarray, dtype: np.dtype, shift: int = 3) -> np.ndarray:
    """``dtype`` items at ``offsets + shift`` (by default the payloads of the messages at ``offsets``), copied
    out of the memory map through a view with a stride of one byte."""
    if len(offsets) == 0:
        return np.zeros(0, dtype)
    view = np.ndarray((size - dtype.itemsize + 1,), dtype, buffer=mm, strides=(1,))
    try:
        return view[offsets + shift]
    finally:
        del view


def _index(mm, data: np.ndarray, size: int, keep: set[int] | None,
           table: _Table | None = None) -> tuple[_Walk, np.ndarray, _Table | None]:
    """Walk the file: the fast walk, its table checked against the FMT messages on its path (redone with the
    checked table up to twice), else the sequential walk. Returns the walk, the offsets of the FMT messages it
    went through, and the checked table (None after the sequential walk)."""
    grow = table is None
    table = _Table.empty() if grow else table
    want = None if keep is None else set(keep) | {FMT_TYPE}
    for _ in range(3):
        walk = _walk_blocks(mm, data, size, table, want, grow)
        grow = False
        fmt_offs = walk.offsets.get(FMT_TYPE, np.zeros(0, np.int64))
        recs = _fmt_records(mm, size, fmt_offs)
        checked = _Table.from_fmts(list(zip(fmt_offs.tolist(), recs["type"].tolist(),
                                            recs["length"].tolist())))
        if checked.conflict:
            break
        used = set(np.flatnonzero(walk.counts).tolist()) | set(np.flatnonzero(checked.lengths).tolist())
        if walk.cut_type is not None:
            used.add(walk.cut_type)
        used = sorted(used)
        if (np.array_equal(table.lengths[used], checked.lengths[used])
                and np.array_equal(table.known_from[used], checked.known_from[used])):
            return walk, fmt_offs, table
        table = checked
    walk, fmts = _walk_sequential(mm, size, want)
    return walk, np.asarray(fmts, np.int64), None


# ------------------------------------------------------------------------------------------------------------
# The reader


@dataclass
class _Topic:
    type_id: int
    raws: tuple = ()                    # raw instance values of an instance topic (empty: every message)


class DataFlashFile(LogFile):
    """An ArduPilot DataFlash log (``.bin``), read as pymavlink's ``DFReader`` reads it (see the module
    docstring for the names, the scaling, the walk and the damage rules).

    Parameters
    ----------
    path : str or Path
        The log file.

    Raises
    ------
    DataError
        The file does not exist, is empty, or is not a DataFlash log (no ``FMT`` message in its first 64 KiB),
        or is cut short inside its first ``FMT`` message (one line naming the file).

    Attributes
    ----------
    damage : str or None
        One line when a message was broken off by the end of the file (set by :attr:`topics` or :meth:`read`).
    bad_bytes : int
        Bytes skipped while resynchronising (junk between messages, a broken tail), once walked.
    skipped : str or None
        One line naming the file, the skipped bytes and the first of them, when there were any.
    """

    format = "dataflash"

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self.bad_bytes = 0
        self.skipped: str | None = None
        self._size = self.path.stat().st_size
        if self._size == 0:
            raise DataError(f"{self.path}: empty file, not a DataFlash log")
        self._file = open(self.path, "rb")
        self._mm = mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
        self._data = np.frombuffer(self._mm, np.uint8)
        try:
            self._check_start()
        except DataError:
            self.close()
            raise
        self._formats: dict[int, _Format] = {}
        self._names: dict[str, _Topic] = {}
        self._table: _Table | None = None
        self._sequential = False
        # the topics walk's offsets, until the first read
        self._index: dict[int, np.ndarray] | None = None

    def _check_start(self) -> None:
        """An FMT message that looks like one near the start, else :class:`DataError`."""
        window = min(self._size, _HEADER_WINDOW)
        pos = self._mm.find(b"\xa3\x95\x80", 0, window)
        while pos >= 0:
            if pos + FMT_LENGTH > self._size:
                raise DataError(
                    f"{self.path}: cut short at byte {self._size} of {self._size} inside the first "
                    "FMT message: no message type is defined"
                )
            rec = _fmt_records(self._mm, self._size, [pos])[0]
            fmt = _Format.parse(int(rec["type"]), int(rec["length"]), rec["name"], rec["format"],
                                rec["columns"])
            if fmt.problem is None and fmt.name.isprintable() and fmt.name:
                return
            pos = self._mm.find(b"\xa3\x95\x80", pos + 1, window)
        raise DataError(
            f"{self.path}: not an ArduPilot DataFlash log (no FMT message, bytes A3 95 80, in its "
            f"first {window} bytes)"
        )

    # -- the walk's results
    # --------------------------------------------------------------------------------------

    def _walk(self, keep: set[int] | None) -> _Walk:
        if self._sequential:
            return _walk_sequential(self._mm, self._size, None if keep is None else keep | {FMT_TYPE})[0]
        walk, _, table = _index(self._mm, self._data, self._size, keep, self._table)
        if table is None:
            self._sequential = True
        self._table = table
        return walk

    def _topics(self) -> dict[str, LogTopic]:
        walk = self._walk(None)
        self._note(walk)
        fmt_offs = walk.offsets.get(FMT_TYPE, np.zeros(0, np.int64))
        recs = _fmt_records(self._mm, self._size, fmt_offs)
        formats: dict[int, _Format] = {}
        names: dict[str, int] = {}
        for rec in recs:
            new = _Format.parse(
                int(rec["type"]),
                int(rec["length"]),
                bytes(rec["name"]),
                bytes(rec["format"]),
                bytes(rec["columns"]),
            )
            old = formats.get(new.type_id)
            if old is not None and not old.same_layout(new):
                new.redefined = True
            elif old is not None:
                new.redefined = old.redefined
            formats[new.type_id] = new
            names[new.name] = new.type_id
        self._formats = formats
        self._units(walk, names)
        out: dict[str, LogTopic] = {}
        self._names = {}
        for name, tid in names.items():
            fmt = formats[tid]
            out[name] = LogTopic(name, fmt.columns, int(walk.counts[tid]))
            self._names[name] = _Topic(tid)
            if fmt.instance is None or fmt.problem is not None or tid not in walk.offsets:
                continue
            raw = _gather_windows(
                self._mm,
                self._size,
                walk.offsets[tid],
                FORMATS[fmt.format[fmt.instance]][0],
                3 + fmt.offsets[fmt.instance],
            )
            values, counts = np.unique(raw, return_counts=True)
            groups: dict[str, tuple[list, int]] = {}
            for value, count in zip(values, counts):
                label = f"{name}[{fmt.label(value)}]"
                raws, total = groups.get(label, ([], 0))
                groups[label] = (raws + [value], total + int(count))
            for label, (raws, total) in groups.items():
                out[label] = LogTopic(label, fmt.columns, total)
                self._names[label] = _Topic(tid, tuple(raws))
        self.damage = self._damage_line(walk) if walk.cut is not None else None
        small = _offset_type(self._size)
        self._index = {tid: offs.astype(small, copy=False) for tid, offs in walk.offsets.items()}
        return out

    def _units(self, walk: _Walk, names: dict[str, int]) -> None:
        """The instance columns, from the FMTU messages (a ``#`` in ``UnitIds``), as ``DFReader`` sets
        them."""
        tid = names.get("FMTU")
        fmtu = self._formats.get(tid) if tid is not None else None
        if fmtu is None or fmtu.problem is not None or tid not in walk.offsets:
            return
        if "UnitIds" not in fmtu.columns or len(fmtu.columns) < 2 or fmtu.format[1] in _TEXT:
            return
        units_col = fmtu.columns.index("UnitIds")
        if fmtu.format[units_col] not in "nNZ":
            return
        recs = _gather(self._mm, self._size, walk.offsets[tid], fmtu.dtype([1, units_col]))
        for ftype, units in zip(recs["c1"].tolist(), recs[f"c{units_col}"].tolist()):
            fmt = self._formats.get(int(ftype))
            mark = _null_term(units).find("#")
            if fmt is not None and mark != -1 and mark < len(fmt.columns) and fmt.problem is None:
                fmt.instance = mark

    def _note(self, walk: _Walk) -> None:
        self.bad_bytes = walk.bad_bytes
        self.skipped = None
        if walk.bad_bytes:
            self.skipped = (
                f"{self.path}: skipped {walk.bad_bytes} bytes that are not messages (the first at byte "
                f"{walk.first_bad})"
            )

    def _damage_line(self, walk: _Walk) -> str:
        what = "a message broken off in its header"
        if walk.cut_type is not None:
            fmt = self._formats.get(walk.cut_type)
            what = f"a {fmt.name if fmt else 'type ' + str(walk.cut_type)} message broken off"
        span = self._time_span(walk)
        read = "read no timed messages" if span is None else f"read {span[0]:.1f}-{span[1]:.1f} s"
        return f"{self.path}: cut short at byte {walk.cut} of {self._size} ({what}); {read}"

    def _time_span(self, walk: _Walk) -> tuple[float, float] | None:
        """TimeUS of the first and the last complete message that has one [s]."""
        first = last = None
        for tid, offs in walk.offsets.items():
            fmt = self._formats.get(tid)
            if fmt is None or fmt.problem or "TimeUS" not in fmt.columns or not len(offs):
                continue
            if first is None or offs[0] < first[0]:
                first = (int(offs[0]), fmt)
            if last is None or offs[-1] > last[0]:
                last = (int(offs[-1]), fmt)
        if first is None:
            return None
        out = []
        for pos, fmt in (first, last):
            col = fmt.columns.index("TimeUS")
            out.append(
                float(fmt.values(_gather(self._mm, self._size, np.array([pos]), fmt.dtype([col])), col)[0])
                / 1e6
            )
        return out[0], out[1]

    # -- reading
    # ---------------------------------------------------------------------------------------------------

    def _blocks(self, wanted: dict[str, tuple[str, ...]], block_bytes: int | None) -> LogBlocks:
        plans = {topic: self._plan(topic, fields) for topic, fields in wanted.items()}
        index, self._index = self._index, None
        tids = {self._names[t].type_id for t in wanted}
        if index is None:
            walk = self._walk(tids)
            self._note(walk)
            index = walk.offsets
        small = _offset_type(self._size)
        offsets = {tid: index.get(tid, np.zeros(0, small)).astype(small, copy=False) for tid in tids}
        del index                               # the other types' offsets
        return _DataFlashBlocks(self, plans, offsets, wanted, int(block_bytes or _WINDOW))

    def _plan(self, topic: str, fields: tuple[str, ...]) -> tuple[_Format, list[int], int]:
        """The format, the wanted columns' indices and the time column of ``topic`` (one-line errors)."""
        fmt = self._formats[self._names[topic].type_id]
        if fmt.problem is not None:
            raise DataError(f"{self.path}: topic {topic} cannot be decoded: {fmt.problem}")
        if fmt.redefined:
            raise DataError(f"{self.path}: topic {topic} is defined twice with different layouts (FMT type "
                            f"{fmt.type_id}); it cannot be read")
        if "TimeUS" not in fmt.columns:
            raise DataError(f"{self.path}: topic {topic} has no TimeUS column, so no times to validate (its "
                            f"columns: {', '.join(fmt.columns)})")
        cols = []
        for name in fields:
            if name not in fmt.columns:
                raise self.missing_field(topic, name)
            col = fmt.columns.index(name)
            if fmt.format[col] in _TEXT:
                raise DataError(f"{self.path}: field {name} of topic {topic} is not a number (format "
                                f"{fmt.format[col]!r})")
            cols.append(col)
        return fmt, cols, fmt.columns.index("TimeUS")

    def _decode(self, fmt: _Format, offs: np.ndarray, cols: list[int], time_col: int, raws: tuple,
                fields: tuple[str, ...]) -> LogSeries:
        """The messages at ``offs`` (those of instances ``raws`` only, when given) as a series of ``cols``."""
        need = sorted(set(cols) | {time_col} | ({fmt.instance} if raws else set()))
        rec = _gather(self._mm, self._size, offs, fmt.dtype(need))
        if raws:
            rec = rec[np.isin(rec[f"c{fmt.instance}"], np.array(raws, dtype=rec[f"c{fmt.instance}"].dtype))]
        values = np.empty((len(rec), len(cols)), np.float64)
        for k, col in enumerate(cols):
            values[:, k] = fmt.values(rec, col)
        return LogSeries(fmt.values(rec, time_col) / 1e6, values, tuple(fields))

    def close(self) -> None:
        """Release the memory map and the file."""
        self._data = None
        mm, self._mm = getattr(self, "_mm", None), None
        if mm is not None:
            try:
                mm.close()
            except BufferError:     # a view still alive somewhere: the garbage collector closes it later
                pass
        handle, self._file = getattr(self, "_file", None), None
        if handle is not None:
            handle.close()


class _DataFlashBlocks(LogBlocks):
    """The wanted series of a DataFlash log per window of the file (:meth:`DataFlashFile.blocks`): each
    window's messages of the wanted types decoded from the memory map, its pages given back after."""

    def __init__(self, log: DataFlashFile, plans: dict, offsets: dict[int, np.ndarray],
                 wanted: dict[str, tuple[str, ...]], window: int):
        counts = {topic: log.topics[topic].count for topic in wanted}
        super().__init__(log.path, {topic: tuple(fields) for topic, fields in wanted.items()}, counts)
        self.log, self.plans, self.offsets, self.window = log, plans, offsets, max(1, int(window))

    def _blocks(self):
        log = self.log
        ends = [int(o[-1]) for o in self.offsets.values() if len(o)]
        if not ends:
            return
        starts = np.arange(0, max(ends) + 1 + self.window, self.window, dtype=np.int64)
        # each window's first message, per type (the starts in the offsets' own type: no copy of the offsets)
        bounds = {tid: np.searchsorted(o, np.minimum(starts, np.iinfo(o.dtype).max).astype(o.dtype))
                  for tid, o in self.offsets.items()}
        for i, w0 in enumerate(starts[:-1].tolist()):
            w1 = w0 + self.window
            out = {}
            for topic, (fmt, cols, time_col) in self.plans.items():
                tid = log._names[topic].type_id
                lo, hi = int(bounds[tid][i]), int(bounds[tid][i + 1])
                if hi > lo:
                    series = log._decode(
                        fmt,
                        self.offsets[tid][lo:hi],
                        cols,
                        time_col,
                        log._names[topic].raws,
                        self.fields[topic],
                    )
                    if series.t_s.size:
                        out[topic] = series
            _release(log._mm, w0, w1)
            if out:
                yield out


# ------------------------------------------------------------------------------------------------------------
# The writer

#: ArduPilot's unit characters (``log_Units``) for the unit texts it knows.
_UNIT_IDS = {"": "-", "s": "s", "rad/s": "E", "deg/s": "k", "m/s/s": "o", "m/s": "n", "m": "m", "rad": "r",
             "deg": "d", "us": "Y", "Hz": "z", "V": "v", "A": "A", "degC": "O", "%": "%", "Pa": "P",
             "rad/s/s": "L", "deg/s/s": "e", "instance": "#"}
_NAME = re.compile(r"^([A-Za-z0-9_]{1,4})(?:\[(\d+)\])?$")
_PWM = re.compile(r"^C\d+$")
_RESERVED = {"FMT", "FMTU", "UNIT", "MULT"}
_FIRST_ID, _LAST_ID = 129, 254


@dataclass
class _Out:
    """One message type to write and the topics (instances) that share it."""

    name: str
    type_id: int
    fields: tuple[str, ...]
    chars: list[str] = field(default_factory=list)
    topics: list[tuple[WriteTopic, int | None]] = field(default_factory=list)
    units: dict[str, str] = field(default_factory=dict)

    @property
    def instanced(self) -> bool:
        return self.topics[0][1] is not None

    @property
    def columns(self) -> list[str]:
        return ["TimeUS"] + (["I"] if self.instanced else []) + list(self.fields)

    @property
    def format(self) -> str:
        return "Q" + ("B" if self.instanced else "") + "".join(self.chars)

    def dtype(self) -> np.dtype:
        names = ["h1", "h2", "id"] + [f"c{k}" for k in range(len(self.columns))]
        formats = ["u1", "u1", "u1"] + [FORMATS[c][0] for c in self.format]
        return np.dtype({"names": names, "formats": formats})


def _char_for(where: str, name: str, values: np.ndarray, pwm: bool) -> str:
    """The format character of a field from its values' dtype (and range, for integers)."""
    if pwm:
        return "H"
    kind = values.dtype.kind
    if kind == "f":
        return "f" if values.dtype.itemsize <= 4 else "d"
    if kind == "b":
        return "B"
    if kind in "iu":
        lo, hi = (int(values.min()), int(values.max())) if len(values) else (0, 0)
        for char, (a, b) in (("B", (0, 255)), ("h", (-2**15, 2**15 - 1)), ("H", (0, 2**16 - 1)),
                             ("i", (-2**31, 2**31 - 1)), ("I", (0, 2**32 - 1)), ("q", (-2**63, 2**63 - 1))):
            if a <= lo and hi <= b:
                return char
        return "Q"
    raise ConfigError(f"{where}: field {name} has values of type {values.dtype}, not numbers")


def _plan_types(path: Path, topics: Sequence[WriteTopic]) -> list[_Out]:
    """Group the topics into message types (instances share one), with their format characters."""
    types: dict[str, _Out] = {}
    for topic in topics:
        match = _NAME.match(topic.name)
        where = f"{path}: topic {topic.name!r}"
        if not match or not topic.name.isascii():
            raise ConfigError(f"{where}: a DataFlash message name is 1 to 4 letters, digits or '_', with [K] "
                              "for an instance")
        name, inst = match.group(1), (None if match.group(2) is None else int(match.group(2)))
        if name in _RESERVED:
            raise ConfigError(f"{where}: {name} is a reserved DataFlash message name")
        if inst is not None and inst > 255:
            raise ConfigError(f"{where}: instance {inst} does not fit the instance column (0-255)")
        fields = tuple(topic.fields)
        for col in fields:
            if (col == "TimeUS" or (col == "I" and inst is not None) or not col or "," in col
                    or not col.isascii() or not col.isprintable()):
                raise ConfigError(
                    f"{where}: field name {col!r} cannot be a column (TimeUS, and I of an instance, "
                    "are written by the writer; no commas)"
                )
        out = types.get(name)
        if out is None:
            out = types[name] = _Out(name, 0, fields)
        elif out.fields != fields or out.instanced != (inst is not None):
            raise ConfigError(
                f"{where}: its instances must have the same fields, and all or none an instance"
            )
        if any(i == inst for _, i in out.topics):
            raise ConfigError(f"{where}: written twice")
        out.topics.append((topic, inst))
        out.units.update({k: v for k, v in topic.units.items() if k in fields})
    if len(types) > _LAST_ID - _FIRST_ID + 1 - 3:
        raise ConfigError(f"{path}: {len(types)} message types, more than a DataFlash log can define")
    for k, out in enumerate(types.values()):
        out.type_id = _FIRST_ID + 3 + k
        for col in out.fields:
            pwm = out.name == "RCOU" and bool(_PWM.match(col))
            values = np.concatenate([np.asarray(t.fields[col]).ravel() for t, _ in out.topics])
            out.chars.append(_char_for(f"{path}: topic {out.name}", col, values, pwm))
        if len(out.columns) > 16:
            raise ConfigError(
                f"{path}: topic {out.name} has {len(out.columns)} columns with TimeUS (a DataFlash "
                "message has at most 16)"
            )
        if len(",".join(out.columns)) > 64:
            raise ConfigError(f"{path}: topic {out.name}: the column names take more than 64 characters")
    return list(types.values())


def _pack(tid: int, fmt: str, *values) -> bytes:
    return struct.pack("<BBB" + "".join(_STRUCT[c] for c in fmt), _H1, _H2, tid, *values)


def _fmt_message(tid: int, name: str, fmt: str, columns: Sequence[str]) -> bytes:
    length = 3 + sum(_field_size(c) for c in fmt)
    return _pack(FMT_TYPE, "BBnNZ", tid, length, name.encode(), fmt.encode(), ",".join(columns).encode())


def _header(path: Path, types: list[_Out], start_us: int) -> bytes:
    """FMT of FMT, FMT of UNIT, FMTU, MULT and of every type; then UNIT, MULT and FMTU messages."""
    unit_id, fmtu_id, mult_id = _FIRST_ID, _FIRST_ID + 1, _FIRST_ID + 2
    out = [_fmt_message(FMT_TYPE, "FMT", "BBnNZ", ("Type", "Length", "Name", "Format", "Columns")),
           _fmt_message(unit_id, "UNIT", "QbZ", ("TimeUS", "Id", "Label")),
           _fmt_message(fmtu_id, "FMTU", "QBNN", ("TimeUS", "FmtType", "UnitIds", "MultIds")),
           _fmt_message(mult_id, "MULT", "Qbd", ("TimeUS", "Id", "Mult"))]
    out += [_fmt_message(t.type_id, t.name, t.format, t.columns) for t in types]
    units = {"s": "s", "instance": "#"}
    free = iter(c for c in "abcfghijlpqtuwxyzBCDFHIJKMNQRSTUVWXZ0123456789" if c not in _UNIT_IDS.values())
    for t in types:
        for col, text in t.units.items():
            if text and text not in units:
                if len(text.encode()) > 64 or not text.isascii():
                    raise ConfigError(f"{path}: topic {t.name}: unit {text!r} of {col} is not ASCII up to 64 "
                                      "characters")
                char = _UNIT_IDS.get(text) or next(free, None)
                if char is None:
                    raise ConfigError(f"{path}: too many different units")
                units[text] = char
    for text, char in units.items():
        out.append(_pack(unit_id, "QbZ", start_us, ord(char), text.encode()))
    for char, mult in (("-", 0.0), ("0", 1.0), ("F", 1e-6)):
        out.append(_pack(mult_id, "Qbd", start_us, ord(char), mult))
    for t in types:
        ids, mults = "s", "F"
        if t.instanced:
            ids, mults = ids + "#", mults + "-"
        for col in t.fields:
            text = t.units.get(col, "")
            ids += units[text] if text else "-"
            mults += "0" if text else "-"
        out.append(_pack(fmtu_id, "QBNN", start_us, t.type_id, ids.encode(), mults.encode()))
    return b"".join(out)


def _records(path: Path, out: _Out, topic: WriteTopic, inst: int | None, start_us: int) -> tuple[np.ndarray,
                                                                                                  np.ndarray]:
    """TimeUS (int64) and the messages (void records) of one topic."""
    where = f"{path}: topic {topic.name}"
    t_raw = np.asarray(topic.t_us)
    if t_raw.ndim != 1:
        raise DataError(f"{where}: t_us must be one-dimensional")
    if t_raw.dtype.kind == "f":
        if not np.all(np.isfinite(t_raw)) or np.any(t_raw != np.rint(t_raw)):
            raise DataError(f"{where}: t_us must be whole microseconds")
    t_us = t_raw.astype(np.int64) + int(start_us)
    if len(t_us) and t_us.min() < 0:
        raise DataError(f"{where}: TimeUS would be negative ({int(t_us.min())} us)")
    if np.any(np.diff(t_us) < 0):
        raise DataError(f"{where}: t_us goes back in time")
    dtype = out.dtype()
    rec = np.zeros(len(t_us), dtype)
    rec["h1"], rec["h2"], rec["id"] = _H1, _H2, out.type_id
    rec["c0"] = t_us
    first = 1
    if inst is not None:
        rec["c1"] = inst
        first = 2
    for k, (col, char) in enumerate(zip(out.fields, out.chars)):
        values = np.asarray(topic.fields[col]).ravel()
        if len(values) != len(t_us):
            raise DataError(f"{where}: field {col} has {len(values)} values for {len(t_us)} times")
        if char in "BhHiIqQ":
            info = np.iinfo(FORMATS[char][0])
            if values.dtype.kind == "f":
                values = np.rint(values)
                if not np.all(np.isfinite(values)):
                    raise DataError(f"{where}: field {col} has values that are not finite (format {char!r})")
            if len(values) and (values.min() < info.min or values.max() > info.max):
                raise DataError(
                    f"{where}: field {col} does not fit format {char!r} ({info.min} to {info.max})"
                )
        rec[f"c{first + k}"] = values
    return t_us, rec.view(f"V{dtype.itemsize}")


def write_dataflash(path: str | Path, topics: Sequence[WriteTopic], *, start_us: int = 0) -> Path:
    """Write ``topics`` as an ArduPilot DataFlash log, laid out as ArduPilot writes one.

    The file starts with the ``FMT`` of ``FMT`` itself, then ``FMT`` of ``UNIT``, ``FMTU``, ``MULT`` and of
    every message type, then the ``UNIT`` and ``MULT`` messages and one ``FMTU`` per type (units from
    :attr:`WriteTopic.units`, ``s`` for ``TimeUS``, ``#`` for the instance column); then the messages of all
    topics interleaved in time order (ties in the order of ``topics``). Type ids are 132 and up (129-131 are
    ``UNIT``, ``FMTU``, ``MULT``). Each type's columns are ``TimeUS`` (format ``Q``), an instance column ``I``
    (``B``, marked ``#`` in ``FMTU``, as ArduPilot's ``IMU``) for topics named ``NAME[K]``, then the fields in
    the order given. A field's format follows its dtype: float64 ``d``, float32 ``f``, integers the smallest
    of ``B h H i I q Q`` that holds them; ``C1``, ``C2``... of ``RCOU`` are PWM ``H`` as in ArduPilot (float
    values rounded to whole microseconds). Written atomically (a temporary file renamed over ``path``).

    Parameters
    ----------
    path : str or Path
        The ``.bin`` file to write; its directory must exist.
    topics : sequence of WriteTopic
        The topics: ``name`` (1-4 letters, digits or ``_``; ``NAME[K]`` for instance ``K`` of 0-255, all
        instances of a name with the same fields), ``t_us`` (non-decreasing whole microseconds), ``fields``
        (name -> one value per time), ``units`` (field -> unit text, optional).
    start_us : int, optional
        Added to every ``t_us`` to give ``TimeUS`` (ArduPilot counts from boot); the ``UNIT``, ``MULT`` and
        ``FMTU`` messages carry this time.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ConfigError
        A name, field or unit that a DataFlash log cannot hold (too long, reserved, more than 16 columns,
        instances with different fields), on one line naming the file and topic.
    DataError
        Values that do not fit: times going back or not whole, a field of another length than ``t_us``, PWM
        values out of 0-65535.
    """
    path = Path(path)
    types = _plan_types(path, topics)
    times, recs, which = [], [], []
    for out in types:
        for topic, inst in out.topics:
            t_us, rec = _records(path, out, topic, inst, start_us)
            times.append(t_us)
            recs.append(rec)
            which.append(np.full(len(t_us), len(recs) - 1, np.int32))
    header = _header(path, types, int(start_us))
    all_t = np.concatenate(times) if times else np.zeros(0, np.int64)
    order = np.argsort(all_t, kind="stable")
    src = np.concatenate(which) if which else np.zeros(0, np.int32)
    row = np.concatenate([np.arange(len(t)) for t in times]) if times else np.zeros(0, np.int64)
    sizes = np.array([r.dtype.itemsize for r in recs], np.int64)
    with atomic_open(path, "wb") as handle:
        handle.write(header)
        for start in range(0, len(order), _CHUNK):
            sel = order[start:start + _CHUNK]
            kinds, rows = src[sel], row[sel]
            lens = sizes[kinds] if len(sizes) else np.zeros(0, np.int64)
            starts = np.concatenate([[0], np.cumsum(lens)[:-1]])
            buf = bytearray(int(lens.sum()))
            for k in np.unique(kinds):
                mask = kinds == k
                width = int(sizes[k])
                view = np.ndarray((len(buf) - width + 1,), f"V{width}", buffer=buf, strides=(1,))
                view[starts[mask]] = recs[k][rows[mask]]
                del view
            handle.write(buf)
    return path
