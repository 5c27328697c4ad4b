"""What every flight-log format gives replay: topics, their fields, and per topic the samples of some fields.

A *topic* is named as the format names it: a ULog message name (``vehicle_angular_velocity``; a multi-instance
one as ``sensor_gyro:1``), a DataFlash message name (``RATE``; an instance as ``IMU[1]``), a CSV file's stem.
A
*field* too: ``xyz[0]``, ``control[3]``, ``ROut``, a CSV column. Times are seconds (float64) on the log's own
clock: ULog ``timestamp_sample`` where the message has one, else ``timestamp``; DataFlash ``TimeUS``; CSV the
time column.

Two ways to read: :meth:`LogFile.read` returns each wanted series whole; :meth:`LogFile.blocks` gives them in
blocks in the log's order (:class:`LogBlocks`: a dict of series chunks per block -- ULog per block of the
file, DataFlash per window of the memory-mapped file, CSV per chunk of rows), so that replay keeps a block in
memory, not the flight.

A damaged file is read up to the damage: :meth:`LogFile.read` returns what came before it and
:attr:`LogFile.damage` says where the file stopped (one line naming the file), never a traceback.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from gap_validation.core.errors import DataError

__all__ = ["LogTopic", "LogSeries", "LogFile", "LogBlocks", "WriteTopic", "LOG_SUFFIXES", "is_log",
           "join_blocks"]

#: Suffix -> format name of the logs :func:`~gap_validation.logs.formats.open_log` reads.
LOG_SUFFIXES = {".ulg": "ulog", ".bin": "dataflash", ".csv": "csv"}


@dataclass(frozen=True)
class LogTopic:
    """A topic of a log: its name, its fields (in the log's order) and how many samples it has."""

    name: str
    fields: tuple[str, ...]
    count: int


@dataclass(frozen=True)
class LogSeries:
    """The samples of some fields of one topic, in time order as logged.

    Attributes
    ----------
    t_s : numpy.ndarray
        Sample times [s] (float64), on the log's clock.
    values : numpy.ndarray
        ``(len(t_s), len(fields))`` float64, the raw values (before a stream's ``offset`` and ``scale``).
    fields : tuple of str
        The fields, in the columns' order.
    """

    t_s: np.ndarray
    values: np.ndarray
    fields: tuple[str, ...]


class LogBlocks:
    """The wanted series of a log in blocks, in the log's order: iterating gives, per block, a dict topic ->
    :class:`LogSeries` holding the block's samples of that topic (only the topics that have samples in it);
    each topic's chunks, one after the other, are its series as :meth:`LogFile.read` gives it. It can be
    iterated more than once (each time reading the file again); the log must stay open meanwhile.

    Parameters
    ----------
    path : Path
        The log file (for the messages).
    fields : dict
        Topic (as asked) -> its fields, in the columns' order, for every topic the log has.
    counts : dict, optional
        Topic -> how many samples it has, where the reader knows (else None: known once read).

    Attributes
    ----------
    fields, counts : dict
        As given.
    """

    def __init__(
        self, path: Path, fields: dict[str, tuple[str, ...]], counts: dict[str, int | None] | None = None
    ):
        self.path = Path(path)
        self.fields = dict(fields)
        self.counts = {topic: (counts or {}).get(topic) for topic in self.fields}
        self._start_s: float | None = None
        self._primed: tuple[dict[str, LogSeries] | None, Iterator[dict[str, LogSeries]]] | None = None

    @property
    def topics(self) -> tuple[str, ...]:
        """The topics it gives, in the order asked."""
        return tuple(self.fields)

    @property
    def start_time_s(self) -> float:
        """The earliest finite sample time [s] (inf when there is none). Here: that of the first block with
        samples (read once, kept for the next iteration; a log in time order starts there); the ULog reader
        knows it of the whole log (from the pass that lists its topics)."""
        if self._start_s is None:
            blocks = self._blocks()
            first = next(blocks, None)
            self._primed = (first, blocks)
            self._start_s = _earliest(first or {})
        return self._start_s

    def __iter__(self) -> Iterator[dict[str, LogSeries]]:
        if self._primed is not None:
            first, rest = self._primed
            self._primed = None
            if first is not None:
                yield first
            yield from rest
        else:
            yield from self._blocks()

    def _blocks(self) -> Iterator[dict[str, LogSeries]]:   # pragma: no cover - abstract
        raise NotImplementedError


def _earliest(block: dict[str, LogSeries]) -> float:
    """The earliest finite time of a block's series (inf when none)."""
    out = math.inf
    for series in block.values():
        t = series.t_s[np.isfinite(series.t_s)]
        if t.size:
            out = min(out, float(t.min()))
    return out


def join_blocks(blocks: LogBlocks) -> dict[str, LogSeries]:
    """Every topic of ``blocks`` as one series (its chunks joined): what :meth:`LogFile.read` returns.

    Parameters
    ----------
    blocks : LogBlocks
        The blocks of the wanted series.
    """
    parts: dict[str, list[LogSeries]] = {topic: [] for topic in blocks.topics}
    for block in blocks:
        for topic, series in block.items():
            parts[topic].append(series)
    out = {}
    for topic, chunks in parts.items():
        fields = tuple(blocks.fields[topic])
        if not chunks:
            out[topic] = LogSeries(np.zeros(0), np.zeros((0, len(fields))), fields)
        elif len(chunks) == 1:
            out[topic] = chunks[0]
        else:
            out[topic] = LogSeries(np.concatenate([c.t_s for c in chunks]),
                                   np.concatenate([c.values for c in chunks]), fields)
        chunks.clear()
    return out


class LogFile:
    """An open log (context manager). Subclasses set :attr:`format` and implement :meth:`_topics` and
    :meth:`_blocks` (and :meth:`_read`, when a whole read has a faster way than joining the blocks).

    Parameters
    ----------
    path : str or Path
        The log file.

    Raises
    ------
    DataError
        The file does not exist or is not a log of this format (one line naming the file).
    """

    format = ""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise DataError(f"{self.path}: no such log file")
        #: Where and why the file stopped early (one line naming the file), once the damage was met; else
        #: None.
        self.damage: str | None = None
        self._topic_cache: dict[str, LogTopic] | None = None

    @property
    def topics(self) -> dict[str, LogTopic]:
        """Topic name -> :class:`LogTopic`, every topic the log has samples or a definition of."""
        if self._topic_cache is None:
            self._topic_cache = self._topics()
        return self._topic_cache

    def read(self, wanted: dict[str, Sequence[str]]) -> dict[str, LogSeries]:
        """The samples of the ``wanted`` fields of each wanted topic (topic -> fields).

        Topics the log does not have are left out (the caller names them with :attr:`topics`); a field a topic
        does not have raises :class:`DataError` naming the file, topic, field and the fields it has.

        Parameters
        ----------
        wanted : dict
            Topic -> the fields to read.
        """
        return self._read({topic: tuple(fields) for topic, fields in wanted.items() if topic in self.topics})

    def blocks(self, wanted: dict[str, Sequence[str]], *, block_bytes: int | None = None) -> LogBlocks:
        """The samples of the ``wanted`` fields of each wanted topic (topic -> fields) in blocks, in the log's
        order (:class:`LogBlocks`); joined, they are what :meth:`read` returns.

        Topics the log does not have are left out; a field a topic does not have raises :class:`DataError` (as
        :meth:`read`), here, before any block is read.

        Parameters
        ----------
        wanted : dict
            Topic -> field names.
        block_bytes : int, optional
            Bytes of the file per block (default: the reader's; ULog 1 MiB, DataFlash 1 MiB, CSV 1 MiB of
            text).
        """
        return self._blocks(
            {topic: tuple(fields) for topic, fields in wanted.items() if topic in self.topics}, block_bytes
        )

    def _topics(self) -> dict[str, LogTopic]:   # pragma: no cover - abstract
        raise NotImplementedError

    def _blocks(self, wanted: dict[str, tuple[str, ...]],  # pragma: no cover
                block_bytes: int | None) -> LogBlocks:
        raise NotImplementedError

    def _read(self, wanted: dict[str, tuple[str, ...]]) -> dict[str, LogSeries]:
        return join_blocks(self._blocks(wanted, None))

    def missing_field(self, topic: str, name: str) -> DataError:
        """The one-line error for a field ``topic`` does not have.

        Parameters
        ----------
        topic : str
            The topic.
        name : str
            The field it lacks.
        """
        have = ", ".join(self.topics[topic].fields)
        return DataError(f"{self.path}: topic {topic} has no field {name} (it has: {have})")

    def close(self) -> None:
        """Release the file."""

    def __enter__(self) -> "LogFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class WriteTopic:
    """One topic to write into a log.

    Attributes
    ----------
    name : str
        Topic name as the format names it (``vehicle_angular_velocity``, ``RATE``, a CSV stem). A ULog
        multi-instance topic as ``name:K``, a DataFlash instance as ``NAME[K]``.
    t_us : numpy.ndarray
        Sample times [us] (int64), non-decreasing.
    fields : dict
        Field name -> values (float; one per sample). ULog arrays as ``xyz[0]`` ... ``xyz[2]``.
    units : dict
        Field name -> unit text (DataFlash and CSV keep it; optional).
    """

    name: str
    t_us: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)


def is_log(path: str | Path) -> bool:
    """Whether ``path`` is a file of a log format :func:`~gap_validation.logs.formats.open_log` reads (by its
    suffix).

    Parameters
    ----------
    path : str or Path
        The file.
    """
    p = Path(path)
    return p.suffix.lower() in LOG_SUFFIXES and not p.is_dir()
