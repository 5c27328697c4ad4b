"""Atomic file writes: a crash, an exception or ``kill -9`` never leaves a half-written file.

Every result file of the tool (JSON, report, configs written by ``--apply-diagnosis``, the validation history,
the node's checkpoint) is written the same way: into a hidden temporary file in the target's directory
(``.<name>.<random>.tmp``, so the rename cannot cross file systems), flushed and ``fsync``-ed, then renamed
over the target with :func:`os.replace` (atomic on POSIX and Windows), and the directory is ``fsync``-ed so
that the rename itself survives a power cut. Readers therefore see either the old file or the new one, never a
mixture. When anything fails before the rename, the temporary file is removed and the old file is untouched;
only a process killed between creating and renaming the temporary file can leave one behind (never the target
half-written).

Plain Python (``os``, ``tempfile``): the core uses it, and so does every front end.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

__all__ = ["atomic_open", "atomic_write_bytes", "atomic_write_text", "TEMP_SUFFIX"]

#: Suffix of the temporary files (their names start with a dot and the target's name).
TEMP_SUFFIX = ".tmp"


def _fsync_directory(directory: Path) -> None:
    """Make a rename in ``directory`` durable (best effort: not every platform can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", encoding: str | None = "utf-8",
                newline: str | None = None) -> Iterator[IO]:
    """Open a temporary file to write ``path`` through; it replaces ``path`` when the block ends normally.

    Parameters
    ----------
    path : str or PathLike
        Target file; its directory must exist.
    mode : {"w", "wb"}
        Text or binary.
    encoding, newline : str, optional
        As for :func:`open` (text mode only).

    Yields
    ------
    file object
        Write the whole new content to it.

    Raises
    ------
    OSError
        When the temporary file cannot be created, written or renamed (``path`` is then unchanged and the
        temporary file removed). Exceptions raised inside the block propagate the same way.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode must be 'w' or 'wb', not {mode!r}")
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=directory)
    done = False
    try:
        kwargs = {} if "b" in mode else {"encoding": encoding, "newline": newline}
        with os.fdopen(fd, mode, **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
        done = True
    finally:
        if not done:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    _fsync_directory(directory)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Replace ``path`` with ``data`` atomically (see :func:`atomic_open`); returns ``path``.

    Parameters
    ----------
    path : str or PathLike
        Target file; its directory must exist.
    data : bytes
        The new content.

    Raises
    ------
    OSError
        When it cannot be written (the old file is kept).
    """
    with atomic_open(path, "wb") as handle:
        handle.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Replace ``path`` with ``text`` atomically, as :func:`atomic_write_bytes` does with bytes.

    Parameters
    ----------
    path : str or PathLike
        Target file; its directory must exist.
    text, encoding : str
        The new content and its encoding.
    """
    with atomic_open(path, "w", encoding=encoding) as handle:
        handle.write(text)
    return Path(path)
