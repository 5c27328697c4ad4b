"""Opening a flight log by its suffix: the one module that knows every format's reader.

:mod:`~gap_validation.logs.base` defines what every format gives; each format's module builds on it; this one
picks among them, so that the base imports none of the formats.
"""
from __future__ import annotations

from pathlib import Path

from gap_validation.core.errors import DataError
from gap_validation.logs.base import LOG_SUFFIXES, LogFile
from gap_validation.logs.csvlog import CsvFile
from gap_validation.logs.dataflash import DataFlashFile
from gap_validation.logs.ulog import ULogFile

__all__ = ["open_log"]


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
        return ULogFile(p)
    if kind == "dataflash":
        return DataFlashFile(p)
    if kind == "csv":
        return CsvFile(p)
    raise DataError(f"{p}: not a log (expected .ulg, .bin or .csv)")
