"""Fast CDR field decoders: read the configured fields of a serialized message, nothing else.

Decoding dominates replay time (and, live, rclpy's deserialisation dominates the node's), while a validation
needs only a few numbers per message. For ``sensor_msgs/msg/Imu``, ``sensor_msgs/msg/JointState`` and
``std_msgs/msg/Float64|Float32|Bool`` (:mod:`gap_validation.core.layouts`) in little-endian CDR,
:func:`fast_decoder` reads exactly the configured fields at their CDR offsets with ``struct`` (XCDR1 alignment:
relative to the end of the 4-byte encapsulation header, primitives aligned to their size). Anything unexpected
(big-endian data, short buffers, a missing joint) raises :class:`FastDecodeError`: decode that record fully.
:class:`gap_validation.messages.decoding.TopicDecoder` checks the first messages of every topic against full
deserialisation before trusting a decoder. Bytes in, numbers out: no rclpy, no rosbags.
"""
from __future__ import annotations

import struct
from typing import Any, Callable, Sequence

from gap_validation.core.fields import FieldPath
from gap_validation.core.layouts import FLOAT32, FLOAT64, IMU, JOINT_ARRAYS, JOINT_STATE, SCALAR_TYPES

__all__ = ["fast_decoder", "FastDecodeError", "Decoder"]

#: ``decoder(raw_cdr) -> (header stamp [s] or None, [raw value per field path])``.
Decoder = Callable[[Any], tuple]


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


def _imu_decoder(paths: Sequence[FieldPath]) -> Decoder | None:
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

    ARRAYS = JOINT_ARRAYS

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
    :class:`FastDecodeError` for records it cannot read (decode those fully)."""
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
