"""Online frequency-response estimator: the measured responses of the paper's Fig. 4, from any manoeuvre.

Samples of the control surface (input) and of the body rate (output) arrive one by one or in batches, each
stream at its own irregular rate (more streams for other surfaces or an injected excitation). The estimator
finds the manoeuvres in the flight, estimates a frequency response from each (the *raw* estimates, the light
curves of Fig. 4) and pools them into the *averaged* estimate (the dark curve), with coherence, degrees of
freedom and the variance of the response per frequency. Nothing grows with flight length.

Data path (one pass, bounded delay)
-----------------------------------
1. **Alignment** (:class:`StreamResampler`, :class:`GridAligner`). Each stream is interpolated on its own onto
   one uniform grid ``t_k = t0 + k / sample_rate_hz`` (default 100 Hz; must be >= 5x the highest frequency):
   cubic Hermite with three-point slopes (Catmull-Rom on uniform samples; a 50 Hz stream read on a 100 Hz grid
   loses < 0.4 % of magnitude at 5 Hz). Grid values wait in bounded queues until every stream has reached the
   same instant (``max_lag_s``). A spacing larger than ``max_gap_s`` is a gap: no interpolation across it, the
   run of data and the manoeuvre in progress end there. Time jumping back (a looped bag) by more than
   ``max(JUMP_BACK_S, max_gap_s)`` starts a new time base once confirmed; smaller steps back and duplicate
   stamps are dropped and counted.
2. **Excited stretches** (:mod:`gap_validation.core.sweeps`): the detector sees the excitation signal (the
input,
   or the injected excitation when there is one); everything else sees the grid samples ``lookahead_samples``
   later (about 2 s), when it is known whether they are excited. An explicit trigger overrides detection.
3. **Records** (:mod:`gap_validation.core.records`). An excited stretch is buffered with ``pre_s`` of trim
   before it and ``post_s`` after it (the response settles), at most ``max_record_s`` (longer excitation is
   cut into several records), then split into the manoeuvres flown (a second of trim between them, or a
   restart of the swept frequency) and each is classified (chirp, multisine, multistep, doublet, pulse,
   broadband, or a trim step, which gives no response). **Trim** (issue 22): every grid sample outside the
   records feeds :class:`~gap_validation.core.background. TrimSpectrum`, the trim motion per frequency between
   manoeuvres; a closed record waits for :data:`TRIM_KNOWN_S` of it (at most :data:`PENDING_RECORDS` records,
   or until the data break or end), because what counts as excited, and as a manoeuvre at all, is judged
   against it.
4. **Local polynomial estimate** (:mod:`gap_validation.core.spectra`): each record is transformed whole and
the
   response at every analysis frequency is fitted to the DFT bins around it with the record's transient
   (leakage, initial and final conditions) removed; the fits of all records add up (pooled estimate) and the
   last ``max_raw_sweeps`` records are kept one by one (raw estimates). A record counts at a frequency only
   where its input is excited there -- 20 dB above the trim motion at that frequency, above its own noise and,
   for a stepped manoeuvre, above what folds back from past the Nyquist frequency -- and its bins resolve it:
   they lie below a quarter of every stream's rate, or, for a slow stream (at most a fifth of the grid's rate)
   whose sampling the streams of the other side see four times faster, below its Nyquist frequency, with those
   streams showing that little folds back onto the band (:func:`~gap_validation.core.spectra.resolved_hz`;
   PX4's servos at 10 Hz: bands up to 31.4 rad/s, frequencies up to 28.6 rad/s).

Why whole records rather than averaged windows
-----------------------------------------------
Averaging short windows (Welch) gives many averages from a long sweep but fails on what flight-test engineers
also fly: a 3-2-1-1 or a doublet lasts a few seconds, a multisine's lines need whole periods, and short
windows leak (a window of a few cycles smears the response over its main lobe and, past the end of a sweep,
reports the response of the last excited frequency with a high coherence). A whole record has the finest
resolution the record allows and no window; the local polynomial method recovers the degrees of freedom from
neighbouring bins (not from overlapping windows, which are not independent) and removes the leakage of a
record that does not start and end at rest. Degrees of freedom are counted honestly: bins minus every
coefficient fitted.

Use
---
Feed the streams roughly in time order (live, or a replay in bag order); one stream may run ahead of another
by at most ``max_lag_s``; for whole recorded arrays use :meth:`FrequencyResponseEstimator.add_time_histories`.
Small calls are buffered and processed every ``batch_s`` of data. Results cover completed manoeuvres: a
manoeuvre is committed ``post_s`` plus ``pre_s`` (and the detector's look-ahead) after it ends, or at
:meth:`FrequencyResponseEstimator.flush`.

Pieces
------
:class:`FrequencyResponseEstimator` is the public face; it wires four collaborators, each in the module named
for what it holds, and solves the sums into estimates:

- :class:`~gap_validation.core.streams.StreamIntake`: the streams until they are on the grid (buffers, time
  bases, rates, resamplers, aligner);
- :class:`~gap_validation.core.tracking.ManoeuvreTracker`: the grid samples until they are manoeuvres
  (detectors, trigger edges, the record in progress, the records waiting for the trim motion, counts per
  kind);
- :class:`~gap_validation.core.accumulation.RecordAccumulator`: the manoeuvres' local polynomial sums, pooled
  and the latest ones one by one;
- :class:`~gap_validation.core.background.TrimSpectrum` (the trim motion between the records) and, with an
  airspeed stream, :class:`~gap_validation.core.condition.DynamicPressureScaling`.

Performance (``benchmarks/bench_estimator.py``): see docs/benchmarks.md.
"""
from __future__ import annotations

