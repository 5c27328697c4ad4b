"""Replay recorded flights (rosbag2, and flight logs: PX4 ULog, ArduPilot DataFlash, CSV) into the online
validator: the offline front end of the one data path.

Every bag is streamed in batches of records (only the config's topics; :meth:`Bag.record_batches`: an mcap
chunk at a time), each record goes through the one decoding step
(:class:`~gap_validation.messages.decoding.TopicDecoder`, as in the node) and
:class:`~gap_validation.messages.router.MessageRouter` into
:class:`~gap_validation.core.validator.OnlineValidator` -- the same objects the ROS 2 node uses -- and the
result is the validator's :class:`ValidationResult`. Per batch, each topic's records are decoded at once
(``TopicDecoder.decode_batch``: the fields read straight from many records, vectorised) and go to the router
as runs in bag order (``MessageRouter.on_values_batch``, which pushes the same batches at the same messages as
one by one); the records it does not read (the first of every topic while the decoder is verified, odd
records) go one by one, in their place, as before batching. The result is the record-by-record one to the bit.

Several bags add up: sweeps from all of them count. Bags are replayed in order of their start time; when a
bag's clock overlaps the data already replayed (e.g. two simulated flights that both start at the same epoch),
its times are shifted to start :data:`BAG_GAP_S` after the last sample, so the estimator always sees
increasing time.

A bad input never discards what was computed: an unreadable bag, a topic of the wrong type or a damaged record
is reported (one line naming the file and topic) and the other bags, topics and records are still validated.

Flight logs (``.ulg``, ``.bin``, ``.csv``; :mod:`gap_validation.logs`) go the same way from the router on,
streamed as bags are. A log gives the topics and fields the config names (a config topic
``/vehicle_angular_velocity`` is the log's ``vehicle_angular_velocity``, ``/IMU[1]`` its ``IMU[1]``) in blocks
(:meth:`~gap_validation.logs.base.LogFile.blocks`: a ULog per 1 MiB block of the file, a DataFlash log per 1
MiB window of its memory map, a CSV file per 1 MiB of rows); the blocks of all its topics are merged in time
order as they come (:func:`~gap_validation.logs.merge.merge_in_time_order`: the order of a stable sort of all
the samples, each topic keeping its logged order) and pushed through ``MessageRouter.on_values_batch`` as raw
values, a run at a time: the router applies each stream's offset, scale and ``time_offset_s``, as for bags.
Memory holds a block or two of samples, not the flight (``benchmarks/bench_replay_memory.py --format
ulog|dataflash|csv``). The CSV files of one directory are one flight (one file per topic, one clock), read
side by side. A log is ordered among the bags by its first sample (a ULog: its earliest stamp; a DataFlash
log, a CSV flight: the earliest of its first block) and shifted by the same rule. Its logging is checked
(:mod:`gap_validation.logs.checks`, gathered block by block and reported when the log was replayed): a topic
logged too slowly for the channel's band, irregular stamps, values that are not numbers, each a warning with
the fix in words; a topic the log lacks is a warning listing what it has; a field a topic lacks an error
naming both (that stream skipped, the rest validated); a damaged log its ``damage`` line as an error, with
what came before it validated.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from gap_validation.bag.batches import RecordBatch
from gap_validation.bag.reader import BAG_SUFFIXES, Bag, open_bag
from gap_validation.core.config import ValidationConfig
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.fields import FieldError
from gap_validation.core.results import ValidationResult
from gap_validation.core.validator import OnlineValidator
from gap_validation.logs.base import LogBlocks, LogFile, LogSeries, is_log
from gap_validation.logs.checks import StampStats, rate_warning
from gap_validation.logs.formats import open_log
from gap_validation.logs.merge import merge_in_time_order
from gap_validation.messages.decoding import TopicDecoder, Undecodable
from gap_validation.messages.router import MessageRouter, note_saturation, stamp_seconds

log = logging.getLogger(__name__)

__all__ = ["replay", "ReplayOutcome", "BagReport", "BAG_GAP_S", "is_log_source"]

#: Gap inserted between bags whose clocks overlap [s].
BAG_GAP_S = 60.0
#: Router batching for replay: messages per topic and time span [s] per push (well inside the estimator's
#: ``max_lag_s`` of 30 s; larger pushes amortise its per-call cost).
REPLAY_BATCH = 8192
REPLAY_BATCH_S = 10.0
#: Records per batch read from a bag (decoded at once per topic, see ``TopicDecoder.decode_batch``).
REPLAY_RECORDS = 4096

ProgressCallback = Callable[[int, int], None]


@dataclass
class BagReport:
    """What happened to one bag or flight log: messages routed, time shift applied, problems found."""

    path: str
    messages: int = 0
    time_offset_s: float = 0.0
    fast_topics: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """No error with this bag or log."""
        return not self.errors


@dataclass
class ReplayOutcome:
    """Result of a replay: the validation result (None when no bag could be read) and every problem.

    ``errors`` make the CLI exit with status 1 (results, if any, are still printed and written).
    """

    result: ValidationResult | None
    bags: list[BagReport]
    errors: list[str]
    warnings: list[str]
    messages: int
    elapsed_s: float
    validator: OnlineValidator | None = None

    @property
    def ok(self) -> bool:
        """No error: the CLI exits with status 0."""
        return not self.errors


class _TopicState:
    """Per-topic state within one bag: its decoding step, whether it is skipped, damaged records."""

    __slots__ = ("routes", "decoding", "disabled", "damaged", "first_damage")

    def __init__(self, decoding: TopicDecoder):
        self.routes = decoding.routes
        self.decoding = decoding
        self.disabled = False
        self.damaged = 0
        self.first_damage = ""


def _check_topics(bag: Bag, router: MessageRouter, report: BagReport) -> dict[str, _TopicState]:
    """Topics to read from ``bag``: warn per missing topic, error on type mismatches, DataError if none."""
    info = bag.topics
    wanted = router.topics
    present = {}
    for topic in wanted:
        routes = router.routes[topic]
        feeds = ", ".join(f"{r.channel}.{r.stream}" for r in routes)
        if topic not in info:
            report.warnings.append(f"{bag.path}: topic {topic} ({feeds}) is not in the bag "
                                   f"(it has: {', '.join(sorted(info)) or 'none'})")
            continue
        msgtype = info[topic].msgtype
        expected = {r.spec.type for r in routes if r.spec is not None and r.spec.type}
        if msgtype is None:
            report.errors.append(f"{bag.path}: topic {topic} has several message types; skipped")
            continue
        if expected and msgtype not in expected:
            report.errors.append(f"{bag.path}: topic {topic} has type {msgtype}, the config expects "
                                 f"{', '.join(sorted(expected))}")
            continue
        try:
            bag.ensure_type(msgtype)
        # every record would fail: one line for the topic, not per record
        except DataError as err:
            report.errors.append(f"{_after_path(str(err), bag)} (topic {topic}, {feeds}); topic skipped")
            continue
        if info[topic].count == 0:
            report.warnings.append(f"{bag.path}: topic {topic} ({feeds}) has no messages")
        present[topic] = msgtype
    if not present and not report.errors:
        have = ", ".join(sorted(info)) or "none"
        raise DataError(f"{bag.path}: none of the configured topics ({', '.join(wanted)}) is in the bag "
                        f"(it has: {have})")
    return present


def _set_time_offset(router: MessageRouter, report: BagReport, t_s: float) -> None:
    """Shift the times of a new bag or log whose first sample is at ``t_s`` to start :data:`BAG_GAP_S` after
    the data already replayed when its clock overlaps them (else no shift)."""
    latest = router.latest_time_s()
    offset = 0.0
    if math.isfinite(latest) and t_s < latest + BAG_GAP_S:
        offset = latest + BAG_GAP_S - t_s
    router.time_offset_s = offset
    report.time_offset_s = offset


def _after_path(text: str, bag: Bag) -> str:
    """``text`` with exactly one ``<bag>: `` prefix."""
    prefix = f"{bag.path}: "
    return text if text.startswith(prefix) else prefix + text


def _after_topic(text: str, topic: str) -> str:
    """``text`` without its ``<bag>: topic <topic>: `` prefix (the report line names both already)."""
    marker = f"topic {topic}: "
    return text.split(marker, 1)[1] if marker in text else text


#: ``on_tick(t_ns, validator, router)``: bag time [ns], the validator, its router (flushed).
TickCallback = Callable[[int, OnlineValidator, MessageRouter], None]
#: Records per batch when ticks are asked for (about 0.3 s of a 200 Hz IMU and 100 Hz surfaces).
TICK_RECORDS = 64


class _Ticks:
    """``on_tick`` every ``tick_s`` of bag time from the first record on, and at the end."""

    def __init__(
        self, on_tick: TickCallback, tick_s: float, validator: OnlineValidator, router: MessageRouter
    ):
        self.on_tick, self.validator, self.router = on_tick, validator, router
        self.period_ns = max(1, int(round(float(tick_s) * 1e9)))
        self.next_ns: int | None = None
        self.last_ns: int | None = None

    def reached(self, t_ns: int) -> None:
        """Records up to bag time ``t_ns`` were routed: the ticks due."""
        if self.next_ns is None:
            self.next_ns = t_ns + self.period_ns
        self.last_ns = t_ns if self.last_ns is None else max(self.last_ns, t_ns)
        while self.next_ns <= t_ns:
            self.router.flush()
            self.on_tick(self.next_ns, self.validator, self.router)
            self.next_ns += self.period_ns

    def end(self) -> None:
        """The data ended (the last manoeuvre closed): one last tick at the last record's time."""
        if self.last_ns is not None:
            self.on_tick(self.last_ns, self.validator, self.router)


