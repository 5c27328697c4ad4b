"""Manoeuvre tracking: the grid's samples turned into records, the records into the manoeuvres flown.

:class:`ManoeuvreTracker` holds everything between a grid sample and a manoeuvre ready to estimate:

- the **excited stretches**: the sweep detectors (:mod:`gap_validation.core.sweeps`) see the excitation signal
  at once, everything else sees the grid samples ``lookahead_samples`` later through a delay line, when it is
  known whether they are excited; an explicit trigger's edges replace detection (trigger mode);
- the **record in progress** (:class:`_RecordBuffer`): an excited stretch with ``pre_s`` of trim before it and
  ``post_s`` after it, at most ``max_record_s``;
- the **trim between the records**, fed to the :class:`~gap_validation.core.background.TrimSpectrum` it was
  given; closed records wait for :data:`TRIM_KNOWN_S` of it (at most :data:`PENDING_RECORDS`), because what
  counts as excited, and as a manoeuvre at all, is judged against it;
- the **manoeuvres**: each record split into the manoeuvres flown
  (:func:`~gap_validation.core.records.split_record`), classified, counted per kind, the short ones offered to
  the time-domain recorder (:class:`~gap_validation.core.manoeuvres.ManoeuvreRecorder`), those that give a
  response handed to the :class:`~gap_validation.core.accumulation.RecordAccumulator` it was given.
"""
from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from typing import Any, Callable

import numpy as np

from gap_validation.core.accumulation import RecordAccumulator
from gap_validation.core.alignment import NO_INDEX
from gap_validation.core.background import TrimSpectrum
from gap_validation.core.condition import DynamicPressureScaling
from gap_validation.core.manoeuvres import Manoeuvre, ManoeuvreRecorder
from gap_validation.core.records import (
    KINDS,
    MIN_ACTIVE_S,
    RESPONSE_KINDS,
    SATURATED_SHARE,
    Piece,
    classify,
    period,
    saturated_share,
    split_record,
    trim_noise,
)
from gap_validation.core.sweeps import DETECTOR_DEFAULTS, SweepDetector, TriggerTracker

__all__ = ["ManoeuvreTracker", "trim_motion", "LOOKBACK_S", "TRIM_KNOWN_S", "PENDING_RECORDS", "SPANS_KEPT"]

_EVENT_CAP = 64                  # pending edges
_ENERGY, _TRIGGER = 0, 1         # source of a record
#: How far before the detector's start a record reaches back (to the end of the previous record at most) [s]:
#: a sweep that starts slowly is seen late, and the record must begin at trim.
LOOKBACK_S = 10.0
#: A record is judged against the trim motion between the records (:mod:`gap_validation.core.background`):
#: until this much trim was transformed [s], closed records wait (at most :data:`PENDING_RECORDS` of them; at
#: a break in the data or at its end they are judged with what is known then).
TRIM_KNOWN_S = 20.0
PENDING_RECORDS = 8
#: Manoeuvres up to this long are offered to the time-domain recorder (doublets, pulses, multisteps) [s].
_SHORT_MANOEUVRE_S = 20.0
#: Manoeuvre spans kept for :attr:`ManoeuvreTracker.spans`.
SPANS_KEPT = 256


def trim_motion(trim: TrimSpectrum, stream: int) -> float:
    """Standard deviation of a stream's trim motion between the records measured so far (0 before any).

    :meth:`TrimSpectrum.std <gap_validation.core.background.TrimSpectrum.std>`: a pilot's corrections, a
    damper answering turbulence. Splitting and classifying widen the band about trim by it
    (:func:`~gap_validation.core.records.trim_tolerance`).

    Parameters
    ----------
    trim : TrimSpectrum
        The trim motion between the records.
    stream : int
        Stream index.

    Returns
    -------
    float
        The standard deviation [stream units].
    """
    between = trim.std(stream)
    return between if math.isfinite(between) else 0.0


