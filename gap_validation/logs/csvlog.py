"""CSV flight logs: one file per topic, the topic named by the file's stem, one column per field.

A file ``imu.csv`` is the topic ``imu``; its header names the fields; one column is the time:
``time_column`` when given (the config's stream key, :class:`~gap_validation.core.config.SignalSpec`), else
the first of :data:`TIME_COLUMNS` the header has. Its unit follows from its name (:func:`time_scale`):
``TimeUS``, ``timestamp`` and names ending in ``_us`` are microseconds, names ending in ``_ms`` milliseconds,
``_ns`` nanoseconds, every other name seconds. Lines starting with ``#`` are comments (:func:`write_csv` puts
the units there); the delimiter is a comma, or a semicolon or tab when the header has no comma.

A cell that is not a number is read as NaN: replay counts it as a bad sample of the streams it feeds (never a
traceback). A file that does not end with a line break may have been cut inside its last row (a logger that
lost power, a copy broken off): that row is left out and is the damage (:attr:`LogFile.damage`), the rows
before it are read (a number cut short would otherwise be read as a wrong number).

Speed (500 000 rows, 4 columns, two read; ``np.loadtxt`` 0.61 s, the ``csv`` module with column lists 1.0 s,
``np.genfromtxt`` 2.3 s): the numbers are parsed by ``np.loadtxt`` (its C parser), a chunk of rows at a time
(1 MiB of text, :meth:`CsvFile.blocks`: replay holds a chunk, not the file), and a chunk it refuses (a cell
that is not a number, a short row) is read again with the ``csv`` module, cell by cell. A file that does not
end with a line break is read cell by cell throughout (its last row is the damage).
"""
from __future__ import annotations

import csv
import io
import math
import warnings
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np

from gap_validation.core.errors import DataError
from gap_validation.logs.base import LogBlocks, LogFile, LogSeries, LogTopic, WriteTopic

__all__ = ["CsvFile", "write_csv", "TIME_COLUMNS", "time_scale"]

#: Time columns looked for, in this order, when the config names none.
TIME_COLUMNS = ("time", "t", "TimeUS", "timestamp")
#: Bytes read at once when counting rows; characters of text per block of rows.
_CHUNK = 1 << 20
#: Rows per block when the file is read cell by cell.
_CELL_ROWS = 1 << 15


def time_scale(column: str) -> float:
    """Seconds per unit of a time column, from its name: ``TimeUS``, ``timestamp`` and names ending in ``_us``
    (or ``US``) are microseconds, ``_ms`` milliseconds, ``_ns`` nanoseconds, anything else seconds.

    Parameters
    ----------
    column : str
        The column's name.
    """
    name = column.strip()
    low = name.lower()
    if low == "timestamp" or low.endswith("_us") or name.endswith("US"):
        return 1e-6
    if low.endswith("_ms") or name.endswith("MS"):
        return 1e-3
    if low.endswith("_ns") or name.endswith("NS"):
        return 1e-9
    return 1.0