class _BagReplay:
    """Streams one bag into the router."""

    def __init__(self, bag: Bag, router: MessageRouter, report: BagReport, fast: bool,
                 progress: Callable[[int], None], ticks: "_Ticks | None" = None):
        self.ticks = ticks
        self.bag = bag
        self.router = router
        self.report = report
        self.fast = fast
        self.progress = progress
        self.states: dict[str, _TopicState] = {}
        self.offset_set = False

    def run(self) -> None:
        present = _check_topics(self.bag, self.router, self.report)
        for topic, msgtype in present.items():
            deserialize = partial(self.bag.deserialize, msgtype=msgtype, topic=topic)
            self.states[topic] = _TopicState(
                TopicDecoder(
                    self.router,
                    topic,
                    msgtype,
                    deserialize,
                    fast=self.fast,
                    errors=(DataError,),
                    on_disagree=_disagree,
                )
            )
        count = 0
        try:
            size = REPLAY_RECORDS if self.ticks is None else TICK_RECORDS
            for batch in self.bag.record_batches(list(present), size):
                count += len(batch)
                self._route_batch(batch)
                self.progress(len(batch))
                if self.ticks is not None and len(batch):
                    self.ticks.reached(int(batch.t_ns[-1]))
        finally:
            self.report.messages = count
            for topic, state in self.states.items():
                if state.damaged:
                    self.report.errors.append(f"{self.bag.path}: topic {topic}: {state.damaged} damaged "
                                              f"record(s) skipped (first: {state.first_damage})")
            self.report.fast_topics = sorted(t for t, s in self.states.items()
                                             if s.decoding.decoder is not None and not s.disabled)

    def _route_batch(self, batch: RecordBatch) -> None:
        """Route a batch in bag order: the records each topic's decoding step reads at once go to the router
        as runs (``on_values_batch``); every other record, one by one through :meth:`_route` (as before
        batching)."""
        states = [self.states[topic] for topic in batch.topics]
        n = len(batch)
        t_bag = batch.t_ns.astype(np.float64) * 1e-9
        t_s = t_bag.copy()
        fast = np.zeros(n, dtype=bool)
        rows = np.zeros(n, dtype=np.int64)                 # row of each record in its topic's values
        values = []
        for k, state in enumerate(states):
            index = np.flatnonzero(batch.which == k)
            if state.disabled:                              # skipped: none of its records is routed
                values.append(np.zeros((0, len(state.routes))))
                continue
            stamps, got, ok = state.decoding.decode_batch(batch.records.take(index))
            fast[index] = ok
            t_s[index] = np.where(np.isnan(stamps), t_bag[index], stamps)
            rows[index] = np.arange(index.size)
            values.append(got)
        start = 0
        for i in [*np.flatnonzero(~fast).tolist(), n]:
            if i > start:
                self._route_run(batch, states, slice(start, i), t_s, rows, values)
            if i < n:
                state = states[batch.which[i]]
                if not state.disabled:
                    self._route(batch.topics[batch.which[i]], state, float(t_bag[i]), batch.records.raw(i))
            start = i + 1

    def _route_run(self, batch: RecordBatch, states: list[_TopicState], run: slice, t_s: np.ndarray,
                   rows: np.ndarray, values: list[np.ndarray]) -> None:
        """Fast-decoded records ``run`` of a batch to the router (those of skipped topics left out)."""
        which, t, rows = batch.which[run], t_s[run], rows[run]
        skipped = [k for k, state in enumerate(states) if state.disabled]
        if skipped:
            keep = ~np.isin(which, skipped)
            which, t, rows = which[keep], t[keep], rows[keep]
        if not t.size:
            return
        if not self.offset_set:
            self._set_offset(float(t[0]))
        self.router.on_values_batch(
            batch.topics, which, t, [v[rows[which == k]] for k, v in enumerate(values)]
        )

    def _set_offset(self, t_s: float) -> None:
        _set_time_offset(self.router, self.report, t_s)
        self.offset_set = True

    def _route(self, topic: str, state: _TopicState, bag_time_s: float, raw: Any) -> None:
        try:
            stamp, values, msg = state.decoding.decode(raw)
        except Undecodable as err:  # a damaged record (counted): note it, keep reading the bag
            state.damaged += 1
            state.first_damage = state.first_damage or _after_topic(str(err.error), topic)
            return
        if msg is None:
            t_s = bag_time_s if stamp is None else stamp
            if not self.offset_set:
                self._set_offset(t_s)
            self.router.on_values(topic, t_s, values)
            return
        if not self.offset_set:
            stamp = stamp_seconds(msg)
            self._set_offset(bag_time_s if stamp is None else stamp)
        try:
            self.router.on_message(topic, msg, bag_time_s)
        except FieldError as err:                # one signal skipped; the topic's other signals still count
            feeds = [(r.channel, r.stream) for r in state.routes]
            broken = [f"{c}.{s}" for c, s in feeds if (c, s) in self.router.broken]
            state.disabled = len(broken) == len(feeds)
            which = next((b for b, key in zip(broken, [k for k in feeds if k in self.router.broken])
                          if self.router.broken[key] == str(err)), broken[-1])
            self.report.errors.append(f"{self.bag.path}: {err}; {which} skipped")


