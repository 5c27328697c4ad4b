"""Fast CDR field decoders: read the configured fields of a serialized message, nothing else.

Decoding dominates replay time (and, live, rclpy's deserialisation dominates the node's), while a validation
needs only a few numbers per message. For ``sensor_msgs/msg/Imu``, ``sensor_msgs/msg/JointState`` and
``std_msgs/msg/Float64|Float32|Bool`` (:mod:`gap_validation.core.layouts`) in little-endian CDR,
:func:`fast_decoder` reads exactly the configured fields at their CDR offsets with ``struct`` (XCDR1
alignment: relative to the end of the 4-byte encapsulation header, primitives aligned to their size). Anything
unexpected (big-endian data, short buffers, a missing joint) raises :class:`FastDecodeError`: decode that
record fully.
:class:`gap_validation.messages.decoding.TopicDecoder` checks the first messages of every topic against full
deserialisation before trusting a decoder. Bytes in, numbers out: no rclpy, no rosbags.

:func:`batch_decoder` reads the same fields from many records at once (:class:`Records`: serialized messages
laid out in one buffer, e.g. a decompressed mcap chunk). A record's *layout* (where its fields lie) is found
by the per-record decoder's own walk over one record, the template; every record equal to the template in the
bytes that decide the layout (encapsulation, ``frame_id`` length, JointState names and array lengths) and long
enough has its fields at the same offsets, so they are gathered for all of them with one numpy fancy index and
read through a structured view (:class:`_Layout`). The values are the per-record decoder's to the bit (the
same bytes read as the same little-endian types); records unlike every template are left to the per-record
path.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from gap_validation.core.fields import FieldPath
from gap_validation.core.layouts import FLOAT32, FLOAT64, IMU, JOINT_ARRAYS, JOINT_STATE, SCALAR_TYPES

__all__ = ["fast_decoder", "batch_decoder", "FastDecodeError", "Decoder", "BatchDecoder", "Records"]

#: ``decoder(raw_cdr) -> (header stamp [s] or None, [raw value per field path])``.
Decoder = Callable[[Any], tuple]
#: ``decoder(records) -> (stamp_s, values, ok)``: per record the header stamp [s] (NaN: none), one raw value
#: per field path (rows), and whether it was read (the others: decode them one by one).
BatchDecoder = Callable[["Records"], tuple]


class FastDecodeError(Exception):
    """The fast decoder cannot read this record; decode it fully instead."""


_HEAD = struct.Struct("<iII")       # header.stamp.sec, header.stamp.nanosec, frame_id length
_U32 = struct.Struct("<I")
_F64 = struct.Struct("<d")
_F32 = struct.Struct("<f")

#: Offsets [bytes] of Imu doubles after the 8-aligned start of ``orientation``.
_IMU_OFFSETS = {
    ("orientation", "x"): 0, ("orientation", "y"): 8, ("orientation", "z"): 16, ("orientation", "w"): 24,
    ("angular_velocity", "x"): 104, ("angular_velocity", "y"): 112, ("angular_velocity", "z"): 120,
    ("linear_acceleration", "x"): 200, ("linear_acceleration", "y"): 208, ("linear_acceleration", "z"): 216,
}
_IMU_SIZE = 296  # 4 + 9 + 3 + 9 + 3 + 9 doubles


def _check_le(raw: Any) -> None:
    if len(raw) < 8 or raw[0] != 0 or raw[1] != 1:
        raise FastDecodeError("not little-endian CDR")


def _stamp(sec: int, nanosec: int) -> float | None:
    return None if sec == 0 and nanosec == 0 else sec + nanosec * 1e-9


def _imu_paths(paths: Sequence[FieldPath]) -> list[tuple[str, ...]] | None:
    """The Imu attribute paths of ``paths``, or None when one is not a plain Imu double."""
    keys = []
    for path in paths:
        if any(s.kind != "attr" for s in path.steps) or path.attributes not in _IMU_OFFSETS:
            return None
        keys.append(path.attributes)
    return keys


def _imu_head(raw: Any) -> tuple[int, int, int]:
    """``(sec, nanosec, base)`` of an Imu record: its stamp and where ``orientation`` starts."""
    _check_le(raw)
    sec, nanosec, slen = _HEAD.unpack_from(raw, 4)
    base = 4 + ((12 + slen + 7) & ~7)  # frame_id ends at 16 + slen; align 8 relative to offset 4
    if len(raw) < base + _IMU_SIZE:
        raise FastDecodeError("short Imu record")
    return sec, nanosec, base


def _imu_decoder(paths: Sequence[FieldPath]) -> Decoder | None:
    keys = _imu_paths(paths)
    if keys is None:
        return None
    offsets = sorted({_IMU_OFFSETS[k] for k in keys})
    fmt, pos = "<", 0
    for off in offsets:
        fmt += (f"{off - pos}x" if off > pos else "") + "d"
        pos = off + 8
    reader = struct.Struct(fmt)
    order = [offsets.index(_IMU_OFFSETS[k]) for k in keys]

    def decode(raw):
        sec, nanosec, base = _imu_head(raw)
        got = reader.unpack_from(raw, base)
        return _stamp(sec, nanosec), [got[i] for i in order]

    return decode


class _JointStateDecoder:
    """``position|velocity|effort[name|index]`` of JointState records; the name table is cached while the
    serialized names do not change."""

    ARRAYS = JOINT_ARRAYS

    def __init__(self, paths: Sequence[FieldPath]):
        self.wants = []
        for path in paths:
            if (
                len(path.steps) != 2
                or path.steps[0].kind != "attr"
                or path.steps[0].value not in self.ARRAYS
                or path.steps[1].kind not in ("key", "index")
            ):
                raise FastDecodeError("unsupported JointState path")
            self.wants.append(
                (self.ARRAYS.index(path.steps[0].value), path.steps[1].kind, path.steps[1].value)
            )
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

    def layout(self, raw) -> tuple[int, int, tuple[int, int], list[tuple[int, int, int]], list[int], int]:
        """Walk one record: ``(sec, nanosec, (start, end) of the names, [(count offset, data start, count) per
        array up to the last wanted], [byte offset of each wanted value], end of the last array)``;
        :class:`FastDecodeError` when it cannot be read."""
        _check_le(raw)
        sec, nanosec, slen = _HEAD.unpack_from(raw, 4)
        start = 4 + ((12 + slen + 3) & ~3)
        names, pos = self._names(raw, start)
        names_span = (start, pos)
        arrays = []
        for _ in range(self.last_arrays + 1):
            pos = 4 + ((pos - 4 + 3) & ~3)
            (count,) = _U32.unpack_from(raw, pos)
            at = pos
            pos += 4
            if count:
                pos = 4 + ((pos - 4 + 7) & ~7)
            arrays.append((at, pos, count))
            pos += 8 * count
        if pos > len(raw):
            raise FastDecodeError("short JointState record")
        offsets = []
        for array, kind, key in self.wants:
            _, start_a, count = arrays[array]
            i = names.get(key, -1) if kind == "key" else (key if key >= 0 else count + key)
            if not 0 <= i < count:
                raise FastDecodeError("missing joint or index")
            offsets.append(start_a + 8 * i)
        return sec, nanosec, names_span, arrays, offsets, pos

    def __call__(self, raw):
        sec, nanosec, _, _, offsets, _ = self.layout(raw)
        return _stamp(sec, nanosec), [_F64.unpack_from(raw, off)[0] for off in offsets]


def _scalar_decoder(paths: Sequence[FieldPath], kind: str) -> Decoder | None:
    if any(p.steps != FieldPath.parse("data").steps for p in paths):
        return None
    n = len(paths)
    if kind == FLOAT64:
        def decode(raw):
            _check_le(raw)
            if len(raw) < 12:
                raise FastDecodeError("short Float64 record")
            return None, [_F64.unpack_from(raw, 4)[0]] * n
    elif kind == FLOAT32:
        def decode(raw):
            _check_le(raw)
            return None, [_F32.unpack_from(raw, 4)[0]] * n
    else:
        def decode(raw):
            if len(raw) < 5 or raw[0] != 0 or raw[1] not in (0, 1):
                raise FastDecodeError("not CDR")
            return None, [1.0 if raw[4] else 0.0] * n
    return decode


def fast_decoder(msgtype: str, paths: Sequence[FieldPath]) -> Decoder | None:
    """A function ``raw_cdr -> (stamp_s or None, [value per path])`` reading only the given fields, or None
    when ``msgtype`` / the paths are not covered (then decode fully). The function raises
    :class:`FastDecodeError` for records it cannot read (decode those fully).

    Parameters
    ----------
    msgtype : str
        The message type.
    paths : sequence of FieldPath
        The fields to read.
    """
    try:
        if msgtype == IMU:
            return _imu_decoder(paths)
        if msgtype == JOINT_STATE:
            return _JointStateDecoder(paths)
        if msgtype in SCALAR_TYPES:
            return _scalar_decoder(paths, msgtype)
    except FastDecodeError:
        return None
    return None


# ------------------------------------------------------------------------------------- many records at once
@dataclass(frozen=True)
class Records:
    """Serialized messages in one buffer: record ``i`` is ``buffer[offsets[i]:offsets[i] + lengths[i]]``.

    A bag reader hands a decompressed mcap chunk as it is (the offsets of the messages in it); any list of
    records becomes one with :meth:`from_raws`.
    """

    buffer: np.ndarray      # uint8, 1-D
    offsets: np.ndarray     # int64
    lengths: np.ndarray     # int64

    @classmethod
    def from_raws(cls, raws: Sequence[Any]) -> "Records":
        """The records of a list of bytes-like objects, copied into one buffer."""
        lengths = np.fromiter(map(len, raws), dtype=np.int64, count=len(raws))
        offsets = np.zeros(len(raws), dtype=np.int64)
        np.cumsum(lengths[:-1], out=offsets[1:])
        return cls(np.frombuffer(b"".join(raws), dtype=np.uint8), offsets, lengths)

    def __len__(self) -> int:
        return int(self.offsets.size)

    def raw(self, i: int) -> bytes:
        """Record ``i`` as bytes (for the per-record decoders and full deserialisation)."""
        start = int(self.offsets[i])
        return self.buffer[start:start + int(self.lengths[i])].tobytes()

    def take(self, index: np.ndarray) -> "Records":
        """The records at ``index`` (same buffer)."""
        return Records(self.buffer, self.offsets[index], self.lengths[index])


class _Layout:
    """Where the fields of a template record lie; valid for every record at least ``size`` bytes long that
    equals the template in the byte ranges ``same`` (those that decide the layout).

    Reading copies the bytes of each record up to the last one it reads or compares into one row (a fancy
    index over a sliding-window view of the buffer) and reads the rows through a structured dtype with the
    stamp (``sec`` int32 and ``nanosec`` uint32 at 4) and the fields at their offsets.
    """

    __slots__ = ("size", "width", "stamped", "dtype", "kinds", "same", "template")

    def __init__(self, raw: Any, same: Sequence[tuple[int, int]], size: int, stamped: bool,
                 fields: Sequence[tuple[int, str]]):
        self.size = size
        self.stamped = stamped
        names, formats, offsets = (["sec", "nanosec"], ["<i4", "<u4"], [4, 8]) if stamped else ([], [], [])
        for j, (offset, kind) in enumerate(fields):
            names.append(f"v{j}")
            formats.append(kind)
            offsets.append(offset)
        self.same = np.concatenate([np.arange(a, b) for a, b in same]).astype(np.int64)
        #: Bytes copied per record: up to the last one read or compared (records are at least ``size`` long).
        self.width = max([int(self.same.max()) + 1, 12 * stamped]
                         + [offset + np.dtype(kind).itemsize for offset, kind in fields])
        self.dtype = np.dtype(
            {"names": names, "formats": formats, "offsets": offsets, "itemsize": self.width}
        )
        self.kinds = [kind for _, kind in fields]
        self.template = np.frombuffer(bytes(raw), dtype=np.uint8)[self.same]

    def read(self, records: Records, index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(read, stamp_s, values)`` for the records at ``index``: the positions in ``index`` this layout
        reads, and their stamps (NaN: unset) and values (one column per field)."""
        index = index[records.lengths[index] >= self.size]
        if index.size:
            rows = np.lib.stride_tricks.sliding_window_view(records.buffer, self.width)[
                records.offsets[index]
            ]
        else:
            rows = np.zeros((0, self.width), dtype=np.uint8)
        hit = (rows[:, self.same] == self.template).all(axis=1)
        if not hit.all():
            rows, index = rows[hit], index[hit]
        view = rows.view(self.dtype)[:, 0]
        if self.stamped:
            sec, nanosec = view["sec"], view["nanosec"]
            stamps = sec.astype(np.float64) + nanosec.astype(np.float64) * 1e-9
            stamps[(sec == 0) & (nanosec == 0)] = np.nan
        else:
            stamps = np.full(index.size, np.nan)
        values = np.empty((index.size, len(self.kinds)))
        for j, kind in enumerate(self.kinds):
            column = view[f"v{j}"]
            values[:, j] = (column != 0) if kind == "u1" else column
        return index, stamps, values