import copy
import math
from collections import Counter
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core.accumulation import RecordAccumulator
from gap_validation.core.background import (
    HANN_BINS_PER_AVERAGE,
    LeadResult,
    TrimResponse,
    TrimSpectra,
    TrimSpectrum,
)
from gap_validation.core.condition import DYNAMIC_PRESSURE_RANGE, TRIM_FOLLOW_S, DynamicPressureScaling  # noqa: F401
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.estimates import NOT_ESTIMABLE_REASONS, SpectralEstimate, record_amplitude
from gap_validation.core.manoeuvres import Manoeuvre
from gap_validation.core.numbers import NON_NEGATIVE, POSITIVE, check_number
from gap_validation.core.records import SWEEP_KINDS
from gap_validation.core.spectra import (  # noqa: F401
    RESOLVED_FRACTION,
    SPECTRA_DEFAULTS,
    BandSums,
    MatrixEstimate,
    interpolation_gain,
    resolved_hz,
    solve_matrix,
)
from gap_validation.core.streams import RATE_STEPS, StreamIntake  # noqa: F401
from gap_validation.core.sweeps import DETECTOR_DEFAULTS
from gap_validation.core.tracking import (  # noqa: F401
    LOOKBACK_S,
    PENDING_RECORDS,
    SPANS_KEPT,
    TRIM_KNOWN_S,
    ManoeuvreTracker,
    trim_motion,
)

__all__ = ["FrequencyResponseEstimator", "SpectralEstimate", "ESTIMATOR_DEFAULTS", "RETIRED_OPTIONS",
           "NOT_ESTIMABLE_REASONS", "record_amplitude"]

#: Options of :class:`FrequencyResponseEstimator` and their defaults (units in the names).
ESTIMATOR_DEFAULTS = {
    "sample_rate_hz": 100.0,      # uniform grid the streams are aligned on; >= 5x the top frequency
    "cubic_interpolation": True,  # False: linear interpolation onto the grid
    "max_gap_s": 0.5,             # a larger sample spacing breaks the data
    "max_lag_s": 30.0,            # how far one stream may run ahead of another before data are dropped
    "batch_s": 0.1,               # samples arriving in small calls are processed in batches of this span
    "detect_sweeps": True,        # False: only an explicit trigger defines manoeuvres
    # energy_window_s, hold_s, on_ratio, off_ratio, min_excitation, quiet_window_s
    **DETECTOR_DEFAULTS,
    # excitations shorter than this give no frequency response (time domain only)
    "min_sweep_s": 0.0,
    "max_raw_sweeps": 50,         # per-record estimates kept (most recent); the average pools all records
    "pre_s": 2.0,                 # trim kept before each manoeuvre [s]
    "post_s": 4.0,                # kept after it (the response settles) [s]
    "min_quiet_s": 1.0,           # trim that separates two manoeuvres [s]
    "max_record_s": 300.0,        # longer excitation is cut into records of this length [s]
    **SPECTRA_DEFAULTS,           # band_fraction, max_band_fraction, min_bins, order, transient_order
}
#: Options of the windowed (Welch) estimator that this one replaced: refused with an explanation.
RETIRED_OPTIONS = ("window_cycles", "min_window_s", "max_window_s", "overlap", "block_s", "detrend")
_BOOL_OPTIONS = ("cubic_interpolation", "detect_sweeps")
_INT_OPTIONS = ("max_raw_sweeps", "min_bins", "order", "transient_order")
# 3: records and local polynomial sums (1, 2: windowed spectra, not resumable)
_STATE_VERSION = 3
#: The checkpoint's keys in the order :meth:`FrequencyResponseEstimator.state_dict` lists them (by name, or
#: the name of their part before the dot without its number: ``pending3.data``, ``s0.k_next``, ``det1.on``).
_STATE_ORDER = (
    "version",
    "w_rad_s",
    "streams",
    "inputs",
    "outputs",
    "trim_airspeed",
    "q_stats",
    "u_trim",
    "opt",
    "t0",
    "last_k",
    "trigger_mode",
    "epoch",
    "epoch_offset",
    "events",
    "n_events",
    "events_dropped",
    "det_on",
    "dl",
    "dl_n",
    "dl_k0",
    "buf",
    "buf_n",
    "spacing",
    "rate_steps",
    "n_sweeps",
    "span",
    "reasons",
    "n_raw",
    "raw_rows",
    "raw_meta",
    "raw_kind",
    "raw_amplitude",
    "kind_counts",
    "counted_counts",
    "flown_counts",
    "longest_n",
    "saturated",
    "other_records",
    "pending_n",
    "pending",
    "tot",
    "align",
    "trig",
    "tbase",
    "man",
    "rec",
    "trim",
    "s",
    "det",
)
_STATE_RANK = {name: i for i, name in enumerate(_STATE_ORDER)}