def _disagree(topic: str) -> None:
    log.debug("fast decoder of %s disagrees with rosbags; decoding fully", topic)


def is_log_source(path: str | Path) -> bool:
    """Whether replay reads ``path`` as a flight log: a ``.ulg``, ``.bin`` or ``.csv`` file, or a directory of
    CSV files (one per topic) without a rosbag2 ``metadata.yaml`` or storage file.

    Parameters
    ----------
    path : str or Path
        A path given to replay.
    """
    p = Path(path)
    if p.is_dir():
        return (not (p / "metadata.yaml").exists() and any(p.glob("*.csv"))
                and not any(q.suffix in BAG_SUFFIXES for q in p.iterdir()))
    return is_log(p)


def _sources(paths: Sequence[str | Path]) -> list[tuple[str, Path | list[Path]]]:
    """``(label, bag path or log files)`` per flight, in the order given: the CSV files of one directory
    (given one by one or as the directory) are one flight."""
    out: list[tuple[str, Path | list[Path]]] = []
    csv_groups: dict[Path, list[Path]] = {}
    for path in map(Path, paths):
        if not is_log_source(path):
            out.append((str(path), path))
        elif path.is_dir() or path.suffix.lower() == ".csv":
            key = (path if path.is_dir() else path.parent).resolve()
            files = sorted(path.glob("*.csv")) if path.is_dir() else [path]
            if key not in csv_groups:
                csv_groups[key] = []
                out.append((str(path if path.is_dir() else path), csv_groups[key]))
            csv_groups[key].extend(f for f in files if f not in csv_groups[key])
        else:
            out.append((str(path), [path]))
    return [(label if not isinstance(item, list) or len(item) < 2 or Path(label).is_dir() else
             str(Path(label).parent), item) for label, item in out]


