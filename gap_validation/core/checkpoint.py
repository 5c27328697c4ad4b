"""Checkpoints of :meth:`OnlineValidator.state_dict` on disk: nothing gathered in flight is lost.

A state is a tree of dicts, lists and tuples whose leaves are numpy arrays, numpy scalars, Python numbers
(``bool``, ``int``, ``float``, ``complex``), strings and ``None``. :func:`save_state` writes it as **one
zip archive in numpy's ``.npz`` layout**: every array (and numpy scalar) is a member ``arrays/<n>_<path>.npy``
written with :func:`numpy.lib.format.write_array` (``allow_pickle=False``), and the tree itself is the JSON
member ``state.json``, where each node is tagged with its type so that the state read back is identical (same
keys and key types, same dtypes, bit-identical floats: JSON holds Python floats as their shortest round-trip
``repr``, non-finite ones as strings). Pickle is never used, so a checkpoint cannot run code when loaded.

The file is written atomically (:mod:`gap_validation.core.atomic`): to a temporary file in the same directory,
flushed and ``fsync``-ed, then renamed over the old checkpoint with :func:`os.replace`. A crash or ``kill -9``
mid-write leaves the previous checkpoint.

Encoding of a node in ``state.json`` (one key per object)::

    {"none": null}   {"bool": true}   {"int": 3}   {"float": 0.25 | "nan" | "inf" | "-inf"}
    {"complex": [re, im]}   {"str": "..."}   {"array": "arrays/0003_channels.pitch.gxx.npy"}
    {"scalar": "arrays/...npy"}   {"list": [...]}   {"tuple": [...]}   {"dict": [[key, value], ...]}

Dict keys are encoded like values (so integer keys stay integers).
"""
from __future__ import annotations

import io
import json
import math
import os
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from gap_validation.core.atomic import atomic_open
from gap_validation.core.errors import DataError

__all__ = ["FORMAT", "VERSION", "save_state", "load_state", "encode_state", "decode_state"]

#: Identifies gap_validation checkpoints inside ``state.json``.
FORMAT = "gap_validation.checkpoint"
#: Version of the file layout (not of the validator state, which carries its own version).
VERSION = 1
_JSON_MEMBER = "state.json"
_SAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def _float_json(value: float) -> float | str:
    return value if math.isfinite(value) else repr(value)  # 'nan', 'inf', '-inf'


def _float_back(value: Any) -> float:
    if isinstance(value, str):
        if value not in ("nan", "inf", "-inf"):
            raise ValueError(f"bad float {value!r}")
        return float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"bad float {value!r}")
    return float(value)


class _Encoder:
    """Turns a state tree into (JSON-able tagged tree, {member name: array})."""

    def __init__(self):
        self.arrays: dict[str, np.ndarray] = {}

    def _member(self, array: np.ndarray, path: str) -> str:
        if array.dtype.hasobject:
            raise TypeError(f"{path or '<root>'}: object arrays cannot be checkpointed without pickle")
        name = f"arrays/{len(self.arrays):04d}_{_SAFE.sub('_', path)[:80] or 'root'}.npy"
        self.arrays[name] = array
        return name

    def encode(self, value: Any, path: str = "") -> dict:
        if value is None:
            return {"none": None}
        if isinstance(value, np.ndarray):
            return {"array": self._member(value, path)}
        if isinstance(value, np.generic):
            return {"scalar": self._member(np.asarray(value), path)}
        if isinstance(value, bool):
            return {"bool": value}
        if isinstance(value, int):
            return {"int": value}
        if isinstance(value, float):
            return {"float": _float_json(value)}
        if isinstance(value, complex):
            return {"complex": [_float_json(value.real), _float_json(value.imag)]}
        if isinstance(value, str):
            return {"str": value}
        if isinstance(value, (list, tuple)):
            tag = "list" if isinstance(value, list) else "tuple"
            return {tag: [self.encode(v, f"{path}.{i}") for i, v in enumerate(value)]}
        if isinstance(value, dict):
            return {"dict": [[self.encode(k, f"{path}.key"), self.encode(v, f"{path}.{k}")]
                             for k, v in value.items()]}
        raise TypeError(f"{path or '<root>'}: cannot checkpoint a {type(value).__name__} "
                        "(numpy arrays, numbers, strings, None, lists, tuples and dicts only)")


def encode_state(state: Any) -> tuple[dict, dict[str, np.ndarray]]:
    """Split a state tree into its tagged JSON tree and the arrays it refers to.

    Parameters
    ----------
    state : object
        A state tree: dicts with string keys, lists, tuples, numbers, strings, None and numpy arrays
        (:meth:`OnlineValidator.state_dict <gap_validation.core.validator.OnlineValidator.state_dict>`).

    Returns
    -------
    tree : dict
        JSON-serialisable tagged tree (see the module docstring).
    arrays : dict
        Member name -> array.

    Raises
    ------
    TypeError
        For leaves that cannot be stored without pickle (objects, object arrays, sets ...), naming the path.
    """
    encoder = _Encoder()
    tree = encoder.encode(state)
    return tree, encoder.arrays


