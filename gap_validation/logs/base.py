"""What every flight-log format gives replay: topics, their fields, and per topic the samples of some fields.

A *topic* is named as the format names it: a ULog message name (``vehicle_angular_velocity``; a multi-instance
one as ``sensor_gyro:1``), a DataFlash message name (``RATE``; an instance as ``IMU[1]``), a CSV file's stem. A
*field* too: ``xyz[0]``, ``control[3]``, ``ROut``, a CSV column. Times are seconds (float64) on the log's own
clock: ULog ``timestamp_sample`` where the message has one, else ``timestamp``; DataFlash ``TimeUS``; CSV the time
column.

A damaged file is read up to the damage: :meth:`LogFile.read` returns what came before it and
:attr:`LogFile.damage` says where the file stopped (one line naming the file), never a traceback.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from gap_validation.core.errors import DataError

__all__ = ["LogTopic", "LogSeries", "LogFile", "WriteTopic", "LOG_SUFFIXES", "open_log", "is_log"]

#: Suffix -> format name of the logs :func:`open_log` reads.
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


class LogFile:
    """An open log (context manager). Subclasses set :attr:`format` and implement :meth:`_topics` and
    :meth:`_read`.

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
        #: Where and why the file stopped early (one line naming the file), once the damage was met; else None.
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
        """
        return self._read({topic: tuple(fields) for topic, fields in wanted.items() if topic in self.topics})

    def _topics(self) -> dict[str, LogTopic]:   # pragma: no cover - abstract
        raise NotImplementedError

    def _read(self, wanted: dict[str, tuple[str, ...]]) -> dict[str, LogSeries]:   # pragma: no cover
        raise NotImplementedError

    def missing_field(self, topic: str, name: str) -> DataError:
        """The one-line error for a field ``topic`` does not have."""
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
    """Whether ``path`` is a file of a log format :func:`open_log` reads (by its suffix)."""
    p = Path(path)
    return p.suffix.lower() in LOG_SUFFIXES and not p.is_dir()


def open_log(path: str | Path) -> LogFile:
    """Open a ``.ulg``, ``.bin`` or ``.csv`` log with the reader of its format.

    Parameters
    ----------
    path : str or Path
        The log file.

    Returns
    -------
    LogFile
        The open log.

    Raises
    ------
    DataError
        Unknown suffix, missing file, or not a log of the format its suffix says (one line naming the file).
    """
    p = Path(path)
    kind = LOG_SUFFIXES.get(p.suffix.lower())
    if kind == "ulog":
        from gap_validation.logs.ulog import ULogFile
        return ULogFile(p)
    if kind == "dataflash":
        from gap_validation.logs.dataflash import DataFlashFile
        return DataFlashFile(p)
    if kind == "csv":
        from gap_validation.logs.csvlog import CsvFile
        return CsvFile(p)
    raise DataError(f"{p}: not a log (expected .ulg, .bin or .csv)")