class _BagSource:
    """A bag to replay: its start time, message count and :class:`_BagReplay`."""

    def __init__(self, bag: Bag, report: BagReport):
        self.bag, self.report = bag, report
        self.start_time_s = bag.start_time_s
        self.sources = [str(bag.path)]

    def count(self, topics: Sequence[str]) -> int:
        return self.bag.message_count(topics)

    def run(
        self, router: MessageRouter, fast: bool, progress: Callable[[int], None], ticks: "_Ticks | None"
    ) -> None:
        _BagReplay(self.bag, router, self.report, fast, progress, ticks).run()

    def close(self) -> None:
        self.bag.close()


#: Log samples pushed to the router per call (several topics interleaved).
LOG_CHUNK = 65536


class _LogTopic:
    """A config topic read from a log: its routes, the column of its series each route reads (-1: the topic
    lacks the field, NaN), its logging checks gathered block by block; ``samples`` as the reader knows them
    (None: known once read; the merge takes only these), ``count`` for the progress (the topic table's where
    the reader does not know: a CSV file's lines)."""

    __slots__ = ("name", "log", "routes", "columns", "stamps", "not_finite", "samples", "count")

    def __init__(self, name: str, log: LogFile, routes, fields: tuple[str, ...], samples: int | None):
        self.name, self.log, self.routes, self.samples = name, log, routes, samples
        self.count = samples if samples is not None else log.topics[name].count if name in log.topics else 0
        self.columns = [fields.index(r.spec.field) if r.spec.field in fields else -1 for r in routes]
        self.stamps = StampStats()
        self.not_finite = np.zeros(len(routes), np.int64)

    def take(self, series: LogSeries) -> tuple[np.ndarray, np.ndarray]:
        """A block's samples as ``(t [s], raw values, one column per route)``, counted for the checks."""
        values = np.full((series.t_s.size, len(self.routes)), np.nan)
        for j, col in enumerate(self.columns):
            if col >= 0:
                values[:, j] = series.values[:, col]
        t = np.asarray(series.t_s, dtype=float)
        self.stamps.add(t)
        self.not_finite += np.count_nonzero(~np.isfinite(values), axis=0)
        return t, values