class CsvFile(LogFile):
    """One CSV file: the topic named by its stem, one column per field, one time column.

    Parameters
    ----------
    path : str or Path
        The ``.csv`` file.
    time_column : str, optional
        The time column (default: the first of :data:`TIME_COLUMNS` the header has).

    Raises
    ------
    DataError
        No such file, no header, or no time column (one line naming the file and the columns it has).
    """

    format = "csv"

    def __init__(self, path: str | Path, time_column: str | None = None) -> None:
        super().__init__(path)
        self.topic = self.path.stem
        self._lines, self._delimiter, self._columns = self._header()
        if time_column is not None:
            if time_column not in self._columns:
                raise DataError(
                    f"{self.path}: no time column {time_column!r} (it has: {', '.join(self._columns)})"
                )
            self.time_column = time_column
        else:
            found = next((c for c in TIME_COLUMNS if c in self._columns), None)
            if found is None:
                raise DataError(f"{self.path}: no time column (looked for {', '.join(TIME_COLUMNS)}; it has: "
                                f"{', '.join(self._columns)}); name it with the config's time_column")
            self.time_column = found
        #: Seconds per unit of the time column (:func:`time_scale`).
        self.time_scale_s = time_scale(self.time_column)

    def _header(self) -> tuple[int, str, tuple[str, ...]]:
        """Lines before the first data row (comments and the header), the delimiter and the column names."""
        skipped = 0
        try:
            with open(self.path, encoding="utf-8-sig", newline="") as f:
                for line in f:
                    skipped += 1
                    if line.strip() and not line.lstrip().startswith("#"):
                        break
                else:
                    raise DataError(f"{self.path}: no header line (an empty CSV file)")
        except UnicodeDecodeError as err:
            raise DataError(
                f"{self.path}: not a text CSV file (byte {err.start} of a line is not UTF-8)"
            ) from None
        except OSError as err:
            raise DataError(f"{self.path}: cannot read ({err.strerror})") from None
        delimiter = "," if "," in line else ";" if ";" in line else "\t" if "\t" in line else ","
        names = tuple(name.strip() for name in next(csv.reader([line], delimiter=delimiter)))
        if not any(names):
            raise DataError(f"{self.path}: the header line names no columns")
        seen = set()
        for name in names:
            if not name:
                raise DataError(f"{self.path}: the header has an empty column name")
            if name in seen:
                raise DataError(f"{self.path}: the header names column {name!r} twice")
            seen.add(name)
        return skipped, delimiter, names

    def _topics(self) -> dict[str, LogTopic]:
        fields = tuple(c for c in self._columns if c != self.time_column)
        return {self.topic: LogTopic(self.topic, fields, self._count_rows())}

    def _count_rows(self) -> int:
        """Data rows (non-empty lines after the header that are not comments), counted without parsing."""
        rows = 0
        with open(self.path, "rb") as f:
            for _ in range(self._lines):
                f.readline()
            tail = b"\n"
            while chunk := f.read(_CHUNK):
                rows += chunk.count(b"\n")
                tail = chunk[-1:]
        return rows + (tail != b"\n")

    def _blocks(self, wanted: dict[str, tuple[str, ...]], block_bytes: int | None) -> LogBlocks:
        if self.topic not in wanted:
            return _CsvBlocks(self, (), (), block_bytes)
        fields = wanted[self.topic]
        for name in fields:
            if name not in self._columns or name == self.time_column:
                raise self.missing_field(self.topic, name)
        columns = [self._columns.index(self.time_column)] + [self._columns.index(name) for name in fields]
        return _CsvBlocks(self, tuple(fields), columns, block_bytes)

    def _series(self, data: np.ndarray, fields: tuple[str, ...]) -> LogSeries:
        """Parsed rows (time column first) as a series: time in seconds, values as parsed."""
        t_s = data[:, 0] * self.time_scale_s if self.time_scale_s != 1.0 else data[:, 0].copy()
        return LogSeries(t_s, np.ascontiguousarray(data[:, 1:]), fields)

    def _chunks(self, columns: list[int], chars: int) -> Iterator[np.ndarray]:
        """The columns, a chunk of rows (about ``chars`` characters of text) at a time: numpy's C parser, a
        chunk it refuses cell by cell; a file that does not end with a line break cell by cell throughout."""
        if not self._ends_with_newline():          # the last row may be cut inside a number
            yield from self._load_cells(columns)
            return
        with open(self.path, encoding="utf-8-sig") as f:
            for _ in range(self._lines):
                f.readline()
            while text := f.read(chars):
                if not text.endswith("\n"):
                    text += f.readline()
                lines = text.split("\n")
                lines.pop()                         # after the last line break
                data = self._load_fast(columns, lines)
                if data is None:
                    yield from self._cells(lines, columns, len(self._columns), None)
                else:
                    yield data

    def _load_fast(self, columns: list[int], lines: list[str]) -> np.ndarray | None:
        """The columns of ``lines`` with numpy's C parser, or None when a row has a cell that is not a number
        or too few cells (then :meth:`_cells` reads them)."""
        try:
            with warnings.catch_warnings():
                # "input contained no data": a header only
                warnings.simplefilter("ignore", UserWarning)
                return np.loadtxt(lines, delimiter=self._delimiter, usecols=columns, ndmin=2, comments="#",
                                  dtype=np.float64, quotechar='"')
        except (ValueError, IndexError):
            return None

    def _load_cells(self, columns: list[int]) -> Iterator[np.ndarray]:
        """The columns of the whole file cell by cell (``csv`` module), in blocks of rows: a cell that is not
        a number is NaN; a last row cut short is the damage."""
        with open(self.path, encoding="utf-8-sig", newline="") as f:
            for _ in range(self._lines):
                f.readline()
            yield from self._cells(f, columns, len(self._columns), self)

    def _cells(self, lines: Iterable[str], columns: list[int], width: int, cut: "CsvFile | None"
               ) -> Iterator[np.ndarray]:
        """Rows of ``lines`` cell by cell, :data:`_CELL_ROWS` at a time; with ``cut``, the last row is held
        back and left out as the damage when the file does not end with a line break."""
        out: list[list[float]] = []
        rows_before = 0             # rows given out before ``out``
        lo, hi = math.inf, -math.inf        # the finite times given out
        short_last = False      # the last row has fewer cells than the header
        pending = None
        for row in csv.reader(lines, delimiter=self._delimiter):
            if not row or (row[0].lstrip().startswith("#")) or not any(cell.strip() for cell in row):
                continue
            if pending is not None:
                out.append(pending)
            pending = [_number(row[c]) if c < len(row) else math.nan for c in columns]
            short_last = len(row) < width
            if cut is None:
                out.append(pending)
                pending = None
            if len(out) >= _CELL_ROWS:
                block = _rows(out, len(columns))
                lo, hi = _span(block, lo, hi)
                rows_before += len(out)
                out = []
                yield block
        if pending is not None:
            if not self._ends_with_newline():        # the last row may be cut inside a number: left out
                block = _rows(out, len(columns))
                lo, hi = _span(block, lo, hi)
                what = "inside row" if short_last else "without a line break after row"
                span = f"{(hi - lo) * self.time_scale_s:.1f}" if hi >= lo else "0.0"
                self.damage = (
                    f"{self.path}: the file ends {what} {rows_before + len(out) + 1} (cut short?); that row "
                    f"is left out, {span} s read before it"
                )
            else:
                out.append(pending)
        if out:
            yield _rows(out, len(columns))

    def _ends_with_newline(self) -> bool:
        with open(self.path, "rb") as f:
            f.seek(0, io.SEEK_END)
            if f.tell() == 0:
                return True
            f.seek(-1, io.SEEK_END)
            return f.read(1) in (b"\n", b"\r")