#: Layouts a batch decoder keeps, and new templates it tries per call, before leaving records to the
#: per-record path (a topic whose layout keeps changing, e.g. JointState names, is read record by record).
_LAYOUTS_KEPT = 4
_NEW_LAYOUTS_PER_CALL = 2


class _BatchDecoder:
    """Reads a topic's fields from :class:`Records` with the layouts of templates (see the module
    docstring)."""

    def __init__(self, layout_of: Callable[[bytes], _Layout], width: int):
        self.layout_of = layout_of
        self.width = width
        self.layouts: list[_Layout] = []

    def __call__(self, records: Records) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(records)
        stamps = np.full(n, np.nan)
        values = np.empty((n, self.width))
        ok = np.zeros(n, dtype=bool)
        todo = np.arange(n)
        tries = list(self.layouts) + [None] * _NEW_LAYOUTS_PER_CALL
        for layout in tries:
            if not todo.size:
                break
            if layout is None:
                try:
                    layout = self.layout_of(records.raw(int(todo[0])))
                except Exception:  # noqa: BLE001 - FastDecodeError, struct.error ...: not fast-decodable
                    break
                self.layouts = [layout, *self.layouts][:_LAYOUTS_KEPT]
            index, got_stamps, got_values = layout.read(records, todo)
            if index.size:
                stamps[index] = got_stamps
                values[index] = got_values
                ok[index] = True
                todo = todo[~ok[todo]]
        return stamps, values, ok