class _LogFlight:
    """One flight from log files (a ``.ulg``, a ``.bin``, or the CSV files of one directory): the config's
    topics and fields checked at :meth:`load` (each log opened for its blocks, :meth:`LogFile.blocks`), then
    streamed by
    :meth:`run`: block by block, merged in time order (:func:`~gap_validation.logs.merge.merge_in_time_order`)
    into the router, the logging checks gathered on the way and reported at the end.

    ``skipped`` holds the ``(channel, stream)`` whose field a topic lacks: their column is NaN (the router
    counts those samples as not finite), the error names file, topic, field and the fields it has.
    """

    def __init__(self, paths: list[Path], router: MessageRouter, config: ValidationConfig, report: BagReport):
        self.paths, self.router, self.config, self.report = paths, router, config, report
        self.logs: list[LogFile] = []
        self.topics: list[_LogTopic] = []                               # in the merge's order
        self.streams: list[tuple[LogBlocks, list[int]]] = []             # blocks and their topics' indices
        self.skipped: set[tuple[str, str]] = set()
        self.sources: list[str] = []
        self.start_time_s = math.inf
        self._damaged: set[int] = set()                                 # logs whose damage was reported

    def count(self, topics: Sequence[str]) -> int:
        return sum(t.count or 0 for t in self.topics if "/" + t.name in topics)

    def close(self) -> None:
        """Close the log files."""
        self.streams = []
        for log in self.logs:
            log.close()

    def _open(self, path: Path) -> LogFile:
        """The log file; a CSV file with the ``time_column`` its topic's streams name."""
        if path.suffix.lower() != ".csv":
            return open_log(path)
        from gap_validation.logs.csvlog import CsvFile

        routes = self.router.routes.get("/" + path.stem, ())
        columns = {r.spec.time_column for r in routes if r.spec is not None and r.spec.time_column}
        if len(columns) > 1:
            raise ConfigError(
                f"{self.config.source}: the streams of topic /{path.stem} name different time_column "
                f"({', '.join(sorted(columns))}): a CSV file has one time column"
            )
        return CsvFile(path, time_column=columns.pop() if columns else None)

    def load(self) -> "_LogFlight":
        """Open every file and its blocks of the config's topics and fields, check them (warnings and errors
        in the report; the logging checks come with :meth:`run`).

        Raises
        ------
        DataError
            None of the configured topics is in the log(s) (and nothing else went wrong first).
        """
        try:
            return self._load()
        except BaseException:
            self.close()
            raise

    def _load(self) -> "_LogFlight":
        for path in self.paths:
            try:
                self.logs.append(self._open(path))
            except DataError as err:
                self.report.errors.append(str(err))
        logs = self.logs
        asked = {}                                   # log topic -> every field the config reads from it
        for topic, routes in self.router.routes.items():
            asked[topic[1:] if topic.startswith("/") else topic] = list(
                dict.fromkeys(r.spec.field for r in routes)
            )
        first = {id(log): self._first_blocks(log, asked) for log in logs}
        have = {}
        for log in logs:
            for name, info in log.topics.items():
                have.setdefault(name, (log, info))
        wanted: dict[int, dict[str, list[str]]] = {}
        for topic, routes in self.router.routes.items():
            name = topic[1:] if topic.startswith("/") else topic
            feeds = ", ".join(f"{r.channel}.{r.stream}" for r in routes)
            if name not in have and name.endswith(":0") and name[:-2] in have:
                have[name] = have[name[:-2]]          # ULog instance 0 is the plain name (pyulog's naming)
            if name not in have:
                if logs:
                    self.report.warnings.append(
                        f"{self._label()}: topic {name} ({feeds}) is not in the log (it has: "
                        f"{', '.join(sorted(have)) or 'none'})")
                continue
            log, info = have[name]
            fields = wanted.setdefault(id(log), {}).setdefault(name, [])
            for r in routes:
                if r.spec.field in info.fields:
                    if r.spec.field not in fields:
                        fields.append(r.spec.field)
                else:
                    self.skipped.add((r.channel, r.stream))
                    self.report.errors.append(
                        f"{log.missing_field(name, r.spec.field)}; {r.channel}.{r.stream} skipped"
                    )
        if logs and not wanted and not self.report.errors:
            raise DataError(
                f"{self._label()}: none of the configured topics "
                f"({', '.join(t.lstrip('/') for t in self.router.topics)}) is in the log (it has: "
                f"{', '.join(sorted(have)) or 'none'})"
            )
        for log in logs:
            if id(log) in wanted:
                self._open_blocks(log, wanted[id(log)], first[id(log)])
        return self

    @staticmethod
    def _first_blocks(log: LogFile, asked: dict[str, list[str]]) -> LogBlocks | None:
        """The blocks of every field the config asks of ``log`` (one pass over a ULog gives its topics too),
        or None when that fails (a field a topic lacks: then the fields are checked one by one and asked
        again)."""
        try:
            return log.blocks(asked)
        except DataError:
            return None

    def _label(self) -> str:
        return self.report.path

    def _open_blocks(
        self, log: LogFile, wanted: dict[str, list[str]], blocks: LogBlocks | None = None
    ) -> None:
        """The blocks of ``wanted`` from one log (``blocks``: what the first ask gave already), its topics
        added to the merge; its damage, when known already, an error."""
        try:
            if blocks is None:
                blocks = log.blocks({name: fields for name, fields in wanted.items() if fields})
        except DataError as err:
            self.report.errors.append(str(err))
            return
        finally:
            self._note_damage(log)
        self.sources.append(str(log.path))
        indices = []
        for name in blocks.topics:
            if name not in wanted:
                continue
            indices.append(len(self.topics))
            self.topics.append(_LogTopic(name, log, self.router.routes["/" + name], blocks.fields[name],
                                         blocks.counts.get(name)))
        if indices:
            self.streams.append((blocks, indices))
            self.start_time_s = min(self.start_time_s, blocks.start_time_s)

    def _note_damage(self, log: LogFile) -> None:
        if log.damage and id(log) not in self._damaged:
            self._damaged.add(id(log))
            self.report.errors.append(log.damage)

    def _checks(self, topic: _LogTopic) -> list[str]:
        """The logging checks of one topic: its rate against the band of the channels it feeds, its stamps,
        its values that are not numbers."""
        out = []
        log, name, routes = topic.log, topic.name, topic.routes
        where = f"{log.path}: topic {name}"
        stamps = topic.stamps.result()
        irregular = stamps.warning(where)
        if irregular:
            out.append(irregular)
        banded = [r for r in routes if r.stream not in ("trigger", "airspeed") and (r.channel, r.stream)
                  not in self.skipped]
        if banded and stamps.samples > 1:
            top = max(self.config.channels[r.channel].frequencies.max_rad_s for r in banded)
            feeds = ", ".join(f"{r.channel}.{r.stream}" for r in banded)
            slow = rate_warning(log.format, name, stamps.rate_hz, top, feeds)
            if slow:
                out.append(f"{log.path}: {slow}")
        for j, r in enumerate(routes):
            bad = int(topic.not_finite[j]) if (r.channel, r.stream) not in self.skipped else 0
            if bad:
                out.append(
                    f"{where}: {bad} of {stamps.samples} values of {r.spec.field} are not numbers (counted "
                    "as "
                    f"bad samples of {r.channel}.{r.stream})"
                )
        return out

    def _stream(
        self, blocks: LogBlocks, indices: list[int]
    ) -> Iterator[dict[int, tuple[np.ndarray, np.ndarray]]]:
        """A log's blocks as the merge takes them: topic index -> (t, raw values per route)."""
        mine = [(k, self.topics[k]) for k in indices]
        for block in blocks:
            yield {k: topic.take(block[topic.name]) for k, topic in mine if topic.name in block}

    def run(
        self, router: MessageRouter, fast: bool, progress: Callable[[int], None], ticks: "_Ticks | None"
    ) -> None:
        """Route every topic's samples in time order (each topic in its logged order) through
        ``on_values_batch``, block by block, the time shift set by the first sample; then the logging checks
        and a damage found on the way."""
        if not self.topics:
            return
        names = ["/" + t.name for t in self.topics]
        _set_time_offset(router, self.report, self.start_time_s if math.isfinite(self.start_time_s) else 0.0)
        chunk = LOG_CHUNK if ticks is None else TICK_RECORDS
        streams = [(indices, self._stream(blocks, indices)) for blocks, indices in self.streams]
        try:
            for which, t_all, values in merge_in_time_order(streams, [len(t.routes) for t in self.topics],
                                                            [t.samples for t in self.topics]):
                done = np.zeros(len(names), np.int64)
                for start in range(0, t_all.size, chunk):
                    part = which[start:start + chunk]
                    counts = np.bincount(part, minlength=len(names))
                    router.on_values_batch(names, part, t_all[start:start + chunk],
                                           [v[done[k]:done[k] + counts[k]] for k, v in enumerate(values)])
                    done += counts
                    self.report.messages += int(part.size)
                    progress(int(part.size))
                    if ticks is not None:
                        last = t_all[start:start + chunk]
                        last = last[np.isfinite(last)]
                        if last.size:
                            ticks.reached(int(round(float(last.max()) * 1e9)))
        finally:
            for topic in self.topics:
                self.report.warnings.extend(self._checks(topic))
            for log in self.logs:
                self._note_damage(log)