def _number(cell: str) -> float:
    """A cell as a float, NaN when it is not a number."""
    try:
        return float(cell)
    except ValueError:
        return math.nan


def _rows(rows: list[list[float]], width: int) -> np.ndarray:
    return np.array(rows, dtype=np.float64).reshape(len(rows), width)


def _span(block: np.ndarray, lo: float, hi: float) -> tuple[float, float]:
    """``(lo, hi)`` widened by the finite times (column 0) of ``block``."""
    times = block[:, 0][np.isfinite(block[:, 0])] if block.size else block
    return (min(lo, float(times.min())), max(hi, float(times.max()))) if times.size else (lo, hi)


class _CsvBlocks(LogBlocks):
    """A CSV file's topic in blocks of rows (:meth:`CsvFile.blocks`); the damage is known once the last block
    was read."""

    def __init__(self, log: CsvFile, fields: tuple[str, ...], columns: list[int], block_bytes: int | None):
        super().__init__(log.path, {log.topic: fields} if columns else {})
        self.log, self.columns, self.chars = log, columns, int(block_bytes or _CHUNK)

    def _blocks(self) -> Iterator[dict[str, LogSeries]]:
        if not self.columns:
            return
        fields = self.fields[self.log.topic]
        for data in self.log._chunks(self.columns, self.chars):
            if len(data):
                yield {self.log.topic: self.log._series(data, fields)}


def write_csv(directory_or_path: str | Path, topics: Sequence[WriteTopic]) -> list[Path]:
    """Write one CSV file per topic: ``<directory>/<topic>.csv`` (or the ``.csv`` path itself for one topic).

    The first column is ``TimeUS`` (integer microseconds, exact), then one column per field, values written in
    full precision (``repr``: read back to the same float64). Units, when given, go in a ``#`` comment line
    before the header.

    Parameters
    ----------
    directory_or_path : str or Path
        A directory (created if needed), or a ``.csv`` file when there is one topic.
    topics : sequence of WriteTopic
        The topics, each with its times and fields.

    Returns
    -------
    list of Path
        The files written, in the order of ``topics``.

    Raises
    ------
    DataError
        Several topics for one ``.csv`` path, a topic whose fields and times differ in length, or times that
        go back.
    """
    target = Path(directory_or_path)
    single = target.suffix.lower() == ".csv"
    if single and len(topics) != 1:
        raise DataError(f"{target}: one CSV file holds one topic, got {len(topics)}; give a directory")
    if not single:
        target.mkdir(parents=True, exist_ok=True)
    written = []
    for topic in topics:
        path = target if single else target / f"{topic.name}.csv"
        t_us = np.asarray(topic.t_us, dtype=np.int64)
        names = list(topic.fields)
        columns = [np.asarray(topic.fields[n], dtype=np.float64) for n in names]
        for name, values in zip(names, columns):
            if values.shape != t_us.shape:
                raise DataError(f"{path}: field {name} has {values.size} values for {t_us.size} times")
        if t_us.size > 1 and np.any(np.diff(t_us) < 0):
            raise DataError(f"{path}: the times of topic {topic.name} go back")
        with open(path, "w", newline="", encoding="utf-8") as f:
            if topic.units:
                f.write("# units: TimeUS [us], " + ", ".join(f"{n} [{topic.units[n]}]" for n in names
                                                               if n in topic.units) + "\n")
            writer = csv.writer(f, lineterminator="\n")
            writer.writerow(["TimeUS", *names])
            block = 65536
            for start in range(0, t_us.size, block):
                stop = start + block
                cells = [t_us[start:stop].astype(str)] + [c[start:stop].astype(str) for c in columns]
                writer.writerows(zip(*cells))
        written.append(path)
    return written