def decode_state(tree: Any, arrays: dict[str, np.ndarray]) -> Any:
    """Inverse of :func:`encode_state`.

    Parameters
    ----------
    tree : dict
        Tagged JSON tree from :func:`encode_state`.
    arrays : dict
        Member name -> array, as :func:`encode_state` returned them.

    Raises
    ------
    ValueError
        When the tree is malformed or refers to a missing array.
    """
    if not isinstance(tree, dict) or len(tree) != 1:
        raise ValueError(f"bad node {str(tree)[:60]}")
    (tag, value), = tree.items()
    if tag == "none":
        return None
    if tag in ("array", "scalar"):
        if value not in arrays:
            raise ValueError(f"missing member {value!r}")
        array = arrays[value]
        return array[()] if tag == "scalar" else array
    if tag == "bool" and isinstance(value, bool):
        return value
    if tag == "int" and isinstance(value, int) and not isinstance(value, bool):
        return value
    if tag == "float":
        return _float_back(value)
    if tag == "complex" and isinstance(value, list) and len(value) == 2:
        return complex(_float_back(value[0]), _float_back(value[1]))
    if tag == "str" and isinstance(value, str):
        return value
    if tag in ("list", "tuple") and isinstance(value, list):
        items = [decode_state(v, arrays) for v in value]
        return items if tag == "list" else tuple(items)
    if tag == "dict" and isinstance(value, list):
        out = {}
        for pair in value:
            if not isinstance(pair, list) or len(pair) != 2:
                raise ValueError("bad dict entry")
            out[decode_state(pair[0], arrays)] = decode_state(pair[1], arrays)
        return out
    raise ValueError(f"bad node with tag {tag!r}")


def save_state(state: dict, path: str | os.PathLike, meta: dict | None = None) -> Path:
    """Write ``state`` (e.g. ``OnlineValidator.state_dict()``) to ``path`` atomically.

    Parameters
    ----------
    state : dict
        Tree of dicts/lists/tuples with numpy arrays, numbers, strings or None as leaves.
    path : str or PathLike
        Checkpoint file (conventionally ``*.npz``); its directory must exist.
    meta : dict, optional
        JSON-serialisable notes stored beside the state (e.g. the config file); see :func:`load_state`.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    TypeError
        When the state holds something that cannot be stored without pickle.
    DataError
        One line naming the file when it cannot be written (the previous checkpoint is then kept).
    """
    path = Path(path)
    tree, arrays = encode_state(state)
    document = {"format": FORMAT, "version": VERSION, "meta": dict(meta or {}), "state": tree}
    text = json.dumps(document, allow_nan=False, separators=(",", ":"))
    try:
        with atomic_open(path, "wb") as fh:
            with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_STORED) as archive:
                archive.writestr(_JSON_MEMBER, text)
                for name, array in arrays.items():
                    buffer = io.BytesIO()
                    np.lib.format.write_array(buffer, np.asanyarray(array), allow_pickle=False)
                    archive.writestr(name, buffer.getvalue())
    except OSError as err:
        raise DataError(f"{path}: cannot write checkpoint ({err.strerror or err})") from None
    return path


def load_state(path: str | os.PathLike, with_meta: bool = False) -> Any:
    """Read a checkpoint written by :func:`save_state`.

    Parameters
    ----------
    path : str or PathLike
        Checkpoint file.
    with_meta : bool
        Return ``(state, meta)`` instead of ``state``.

    Raises
    ------
    DataError
        One line naming the file when it is missing, unreadable, truncated or not a gap_validation
        checkpoint (never a traceback from zip/JSON/numpy internals).
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path, "r") as archive:
            document = json.loads(archive.read(_JSON_MEMBER).decode("utf-8"))
            if not isinstance(document, dict) or document.get("format") != FORMAT:
                raise ValueError("not a gap_validation checkpoint")
            if document.get("version") != VERSION:
                raise ValueError(f"checkpoint layout version {document.get('version')!r}, expected {VERSION}")
            arrays = {}
            for name in archive.namelist():
                if name.endswith(".npy"):
                    with archive.open(name) as member:
                        arrays[name] = np.lib.format.read_array(io.BytesIO(member.read()), allow_pickle=False)
            state = decode_state(document.get("state"), arrays)
            meta = document.get("meta") if isinstance(document.get("meta"), dict) else {}
    except FileNotFoundError:
        raise DataError(f"{path}: checkpoint not found") from None
    except OSError as err:
        raise DataError(f"{path}: cannot read checkpoint ({err.strerror or err})") from None
    except (zipfile.BadZipFile, KeyError, UnicodeDecodeError, json.JSONDecodeError, ValueError, TypeError,
            EOFError, RecursionError) as err:
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise DataError(f"{path}: corrupt checkpoint ({reason})") from None
    return (state, meta) if with_meta else state