def _open_all(paths: Sequence[str | Path], reports: list[BagReport], router: MessageRouter,
              config: ValidationConfig) -> list["_BagSource | _LogFlight"]:
    """Every bag and log opened (logs read), ordered by start time; a file that cannot be opened is an error
    of its report."""
    opened: list[_BagSource | _LogFlight] = []
    for label, item in _sources(paths):
        report = BagReport(label)
        reports.append(report)
        try:
            if isinstance(item, list):
                opened.append(_LogFlight(item, router, config, report).load())
            else:
                opened.append(_BagSource(open_bag(item), report))
        except DataError as err:
            report.errors.append(str(err))
    opened.sort(key=lambda source: source.start_time_s)
    return opened


def _channel_checks(config: ValidationConfig, router: MessageRouter,
                    reported: set[tuple[str, str]] = frozenset()) -> tuple[list[str], list[str]]:
    """Errors for streams without a usable sample: those that received messages none of which could be used,
    and those with no data at all (a requested channel whose topic is missing or silent: the others are still
    validated and written, the exit status is 1). Streams in ``reported`` (a log topic lacks their field) have
    their own error already."""
    errors, warnings = [], []
    for name, channel in config.channels.items():
        for stream in (
            *channel.input_streams,
            *channel.output_streams,
            *(extra for extra, _ in channel.extra_streams()),
        ):
            spec = channel.signal(stream)
            if router.samples(name, stream) or (name, stream) in reported:
                continue
            bad = router.bad.get((name, stream), {})
            where = f"channel {name}: {stream} {spec.topic} {spec.field!r}"
            if bad:
                first = router.first_error.get((name, stream))
                reasons = ", ".join(f"{n} {reason}" for reason, n in sorted(bad.items()))
                errors.append(f"{where}: no usable sample ({reasons})" + (f": {first}" if first else ""))
            else:
                errors.append(
                    f"{where}: no samples (topic missing from the data or silent): channel not validated"
                )
    if not any(all(router.samples(name, stream) for stream in ch.input_streams + ch.output_streams)
               for name, ch in config.channels.items()):
        errors.append("no channel has both input and output samples in the data: nothing to validate "
                      "(check the config's topics and fields against the bag)")
    return errors, warnings


