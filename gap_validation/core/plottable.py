"""A channel's frequency response as plot curves: one table a live plotter draws (the node's
``~/<channel>/frequency_response`` topic, docs/NODE_TOPICS.md) and :func:`read_table` reads back.

The table has one row per curve (:data:`CURVES`) and one column per frequency of the channel's analysis grid
(:meth:`~gap_validation.core.config.FrequencyGrid.values`, fixed for a config): the columns a result does not
cover (not estimated yet, or outside the band the flight excited when the grid follows it) hold NaN, so a plot
layout's column indices stay valid all flight long. Magnitudes and phases are those of the JSON (``measured``
and ``model``: the measured phase unwrapped next to the model's), so the curves equal the report's.
"""
from __future__ import annotations

import re
from functools import lru_cache
from typing import Mapping, Sequence

import numpy as np

from gap_validation.core.config import ChannelConfig
from gap_validation.core.results import ChannelResult

__all__ = [
    "CURVES",
    "FLAG_CODES",
    "frequency_response_table",
    "read_table",
    "flags_from_codes",
    "topic_token",
    "table_dims",
]

#: The rows of the table, in order: the frequency (also as log10, for plot axes without a log scale), the
#: measured and model Bode curves, coherence, epsilon(w) (eq. 14), kappa(w) (the chordal distance), the random
#: error and the per-frequency flag (:data:`FLAG_CODES`).
CURVES = ("frequency_rad_s", "log10_frequency_rad_s", "measured_magnitude_db", "measured_phase_deg",
          "model_magnitude_db", "model_phase_deg", "coherence", "epsilon", "kappa", "random_error", "flag")

#: The ``flag`` row's numbers for the JSON's ``frequency_flags`` (NaN: no estimate at that frequency).
FLAG_CODES = {"ok": 0.0, "model": 1.0, "data": 2.0, "excluded": 3.0, "not_excited": 4.0}


def frequency_response_table(result: ChannelResult, channel: ChannelConfig) -> np.ndarray | None:
    """The curves of a SISO channel's result on its whole analysis grid.

    Parameters
    ----------
    result : ChannelResult
        The channel's result (cheap or full).
    channel : ChannelConfig
        Its config (the analysis grid).

    Returns
    -------
    ndarray of float, shape (len(CURVES), grid size), or None
        None for a MIMO channel (a matrix of responses: its JSON ``mimo`` object).
    """
    if getattr(channel, "is_mimo", False):
        return None
    grid = _grid(channel.frequencies)
    table = np.full((len(CURVES), grid.size), np.nan)
    table[0], table[1] = grid, np.log10(grid)
    w = result.frequency_rad_s
    if w is None or not np.size(w):
        return table
    w = np.asarray(w, dtype=float)
    at = np.clip(np.searchsorted(grid, w), 0, grid.size - 1)
    closer = np.clip(at - 1, 0, grid.size - 1)
    at = np.where(np.abs(grid[closer] - w) < np.abs(grid[at] - w), closer, at)
    if not np.allclose(grid[at], w, rtol=1e-9, atol=0.0):
        raise ValueError(f"channel {result.name}: its result's frequencies are not on its analysis grid")
    curves = result.curves()      # the JSON's curves, nulls as NaN (without building its lists)
    rows = {
        "measured_magnitude_db": curves["measured_magnitude_db"],
        "measured_phase_deg": curves["measured_phase_deg"],
        "model_magnitude_db": curves["model_magnitude_db"],
        "model_phase_deg": curves["model_phase_deg"],
        "coherence": curves["coherence"],
        "epsilon": curves["epsilon_per_frequency"],
        "kappa": curves["kappa"],
        "random_error": curves["random_error"],
        "flag": np.array([np.nan if code is None else code
                          for code in (FLAG_CODES.get(f) for f in result.frequency_flags)], dtype=float),
    }
    for name, values in rows.items():
        if values is not None and len(values) == w.size:
            table[CURVES.index(name), at] = values
    return table


@lru_cache(maxsize=64)
def _grid(frequencies) -> np.ndarray:
    """A grid's frequencies (read-only; a config's grid is fixed: computed once, not at every table)."""
    grid = np.asarray(frequencies.values(), dtype=float)
    grid.flags.writeable = False
    return grid


def read_table(data: Sequence[float], labels: Sequence[str]) -> dict[str, np.ndarray]:
    """The curves of a published table: curve name -> values per frequency.

    Parameters
    ----------
    data : sequence of float
        The table row after row (``Float64MultiArray.data``).
    labels : sequence of str
        The row names, in order (the layout's first dimension label, split at the commas).

    Returns
    -------
    dict
        Each name of ``labels`` -> its row (NaN where the result has no value).
    """
    values = np.asarray(data, dtype=float)
    if not labels or values.size % len(labels):
        raise ValueError(f"a table of {len(labels)} curves cannot hold {values.size} numbers")
    rows = values.reshape(len(labels), -1)
    return {name: rows[i] for i, name in enumerate(labels)}


def flags_from_codes(codes: Sequence[float]) -> list[str | None]:
    """The ``flag`` row back as the JSON's words.

    Parameters
    ----------
    codes : sequence of float
        The ``flag`` row (:data:`FLAG_CODES`; NaN where the result has no estimate).

    Returns
    -------
    list of str or None
        ``frequency_flags``' words, None where NaN.
    """
    words: Mapping[float, str] = {v: k for k, v in FLAG_CODES.items()}
    return [None if not np.isfinite(c) else words[float(c)] for c in codes]


def topic_token(channel: str) -> str:
    """A channel name as a topic name token: ``~/<token>/frequency_response``.

    Parameters
    ----------
    channel : str
        The channel's name in the config; characters other than letters, digits and ``_`` become ``_``, a
        leading digit gets ``c_``.
    """
    token = re.sub(r"[^A-Za-z0-9_]", "_", channel)
    return token if token and not token[0].isdigit() else f"c_{token}"


def table_dims(table: np.ndarray) -> list[tuple[str, int, int]]:
    """The ``MultiArrayLayout`` dimensions of a table, ``(label, size, stride)``: the rows (label: the curve
    names joined by commas), then the frequencies (label ``frequency``).

    Parameters
    ----------
    table : ndarray
        From :func:`frequency_response_table`.
    """
    rows, n = table.shape
    return [(",".join(CURVES), rows, rows * n), ("frequency", n, n)]