def _state_rank(key: str) -> int:
    """Where ``key`` comes in a checkpoint (:data:`_STATE_ORDER`)."""
    head, dot, _ = key.partition(".")
    return _STATE_RANK[head.rstrip("0123456789") if dot else head]


# ---------------------------------------------------------------------------------------------- options
def _number(name: str, value, positive: bool = True) -> float:
    """An estimator option's number (numeric strings accepted), > 0 or (``positive=False``) >= 0."""
    return check_number(
        value,
        f"estimator option {name}",
        POSITIVE if positive else NON_NEGATIVE,
        strings=True,
        expected=f"a {'positive' if positive else 'non-negative'} finite number",
    )


def _validate_options(w_rad_s: np.ndarray, options: dict) -> dict:
    retired = sorted(set(options) & set(RETIRED_OPTIONS))
    if retired:
        raise ConfigError(f"estimator option {retired[0]!r} is no longer used: the estimator works on whole "
                          "manoeuvres now (local polynomial method, docs/ARCHITECTURE.md); remove it "
                          "(band_fraction and min_bins set the resolution)")
    unknown = sorted(set(options) - set(ESTIMATOR_DEFAULTS))
    if unknown:
        raise ConfigError(f"estimator option {unknown[0]!r} is unknown "
                          f"(known: {', '.join(ESTIMATOR_DEFAULTS)})")
    opts = {**ESTIMATOR_DEFAULTS, **options}
    out = {}
    for name, value in opts.items():
        if name in _BOOL_OPTIONS:
            if not isinstance(value, (bool, np.bool_, int, np.integer)) or value not in (0, 1):
                raise ConfigError(f"estimator option {name}: expected true or false, got {value!r}")
            out[name] = bool(value)
        elif name in _INT_OPTIONS:
            number = float(value) if name == "transient_order" and value == -1 else \
                _number(name, value, positive=name not in ("order", "transient_order"))
            if not number.is_integer():
                raise ConfigError(f"estimator option {name}: expected a whole number, got {value!r}")
            out[name] = int(number)
        elif name in ("min_sweep_s", "batch_s", "pre_s", "post_s", "min_quiet_s"):
            out[name] = _number(name, value, positive=False)
        else:
            out[name] = _number(name, value)
    if out["order"] > 3 or out["transient_order"] > 3:
        raise ConfigError(f"estimator options order / transient_order: expected 0 to 3, got "
                          f"{opts['order']!r} / {opts['transient_order']!r}")
    if out["min_bins"] < out["order"] + out["transient_order"] + 3:
        raise ConfigError(f"estimator option min_bins: {opts['min_bins']!r} leaves no degree of freedom "
                          f"(needs at least order + transient_order + 3 = "
                          f"{out['order'] + out['transient_order'] + 3})")
    if not out["band_fraction"] <= out["max_band_fraction"]:
        raise ConfigError(f"estimator option max_band_fraction: {opts['max_band_fraction']!r} is below "
                          f"band_fraction {opts['band_fraction']!r}")
    f_max = float(np.max(w_rad_s)) / (2.0 * math.pi)
    if out["sample_rate_hz"] < 5.0 * f_max:
        raise ConfigError(f"estimator option sample_rate_hz: {opts['sample_rate_hz']!r} Hz is below 5x the "
                          f"highest frequency ({f_max:.4g} Hz)")
    if out["max_record_s"] < 2.0 * (out["pre_s"] + out["post_s"]):
        raise ConfigError(f"estimator option max_record_s: {opts['max_record_s']!r} s is shorter than twice "
                          f"pre_s + post_s")
    return out