# ---------------------------------------------------------------------------------------------- records
class _RecordBuffer:
    """Grid samples of the manoeuvre in progress, with the trim before it (constant size).

    ``start(k)`` opens a record ``lookback_n`` samples before ``k`` (from a ring of the latest samples, at
    most back to the end of the previous record): the detector sees a slowly starting sweep late, and the
    record must begin at trim (the splitter measures the trim there and keeps ``pre_n`` of it). ``stop(k)``
    marks the end of the excitation; the record closes ``post_n`` samples after it once ``post_n + pre_n``
    samples passed without a new start (energy detection merges nearby excitations: the record is split into
    manoeuvres afterwards), at once when a trigger starts again (trigger records never merge), when it reaches
    ``cap`` samples, or at the end of a run. :meth:`feed` returns the closed records as ``(k0, samples, src,
    act0, act1)``: first grid index, samples (streams x n), source, and the excited span (relative indices)
    the edges gave. A full buffer calls ``on_full(k0, samples, src, act0)``, which processes what is complete
    and returns how many leading samples it took; the record goes on with the rest.
    """

    def __init__(self, n_streams: int, pre_n: int, post_n: int, cap: int,
                 on_full: Callable[[int, np.ndarray, int, int], int], lookback_n: int = 0) -> None:
        self.n, self.pre_n, self.post_n, self.cap = n_streams, pre_n, post_n, cap
        self.lookback_n = max(lookback_n, pre_n)
        self.last_end_k = NO_INDEX
        self.closed_span: tuple[int, np.ndarray] | None = None    # (k0, samples) of the last record closed
        self.on_full = on_full
        self.ring = np.zeros((n_streams, 0))
        self.ring_k = 0
        self.buf = np.zeros((n_streams, cap))
        self.buf_n = 0
        self.k0 = 0
        self.open = False
        self.src = _ENERGY
        self.on_k = NO_INDEX
        self.off_k = NO_INDEX

    @property
    def next_k(self) -> int:
        """Grid index of the next sample the open record expects."""
        return self.k0 + self.buf_n

    def start(self, k: int, src: int) -> list:
        """An excitation starts at ``k`` (edges are applied in time order, before the sample at ``k``)."""
        closed = []
        if self.open and self.off_k != NO_INDEX and (src == _TRIGGER or self.src == _TRIGGER):
            end = max(self.off_k, min(self.off_k + self.post_n, (self.off_k + k) // 2))
            closed.append(self._close(end))
        if self.open:
            self.off_k = NO_INDEX
            return closed
        ring_end = self.ring_k + self.ring.shape[1] if self.ring.shape[1] else k
        back = self.pre_n if src == _TRIGGER else self.lookback_n     # a trigger dates its start exactly
        lo = min(max(k - back, self.ring_k, self.last_end_k), ring_end)
        seg = self.ring[:, max(0, lo - self.ring_k):]
        self.buf[:, : seg.shape[1]] = seg
        self.buf_n, self.k0 = seg.shape[1], ring_end - seg.shape[1]
        self.open, self.src, self.on_k, self.off_k = True, src, k, NO_INDEX
        return closed

    def stop(self, k: int) -> None:
        """The excitation ends at ``k``."""
        if self.open:
            self.off_k = max(k, self.k0)

    def feed(self, k_a: int, block: np.ndarray) -> list:
        """Contiguous released samples (streams x n) from grid index ``k_a``; returns the records closed."""
        closed = []
        # not contiguous (never expected): close what there is
        if self.open and k_a != self.next_k:
            closed.append(self._close(self.next_k))
        pos, n = 0, block.shape[1]
        while pos < n:
            if not self.open:
                break
            k = k_a + pos
            limit = n - pos
            if self.off_k != NO_INDEX:
                limit = min(limit, self.off_k + self.post_n + self.pre_n - k)
            limit = min(limit, self.cap - self.buf_n)
            if limit > 0:
                self.buf[:, self.buf_n:self.buf_n + limit] = block[:, pos:pos + limit]
                self.buf_n += limit
                pos += limit
            if self.off_k != NO_INDEX and self.next_k >= self.off_k + self.post_n + self.pre_n:
                closed.append(self._close(self.off_k + self.post_n))
            elif self.buf_n >= self.cap:  # full (max_record_s): the owner takes what it can
                self._drop(
                    self.on_full(self.k0, self.buf[:, : self.buf_n], self.src, max(0, self.on_k - self.k0))
                )
        self._remember(k_a, block)
        return closed

    def _remember(self, k_a: int, block: np.ndarray) -> None:
        """Keep the latest ``pre_n`` samples (the trim before the next record)."""
        if self.ring.shape[1] and k_a != self.ring_k + self.ring.shape[1]:
            self.ring = self.ring[:, :0]
        if self.ring.shape[1] == 0:
            self.ring_k = k_a
        ring = np.concatenate((self.ring, block), axis=1)
        drop = max(0, ring.shape[1] - self.lookback_n)
        self.ring, self.ring_k = ring[:, drop:].copy(), self.ring_k + drop

    def _drop(self, n: int) -> None:
        """Forget the first ``n`` samples of the open record (the owner processed them); go on with the
        rest."""
        n = max(1, min(int(n), self.buf_n))
        rest = self.buf_n - n
        self.buf[:, :rest] = self.buf[:, n:self.buf_n]
        self.buf_n, self.k0 = rest, self.k0 + n
        self.on_k = max(self.on_k, self.k0)

    def end_run(self) -> list:
        """The data break: the open record closes with what it has (``post_n`` after the excitation's end at
        most); the ring is forgotten."""
        end = self.next_k if self.off_k == NO_INDEX else min(self.next_k, self.off_k + self.post_n)
        closed = [self._close(end)] if self.open and self.buf_n else []
        self.open = False
        self.buf_n = 0
        self.ring = self.ring[:, :0]
        return closed

    def _close(self, end_k: int) -> tuple:
        n = max(0, min(self.buf_n, end_k - self.k0))
        act0 = max(0, self.on_k - self.k0)
        act1 = n if self.off_k == NO_INDEX else max(act0, min(n, self.off_k - self.k0))
        out = (self.k0, self.buf[:, :n].copy(), self.src, act0, act1)
        # every sample fed so far, the ones after the record's end included (the pre_n of quiet that closed
        # it, fed in earlier blocks): the trim after the record begins at its end whatever the blocks were
        self.closed_span = (self.k0, self.buf[:, :self.buf_n].copy())
        self.last_end_k = self.k0 + n
        self.open = False
        self.buf_n = 0
        return out

    def state_dict(self) -> dict:
        """State with the record's filled samples only (bounded by ``cap``)."""
        return {
            "ring": self.ring.copy(),
            "ring_k": self.ring_k,
            "buf": self.buf[:, : self.buf_n].copy(),
            "k0": self.k0,
            "open": int(self.open),
            "src": self.src,
            "on_k": self.on_k,
            "off_k": self.off_k,
            "last_end_k": self.last_end_k,
        }

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict`."""
        self.ring = np.asarray(st["ring"], float).reshape(self.n, -1).copy()
        self.ring_k = int(st["ring_k"])
        buf = np.asarray(st["buf"], float).reshape(self.n, -1)
        self.buf_n = buf.shape[1]
        self.buf[:, : self.buf_n] = buf
        self.k0, self.open, self.src = int(st["k0"]), bool(st["open"]), int(st["src"])
        self.on_k, self.off_k = int(st["on_k"]), int(st["off_k"])
        self.last_end_k = int(st["last_end_k"])



# ---------------------------------------------------------------------------------------------- tracker
class ManoeuvreTracker:
    """From the grid's samples to the manoeuvres flown: detection, trigger, records, trim, classification.

    Holds the detectors and their delay line, the pending edges, the record in progress, the records waiting
    for the trim motion and the counts of the manoeuvres seen (per kind, flown, saturated, their spans). What
    gives a response goes to ``accumulator``.

    Parameters
    ----------
    dt : float
        Grid step [s].
    inputs, outputs : int
        Inputs and outputs among the data streams (the rest are instruments).
    data_streams : int
        Streams a record holds (inputs, outputs, instruments).
    grid_streams : int
        Rows of the grid samples (the data streams, and the airspeed last when there is one).
    options : dict
        The estimator's validated options (detector options, ``detect_sweeps``, ``pre_s``, ``post_s``,
        ``max_record_s``, ``min_quiet_s``, ``min_sweep_s``, ``sample_rate_hz``).
    conditioned : bool
        Several inputs without an excitation signal are split each on its own (``other_inputs``).
    trim : TrimSpectrum
        The trim motion between the records (fed and cut here).
    accumulator : RecordAccumulator
        Where each manoeuvre that gives a response is estimated.
    clock : callable
        ``clock(k)``: the time of grid index ``k`` [s].
    scaling : DynamicPressureScaling, optional
        Brings the inputs to the model's dynamic pressure (with an airspeed stream, the last grid row).
    """

    def __init__(
        self,
        dt: float,
        inputs: int,
        outputs: int,
        data_streams: int,
        grid_streams: int,
        options: dict,
        conditioned: bool,
        trim: TrimSpectrum,
        accumulator: RecordAccumulator,
        clock: Callable[[int], float],
        scaling: DynamicPressureScaling | None = None,
    ) -> None:
        fs = options["sample_rate_hz"]
        self._dt = dt
        self._m, self._p, self._S = int(inputs), int(outputs), int(data_streams)
        self._min_quiet_s, self._min_sweep_s = options["min_quiet_s"], options["min_sweep_s"]
        # other_inputs (issue 13): the channel's own input first, the others conditioned on and split on their
        # own (a MIMO channel's inputs, ``inputs[j]``, are split by :meth:`_pieces_per_stream` instead)
        self._conditioned = conditioned
        self._trim, self._records, self._clock, self._scaling = trim, accumulator, clock, scaling
        self._det_streams = list(range(self._m + self._p, self._S)) or list(range(self._m))
        self._dets = [
            SweepDetector(fs, **{k: options[k] for k in DETECTOR_DEFAULTS}) for _ in self._det_streams
        ]
        self._det_on = [False] * len(self._dets)
        self._man = ManoeuvreRecorder(fs)
        self._trig = TriggerTracker()
        self._delay_n = max(d.lookahead_samples for d in self._dets)
        self._dl = np.zeros((grid_streams, self._delay_n))   # the airspeed too: the scaling follows the edges
        self._dl_n = 0
        self._dl_k0 = 0
        self._last_k: int | None = None
        self._trigger_mode = not options["detect_sweeps"]
        self._events: list[tuple[int, bool, int]] = []
        self._events_dropped = 0
        self._rec = _RecordBuffer(
            self._S,
            int(round(options["pre_s"] * fs)),
            int(round(options["post_s"] * fs)),
            max(16, int(round(options["max_record_s"] * fs))),
            self._record_full,
            int(round(LOOKBACK_S * fs)),
        )
        self._kinds: Counter = Counter()
        # manoeuvres long enough to estimate, per kind, whatever they gave
        self._flown: Counter = Counter()
        self._saturated = 0
        # other_inputs: manoeuvre -> the input it belongs to
        self._piece_stream: dict = {}
        # grid spans of the latest manoeuvres (not checkpointed)
        self._spans: deque = deque(maxlen=SPANS_KEPT)
        # records waiting for the trim motion
        self._pending: list[tuple[int, np.ndarray, int, int, int]] = []
        #: Called as ``record_observer(samples, kind, t0_s, dt_s)`` with the grid samples (streams x n) of the
        #: excited span of every manoeuvre of this channel that gives a response, its kind, the time of its
        #: first sample and the grid step; None: nobody. It returns False for a manoeuvre that is another
        #: surface's (the input following it through an interconnect): left out of the estimates and the
        #: counts.
        self.record_observer: Callable[..., Any] | None = None

    # ------------------------------------------------------------------ what it holds
    @property
    def in_record(self) -> bool:
        """True while a record is open (delayed by the detectors' look-ahead)."""
        return self._rec.open

    @property
    def trigger_mode(self) -> bool:
        """True once an explicit trigger (or ``detect_sweeps=False``) defines the manoeuvres."""
        return self._trigger_mode

    @property
    def events_dropped(self) -> int:
        """Edges dropped beyond the bounded queue."""
        return self._events_dropped

    @property
    def kinds(self) -> Counter:
        """Manoeuvres seen per kind, counted or not (a copy)."""
        return Counter(self._kinds)

    @property
    def flown(self) -> Counter:
        """Manoeuvres flown per kind (see :attr:`FrequencyResponseEstimator.flown_kinds`; a copy)."""
        return Counter(self._flown)

    @property
    def saturated(self) -> int:
        """Manoeuvres not used because their excitation was pinned at its extremes."""
        return self._saturated

    @property
    def spans(self) -> list[tuple[int, int]]:
        """Grid spans (first, end) of the latest manoeuvres' own excited stretches (up to
        :data:`SPANS_KEPT`)."""
        return list(self._spans)

    @property
    def manoeuvres_key(self) -> bytes:
        """Changes exactly when :meth:`manoeuvres` changes."""
        return self._man.key

    def manoeuvres(self, t0_s: float) -> list[Manoeuvre]:
        """Short manoeuvres (doublets, pulses, multisteps) kept for the time-domain check (largest 3).

        Parameters
        ----------
        t0_s : float
            Time of grid index 0 [s].

        Returns
        -------
        list of Manoeuvre
            Oldest first.
        """
        return self._man.manoeuvres(t0_s, self._dt)

    # ------------------------------------------------------------------ data in
    def process(self, idx: np.ndarray, vals: np.ndarray) -> None:
        """Grid samples: indices (increasing; a jump is a break in the data) and values (streams x n).

        Parameters
        ----------
        idx : ndarray
            Grid indices.
        vals : ndarray
            Values (grid streams x ``idx.size``).
        """
        if idx.size == 0:
            return
        cuts = np.flatnonzero(np.diff(idx) != 1) + 1
        bounds = np.concatenate(([0], cuts, [idx.size]))
        for a, b in zip(bounds[:-1], bounds[1:]):
            k0 = int(idx[a])
            if self._last_k is not None and k0 != self._last_k + 1:
                self._end_run()
            if self._last_k is None:
                for det in self._dets:
                    det.start_run(k0)
            self._run_chunk(k0, vals[:, a:b])
            self._last_k = int(idx[b - 1])

    def end_data(self) -> None:
        """End of data: the run of data in progress ends (the manoeuvre in progress closes)."""
        if self._last_k is not None:
            self._end_run()

    def enter_trigger_mode(self, k_switch: int) -> None:
        """An explicit trigger arrived: detection is off from grid index ``k_switch`` on.

        Parameters
        ----------
        k_switch : int
            Grid index of the trigger's first sample.
        """
        self._trigger_mode = True
        self._events = [e for e in self._events if e[0] < k_switch]
        self._det_on = [False] * len(self._dets)
        on = self._events[-1][1] if self._events else self._rec.open and self._rec.off_k == NO_INDEX
        if on:
            self._push_event(k_switch, False, _ENERGY)

    def add_trigger(self, k: np.ndarray, active: np.ndarray) -> None:
        """Trigger samples on the grid: their edges start and end manoeuvres.

        Parameters
        ----------
        k : ndarray
            Grid indices of the samples.
        active : ndarray of bool
            The trigger's values.
        """
        for kk, on in self._trig.edges(k, active):
            self._push_event(kk, on, _TRIGGER)

    def _run_chunk(self, k0: int, block: np.ndarray) -> None:
        if not self._trigger_mode:
            self._detect([det.process(k0, block[s]) for det, s in zip(self._dets, self._det_streams)])
        D = self._delay_n
        if self._dl_n:
            block = np.concatenate((self._dl[:, : self._dl_n], block), axis=1)
            ks = self._dl_k0
        else:
            ks = k0
        release = block.shape[1] - D
        if release > 0:
            self._consume(ks, block[:, :release])
            self._dl[:] = block[:, release:]
            self._dl_n, self._dl_k0 = D, ks + release
        else:
            self._dl[:, : block.shape[1]] = block
            self._dl_n, self._dl_k0 = block.shape[1], ks

    def _detect(self, edge_lists: list) -> None:
        """Combine the detectors' edges: excited while any detection signal is."""
        merged = sorted((k, on, i) for i, edges in enumerate(edge_lists) for k, on in edges)
        for k, on, i in merged:
            was = any(self._det_on)
            self._det_on[i] = on
            now = any(self._det_on)
            if now != was:
                self._push_event(k, now, _ENERGY)

    def _end_run(self) -> None:
        """The current run of contiguous data ended (gap or end of data)."""
        k_end = self._last_k + 1
        if not self._trigger_mode:
            self._detect([det.end_run(k_end) for det in self._dets])
        if self._dl_n:
            self._consume(self._dl_k0, self._dl[:, : self._dl_n].copy())
            self._dl_n = 0
        while self._events and self._events[0][0] <= k_end:
            k, on, src = self._events.pop(0)
            self._apply_edge(k, on, src)
        for record in self._rec.end_run():
            self._close_record(*record)
        self._trim.end_stretch()
        self._judge_pending(force=True)
        self._last_k = None

    # ------------------------------------------------------------------ internals: manoeuvres
    def _push_event(self, k: int, on: bool, src: int) -> None:
        keys = [e[0] for e in self._events]
        self._events.insert(bisect.bisect_right(keys, k), (int(k), bool(on), int(src)))
        if len(self._events) > _EVENT_CAP:
            self._events.pop(0)
            self._events_dropped += 1

    def _apply_edge(self, k: int, on: bool, src: int) -> None:
        opened = on and not self._rec.open
        records = self._rec.start(k, src) if on else (self._rec.stop(k) or [])
        for record in records:
            self._close_record(*record)
        if opened or (on and records):      # a new record reaches back into what looked like trim
            self._trim.cut(self._rec.k0)

    def _consume(self, k_a: int, block: np.ndarray) -> None:
        """Released (delayed) contiguous grid samples from index ``k_a``: apply the edges, record."""
        end = k_a + block.shape[1]
        pos = k_a
        while self._events and self._events[0][0] < end:
            k, on, src = self._events.pop(0)
            k = max(k, pos)
            if k > pos:
                self._feed(pos, block[:, pos - k_a: k - k_a])
            pos = k
            self._apply_edge(k, on, src)
        if end > pos:
            self._feed(pos, block[:, pos - k_a:])

    def _feed(self, k_a: int, block: np.ndarray) -> None:
        if self._scaling is not None:
            block = self._scaling.scale(block, self._rec.open)
        was_open = self._rec.open
        self._rec.closed_span = None
        for record in self._rec.feed(k_a, block):
            self._close_record(*record)
        # trim: the samples outside every record (records open only at edges, between feeds)
        first = k_a if not was_open else (self._rec.last_end_k if not self._rec.open else None)
        if first is not None and first < k_a and self._rec.closed_span is not None:
            # the record closed pre_n samples after its end: those came in earlier blocks, held by the record
            span_k, span = self._rec.closed_span
            a = max(first, span_k)
            if a < k_a <= span_k + span.shape[1]:
                self._trim.feed(a, span[:, a - span_k:k_a - span_k])
        self._rec.closed_span = None
        if first is not None and first < k_a + block.shape[1]:
            self._trim.feed(max(first, k_a), block[:, max(first - k_a, 0):])
            if self._pending:
                self._judge_pending()

    def _pieces(self, data: np.ndarray, src: int, act0: int, act1: int,
                open_end: bool = False) -> list[Piece]:
        """The record's manoeuvres; ``open_end``: the record was cut while one went on (its tail is no
        trim: :func:`~gap_validation.core.records.split_record`)."""
        n = data.shape[1]
        if src == _TRIGGER:
            return [Piece(0, n, min(act0, n), max(min(act1, n), min(act0, n)))]
        if len(self._det_streams) > 1:
            return (self._multi_pieces(data, open_end) if self._conditioned
                    else self._pieces_per_stream(data, open_end))
        return self._split(data[self._det_streams[0]], 0, n, self._det_streams[0], open_end)

    def _motion(self, stream: int) -> float:
        """:func:`trim_motion` of a detection stream."""
        return trim_motion(self._trim, stream)

    def _multi_pieces(self, data: np.ndarray, open_end: bool = False) -> list[Piece]:
        """Several inputs without an excitation signal (``other_inputs``): the manoeuvres of every input, each
        kept where its own input is the most excited (relative to its trim noise) over its excited span, so a
        surface that only follows another through an interconnect adds no manoeuvre of its own; in time order.
        :attr:`_piece_stream` remembers which input each one belongs to."""
        found = []
        noise = {s: max(trim_noise(data[s], self._dt), 1e-12) for s in self._det_streams}
        for s in self._det_streams:
            for piece in split_record(data[s], self._dt, noise[s], self._rec.pre_n, self._rec.post_n,
                                      self._min_quiet_s, self._motion(s), open_end):
                if piece.active_end <= piece.active_start:
                    continue
                span = slice(piece.active_start, piece.active_end)
                level = {r: float(np.std(data[r, span])) / noise[r] for r in self._det_streams}
                if max(level, key=level.get) == s:
                    found.append((piece, s))
        found.sort(key=lambda item: (item[0].start, item[1]))
        self._piece_stream = {(p.start, p.end, p.active_start, p.active_end): s for p, s in found}
        return [p for p, _ in found]

    def _det_index(self, data: np.ndarray) -> int:
        """The detection stream a record is split and classified on: the only one, or (several inputs without
        an excitation signal: ``other_inputs``) the one most excited relative to its trim noise."""
        if len(self._det_streams) == 1:
            return self._det_streams[0]
        best, best_ratio = self._det_streams[0], -1.0
        for s in self._det_streams:
            row = data[s]
            ratio = float(np.std(row)) / max(trim_noise(row, self._dt), 1e-12)
            if ratio > best_ratio:
                best, best_ratio = s, ratio
        return best

    def _record_full(self, k0: int, data: np.ndarray, src: int, act0: int) -> int:
        """The record buffer is full (``max_record_s``): estimate the manoeuvres it completed and keep the one
        still going (from its trim on); a single manoeuvre longer than the buffer is cut here. Records waiting
        for
        the trim motion are judged first (in time order)."""
        self._judge_pending(force=True)
        n = data.shape[1]
        pieces = self._pieces(data, src, act0, n, open_end=True)
        going = [p for p in pieces if p.group == pieces[-1].group] if pieces and pieces[-1].end >= n else []
        if self._conditioned and src != _TRIGGER:      # other_inputs split separately: groups differ
            going = [p for p in pieces if p.end >= n]
            if going and len(going) < len(pieces):
                first = min(p.start for p in going)
                self._estimate_pieces(k0, data, [p for p in pieces if p.end < n], src == _TRIGGER)
                return first
        if going and len(going) < len(pieces):
            self._estimate_pieces(k0, data, pieces[:len(pieces) - len(going)], src == _TRIGGER)
            return going[0].start
        self._estimate_pieces(k0, data, pieces, src == _TRIGGER)
        return n

    def _close_record(self, k0: int, data: np.ndarray, src: int, act0: int, act1: int) -> None:
        """A buffered record closed: split it into manoeuvres, classify them, estimate their responses.

        A manoeuvre that begins in the record's trim tail, after the detector's end of excitation, and runs to
        the record's last sample was cut by the record, not flown that short (a sweep that starts slowly is
        detected
        seconds late): it is left to the next record, which may reach back to its start."""
        if data.shape[1] < 4:
            return
        pieces = self._pieces(data, src, act0, act1)
        quiet_n = int(round(self._min_quiet_s / self._dt))
        if src != _TRIGGER and pieces and pieces[-1].active_start >= act1 and pieces[-1].start > 0 and \
                pieces[-1].active_end > data.shape[1] - quiet_n:
            self._rec.last_end_k = k0 + pieces[-1].start
            data = data[:, :pieces[-1].start]
            act1 = min(act1, data.shape[1])
        self._pending.append((k0, data, src, act0, act1))
        self._judge_pending(force=len(self._pending) > PENDING_RECORDS)

    def _judge_pending(self, force: bool = False) -> None:
        """Split, classify and estimate the records that wait for the trim motion: all of them once it is
        known (:data:`TRIM_KNOWN_S`) or when ``force``-d (a break or the end of the data, a record too long to
        wait),
        else only the oldest beyond :data:`PENDING_RECORDS`."""
        while self._pending and (
            force or self._trim.seconds >= TRIM_KNOWN_S or len(self._pending) > PENDING_RECORDS
        ):
            k0, data, src, act0, act1 = self._pending.pop(0)
            if data.shape[1] >= 4:
                self._estimate_pieces(k0, data, self._pieces(data, src, act0, act1), src == _TRIGGER)

    def _pieces_per_stream(self, data: np.ndarray, open_end: bool = False) -> list[Piece]:
        """Several detection streams (a MIMO channel's inputs, flown one at a time): the record split by each
        stream on its own (a record may hold an aileron doublet and the rudder sweep after it). The manoeuvre
        that moves its stream most is kept first; a later one that overlaps kept ones keeps only what lies
        outside them (excited spans), split again on its own trim there (a surface the pilot re-trimmed during
        the other surface's sweep
        looks excited across it: its own sweep after it is a manoeuvre, the re-trim a trim step)."""
        found = []
        for n, s in enumerate(self._det_streams):
            det = data[s]
            for piece in self._split(det, 0, det.size, s, open_end):
                moved = float(np.var(det[piece.active_start:piece.active_end])) if piece.active_end > \
                    piece.active_start else 0.0
                found.append((moved, n, Piece(piece.start, piece.end, piece.active_start, piece.active_end,
                                              piece.group + n * 1_000_000)))
        kept: list[Piece] = []
        shortest = max(int(round(MIN_ACTIVE_S / self._dt)), 1)
        for _, n, piece in sorted(found, key=lambda item: -item[0]):
            gaps = [(piece.active_start, piece.active_end)]
            for k in kept:
                gaps = [
                    part
                    for lo, hi in gaps
                    for part in ((lo, min(hi, k.active_start)), (max(lo, k.active_end), hi))
                    if part[1] > part[0]
                ]
            if gaps == [(piece.active_start, piece.active_end)]:
                kept.append(piece)
                continue
            for part, (lo, hi) in enumerate(gaps):
                if hi - lo < shortest:
                    continue
                end = piece.end if hi == piece.active_end else hi
                kept += [Piece(p.start + lo, p.end + lo, p.active_start + lo, p.active_end + lo,
                               piece.group + 1000 * (part + 1) + p.group)
                         for p in self._split(data[self._det_streams[n]], lo, end, self._det_streams[n],
                                              open_end and end >= data.shape[1])]
        return sorted(kept, key=lambda p: (p.start, p.active_start))

    def _split(self, det: np.ndarray, lo: int, hi: int, stream: int, open_end: bool = False) -> list[Piece]:
        """:func:`~gap_validation.core.records.split_record` of ``det[lo:hi]`` (indices relative to ``lo``;
        ``det``
        is stream ``stream``)."""
        seg = det[lo:hi]
        return split_record(seg, self._dt, trim_noise(seg, self._dt), self._rec.pre_n, self._rec.post_n,
                            self._min_quiet_s, self._motion(stream), open_end and hi >= det.size) \
            if seg.size >= 3 else []

    def _detection_signal(self, data: np.ndarray, piece: Piece) -> int:
        """The stream a manoeuvre is classified by: the detection stream, or with several (a MIMO channel's
        inputs, flown one at a time) the one that varies most during the manoeuvre."""
        if len(self._det_streams) == 1:
            return self._det_streams[0]
        candidates = data[self._det_streams][
            :, piece.active_start : max(piece.active_end, piece.active_start + 1)
        ]
        return self._det_streams[int(np.argmax(np.var(candidates, axis=1)))]

    def _estimate_pieces(
        self, k0: int, data: np.ndarray, pieces: list[Piece], declared: bool = False
    ) -> None:
        """Classify and estimate a record's manoeuvres; ``declared``: the record is a trigger's (its manoeuvre
        counts as flown even where it gives no response)."""
        single = len(self._det_streams) == 1
        det_index = self._det_index(data) if self._conditioned else self._det_streams[0]
        det = data[det_index]
        noise, motion = trim_noise(det, self._dt), self._motion(det_index)
        for piece in pieces:
            if piece.active_end <= piece.active_start:
                continue
            if not single:
                if self._conditioned:      # other_inputs: each manoeuvre on the input it belongs to
                    det_index = self._piece_stream.get(
                        (piece.start, piece.end, piece.active_start, piece.active_end), det_index)
                else:                      # MIMO: the input that varies most during the manoeuvre
                    det_index = self._detection_signal(data, piece)
                det = data[det_index]
                noise, motion = trim_noise(det, self._dt), self._motion(det_index)
            # other_inputs: a manoeuvre of another input (its own sweep) pools into the average, which needs
            # it to separate the inputs, but is not a sweep of this channel (no raw estimate of its own)
            own = not self._conditioned or det_index == self._det_streams[0] or self._m + self._p < self._S
            self._spans.append((k0 + piece.active_start, k0 + piece.active_end))
            kind = classify(det, self._dt, piece, noise, motion)
            self._kinds[kind] += 1
            active_s = (piece.active_end - piece.active_start) * self._dt
            seg = data[:, piece.start:piece.end]
            if kind in ("doublet", "pulse", "multistep") and active_s <= _SHORT_MANOEUVRE_S and own:
                self._man.offer(k0 + piece.start, seg[0], seg[self._m], k0 + piece.active_start,
                                k0 + piece.active_end, kind)
            if kind not in RESPONSE_KINDS or active_s < self._min_sweep_s:
                continue
            if self.record_observer is not None and own and \
                    self.record_observer(data[:, piece.active_start:piece.active_end], kind,
                                         self._clock(k0 + piece.active_start), self._dt) is False:
                continue             # another surface's manoeuvre, the input following it (an interconnect)
            if declared and own:      # a trigger's manoeuvre is flown, whatever it gives
                self._flown[kind] += 1
            if kind in ("chirp", "multisine", "broadband") and saturated_share(det, piece) >= SATURATED_SHARE:
                self._saturated += 1
                continue
            # whole periods only: its lines do not leak (nor another axis' lines)
            if kind == "multisine":
                n_p = period(det[piece.active_start:piece.active_end], self._dt)
                # whole periods within the excited span (a fade is not periodic: the lines would leak)
                whole = (piece.active_end - piece.active_start) // n_p * n_p if n_p else 0
                if whole:
                    start = piece.active_start + (piece.active_end - piece.active_start - whole) // 2
                    seg = data[:, start:start + whole]
                    self._estimate_piece(k0 + start, seg, kind, noise, (k0 + start, k0 + start + whole), own,
                                         declared)
                    continue
            self._estimate_piece(k0 + piece.start, seg, kind, noise,
                                 (k0 + piece.active_start, k0 + piece.active_end), own, declared)

    def _estimate_piece(self, k_start: int, seg: np.ndarray, kind: str, noise: float, active: tuple[int, int],
                        own: bool, declared: bool) -> None:
        """Estimate one manoeuvre (:meth:`RecordAccumulator.add`); a detected manoeuvre of this channel's own
        is
        flown where it gave a response (else: trim wander)."""
        if self._records.add(k_start, seg, kind, noise, active, own) and own and not declared:
            self._flown[kind] += 1

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """The estimator's checkpoint keys of the tracker: ``last_k``, ``trigger_mode``, the edges
        (``events``, ``n_events``, ``events_dropped``, ``det_on``), the delay line (``dl``, ``dl_n``,
        ``dl_k0``), the counts (``kind_counts``, ``flown_counts``, ``saturated``), the records waiting
        (``pending_n``, ``pending<i>.``),
        and the ``trig.``, ``man.``, ``rec.`` and ``det<i>.`` parts."""
        ev = np.zeros((_EVENT_CAP, 3), np.int64)
        for i, e in enumerate(self._events):
            ev[i] = e
        st: dict = {
            "last_k": NO_INDEX if self._last_k is None else self._last_k,
            "trigger_mode": int(self._trigger_mode),
            "events": ev, "n_events": len(self._events), "events_dropped": self._events_dropped,
            "det_on": np.array(self._det_on, np.int64),
            "dl": self._dl.copy(), "dl_n": self._dl_n, "dl_k0": self._dl_k0,
            "kind_counts": np.array([self._kinds[k] for k in KINDS], np.int64),
            "flown_counts": np.array([self._flown[k] for k in KINDS], np.int64),
            "saturated": self._saturated, "pending_n": len(self._pending),
        }
        for i, (k0, data, src, act0, act1) in enumerate(self._pending):
            st[f"pending{i}.data"] = data.copy()
            st[f"pending{i}.meta"] = np.array([k0, src, act0, act1], np.int64)
        for prefix, part in self._parts().items():
            for key, value in part.state_dict().items():
                st[f"{prefix}.{key}"] = value
        return st

    def _parts(self) -> dict:
        parts = {"trig": self._trig, "man": self._man, "rec": self._rec}
        parts.update({f"det{i}": d for i, d in enumerate(self._dets)})
        return parts

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            The estimator's checkpoint (other keys are ignored; checkpoints before the count of manoeuvres
            flown count those that gave a response).
        """
        last_k = int(st["last_k"])
        self._last_k = None if last_k == NO_INDEX else last_k
        self._trigger_mode = bool(st["trigger_mode"])
        ev = np.asarray(st["events"], np.int64)
        self._events = [(int(k), bool(on), int(src)) for k, on, src in ev[: int(st["n_events"])]]
        self._events_dropped = int(st["events_dropped"])
        self._det_on = [bool(v) for v in np.asarray(st["det_on"])]
        self._dl[:] = st["dl"]
        self._dl_n, self._dl_k0 = int(st["dl_n"]), int(st["dl_k0"])
        self._saturated = int(st["saturated"])
        self._pending = []
        for i in range(int(st.get("pending_n", 0))):
            k0, src, act0, act1 = (int(v) for v in np.asarray(st[f"pending{i}.meta"], np.int64))
            data = np.asarray(st[f"pending{i}.data"], float).reshape(self._S, -1)
            self._pending.append((k0, data.copy(), src, act0, act1))
        self._kinds = Counter({k: int(v) for k, v in zip(KINDS, st["kind_counts"]) if int(v)})
        self._flown = Counter({k: int(v) for k, v in zip(KINDS, st.get("flown_counts", st["counted_counts"]))
                               if int(v)})
        for prefix, part in self._parts().items():
            n = len(prefix) + 1
            part.load_state({k[n:]: v for k, v in st.items() if k.startswith(prefix + ".")})