def batch_decoder(msgtype: str, paths: Sequence[FieldPath]) -> BatchDecoder | None:
    """The many-records form of :func:`fast_decoder`: ``decoder(records) -> (stamp_s, values, ok)`` with, per
    record of a :class:`Records`, the header stamp [s] (NaN where unset or not a stamped type), one row of raw
    values (one per path, equal to the per-record decoder's to the bit) and whether it was read; or None when
    ``msgtype`` / the paths are not covered. Records not read (unlike every layout the decoder found, or not
    fast-decodable) are for the per-record path.

    Parameters
    ----------
    msgtype : str
        The message type.
    paths : sequence of FieldPath
        The fields to read.
    """
    decode = fast_decoder(msgtype, paths)
    if decode is None:
        return None
    n = len(paths)
    if msgtype == IMU:
        keys = _imu_paths(paths)

        def imu_layout(raw):
            _, _, base = _imu_head(raw)
            return _Layout(raw, ((0, 2), (12, 16)), base + _IMU_SIZE, True,
                           [(base + _IMU_OFFSETS[k], "<f8") for k in keys])
        return _BatchDecoder(imu_layout, n)
    if msgtype == JOINT_STATE:
        def joint_layout(raw):
            _, _, names, arrays, offsets, end = decode.layout(raw)
            same = ((0, 2), (12, 16), names, *((at, at + 4) for at, _, _ in arrays))
            return _Layout(raw, same, end, True, [(offset, "<f8") for offset in offsets])
        return _BatchDecoder(joint_layout, n)
    kind, size = {FLOAT64: ("<f8", 12), FLOAT32: ("<f4", 8)}.get(msgtype, ("u1", 5))

    def scalar_layout(raw):
        decode(raw)                                   # the template must be fast-decodable
        return _Layout(raw, ((0, 2),), size, False, [(4, kind)] * n)
    return _BatchDecoder(scalar_layout, n)
