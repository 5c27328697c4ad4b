"""The samples of several topics of a flight log merged into one time-ordered sequence, block by block, in
memory that does not grow with the log.

A log gives each topic's samples in blocks (:meth:`~gap_validation.logs.base.LogFile.blocks`): a ULog or
DataFlash file is one *stream* of blocks holding all its topics, each CSV file a stream of one topic. The
order is the one a stable sort of all the samples together by their *key* gives, ties broken by the topic's
index and then by logged order, a sample's key being the latest finite stamp of its topic up to it (so every
topic keeps its logged order, and the samples before its first finite stamp come first): what replay did with
the whole series in memory.

:func:`merge_in_time_order` reads the streams a block at a time and hands out every sample no later sample can
precede: those whose key lies below the *frontier*, the smallest last key of the topics that may still have
samples (a topic has none left when its stream ended or, where the reader knows how many it has, when all
came). It reads next from the stream of the topic at the frontier, so the CSV files of a flight are read side
by side. What waits is what lies between the frontier and the blocks' ends.

A topic of a multi-topic stream whose last key lies more than ``lag_s`` (:data:`LAG_S`) behind the latest key
of its stream -- one that has not started yet, has stopped, or pauses -- does not hold the frontier back. The
merge is exact whenever each topic's samples lie in the file no later than the other topics' samples ``lag_s``
after them (PX4 and ArduPilot write each message as it comes, a sample's stamp a few milliseconds before its
writing); a message written more than that late goes out after samples stamped later than it, as a bag's late
message would.
"""
from __future__ import annotations

import math
from typing import Iterable, Iterator, Mapping, Sequence

import numpy as np

__all__ = ["merge_in_time_order", "LAG_S"]

#: How far [s] a topic of a stream may lag behind the stream's latest sample before it no longer holds the
#: others.
LAG_S = 10.0


class _Topic:
    """One topic's samples waiting to go out and what is known of its future."""

    __slots__ = ("keys", "t", "values", "carry", "last", "seen", "count", "group", "done")

    def __init__(self, group: int, count: int | None, width: int):
        self.keys = np.zeros(0)
        self.t = np.zeros(0)
        self.values = np.zeros((0, width))
        self.carry = math.nan            # the latest finite stamp so far (NaN: none yet)
        # the key of its last sample (its next samples' keys are not below it)
        self.last = -math.inf
        self.seen = 0
        self.count = count
        self.group = group
        self.done = count == 0

    def add(self, t: np.ndarray, values: np.ndarray) -> None:
        t = np.asarray(t, dtype=float)
        if not t.size:
            return
        key = np.fmax.accumulate(t)
        if not math.isnan(self.carry):
            key = np.fmax(key, self.carry)
        self.carry = float(key[-1])
        key = np.where(np.isnan(key), -math.inf, key)
        self.last = float(key[-1])
        self.seen += int(t.size)
        if self.count is not None and self.seen >= self.count:
            self.done = True
        if self.t.size:
            self.keys = np.concatenate([self.keys, key])
            self.t = np.concatenate([self.t, t])
            self.values = np.concatenate([self.values, values])
        else:
            self.keys, self.t, self.values = key, t, np.asarray(values, dtype=float)

    def take(self, frontier: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The waiting samples whose key lies below ``frontier`` (they leave the topic)."""
        cut = (
            int(np.searchsorted(self.keys, frontier, side="left")) if frontier < math.inf else self.keys.size
        )
        out = self.keys[:cut], self.t[:cut], self.values[:cut]
        self.keys, self.t, self.values = self.keys[cut:], self.t[cut:], self.values[cut:]
        return out


def merge_in_time_order(
    streams: Sequence[tuple[Sequence[int], Iterable[Mapping[int, tuple[np.ndarray, np.ndarray]]]]],
    widths: Sequence[int],
    counts: Sequence[int | None] | None = None,
    lag_s: float = LAG_S,
) -> Iterator[tuple[np.ndarray, np.ndarray, list[np.ndarray]]]:
    """The samples of every topic of ``streams`` in time order (see the module docstring), a run at a time.

    Parameters
    ----------
    streams : sequence of (topics, blocks)
        Per stream, the indices of its topics (each topic in one stream) and its blocks in logged order, each
        block ``{topic index: (t [s], values)}`` (``values`` one row per sample, ``widths[topic]`` columns).
    widths : sequence of int
        Per topic (by index), the number of value columns.
    counts : sequence of int or None, optional
        Per topic, how many samples it has (None: not known; its stream's end says it has no more).
    lag_s : float
        How far [s] a topic may lag behind the latest sample of its (multi-topic) stream and still hold the
        others back.

    Yields
    ------
    which : numpy.ndarray of int
        Per sample, its topic's index.
    t : numpy.ndarray of float
        Per sample, its stamp (as given, NaN included).
    values : list of numpy.ndarray
        Per topic (by index), its rows of the run in order (empty for a topic without samples in the run).
    """
    n = len(widths)
    counts = list(counts) if counts is not None else [None] * n
    topics: list[_Topic | None] = [None] * n
    members: list[list[int]] = []
    for g, (indices, _) in enumerate(streams):
        members.append(list(indices))
        for k in indices:
            topics[k] = _Topic(g, counts[k], int(widths[k]))
    for k in range(n):
        if topics[k] is None:                      # in no stream: never any sample
            topics[k] = _Topic(-1, 0, int(widths[k]))
    readers = [iter(blocks) for _, blocks in streams]
    finished = [False] * len(streams)

    def holding() -> list[_Topic]:
        """The topics that hold the frontier: samples may come, and they do not lag behind their stream."""
        out = []
        for g, indices in enumerate(members):
            live = [topics[k] for k in indices if not topics[k].done]
            if not live:
                continue
            newest = max(topics[k].last for k in indices)
            out += [topic for topic in live if len(indices) == 1 or not newest - topic.last > lag_s]
        return out

    while True:
        hold = holding()
        frontier = min((topic.last for topic in hold), default=math.inf)
        out = _take(topics, frontier, widths)
        if out is not None:
            yield out
        pending = [g for g in range(len(streams)) if not finished[g]]
        if not pending:
            break
        at = [topic for topic in hold if topic.last == frontier and not finished[topic.group]]
        g = at[0].group if at else pending[0]
        block = next(readers[g], None)
        if block is None:
            finished[g] = True
            for k in members[g]:
                topics[k].done = True
            continue
        for k, (t, values) in block.items():
            topics[k].add(t, values)
    out = _take(topics, math.inf, widths)
    if out is not None:
        yield out


def _take(topics: list[_Topic], frontier: float, widths: Sequence[int]
          ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]] | None:
    """Every waiting sample below ``frontier``, in order (None when there is none)."""
    parts = [topic.take(frontier) for topic in topics]
    total = sum(p[0].size for p in parts)
    if not total:
        return None
    keys = np.concatenate([p[0] for p in parts])
    which = np.concatenate([np.full(p[0].size, k, np.int64) for k, p in enumerate(parts)])
    order = np.argsort(keys, kind="stable")
    t = np.concatenate([p[1] for p in parts])[order]
    return (
        which[order],
        t,
        [p[2] if p[2].size else np.zeros((0, int(widths[k]))) for k, p in enumerate(parts)],
    )
