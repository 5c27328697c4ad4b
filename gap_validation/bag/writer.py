"""Writing rosbag2 files (through ``rosbags``): a simulated flight as a bag.

:func:`write_flight` writes a :class:`~gap_validation.core.simulation.SimulatedFlight` as a rosbag2 (mcap with
zstd chunk compression by default, or sqlite3), each topic's messages built for its type
(:mod:`gap_validation.core.layouts`) and serialised from a CDR template with the stamp and fields patched in.
"""
from __future__ import annotations

import json
import shutil
import struct
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2.errors import WriterError
from rosbags.typesys import get_typestore

from gap_validation.bag.reader import BAG_SUFFIXES, TYPESTORE
from gap_validation.core.errors import ConfigError, one_line
from gap_validation.core.fields import FieldPath
from gap_validation.core.layouts import BOOL, FLOAT64, IMU, JOINT_ARRAYS, JOINT_STATE, STAMPED_TYPES

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.logged_topics import TopicSeries
    from gap_validation.core.simulation import SimulatedFlight

__all__ = ["write_flight", "STORAGES"]

#: Storage plugins :func:`write_flight` can write.
STORAGES = ("mcap", "sqlite3")

_F64 = struct.Struct("<d")
_STAMP = struct.Struct("<iI")       # header.stamp.sec, header.stamp.nanosec


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
        self.stamped = self.msgtype in STAMPED_TYPES

    def values(self, i: int) -> dict[str, float]:
        """Field text -> value of message ``i``."""
        return {text: float(values[i]) for text, values in self.series.values.items()}

    def _header(self, stamp_ns: int):
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        return self.types["std_msgs/msg/Header"](stamp=self.types["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=nanosec), frame_id=self.frame_id)

    def build(self, values: dict[str, float], stamp_ns: int):
        """A message with ``values`` (field text -> value) and ``header.stamp`` = ``stamp_ns``."""
        if self.msgtype == IMU:
            return self._imu(values, stamp_ns)
        if self.msgtype == JOINT_STATE:
            return self._joint_state(values, stamp_ns)
        value = next(iter(values.values()))
        if self.msgtype == BOOL:
            return self.types[self.msgtype](data=bool(value))
        return self.types[self.msgtype](data=float(value))

    def _imu(self, values: dict[str, float], stamp_ns: int):
        vec, quat = self.types["geometry_msgs/msg/Vector3"], self.types["geometry_msgs/msg/Quaternion"]
        orientation_cov = np.zeros(9)
        orientation_cov[0] = -1.0  # REP 145: no orientation estimate
        msg = self.types[IMU](
            header=self._header(stamp_ns), orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=orientation_cov, angular_velocity=vec(x=0.0, y=0.0, z=0.0),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=vec(x=0.0, y=0.0, z=9.80665),
            linear_acceleration_covariance=np.zeros(9))
        for text, value in values.items():
            _set_path(msg, self.paths[text].attributes, value)
        return msg

    def _joint_state(self, values: dict[str, float], stamp_ns: int):
        names = list(self.series.joint_names)
        arrays = {name: np.zeros(len(names)) if name == "position" else None for name in JOINT_ARRAYS}
        for text, value in values.items():
            path = self.paths[text]
            array = path.attributes[0]
            if arrays[array] is None:
                arrays[array] = np.zeros(len(names))
            idx = names.index(path.key) if path.key is not None else path.index
            arrays[array][idx] = value
        empty = np.zeros(0)
        return self.types[JOINT_STATE](
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
        self.serialize_full = lambda msg: bytes(
            typestore.serialize_cdr(msg, builder.msgtype, little_endian=True)
        )
        self.template: bytes | None = None
        self.fields: list[tuple[int, str]] = []
        self.stamp_offset: int | None = None
        self.checks_left = self.CHECKS
        if builder.msgtype in (IMU, JOINT_STATE, FLOAT64):
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