# ---------------------------------------------------------------------------------------------- estimator
class FrequencyResponseEstimator:
    """Online frequency response from separate input and output streams, per manoeuvre and pooled (Fig. 4).

    Parameters
    ----------
    w_rad_s : array_like
        Frequencies to estimate [rad/s] (e.g. log-spaced, ``FrequencyGrid.values()``).
    streams : sequence of str
        Names of the signals, inputs first: ``("input", "output")`` by default. ``inputs`` of them are inputs
        (regressors), then ``outputs`` outputs, then any instruments (injected excitation signals).
    inputs, outputs : int
        How many of ``streams`` are inputs and outputs (the rest are instruments).
    trim_airspeed : float, optional
        With it, the last of ``streams`` is the airspeed (the flight condition), not an instrument: on the
        grid each input's deviation from its trim is multiplied by ``(airspeed / trim_airspeed)^2``, the
        dynamic pressure relative to the model's (control power scales with it), so gusts and small drifts of
        the condition do not read as a model error
        (:class:`~gap_validation.core.condition.DynamicPressureScaling`). :attr:`dynamic_pressure_ratio` says
        how far the flight strayed.
    **options
        See :data:`ESTIMATOR_DEFAULTS` and the module docstring. Unknown names raise
        :class:`~gap_validation.core.errors.ConfigError` naming the key.

    Notes
    -----
    Feed the streams roughly interleaved in time (live, or a replay in bag order): one stream may run ahead
    of another by at most ``max_lag_s``. For whole recorded arrays use :meth:`add_time_histories`. Results
    cover completed manoeuvres; :meth:`flush` closes the one in progress at the end of data.
    """

    #: Accepted option names (the config checks them against this).
    OPTIONS = tuple(ESTIMATOR_DEFAULTS)

    def __init__(self, w_rad_s: ArrayLike, streams: Sequence[str] = ("input", "output"), inputs: int = 1,
                 outputs: int = 1, trim_airspeed: float | None = None, **options: Any) -> None:
        w = np.atleast_1d(np.asarray(w_rad_s, dtype=float))
        if w.ndim != 1 or w.size == 0 or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise ConfigError(
                f"estimator frequencies: expected positive finite rad/s values, got {w_rad_s!r}"
            )
        names = tuple(str(s) for s in streams)
        scheduled = trim_airspeed is not None
        if len(set(names)) != len(names) or inputs < 1 or outputs < 1 or \
                inputs + outputs + int(scheduled) > len(names):
            raise ConfigError(
                f"estimator streams {names!r}: need distinct names, at least one input and one "
                f"output ({inputs} inputs, {outputs} outputs{', the airspeed' if scheduled else ''})"
            )
        if scheduled and not (math.isfinite(trim_airspeed) and trim_airspeed > 0):
            raise ConfigError(
                f"estimator trim_airspeed: expected a positive airspeed [m/s], got {trim_airspeed!r}"
            )
        opts = _validate_options(w, options)
        self._w = w.copy()
        self._opts = opts
        self._names = names
        self._m, self._p = int(inputs), int(outputs)
        self._dt = dt = 1.0 / opts["sample_rate_hz"]
        S_all = len(names)                       # every stream resampled and aligned
        self._S = S = S_all - int(scheduled)     # the data streams the records hold (the airspeed is not one)
        self._scaling = DynamicPressureScaling(self._m, trim_airspeed, dt) if scheduled else None
        # the trim motion between the records, per frequency (:mod:`gap_validation.core.background`)
        self._trim = TrimSpectrum(w, S, dt, opts["band_fraction"], opts["max_band_fraction"], LOOKBACK_S,
                                  lead=(0, self._m))
        self._intake = StreamIntake(
            S_all,
            dt,
            opts["max_gap_s"],
            opts["cubic_interpolation"],
            opts["max_lag_s"],
            opts["batch_s"],
            self._grid_samples,
        )
        self._records = RecordAccumulator(self._w, self._m, self._p, S, dt, opts, self._trim,
                                          lambda: self._intake.rates_hz(S))
        # other_inputs (issue 13): the channel's own input first, the others conditioned on and split on their
        # own
        conditioned = any(n.startswith("other_input") for n in names)
        self._tracker = ManoeuvreTracker(dt, self._m, self._p, S, S_all, opts, conditioned, self._trim,
                                         self._records, self._intake.time_s, self._scaling)
        # (key, estimate) of the last :meth:`averaged`
        self._averaged: tuple | None = None
        self._sweeps_built: tuple | None = None                     # (key, sweeps) of the last :attr:`sweeps`

    def _grid_samples(self, idx: np.ndarray, vals: np.ndarray) -> None:
        """The intake's grid samples, to the tracker (bound after both exist)."""
        self._tracker.process(idx, vals)

    @property
    def record_observer(self) -> Callable[..., Any] | None:
        """Called as ``record_observer(samples, kind, t0_s, dt_s)`` with the grid samples (streams x n) of the
        excited span of every manoeuvre of this channel that gives a response, its kind, the time of its first
        sample and the grid step (the coupling monitors of :mod:`gap_validation.core.closed_loop`); None:
        nobody. Not checkpointed. It returns False for a manoeuvre that is another surface's (the input
        following it
        through an interconnect): left out of the estimates and the counts."""
        return self._tracker.record_observer

    @record_observer.setter
    def record_observer(self, observer: Callable[..., Any] | None) -> None:
        self._tracker.record_observer = observer

    # ------------------------------------------------------------------ properties
    @property
    def w_rad_s(self) -> np.ndarray:
        """Frequencies [rad/s]."""
        return self._w.copy()

    @property
    def options(self) -> dict:
        """All options in effect (defaults filled in)."""
        return dict(self._opts)

    @property
    def streams(self) -> tuple[str, ...]:
        """Signal names, inputs first."""
        return self._names

    @property
    def n_sweeps(self) -> int:
        """Sweeps that gave a frequency response so far (every manoeuvre that did, when none is a sweep; see
        :attr:`sweeps`)."""
        sweeps = sum(n for kind, n in self._records.counted.items() if kind in SWEEP_KINDS)
        return sweeps or self._records.n_records

    @property
    def n_manoeuvres(self) -> int:
        """Manoeuvres of any kind that gave a frequency response so far."""
        return self._records.n_records

    def input_trim_motion(self) -> float:
        """Standard deviation of the (first) input's trim motion between the manoeuvres (0 before any)."""
        return trim_motion(self._trim, 0)

    @property
    def flown_kinds(self) -> dict[str, int]:
        """Manoeuvres flown, per kind: those that gave a frequency response (:attr:`counted_kinds`) and, with
        a ``trigger``, every manoeuvre it marked that is long enough to estimate (``min_sweep_s``), whether it
        gave one or not (saturated, or nowhere 20 dB above the trim motion, as a loop answering turbulence
        leaves a sweep). A detected stretch that gives nothing is not counted: it cannot be told from trim
        wander. Another
        input's manoeuvres (``other_inputs``) are not this channel's."""
        return dict(self._tracker.flown)

    @property
    def counted_kinds(self) -> dict[str, int]:
        """Manoeuvres that gave a frequency response, per kind."""
        return dict(self._records.counted)

    @property
    def excitation(self) -> str | None:
        """The kind of excitation flown (JSON ``excitation``): the most frequent kind among the manoeuvres
        that
        gave a response (sweep kinds first on a tie), else among all seen; None before any."""
        counts = self._records.counted or Counter(
            {k: v for k, v in self._tracker.kinds.items() if k != "step"}
        )
        if not counts:
            return None
        order = ("chirp", "multisine", "multistep", "broadband", "doublet", "pulse")
        return max(counts, key=lambda k: (counts[k], -order.index(k) if k in order else -len(order)))

    @property
    def longest_record_s(self) -> float:
        """Length of the longest manoeuvre record so far [s] (0 before any)."""
        return self._records.longest_n * self._dt

    @property
    def saturated(self) -> int:
        """Manoeuvres not used because their excitation was pinned at its extremes (clipped; see
        :func:`gap_validation.core.records.saturated_share`)."""
        return self._tracker.saturated

    @property
    def not_estimable(self) -> dict[str, int]:
        """Per reason in :data:`NOT_ESTIMABLE_REASONS`: (record, frequency) pairs that gave nothing."""
        reasons = self._records.reasons
        return {name: int(np.sum(reasons[i])) for i, name in enumerate(NOT_ESTIMABLE_REASONS)}

    @property
    def kinds(self) -> dict[str, int]:
        """Manoeuvres seen per kind (:data:`gap_validation.core.records.KINDS`), counted or not."""
        return dict(self._tracker.kinds)

    @property
    def in_sweep(self) -> bool:
        """True while a manoeuvre is being recorded (delayed by ``lookahead_samples``)."""
        return self._tracker.in_record

    @property
    def t0_s(self) -> float:
        """Time origin of the grid [s] (NaN before the first sample)."""
        return self._intake.t0

    @property
    def stream_rates_hz(self) -> np.ndarray:
        """Sample rate of each stream [Hz]: one over the median of its first :data:`RATE_STEPS` sample
        intervals (dropped messages and jitter aside; the same however the samples were cut into calls), to
        three
        significant digits; inf before two samples."""
        return self._intake.rates_hz(self._S)    # the data streams (the airspeed's rate carries no band)

    @property
    def resolved_rad_s(self) -> float:
        """Highest frequency the streams resolve [rad/s]: no band reaches above it. A quarter of the slowest
        stream's rate (``RESOLVED_FRACTION``), or up to its Nyquist frequency for a slow stream whose sampling
        the faster
        streams of the other side show (:func:`~gap_validation.core.spectra.resolved_hz`)."""
        limit_hz, _ = resolved_hz(self.stream_rates_hz, self._m, self._p, self._opts["sample_rate_hz"])
        return float(2.0 * math.pi * limit_hz)

    @property
    def bad_sample_counts(self) -> dict:
        """Counts of samples not used, by stream and reason.

        ``nonfinite`` (NaN/inf time or value, or absurd: ``|t| >= 1e11`` s, ``|value| >= 1e100``),
        ``non_monotonic`` (time not after an earlier sample, within ``max(JUMP_BACK_S, max_gap_s)``, or a
        stray stamp further back), ``time_jumps_back`` (new time bases started: not samples lost, the data
        before and after both count), ``dropped_lag`` (grid values given up because another stream fell more
        than ``max_lag_s`` behind or had no data), and ``events_dropped`` (edges beyond the bounded queue).
        """
        out = self._intake.bad_sample_counts(self._names)
        out["events_dropped"] = self._tracker.events_dropped
        return out


    # ------------------------------------------------------------------ data in
    def add_input(self, t_s: ArrayLike, u: ArrayLike) -> None:
        """Feed control-surface samples (the first input).

        Parameters
        ----------
        t_s : array_like
            Sample times [s], increasing (any rate, jitter or drops).
        u : array_like
            Values, same length.
        """
        self._add_stream(0, t_s, u, self._names[0])

    def add_output(self, t_s: ArrayLike, y: ArrayLike) -> None:
        """Feed response (e.g. IMU body-rate) samples (the first output).

        Parameters
        ----------
        t_s : array_like
            Sample times [s], increasing.
        y : array_like
            Values, same length.
        """
        self._add_stream(self._m, t_s, y, self._names[self._m])

    def add_samples(self, stream: str, t_s: ArrayLike, values: ArrayLike) -> None:
        """Feed samples of one signal.

        Parameters
        ----------
        stream : str
            One of :attr:`streams`.
        t_s : array_like
            Sample times [s], increasing.
        values : array_like
            Values, same length.
        """
        try:
            s = self._names.index(stream)
        except ValueError:
            raise ConfigError(
                f"unknown stream {stream!r} (expected one of {', '.join(self._names)})"
            ) from None
        self._add_stream(s, t_s, values, stream)

    def add_time_histories(self, t_input_s: ArrayLike, u: ArrayLike, t_output_s: ArrayLike, y: ArrayLike,
                           chunk_s: float | None = None) -> None:
        """Feed two whole recorded streams (first input, first output), interleaved in chunks of ``chunk_s``.

        Parameters
        ----------
        t_input_s, u : array_like
            Input sample times [s] and values.
        t_output_s, y : array_like
            Output sample times [s] and values.
        chunk_s : float, optional
            At most ``max_lag_s / 2`` (default ``max_lag_s / 3``) so that nothing is dropped [s].
        """
        self.add_histories({self._names[0]: (t_input_s, u), self._names[self._m]: (t_output_s, y)}, chunk_s)

    def add_histories(self, histories: dict, chunk_s: float | None = None) -> None:
        """Feed whole recorded streams, interleaved in time.

        Parameters
        ----------
        histories : dict
            ``{stream name: (t_s, values)}``.
        chunk_s : float, optional
            Interleaving step [s] (see :meth:`add_time_histories`).
        """
        series = {}
        for name, (t, v) in histories.items():
            t, v = np.asarray(t, float).ravel(), np.asarray(v, float).ravel()
            if t.shape != v.shape:
                raise DataError(f"add_time_histories: {t.size} {name} times for {v.size} values")
            series[name] = (t, v)
        finite = np.concatenate([t[np.isfinite(t)] for t, _ in series.values()] or [np.empty(0)])
        if finite.size == 0 or any(t.size == 0 for t, _ in series.values()):
            for name, (t, v) in series.items():
                self.add_samples(name, t, v)
            return
        lag = self._opts["max_lag_s"]
        step = lag / 3.0 if chunk_s is None else min(_number("chunk_s", chunk_s), lag / 2.0)
        lo = float(finite.min())
        # only the chunk ends that close a non-empty chunk (at most one per sample, however far apart the
        # timestamps are: a stray zero stamp among epoch times would be 1e8 chunks)
        edges = lo + np.unique(np.maximum(np.ceil((finite - lo) / step), 1.0)) * step
        cuts = {name: np.searchsorted(t, edges, side="right") for name, (t, _) in series.items()}
        start = {name: 0 for name in series}
        for j in range(edges.size):
            for name, (t, v) in series.items():
                b = cuts[name][j]
                self.add_samples(name, t[start[name]:b], v[start[name]:b])
                start[name] = b
        for name, (t, v) in series.items():
            self.add_samples(name, t[start[name]:], v[start[name]:])

    def add_trigger(self, t_s: ArrayLike, active: ArrayLike) -> None:
        """Feed samples of an explicit sweep trigger (``std_msgs/Bool``): manoeuvres are where it is true.

        The first trigger sample switches detection off for the rest of the flight.

        Parameters
        ----------
        t_s : array_like
            Sample times [s].
        active : array_like of bool
            The trigger's values.
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=float)).ravel()
        a = np.atleast_1d(np.asarray(active)).ravel()
        if t.shape != a.shape:
            raise DataError(f"trigger: {t.size} times but {a.size} values")
        k, a = self._intake.trigger_indices(t, a.astype(float))
        if k.size == 0:
            return
        if not self._tracker.trigger_mode:
            self._intake.drain_all()
            self._tracker.enter_trigger_mode(int(k[0]))
        self._tracker.add_trigger(k, a != 0)

    def flush(self) -> None:
        """End of data (or a pause): process everything received and close the manoeuvre in progress."""
        self._intake.flush()
        self._tracker.end_data()

    def _add_stream(self, s: int, t_s: ArrayLike, values: ArrayLike, name: str) -> None:
        t = np.atleast_1d(np.asarray(t_s, dtype=float)).ravel()
        v = np.atleast_1d(np.asarray(values, dtype=float)).ravel()
        if t.shape != v.shape:
            raise DataError(f"{name}: {t.size} times but {v.size} values")
        self._intake.add(s, t, v)

    # ------------------------------------------------------------------ results
    @property
    def sweeps(self) -> list[SpectralEstimate]:
        """Raw estimate of each sweep (the most recent ``max_raw_sweeps``), oldest first.

        A *sweep* is a manoeuvre of a kind in :data:`~gap_validation.core.records.SWEEP_KINDS` (chirp,
        multisine, multistep, broadband): an identification experiment. Doublets and pulses add to the pooled
        estimate but are not sweeps, unless the flight has no sweep at all (then every manoeuvre is one).
        """
        # built again only when a record came or went (the node asks every diagnostics tick)
        key = (*self._records.raw_key, self.t0_s)
        if self._sweeps_built is None or self._sweeps_built[0] != key:
            raw = self._records.raw
            raw = [r for r in raw if r[3] in SWEEP_KINDS] or raw
            time_s = self._intake.time_s
            self._sweeps_built = (
                key,
                [
                    SpectralEstimate.from_rows(
                        self._w,
                        rows,
                        time_s(k0),
                        time_s(k1),
                        kind,
                        self._opts["band_fraction"],
                        self._opts["order"] + 1,
                        amplitude,
                    )
                    for rows, k0, k1, kind, amplitude in raw
                ],
            )
        return list(self._sweeps_built[1])

    @property
    def record_spans_s(self) -> list[tuple[float, float]]:
        """Start and end [s] of the latest manoeuvres of any kind (up to 256): each manoeuvre's own excited
        span,
        without the trim kept around it; since the start of this process (not checkpointed)."""
        time_s = self._intake.time_s
        return [(time_s(a), time_s(b)) for a, b in self._tracker.spans]

    @property
    def manoeuvres(self) -> list[Manoeuvre]:
        """Short manoeuvres (doublets, pulses, multisteps) kept for the time-domain check (largest 3)."""
        return self._tracker.manoeuvres(self.t0_s)

    @property
    def manoeuvres_key(self) -> bytes:
        """Changes exactly when :attr:`manoeuvres` changes."""
        return self._tracker.manoeuvres_key

    def averaged(self) -> SpectralEstimate | None:
        """Estimate pooled over every manoeuvre so far (None before the first)."""
        records = self._records
        if records.n_records == 0:
            return None
        # solved again only when a manoeuvre changed the sums (the node asks every diagnostics tick)
        key = (*records.key, self.t0_s)
        if self._averaged is None or self._averaged[0] != key:
            reasons = records.reasons
            k0, k1 = records.span
            self._averaged = (key, SpectralEstimate.from_sums(
                self._w, records.sums, self._dt, self._opts["band_fraction"], self._intake.time_s(k0),
                self._intake.time_s(k1), records.n_records, "",
                {name: reasons[i].copy() for i, name in enumerate(NOT_ESTIMABLE_REASONS)}))
        return copy.copy(self._averaged[1])

    @property
    def shape(self) -> tuple[int, int]:
        """(outputs p, inputs m) of the response matrix."""
        return self._p, self._m

    def averaged_matrix(self) -> MatrixEstimate | None:
        """The whole p x m response matrix pooled over every manoeuvre so far, with per-element variances and
        coherences (:func:`~gap_validation.core.spectra.solve_matrix`); None before the first manoeuvre.

        With single-axis manoeuvres flown in turn each record excites one input; pooled, they determine every
        element (``H = G_yu G_uu^-1``). :meth:`averaged` is its first element (the SISO view).
        """
        if self._records.n_records == 0:
            return None
        return solve_matrix(self._records.sums)

    @property
    def pooled_sums(self) -> BandSums:
        """The pooled local polynomial sums (a copy)."""
        return self._records.sums.copy()

    @property
    def dynamic_pressure_ratio(self) -> dict | None:
        """With an airspeed stream: the dynamic pressure relative to the model's, ``(V / V_trim)^2``, over the
        flight's grid samples (``mean``, ``min``, ``max``; ``clipped``: samples beyond
        :data:`~gap_validation.core.condition.DYNAMIC_PRESSURE_RANGE`); None without one or before a
        sample."""
        return None if self._scaling is None else self._scaling.summary()

    @property
    def trim_airspeed(self) -> float | None:
        """The airspeed the inputs are scaled to [m/s] (None: not scaled)."""
        return None if self._scaling is None else self._scaling.trim_airspeed

    def between_manoeuvres(self) -> TrimResponse:
        """The response from the first input to the first output between the manoeuvres (the trim motion
        measured outside every record), its coherence and averages, and the input's trim motion per frequency
        in
        the units of the records' input power (:class:`~gap_validation.core.background.TrimResponse`)."""
        h, coherence, bins = self._trim.response(0, self._m)
        gain = interpolation_gain(self._w, self.stream_rates_hz[0], self._opts["cubic_interpolation"])
        return TrimResponse(h, coherence, bins / HANN_BINS_PER_AVERAGE,
                            self._trim.power([0]) / np.maximum(gain, 1e-3) ** 2)

    def trim_spectra(self) -> TrimSpectra:
        """The first input's and first output's spectra between the manoeuvres, their averages and the 20 dB
        test's floor, on the whole grid (:class:`~gap_validation.core.background.TrimSpectra`: the noise a
        manoeuvre will meet); each stream's interpolation gain restored, as the records restore it."""
        cubic = self._opts["cubic_interpolation"]
        rates = self.stream_rates_hz
        g_u = interpolation_gain(self._w, rates[0], cubic)
        g_y = interpolation_gain(self._w, rates[self._m], cubic)
        s = self._trim.spectra(0, self._m)
        return TrimSpectra(s.input_power / g_u ** 2, s.output_power / g_y ** 2, s.cross / (g_u * g_y),
                           s.averages, s.input_floor / np.maximum(g_u, 1e-3) ** 2)

    def surface_led(self) -> "LeadResult | None":
        """Whether the rate leads the surface between the manoeuvres (the first input and output;
        :class:`~gap_validation.core.background.LeadTest`); None before enough trim."""
        return self._trim.lead.result() if self._trim.lead is not None else None

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """Complete state as a flat dict of numpy arrays and numbers (bounded size, whatever the flight
        length).

        :meth:`from_state` rebuilds an estimator that continues exactly where this one stopped.
        """
        st: dict = {"version": _STATE_VERSION, "w_rad_s": self._w.copy(),
                    "streams": np.array(self._names), "inputs": self._m, "outputs": self._p}
        if self._scaling is not None:
            st.update(self._scaling.state_dict())
        for name, value in self._opts.items():
            st["opt." + name] = int(value) if name in _BOOL_OPTIONS + _INT_OPTIONS else float(value)
        for part in (self._intake, self._tracker, self._records):
            st.update(part.state_dict())
        for key, value in self._trim.state_dict().items():
            st["trim." + key] = value
        return {key: st[key] for key in sorted(st, key=_state_rank)}

    @classmethod
    def from_state(cls, state: dict) -> "FrequencyResponseEstimator":
        """Rebuild an estimator from :meth:`state_dict` (e.g. a checkpoint loaded from disk).

        Parameters
        ----------
        state : dict
            From :meth:`state_dict`.
        """
        version = state.get("version") if isinstance(state, dict) else None
        if version is not None and int(version) in (1, 2):
            raise DataError(f"estimator state: version {int(version)} holds windowed spectra of an earlier "
                            f"estimator; they cannot be resumed (start afresh)")
        if version is None or int(version) != _STATE_VERSION:
            raise DataError(f"estimator state: unsupported version {version!r} (expected {_STATE_VERSION})")
        try:
            opts = {}
            for name in ESTIMATOR_DEFAULTS:
                value = state["opt." + name]
                opts[name] = (bool(value) if name in _BOOL_OPTIONS else
                              int(value) if name in _INT_OPTIONS else float(value))
            names = [str(s) for s in np.atleast_1d(state["streams"])]
            trim_airspeed = float(state["trim_airspeed"]) if "trim_airspeed" in state else None
            self = cls(
                np.asarray(state["w_rad_s"], float),
                names,
                int(state["inputs"]),
                int(state["outputs"]),
                trim_airspeed,
                **opts,
            )
            self._load(state)
        except KeyError as err:
            raise DataError(f"estimator state: missing key {err.args[0]!r}") from None
        except ConfigError:
            raise
        except (TypeError, ValueError, IndexError) as err:    # arrays of the wrong shape or type
            reason = str(err).splitlines()[0] if str(err) else type(err).__name__
            raise DataError(f"estimator state: inconsistent ({reason})") from None
        return self

    def _load(self, st: dict) -> None:
        if self._scaling is not None:
            self._scaling.load_state(st)
        for part in (self._intake, self._tracker, self._records):
            part.load_state(st)
        if any(k.startswith("trim.") for k in st):     # checkpoints before the trim spectrum start without it
            self._trim.load_state({k[5:]: v for k, v in st.items() if k.startswith("trim.")})
        self._averaged = None
        self._sweeps_built = None