def replay(bags: Sequence[str | Path], config: ValidationConfig, *, progress: ProgressCallback | None = None,
           fast: bool = True, validator: OnlineValidator | None = None, diagnose: bool = True,
           on_tick: TickCallback | None = None, tick_s: float = 1.0) -> ReplayOutcome:
    """Validate the config's models against recorded flights.

    Parameters
    ----------
    bags : sequence of path
        rosbag2 directories, ``.mcap`` or ``.db3`` files, and flight logs: ``.ulg``, ``.bin``, ``.csv`` files
        or a directory of CSV files (the CSV files of one directory are one flight); sweeps from all of them
        count.
    config : ValidationConfig
        Channels, models, topics and fields.
    progress : callable, optional
        ``progress(done, total)`` in messages of the configured topics, called every few thousand messages.
    fast : bool
        Use the fast CDR field decoders where they apply (verified against full deserialisation).
    validator : OnlineValidator, optional
        Continue an existing validator (default: a new one for ``config``).
    diagnose : bool
        Let the new validator run the diagnosis (effect fitting) in its results.
    on_tick : callable, optional
        ``on_tick(t_ns, validator, router)`` every ``tick_s`` of bag time, the router flushed up to there (the
        records are then read in small batches: the tick comes at most :data:`TICK_RECORDS` records late), and
        once more at the end of the last bag after the last manoeuvre closed: what a node would have seen at
        each moment (``--annotate``).
    tick_s : float
        Period of ``on_tick`` [s] of bag time.

    Returns
    -------
    ReplayOutcome
        The validation result and every error and warning (one line each).

    Raises
    ------
    DataError
        When no bag or log could be read at all (the message names the first problem).
    """
    start = time.perf_counter()
    validator = validator or OnlineValidator(config, diagnose=diagnose)
    router = MessageRouter(config, validator, batch=REPLAY_BATCH, max_batch_s=REPLAY_BATCH_S)
    reports: list[BagReport] = []
    opened = _open_all(bags, reports, router, config)
    total = sum(source.count(router.topics) for source in opened)
    done = [0]

    def advance(n: int) -> None:
        done[0] += n
        if progress is not None and n:
            progress(min(done[0], total), total)

    ticks = _Ticks(on_tick, tick_s, validator, router) if on_tick is not None else None
    for source in opened:
        try:
            source.run(router, fast, advance, ticks)
            if source.report.messages:
                validator.sources.extend(source.sources)
        except DataError as err:
            source.report.errors.append(str(err))
        finally:
            source.close()
        router.flush()
    errors = [e for r in reports for e in r.errors]
    warnings = [w for r in reports for w in r.warnings]
    read = [r for r in reports if r.messages]
    if not read:
        raise DataError(errors[0] + (f" (and {len(errors) - 1} more problems)" if len(errors) > 1 else "")
                        if errors else "no messages of the configured topics in " + ", ".join(map(str, bags)))
    router.flush()
    validator.finish()
    if ticks is not None:
        ticks.end()
    skipped = {key for source in opened if isinstance(source, _LogFlight) for key in source.skipped}
    channel_errors, channel_warnings = _channel_checks(config, router, skipped)
    errors += channel_errors
    warnings += channel_warnings
    result = validator.results()
    warnings += note_saturation(config, router, result)
    result.sources = [r.path for r in read]
    result.notes = list(result.notes) + [f"error: {e}" for e in errors] + [f"warning: {w}" for w in warnings]
    return ReplayOutcome(result=result, bags=reports, errors=errors, warnings=warnings,
                         messages=sum(r.messages for r in reports), elapsed_s=time.perf_counter() - start,
                         validator=validator)
