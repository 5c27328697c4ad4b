"""Online frequency-response estimator: the measured responses of the paper's Fig. 4, from any manoeuvre.

Samples of the control surface (input) and of the body rate (output) arrive one by one or in batches, each stream
at its own irregular rate (more streams for other surfaces or an injected excitation). The estimator finds the
manoeuvres in the flight, estimates a frequency response from each (the *raw* estimates, the light curves of
Fig. 4) and pools them into the *averaged* estimate (the dark curve), with coherence, degrees of freedom and the
variance of the response per frequency. Nothing grows with flight length.

Data path (one pass, bounded delay)
-----------------------------------
1. **Alignment** (:class:`StreamResampler`, :class:`GridAligner`). Each stream is interpolated on its own onto
   one uniform grid ``t_k = t0 + k / sample_rate_hz`` (default 100 Hz; must be >= 5x the highest frequency):
   cubic Hermite with three-point slopes (Catmull-Rom on uniform samples; a 50 Hz stream read on a 100 Hz grid
   loses < 0.4 % of magnitude at 5 Hz). Grid values wait in bounded queues until every stream has reached the
   same instant (``max_lag_s``). A spacing larger than ``max_gap_s`` is a gap: no interpolation across it, the
   run of data and the manoeuvre in progress end there. Time jumping back (a looped bag) by more than
   ``max(JUMP_BACK_S, max_gap_s)`` starts a new time base once confirmed; smaller steps back and duplicate stamps
   are dropped and counted.
2. **Excited stretches** (:mod:`gap_validation.core.sweeps`): the detector sees the excitation signal (the input,
   or the injected excitation when there is one); everything else sees the grid samples ``lookahead_samples``
   later (about 2 s), when it is known whether they are excited. An explicit trigger overrides detection.
3. **Records** (:mod:`gap_validation.core.records`). An excited stretch is buffered with ``pre_s`` of trim
   before it and ``post_s`` after it (the response settles), at most ``max_record_s`` (longer excitation is cut
   into several records), then split into the manoeuvres flown (a second of trim between them, or a restart of
   the swept frequency) and each is classified (chirp, multisine, multistep, doublet, pulse, broadband, or a trim
   step, which gives no response).
   **Trim** (issue 22): every grid sample outside the records feeds :class:`~gap_validation.core.background.
   TrimSpectrum`, the trim motion per frequency between manoeuvres; a closed record waits for
   :data:`TRIM_KNOWN_S` of it (at most :data:`PENDING_RECORDS` records, or until the data break or end), because
   what counts as excited, and as a manoeuvre at all, is judged against it.
4. **Local polynomial estimate** (:mod:`gap_validation.core.spectra`): each record is transformed whole and the
   response at every analysis frequency is fitted to the DFT bins around it with the record's transient
   (leakage, initial and final conditions) removed; the fits of all records add up (pooled estimate) and the
   last ``max_raw_sweeps`` records are kept one by one (raw estimates). A record counts at a frequency only
   where its input is excited there -- 20 dB above the trim motion at that frequency, above its own noise and, for
   a stepped manoeuvre, above what folds back from past the Nyquist frequency -- and its bins resolve it: they
   lie below a quarter of every stream's rate, or, for a slow stream (at most a fifth of the grid's rate) whose
   sampling the streams of the other side see four times faster, below its Nyquist frequency, with those streams
   showing that little folds back onto the band (:func:`~gap_validation.core.spectra.resolved_hz`; PX4's servos
   at 10 Hz: bands up to 31.4 rad/s, frequencies up to 28.6 rad/s).

Why whole records rather than averaged windows
-----------------------------------------------
Averaging short windows (Welch) gives many averages from a long sweep but fails on what flight-test engineers
also fly: a 3-2-1-1 or a doublet lasts a few seconds, a multisine's lines need whole periods, and short windows
leak (a window of a few cycles smears the response over its main lobe and, past the end of a sweep, reports the
response of the last excited frequency with a high coherence). A whole record has the finest resolution the
record allows and no window; the local polynomial method recovers the degrees of freedom from neighbouring bins
(not from overlapping windows, which are not independent) and removes the leakage of a record that does not
start and end at rest. Degrees of freedom are counted honestly: bins minus every coefficient fitted.

Use
---
Feed the streams roughly in time order (live, or a replay in bag order); one stream may run ahead of another by
at most ``max_lag_s``; for whole recorded arrays use :meth:`FrequencyResponseEstimator.add_time_histories`.
Small calls are buffered and processed every ``batch_s`` of data. Results cover completed manoeuvres: a
manoeuvre is committed ``post_s`` plus ``pre_s`` (and the detector's look-ahead) after it ends, or at
:meth:`FrequencyResponseEstimator.flush`.

Performance (``benchmarks/bench_estimator.py``): see docs/benchmarks.md.
"""
from __future__ import annotations

import copy

import bisect
import math
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core.alignment import (NO_INDEX, JUMP_BACK_S, GridAligner, StreamResampler, TimeBase,
                                           jump_back_s)
from gap_validation.core.background import HANN_BINS_PER_AVERAGE, LeadResult, TrimResponse, TrimSpectrum
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.manoeuvres import Manoeuvre, ManoeuvreRecorder
from gap_validation.core.numbers import NON_NEGATIVE, POSITIVE, check_number
from gap_validation.core.records import (KINDS, MIN_ACTIVE_S, RESPONSE_KINDS, SATURATED_SHARE, SWEEP_KINDS, Piece,
                                         classify, period, saturated_share, split_record, trim_noise)
from gap_validation.core.spectra import (RESOLVED_FRACTION, SPECTRA_DEFAULTS, BandSums, MatrixEstimate,  # noqa: F401
                                         expected_estimate, interpolation_gain, record_bands, resolved_hz,
                                         solve_bands, solve_matrix)
from gap_validation.core.sweeps import DETECTOR_DEFAULTS, SweepDetector, TriggerTracker

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
    **DETECTOR_DEFAULTS,          # energy_window_s, hold_s, on_ratio, off_ratio, min_excitation, quiet_window_s
    "min_sweep_s": 0.0,           # excitations shorter than this give no frequency response (time domain only)
    "max_raw_sweeps": 50,         # per-record estimates kept (most recent); the average pools all records
    "pre_s": 2.0,                 # trim kept before each manoeuvre [s]
    "post_s": 4.0,                # kept after it (the response settles) [s]
    "min_quiet_s": 1.0,           # trim that separates two manoeuvres [s]
    "max_record_s": 300.0,        # longer excitation is cut into records of this length [s]
    **SPECTRA_DEFAULTS,           # band_fraction, max_band_fraction, min_bins, order, transient_order
}
#: Options of the windowed (Welch) estimator that this one replaced: refused with an explanation.
RETIRED_OPTIONS = ("window_cycles", "min_window_s", "max_window_s", "overlap", "block_s", "detrend")
#: Why a frequency has no estimate (:attr:`SpectralEstimate.reasons` counts records per reason).
NOT_ESTIMABLE_REASONS = ("not_excited", "too_short", "above_grid", "too_few_bins", "below_trim")
_BOOL_OPTIONS = ("cubic_interpolation", "detect_sweeps")
_INT_OPTIONS = ("max_raw_sweeps", "min_bins", "order", "transient_order")
_EVENT_CAP = 64                  # pending edges
#: Dynamic pressure ratios an airspeed stream may scale the inputs by (airspeed 50-200 % of the model's trim);
#: samples beyond are clipped and counted (:attr:`FrequencyResponseEstimator.dynamic_pressure_ratio`).
DYNAMIC_PRESSURE_RANGE = (0.25, 4.0)
#: Time constant of the input's trim level followed outside the manoeuvres [s] (the airspeed scaling leaves it).
TRIM_FOLLOW_S = 2.0
_BUFFER_CAP = 256                # samples per stream buffered before processing (amortises per-call cost)
_ENERGY, _TRIGGER = 0, 1         # source of a record
_STATE_VERSION = 3               # 3: records and local polynomial sums (1, 2: windowed spectra, not resumable)
#: Sample intervals of each stream whose median gives its rate (the first ones: 2.6 s at 50 Hz).
RATE_STEPS = 128
#: How far before the detector's start a record reaches back (to the end of the previous record at most) [s]:
#: a sweep that starts slowly is seen late, and the record must begin at trim.
LOOKBACK_S = 10.0
#: A record is judged against the trim motion between the records (:mod:`gap_validation.core.background`): until
#: this much trim was transformed [s], closed records wait (at most :data:`PENDING_RECORDS` of them; at a break in
#: the data or at its end they are judged with what is known then).
TRIM_KNOWN_S = 20.0
PENDING_RECORDS = 8
#: Manoeuvres made of steps: not band-limited (:data:`gap_validation.core.spectra.ALIAS_MARGIN`).
_STEPPED_KINDS = ("doublet", "pulse", "multistep")
#: Manoeuvres up to this long are offered to the time-domain recorder (doublets, pulses, multisteps) [s].
_SHORT_MANOEUVRE_S = 20.0
#: Manoeuvre spans kept for :attr:`FrequencyResponseEstimator.record_spans_s`.
SPANS_KEPT = 256


# ---------------------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class SpectralEstimate:
    """Frequency response at the channel's frequencies: one record (raw), or pooled over records.

    Attributes
    ----------
    w_rad_s : ndarray
        Frequencies [rad/s].
    gxx, gyy : ndarray
        One-sided auto-spectral densities of input and output near each frequency (mean over the band's bins
        after the transient is removed) [unit^2/Hz].
    gxy : ndarray
        ``H gxx`` (complex) [unit_x unit_y/Hz].
    n_averages : ndarray
        Degrees of freedom of the noise estimate per frequency (bins minus every fitted coefficient); 0 where
        nothing was estimated.
    response : ndarray
        ``H(w)`` (complex; NaN where nothing was estimated).
    coherence : ndarray
        Multiple coherence of the local fit, ``1 - residual / output power`` in [0, 1]; 0 where nothing was
        estimated.
    random_error : ndarray
        Normalised random error of ``|H|`` (and the phase error in rad): ``sqrt(variance / 2) / |H|``; inf where
        nothing was estimated.
    start_s, end_s : float
        Time span (pooled: first start, last end) [s].
    n_sweeps : int
        Records pooled (1 for a raw estimate).
    variance : ndarray
        ``E |H_est - H|^2`` [unit_y^2/unit_x^2] (both components together).
    kind : str
        A raw estimate's manoeuvre kind (:data:`gap_validation.core.records.KINDS`); ``""`` when pooled.
    reasons : dict
        Per reason in :data:`NOT_ESTIMABLE_REASONS`: how many records did not count, per frequency (arrays).
    sums : BandSums or None
        The sufficient statistics (for :meth:`expected`); None for a raw estimate.
    band_fraction : float
        The estimator's ``band_fraction``.
    coefficients : int
        Complex coefficients of the response polynomial (``order + 1``).
    amplitude : float
        A raw estimate's input amplitude: ``sqrt(2)`` times the RMS of the first input over the manoeuvre's own
        span, its trim (linear trend) removed (the amplitude of a sinusoid of the same power; exactly the
        amplitude of a constant-amplitude chirp) [input units]; NaN when unknown or pooled
        (:func:`record_amplitude`).
    """

    w_rad_s: np.ndarray
    gxx: np.ndarray
    gyy: np.ndarray
    gxy: np.ndarray
    n_averages: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    random_error: np.ndarray
    start_s: float = float("nan")
    end_s: float = float("nan")
    n_sweeps: int = 1
    variance: np.ndarray | None = None
    kind: str = ""
    reasons: dict = field(default_factory=dict)
    sums: BandSums | None = None
    band_fraction: float = SPECTRA_DEFAULTS["band_fraction"]
    coefficients: int = SPECTRA_DEFAULTS["order"] + 1
    amplitude: float = float("nan")

    @classmethod
    def from_sums(cls, w_rad_s: ArrayLike, sums: BandSums, dt: float, band_fraction: float, start_s: float = float("nan"),
                  end_s: float = float("nan"), n_sweeps: int = 1, kind: str = "",
                  reasons: dict | None = None) -> "SpectralEstimate":
        """Solve :class:`~gap_validation.core.spectra.BandSums` into an estimate.

        Parameters
        ----------
        w_rad_s : array_like
            Frequencies [rad/s].
        sums : BandSums
            Local polynomial sums (one record or pooled).
        dt : float
            Grid step [s] (densities).
        band_fraction : float
            The estimator's ``band_fraction``.
        start_s, end_s : float
            Time span [s].
        n_sweeps : int
            Records in ``sums``.
        kind : str
            Manoeuvre kind of a raw estimate.
        reasons : dict, optional
            Records not counted, per reason and frequency.
        """
        local = solve_bands(sums)
        bins = np.maximum(sums.bins, 1)
        ok = np.isfinite(local.response)
        gxx = np.where(ok, 2.0 * dt * sums.input_power / bins, 0.0)
        gyy = np.where(ok, 2.0 * dt * sums.yy[:, 0, 0].real / bins, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            err = np.sqrt(local.variance / 2.0) / np.abs(local.response)
        err = np.where(ok & np.isfinite(err), err, np.inf)
        return cls(np.asarray(w_rad_s, float).copy(), gxx, gyy, np.where(ok, local.response * gxx, 0.0),
                   np.where(ok, local.dof, 0), local.response, np.where(ok, local.coherence, 0.0), err,
                   float(start_s), float(end_s), int(n_sweeps), np.where(ok, local.variance, np.inf), kind,
                   dict(reasons or {}), sums, float(band_fraction), sums.order + 1)

    #: Rows of :meth:`rows` (a raw estimate kept in fixed-size arrays).
    ROWS = ("response_re", "response_im", "variance", "n_averages", "coherence", "gxx", "gyy")

    def rows(self) -> np.ndarray:
        """The estimate as a (7, F) array (:data:`ROWS`): what a raw estimate keeps and checkpoints."""
        return np.stack([self.response.real, self.response.imag, self.variance, self.n_averages,
                         self.coherence, self.gxx, self.gyy]).astype(float)

    @classmethod
    def from_rows(cls, w_rad_s: ArrayLike, rows: np.ndarray, start_s: float, end_s: float, kind: str,
                  band_fraction: float, coefficients: int, amplitude: float = float("nan")) -> "SpectralEstimate":
        """Inverse of :meth:`rows` (a raw estimate).

        Parameters
        ----------
        w_rad_s : array_like
            Frequencies [rad/s].
        rows : ndarray, (7, F)
            From :meth:`rows`.
        start_s, end_s : float
            Time span [s].
        kind : str
            Manoeuvre kind.
        band_fraction : float
            The estimator's ``band_fraction``.
        coefficients : int
            ``order + 1``.
        amplitude : float, optional
            The record's input amplitude (:attr:`amplitude`).
        """
        response = rows[0] + 1j * rows[1]
        variance, n, coherence, gxx, gyy = rows[2], rows[3].astype(np.int64), rows[4], rows[5], rows[6]
        ok = np.isfinite(response)
        with np.errstate(divide="ignore", invalid="ignore"):
            err = np.where(ok, np.sqrt(variance / 2.0) / np.abs(response), np.inf)
        return cls(np.asarray(w_rad_s, float).copy(), gxx, gyy, np.where(ok, response * gxx, 0.0), n, response,
                   coherence, np.where(np.isfinite(err), err, np.inf), float(start_s), float(end_s), 1, variance,
                   kind, {}, None, float(band_fraction), int(coefficients), float(amplitude))

    @property
    def excited(self) -> np.ndarray:
        """Frequencies at which at least one record counted."""
        return np.isfinite(self.response)

    def select(self, index: slice | ArrayLike) -> "SpectralEstimate":
        """The estimate at the frequencies ``index`` only (a slice or index array).

        Parameters
        ----------
        index : slice or array_like
            Frequencies to keep.
        """
        arrays = {name: np.asarray(getattr(self, name))[index]
                  for name in ("w_rad_s", "gxx", "gyy", "gxy", "n_averages", "response", "coherence",
                               "random_error")}
        variance = None if self.variance is None else np.asarray(self.variance)[index]
        reasons = {k: np.asarray(v)[index] for k, v in self.reasons.items()}
        sums = None if self.sums is None else self.sums.take(index)
        return SpectralEstimate(**arrays, start_s=self.start_s, end_s=self.end_s, n_sweeps=self.n_sweeps,
                                variance=variance, kind=self.kind, reasons=reasons, sums=sums,
                                band_fraction=self.band_fraction, coefficients=self.coefficients,
                                amplitude=self.amplitude)

    def expected(self, model_response: Callable[[np.ndarray], ArrayLike]) -> tuple[np.ndarray, np.ndarray]:
        """The estimate a model would give through this estimator (see
        :func:`~gap_validation.core.spectra.expected_estimate`): ``(expected, expansion_error)``.

        Parameters
        ----------
        model_response : callable
            ``model_response(w_rad_s) -> complex array``.
        """
        if self.sums is None:
            return np.asarray(model_response(self.w_rad_s), complex), np.zeros(self.w_rad_s.shape)
        expected, error = expected_estimate(self.sums, self.w_rad_s, self.band_fraction, model_response)
        return np.where(self.excited, expected, np.nan + 0j), error


def record_amplitude(u: np.ndarray) -> float:
    """Input amplitude of one manoeuvre: ``sqrt(2)`` times the RMS of ``u`` about its least-squares line.

    The line removes the trim and a slow re-trim; ``sqrt(2) RMS`` is the amplitude of a sinusoid of the same
    power, so a constant-amplitude chirp gives its amplitude at every frequency it passes (what a describing
    function needs); for a multisine or a multistep it is the amplitude of the equivalent sinusoid.

    Parameters
    ----------
    u : ndarray
        Samples of the input over the manoeuvre's own span (uniform grid).

    Returns
    -------
    float
        The amplitude [input units]; NaN for fewer than 3 samples or non-finite data.
    """
    u = np.asarray(u, float).ravel()
    if u.size < 3 or not np.all(np.isfinite(u)):
        return float("nan")
    x = np.arange(u.size, dtype=float)
    coef = np.polyfit(x, u, 1)
    return float(math.sqrt(2.0) * np.std(u - np.polyval(coef, x)))


# ---------------------------------------------------------------------------------------------- options
def _number(name: str, value, positive: bool = True) -> float:
    """An estimator option's number (numeric strings accepted), > 0 or (``positive=False``) >= 0."""
    return check_number(value, f"estimator option {name}", POSITIVE if positive else NON_NEGATIVE, strings=True,
                        expected=f"a {'positive' if positive else 'non-negative'} finite number")


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


# ---------------------------------------------------------------------------------------------- records
class _RecordBuffer:
    """Grid samples of the manoeuvre in progress, with the trim before it (constant size).

    ``start(k)`` opens a record ``lookback_n`` samples before ``k`` (from a ring of the latest samples, at most
    back to the end of the previous record): the detector sees a slowly starting sweep late, and the record must
    begin at trim (the splitter measures the trim there and keeps ``pre_n`` of it). ``stop(k)``
    marks the end of the excitation; the record closes ``post_n`` samples after it once ``post_n + pre_n``
    samples passed without a new start (energy detection merges nearby excitations: the record is split into
    manoeuvres afterwards), at once when a trigger starts again (trigger records never merge), when it reaches
    ``cap`` samples, or at the end of a run. :meth:`feed` returns the closed records as
    ``(k0, samples, src, act0, act1)``: first grid index, samples (streams x n), source, and the excited span
    (relative indices) the edges gave. A full buffer calls ``on_full(k0, samples, src, act0)``, which processes
    what is complete and returns how many leading samples it took; the record goes on with the rest.
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
        if self.open and k_a != self.next_k:               # not contiguous (never expected): close what there is
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
            elif self.buf_n >= self.cap:                  # full (max_record_s): the owner takes what it can
                self._drop(self.on_full(self.k0, self.buf[:, : self.buf_n], self.src, max(0, self.on_k - self.k0)))
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
        """Forget the first ``n`` samples of the open record (the owner processed them); go on with the rest."""
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
        # every sample fed so far, the ones after the record's end included (the pre_n of quiet that closed it,
        # fed in earlier blocks): the trim after the record begins at its end whatever the blocks were
        self.closed_span = (self.k0, self.buf[:, :self.buf_n].copy())
        self.last_end_k = self.k0 + n
        self.open = False
        self.buf_n = 0
        return out

    def state_dict(self) -> dict:
        """State with the record's filled samples only (bounded by ``cap``)."""
        return {"ring": self.ring.copy(), "ring_k": self.ring_k, "buf": self.buf[:, : self.buf_n].copy(),
                "k0": self.k0, "open": int(self.open), "src": self.src, "on_k": self.on_k, "off_k": self.off_k,
                "last_end_k": self.last_end_k}

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
        With it, the last of ``streams`` is the airspeed (the flight condition), not an instrument: on the grid
        each input's deviation from its trim is multiplied by ``(airspeed / trim_airspeed)^2``, the dynamic
        pressure relative to the model's (control power scales with it), so gusts and small drifts of the
        condition do not read as a model error (:meth:`_at_trim_condition`). :attr:`dynamic_pressure_ratio` says
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
            raise ConfigError(f"estimator frequencies: expected positive finite rad/s values, got {w_rad_s!r}")
        names = tuple(str(s) for s in streams)
        scheduled = trim_airspeed is not None
        if len(set(names)) != len(names) or inputs < 1 or outputs < 1 or \
                inputs + outputs + int(scheduled) > len(names):
            raise ConfigError(f"estimator streams {names!r}: need distinct names, at least one input and one "
                              f"output ({inputs} inputs, {outputs} outputs{', the airspeed' if scheduled else ''})")
        if scheduled and not (math.isfinite(trim_airspeed) and trim_airspeed > 0):
            raise ConfigError(f"estimator trim_airspeed: expected a positive airspeed [m/s], got {trim_airspeed!r}")
        opts = _validate_options(w, options)
        self._w = w.copy()
        self._opts = opts
        self._names = names
        # other_inputs (issue 13): the channel's own input first, the others conditioned on and split on their own
        # (a MIMO channel's inputs, ``inputs[j]``, are split by :meth:`_pieces_per_stream` instead)
        self._conditioned = any(n.startswith("other_input") for n in names)
        self._m, self._p = int(inputs), int(outputs)
        fs = opts["sample_rate_hz"]
        self._dt = 1.0 / fs
        self._trim_airspeed = None if trim_airspeed is None else float(trim_airspeed)
        #: dynamic pressure ratio over the flight's grid samples: count, sum, min, max, and samples clipped
        self._q_stats = np.array([0.0, 0.0, np.inf, -np.inf, 0.0])
        #: each input's trim level (followed outside the manoeuvres, held in them): what is not scaled
        self._u_trim = np.full(int(inputs), np.nan)
        S_all = len(names)                       # every stream resampled and aligned
        S = S_all - int(scheduled)               # the data streams the records hold (the airspeed is not one)
        self._S = S
        self._det_streams = list(range(self._m + self._p, S)) or list(range(self._m))
        self._dets = [SweepDetector(fs, **{k: opts[k] for k in DETECTOR_DEFAULTS}) for _ in self._det_streams]
        self._det_on = [False] * len(self._dets)
        self._man = ManoeuvreRecorder(fs)
        self._trig = TriggerTracker()
        self._streams = [StreamResampler(self._dt, opts["max_gap_s"], opts["cubic_interpolation"])
                         for _ in range(S_all)]
        self._align = GridAligner(S_all, max(16, int(math.ceil(opts["max_lag_s"] * fs))))
        self._delay_n = max(d.lookahead_samples for d in self._dets)
        self._dl = np.zeros((S_all, self._delay_n))       # the airspeed too: the scaling follows the edges
        self._dl_n = 0
        self._dl_k0 = 0
        self._buf = np.zeros((S_all, 2, _BUFFER_CAP))      # stream, (t, value), sample
        self._buf_n = [0] * S_all
        # per stream: its first RATE_STEPS sample intervals (the rate is their median: fixed by the data alone,
        # not by how the samples were cut into calls), how many, and the last sample time
        self._steps = np.zeros((S_all, RATE_STEPS))
        self._spacing = np.zeros((S_all, 2))                 # per stream: intervals kept, last t
        self._spacing[:, 1] = -np.inf
        self._t0 = float("nan")
        self._last_k: int | None = None
        self._trigger_mode = not opts["detect_sweeps"]
        self._trig_base = TimeBase()
        self._jump_tol_s = jump_back_s(opts["max_gap_s"])
        self._jump_gap_s = 2.0 * opts["max_gap_s"] + 1.0     # between the old and the new time base [s]
        self._epoch = 0
        self._epoch_offset = 0.0
        self._events: list[tuple[int, bool, int]] = []
        self._events_dropped = 0
        self._rec = _RecordBuffer(S, int(round(opts["pre_s"] * fs)), int(round(opts["post_s"] * fs)),
                                  max(16, int(round(opts["max_record_s"] * fs))), self._record_full,
                                  int(round(LOOKBACK_S * fs)))
        F = w.size
        self._spectra_opts = {k: opts[k] for k in SPECTRA_DEFAULTS}
        # the trim motion between the records, per frequency (:mod:`gap_validation.core.background`)
        self._trim = TrimSpectrum(w, S, self._dt, opts["band_fraction"], opts["max_band_fraction"], LOOKBACK_S,
                                  lead=(0, self._m))
        self._tot = self._new_sums()
        self._tot_changes = 0                      # additions to _tot (the key of the cached averaged())
        self._averaged: tuple | None = None
        self._reasons = np.zeros((len(NOT_ESTIMABLE_REASONS), F), np.int64)
        self._raw: list[tuple[np.ndarray, int, int, str]] = []    # estimate rows, k0, k1, kind
        self._raw_amplitude: list[float] = []                       # input amplitude of each raw record
        self._raw_changes = 0                                       # records added to or dropped from _raw
        self._sweeps_built: tuple | None = None                     # (key, sweeps) of the last :attr:`sweeps`
        self._n_sweeps = 0
        self._span = [0, 0]
        self._kinds: Counter = Counter()
        self._counted: Counter = Counter()
        self._flown: Counter = Counter()       # manoeuvres long enough to estimate, per kind, whatever they gave
        self._longest_n = 0
        self._saturated = 0
        self._other_records = 0
        self._own_record = True
        self._declared = False                               # the record being estimated is a trigger's
        self._piece_stream: dict = {}                        # other_inputs: manoeuvre -> the input it belongs to
        self._spans: deque = deque(maxlen=SPANS_KEPT)     # grid spans of the latest manoeuvres (not checkpointed)
        self._pending: list[tuple[int, np.ndarray, int, int, int]] = []   # records waiting for the trim motion
        #: Called as ``record_observer(samples, kind, t0_s, dt_s)`` with the grid samples (streams x n) of the
        #: excited span of every manoeuvre of this channel that gives a response, its kind, the time of its first
        #: sample and the grid step (the coupling monitors of :mod:`gap_validation.core.closed_loop`); None:
        #: nobody. Not checkpointed. It returns False for a manoeuvre that is another surface's (the input
        #: following it through an interconnect): left out of the estimates and the counts.
        self.record_observer = None

    def _new_sums(self) -> BandSums:
        q = self._S - self._m - self._p
        return BandSums.zeros(self._w.size, self._m, self._p, q or None, self._opts["order"])

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
        sweeps = sum(n for kind, n in self._counted.items() if kind in SWEEP_KINDS)
        return sweeps or self._n_sweeps

    @property
    def n_manoeuvres(self) -> int:
        """Manoeuvres of any kind that gave a frequency response so far."""
        return self._n_sweeps

    def input_trim_motion(self) -> float:
        """Standard deviation of the (first) input's trim motion between the manoeuvres (0 before any)."""
        return self._motion(0)

    @property
    def flown_kinds(self) -> dict[str, int]:
        """Manoeuvres flown, per kind: those that gave a frequency response (:attr:`counted_kinds`) and, with a
        ``trigger``, every manoeuvre it marked that is long enough to estimate (``min_sweep_s``), whether it gave
        one or not (saturated, or nowhere 20 dB above the trim motion, as a loop answering turbulence leaves a
        sweep). A detected stretch that gives nothing is not counted: it cannot be told from trim wander. Another
        input's manoeuvres (``other_inputs``) are not this channel's."""
        return dict(self._flown)

    @property
    def counted_kinds(self) -> dict[str, int]:
        """Manoeuvres that gave a frequency response, per kind."""
        return dict(self._counted)

    @property
    def excitation(self) -> str | None:
        """The kind of excitation flown (JSON ``excitation``): the most frequent kind among the manoeuvres that
        gave a response (sweep kinds first on a tie), else among all seen; None before any."""
        counts = self._counted or Counter({k: v for k, v in self._kinds.items() if k != "step"})
        if not counts:
            return None
        order = ("chirp", "multisine", "multistep", "broadband", "doublet", "pulse")
        return max(counts, key=lambda k: (counts[k], -order.index(k) if k in order else -len(order)))

    @property
    def longest_record_s(self) -> float:
        """Length of the longest manoeuvre record so far [s] (0 before any)."""
        return self._longest_n * self._dt

    @property
    def saturated(self) -> int:
        """Manoeuvres not used because their excitation was pinned at its extremes (clipped; see
        :func:`gap_validation.core.records.saturated_share`)."""
        return self._saturated

    @property
    def not_estimable(self) -> dict[str, int]:
        """Per reason in :data:`NOT_ESTIMABLE_REASONS`: (record, frequency) pairs that gave nothing."""
        return {name: int(np.sum(self._reasons[i])) for i, name in enumerate(NOT_ESTIMABLE_REASONS)}

    @property
    def kinds(self) -> dict[str, int]:
        """Manoeuvres seen per kind (:data:`gap_validation.core.records.KINDS`), counted or not."""
        return dict(self._kinds)

    @property
    def in_sweep(self) -> bool:
        """True while a manoeuvre is being recorded (delayed by ``lookahead_samples``)."""
        return self._rec.open

    @property
    def t0_s(self) -> float:
        """Time origin of the grid [s] (NaN before the first sample)."""
        return self._t0

    @property
    def stream_rates_hz(self) -> np.ndarray:
        """Sample rate of each stream [Hz]: one over the median of its first :data:`RATE_STEPS` sample intervals
        (dropped messages and jitter aside; the same however the samples were cut into calls), to three
        significant digits; inf before two samples."""
        rates = []
        for s in range(self._S):                 # the data streams (the airspeed's rate carries no band)
            n = int(self._spacing[s, 0])
            step = float(np.median(self._steps[s, :n])) if n else 0.0
            rates.append(float(f"{1.0 / step:.3g}") if step > 0 else np.inf)
        return np.array(rates)

    @property
    def resolved_rad_s(self) -> float:
        """Highest frequency the streams resolve [rad/s]: no band reaches above it. A quarter of the slowest stream's
        rate (``RESOLVED_FRACTION``), or up to its Nyquist frequency for a slow stream whose sampling the faster
        streams of the other side show (:func:`~gap_validation.core.spectra.resolved_hz`)."""
        limit_hz, _ = resolved_hz(self.stream_rates_hz, self._m, self._p, self._opts["sample_rate_hz"])
        return float(2.0 * math.pi * limit_hz)

    @property
    def bad_sample_counts(self) -> dict:
        """Counts of samples not used, by stream and reason.

        ``nonfinite`` (NaN/inf time or value, or absurd: ``|t| >= 1e11`` s, ``|value| >= 1e100``),
        ``non_monotonic`` (time not after an earlier sample, within ``max(JUMP_BACK_S, max_gap_s)``, or a stray
        stamp further back), ``time_jumps_back`` (new time bases started: not samples lost, the data before and
        after both count), ``dropped_lag`` (grid values given up because another stream fell more than
        ``max_lag_s`` behind or had no data), and ``events_dropped`` (edges beyond the bounded queue).
        """
        out = {}
        for s, name in enumerate(self._names):
            b = self._streams[s].base
            out[name] = {"accepted": b.accepted, "nonfinite": b.nonfinite, "non_monotonic": b.non_monotonic,
                         "time_jumps_back": b.jumps, "dropped_lag": self._align.dropped[s]}
        b = self._trig_base
        out["trigger"] = {"accepted": b.accepted, "nonfinite": b.nonfinite, "non_monotonic": b.non_monotonic,
                          "time_jumps_back": b.jumps}
        out["events_dropped"] = self._events_dropped
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
            raise ConfigError(f"unknown stream {stream!r} (expected one of {', '.join(self._names)})") from None
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
        t, a = self._trig_base.intake(t, a.astype(float), self._jump_tol_s, self._new_base)
        if t.size == 0:
            return
        self._ensure_t0(t[0])
        k = np.ceil((t - self._t0) / self._dt - 1e-9).astype(np.int64)
        if not self._trigger_mode:
            for s in range(len(self._names)):
                self._drain(s)
            self._enter_trigger_mode(int(k[0]))
        for kk, on in self._trig.edges(k, a != 0):
            self._push_event(kk, on, _TRIGGER)

    def flush(self) -> None:
        """End of data (or a pause): process everything received and close the manoeuvre in progress."""
        S = len(self._names)
        for s in range(S):
            self._drain(s)
        self._trig_base.drop_pending()
        for s in range(S):
            self._streams[s].base.drop_pending()
            k, v = self._streams[s].flush()
            self._align.push(s, k, v)
        idx, vals = self._align.combine([st.k_next for st in self._streams])
        self._process_combined(idx, vals)
        self._align.clear()
        if self._last_k is not None:
            self._end_run()

    # ------------------------------------------------------------------ results
    @property
    def sweeps(self) -> list[SpectralEstimate]:
        """Raw estimate of each sweep (the most recent ``max_raw_sweeps``), oldest first.

        A *sweep* is a manoeuvre of a kind in :data:`~gap_validation.core.records.SWEEP_KINDS` (chirp,
        multisine, multistep, broadband): an identification experiment. Doublets and pulses add to the pooled
        estimate but are not sweeps, unless the flight has no sweep at all (then every manoeuvre is one).
        """
        # built again only when a record came or went (the node asks every diagnostics tick)
        key = (self._raw_changes, len(self._raw), self._t0)
        if self._sweeps_built is None or self._sweeps_built[0] != key:
            amplitudes = self._raw_amplitude + [float("nan")] * (len(self._raw) - len(self._raw_amplitude))
            raw = [(r, a) for r, a in zip(self._raw, amplitudes) if r[3] in SWEEP_KINDS] \
                or list(zip(self._raw, amplitudes))
            self._sweeps_built = (key, [SpectralEstimate.from_rows(self._w, rows, self._time(k0), self._time(k1), kind,
                                                                   self._opts["band_fraction"], self._opts["order"] + 1,
                                                                   amplitude)
                                        for (rows, k0, k1, kind), amplitude in raw])
        return list(self._sweeps_built[1])

    @property
    def record_spans_s(self) -> list[tuple[float, float]]:
        """Start and end [s] of the latest manoeuvres of any kind (up to 256): each manoeuvre's own excited span,
        without the trim kept around it; since the start of this process (not checkpointed)."""
        return [(self._time(a), self._time(b)) for a, b in self._spans]

    @property
    def manoeuvres(self) -> list[Manoeuvre]:
        """Short manoeuvres (doublets, pulses, multisteps) kept for the time-domain check (largest 3)."""
        return self._man.manoeuvres(self._t0, self._dt)

    @property
    def manoeuvres_key(self) -> bytes:
        """Changes exactly when :attr:`manoeuvres` changes."""
        return self._man.key

    def averaged(self) -> SpectralEstimate | None:
        """Estimate pooled over every manoeuvre so far (None before the first)."""
        if self._n_sweeps == 0:
            return None
        # solved again only when a manoeuvre changed the sums (the node asks every diagnostics tick)
        key = (id(self._tot), self._tot_changes, self._n_sweeps, tuple(self._span), self._reasons.tobytes(),
               self._t0)
        if self._averaged is None or self._averaged[0] != key:
            reasons = {name: self._reasons[i].copy() for i, name in enumerate(NOT_ESTIMABLE_REASONS)}
            self._averaged = (key, SpectralEstimate.from_sums(self._w, self._tot, self._dt,
                                                              self._opts["band_fraction"], self._time(self._span[0]),
                                                              self._time(self._span[1]), self._n_sweeps, "", reasons))
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
        if self._n_sweeps == 0:
            return None
        return solve_matrix(self._tot)

    @property
    def pooled_sums(self) -> BandSums:
        """The pooled local polynomial sums (a copy)."""
        return self._tot.copy()

    def _time(self, k: int) -> float:
        return float(self._t0 + k * self._dt)

    # ------------------------------------------------------------------ internals: streams
    def _ensure_t0(self, t: float) -> None:
        if math.isnan(self._t0):
            self._t0 = float(math.floor(t))

    def _add_stream(self, s: int, t_s, values, name: str) -> None:
        t = np.atleast_1d(np.asarray(t_s, dtype=float)).ravel()
        v = np.atleast_1d(np.asarray(values, dtype=float)).ravel()
        if t.shape != v.shape:
            raise DataError(f"{name}: {t.size} times but {v.size} values")
        n = self._buf_n[s]
        if n + t.size > _BUFFER_CAP or t.size > _BUFFER_CAP // 2:
            self._drain(s)                                  # keep time order: older samples first
            n = 0
        if t.size > _BUFFER_CAP // 2:
            self._process_stream(s, t, v)
            return
        buf = self._buf[s]
        buf[0, n:n + t.size] = t
        buf[1, n:n + t.size] = v
        self._buf_n[s] = n = n + t.size
        if n and not buf[0, n - 1] - buf[0, 0] < self._opts["batch_s"]:     # also on NaN times
            self._drain(s)

    def _drain(self, s: int) -> None:
        n = self._buf_n[s]
        if n:
            self._buf_n[s] = 0
            self._process_stream(s, self._buf[s, 0, :n].copy(), self._buf[s, 1, :n].copy())

    def _process_stream(self, s: int, t: np.ndarray, v: np.ndarray) -> None:
        st = self._streams[s]
        t, v = st.base.intake(t, v, self._jump_tol_s, self._new_base, self._jump_tol_s)
        if t.size == 0:
            return
        n = int(self._spacing[s, 0])
        if n < RATE_STEPS:
            steps = np.diff(t, prepend=self._spacing[s, 1])
            steps = steps[(steps > 0) & (steps <= self._opts["max_gap_s"])][: RATE_STEPS - n]
            self._steps[s, n:n + steps.size] = steps
            self._spacing[s, 0] = n + steps.size
        self._spacing[s, 1] = t[-1]
        self._ensure_t0(t[0])
        k, vals = st.add(t - self._t0, v)
        self._align.push(s, k, vals)
        idx, combined = self._align.combine([q.k_next for q in self._streams])
        self._process_combined(idx, combined)

    def _new_base(self, base: TimeBase, t_raw: float) -> None:
        """``base``'s time jumped back to ``t_raw`` [s] (confirmed): adopt the new time base another stream
        already opened, or open one just after the latest sample of every stream (a gap: the run ends)."""
        if self._epoch > base.epoch and t_raw + self._epoch_offset > base.latest_s + self._opts["max_gap_s"]:
            base.epoch, base.offset = self._epoch, self._epoch_offset
            return
        latest = max(b.latest_s for b in [st.base for st in self._streams] + [self._trig_base])
        self._epoch += 1
        # a whole number of grid steps: the new base samples the data at the same grid phase as before
        self._epoch_offset = math.ceil((latest + self._jump_gap_s - t_raw) / self._dt) * self._dt
        base.epoch, base.offset = self._epoch, self._epoch_offset

    def _process_combined(self, idx: np.ndarray, vals: np.ndarray) -> None:
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

    def _at_trim_condition(self, vals: np.ndarray) -> np.ndarray:
        """The data streams with each input's deviation from its trim scaled by the dynamic pressure ratio
        ``(V / V_trim)^2`` of the last stream, the airspeed (within :data:`DYNAMIC_PRESSURE_RANGE`: beyond it the
        sample is clipped and counted, a flight that far from the model's condition is not a test of it).

        Only the deviation: the model is about trim, where the surface's moment at the trim deflection balances
        the rest of the airframe's, all of them scaling with the dynamic pressure together. The trim level is
        followed outside the manoeuvres (time constant :data:`TRIM_FOLLOW_S`) and held while one is recorded; the
        manoeuvres are found on the logged surface, before scaling."""
        m = self._m
        if not self._rec.open or np.isnan(self._u_trim).any():
            first = np.isnan(self._u_trim)
            self._u_trim[first] = vals[:m, 0][first]
            alpha = 1.0 - math.exp(-vals.shape[1] * self._dt / TRIM_FOLLOW_S)
            self._u_trim += alpha * (np.mean(vals[:m], axis=1) - self._u_trim)
        ratio = (vals[-1] / self._trim_airspeed) ** 2
        low, high = DYNAMIC_PRESSURE_RANGE
        clipped = np.clip(ratio, low, high)
        st = self._q_stats
        st[0] += ratio.size
        st[1] += float(np.sum(clipped))
        st[2] = min(st[2], float(np.min(clipped)))
        st[3] = max(st[3], float(np.max(clipped)))
        st[4] += float(np.count_nonzero(clipped != ratio))
        out = vals[:-1].copy()
        trim = self._u_trim[:, None]
        out[:m] = trim + (out[:m] - trim) * clipped
        return out

    @property
    def dynamic_pressure_ratio(self) -> dict | None:
        """With an airspeed stream: the dynamic pressure relative to the model's, ``(V / V_trim)^2``, over the
        flight's grid samples (``mean``, ``min``, ``max``; ``clipped``: samples beyond
        :data:`DYNAMIC_PRESSURE_RANGE`); None without one or before a sample."""
        n, total, low, high, clipped = self._q_stats
        if self._trim_airspeed is None or not n:
            return None
        return {"mean": total / n, "min": low, "max": high, "clipped": int(clipped)}

    @property
    def trim_airspeed(self) -> float | None:
        """The airspeed the inputs are scaled to [m/s] (None: not scaled)."""
        return self._trim_airspeed

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

    def _enter_trigger_mode(self, k_switch: int) -> None:
        self._trigger_mode = True
        self._events = [e for e in self._events if e[0] < k_switch]
        self._det_on = [False] * len(self._dets)
        on = self._events[-1][1] if self._events else self._rec.open and self._rec.off_k == NO_INDEX
        if on:
            self._push_event(k_switch, False, _ENERGY)

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
        if self._trim_airspeed is not None:
            block = self._at_trim_condition(block)
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

    def _pieces(self, data: np.ndarray, src: int, act0: int, act1: int) -> list[Piece]:
        n = data.shape[1]
        if src == _TRIGGER:
            return [Piece(0, n, min(act0, n), max(min(act1, n), min(act0, n)))]
        if len(self._det_streams) > 1:
            return self._multi_pieces(data) if self._conditioned else self._pieces_per_stream(data)
        return self._split(data[self._det_streams[0]], 0, n, self._det_streams[0])

    def _motion(self, stream: int) -> float:
        """Standard deviation of a detection stream's trim motion between the records measured so far
        (:meth:`TrimSpectrum.std`: a pilot's corrections, a damper answering turbulence; 0 before any): splitting
        and classifying widen the band about trim by it (:func:`~gap_validation.core.records.trim_tolerance`)."""
        between = self._trim.std(stream)
        return between if math.isfinite(between) else 0.0

    def _multi_pieces(self, data: np.ndarray) -> list[Piece]:
        """Several inputs without an excitation signal (``other_inputs``): the manoeuvres of every input, each
        kept where its own input is the most excited (relative to its trim noise) over its excited span, so a
        surface that only follows another through an interconnect adds no manoeuvre of its own; in time order.
        :attr:`_piece_stream` remembers which input each one belongs to."""
        found = []
        noise = {s: max(trim_noise(data[s], self._dt), 1e-12) for s in self._det_streams}
        for s in self._det_streams:
            for piece in split_record(data[s], self._dt, noise[s], self._rec.pre_n, self._rec.post_n,
                                      self._opts["min_quiet_s"], self._motion(s)):
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
        still going (from its trim on); a single manoeuvre longer than the buffer is cut here. Records waiting for
        the trim motion are judged first (in time order)."""
        self._judge_pending(force=True)
        n = data.shape[1]
        pieces = self._pieces(data, src, act0, n)
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

        A manoeuvre that begins in the record's trim tail, after the detector's end of excitation, and runs to the
        record's last sample was cut by the record, not flown that short (a sweep that starts slowly is detected
        seconds late): it is left to the next record, which may reach back to its start."""
        if data.shape[1] < 4:
            return
        pieces = self._pieces(data, src, act0, act1)
        quiet_n = int(round(self._opts["min_quiet_s"] / self._dt))
        if src != _TRIGGER and pieces and pieces[-1].active_start >= act1 and pieces[-1].start > 0 and \
                pieces[-1].active_end > data.shape[1] - quiet_n:
            self._rec.last_end_k = k0 + pieces[-1].start
            data = data[:, :pieces[-1].start]
            act1 = min(act1, data.shape[1])
        self._pending.append((k0, data, src, act0, act1))
        self._judge_pending(force=len(self._pending) > PENDING_RECORDS)

    def _judge_pending(self, force: bool = False) -> None:
        """Split, classify and estimate the records that wait for the trim motion: all of them once it is known
        (:data:`TRIM_KNOWN_S`) or when ``force``-d (a break or the end of the data, a record too long to wait),
        else only the oldest beyond :data:`PENDING_RECORDS`."""
        while self._pending and (force or self._trim.seconds >= TRIM_KNOWN_S or len(self._pending) > PENDING_RECORDS):
            k0, data, src, act0, act1 = self._pending.pop(0)
            if data.shape[1] >= 4:
                self._estimate_pieces(k0, data, self._pieces(data, src, act0, act1), src == _TRIGGER)

    def _pieces_per_stream(self, data: np.ndarray) -> list[Piece]:
        """Several detection streams (a MIMO channel's inputs, flown one at a time): the record split by each
        stream on its own (a record may hold an aileron doublet and the rudder sweep after it). The manoeuvre
        that moves its stream most is kept first; a later one that overlaps kept ones keeps only what lies outside
        them (excited spans), split again on its own trim there (a surface the pilot re-trimmed during the other surface's sweep
        looks excited across it: its own sweep after it is a manoeuvre, the re-trim a trim step)."""
        found = []
        for n, s in enumerate(self._det_streams):
            det = data[s]
            for piece in self._split(det, 0, det.size, s):
                moved = float(np.var(det[piece.active_start:piece.active_end])) if piece.active_end > \
                    piece.active_start else 0.0
                found.append((moved, n, Piece(piece.start, piece.end, piece.active_start, piece.active_end,
                                              piece.group + n * 1_000_000)))
        kept: list[Piece] = []
        shortest = max(int(round(MIN_ACTIVE_S / self._dt)), 1)
        for _, n, piece in sorted(found, key=lambda item: -item[0]):
            gaps = [(piece.active_start, piece.active_end)]
            for k in kept:
                gaps = [part for lo, hi in gaps
                        for part in ((lo, min(hi, k.active_start)), (max(lo, k.active_end), hi)) if part[1] > part[0]]
            if gaps == [(piece.active_start, piece.active_end)]:
                kept.append(piece)
                continue
            for part, (lo, hi) in enumerate(gaps):
                if hi - lo < shortest:
                    continue
                end = piece.end if hi == piece.active_end else hi
                kept += [Piece(p.start + lo, p.end + lo, p.active_start + lo, p.active_end + lo,
                               piece.group + 1000 * (part + 1) + p.group)
                         for p in self._split(data[self._det_streams[n]], lo, end, self._det_streams[n])]
        return sorted(kept, key=lambda p: (p.start, p.active_start))

    def _split(self, det: np.ndarray, lo: int, hi: int, stream: int) -> list[Piece]:
        """:func:`~gap_validation.core.records.split_record` of ``det[lo:hi]`` (indices relative to ``lo``; ``det``
        is stream ``stream``)."""
        seg = det[lo:hi]
        return split_record(seg, self._dt, trim_noise(seg, self._dt), self._rec.pre_n, self._rec.post_n,
                            self._opts["min_quiet_s"], self._motion(stream)) if seg.size >= 3 else []

    def _detection_signal(self, data: np.ndarray, piece: Piece) -> int:
        """The stream a manoeuvre is classified by: the detection stream, or with several (a MIMO channel's
        inputs, flown one at a time) the one that varies most during the manoeuvre."""
        if len(self._det_streams) == 1:
            return self._det_streams[0]
        candidates = data[self._det_streams][:, piece.active_start:max(piece.active_end, piece.active_start + 1)]
        return self._det_streams[int(np.argmax(np.var(candidates, axis=1)))]

    def _estimate_pieces(self, k0: int, data: np.ndarray, pieces: list[Piece], declared: bool = False) -> None:
        """Classify and estimate a record's manoeuvres; ``declared``: the record is a trigger's (its manoeuvre
        counts as flown even where it gives no response)."""
        self._declared = declared
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
            # other_inputs: a manoeuvre of another input (its own sweep) pools into the average, which needs it to
            # separate the inputs, but is not a sweep of this channel (no raw estimate of its own)
            self._own_record = (not self._conditioned or det_index == self._det_streams[0]
                                or self._m + self._p < self._S)
            self._spans.append((k0 + piece.active_start, k0 + piece.active_end))
            kind = classify(det, self._dt, piece, noise, motion)
            self._kinds[kind] += 1
            active_s = (piece.active_end - piece.active_start) * self._dt
            seg = data[:, piece.start:piece.end]
            if kind in ("doublet", "pulse", "multistep") and active_s <= _SHORT_MANOEUVRE_S and self._own_record:
                self._man.offer(k0 + piece.start, seg[0], seg[self._m], k0 + piece.active_start,
                                k0 + piece.active_end, kind)
            if kind not in RESPONSE_KINDS or active_s < self._opts["min_sweep_s"]:
                continue
            if self.record_observer is not None and self._own_record and \
                    self.record_observer(data[:, piece.active_start:piece.active_end], kind,
                                         self._time(k0 + piece.active_start), self._dt) is False:
                continue             # another surface's manoeuvre, the input following it (an interconnect)
            if declared and self._own_record:      # a trigger's manoeuvre is flown, whatever it gives
                self._flown[kind] += 1
            if kind in ("chirp", "multisine", "broadband") and saturated_share(det, piece) >= SATURATED_SHARE:
                self._saturated += 1
                continue
            if kind == "multisine":          # whole periods only: its lines do not leak (nor another axis' lines)
                n_p = period(det[piece.active_start:piece.active_end], self._dt)
                # whole periods within the excited span (a fade is not periodic: the lines would leak)
                whole = (piece.active_end - piece.active_start) // n_p * n_p if n_p else 0
                if whole:
                    start = piece.active_start + (piece.active_end - piece.active_start - whole) // 2
                    seg = data[:, start:start + whole]
                    self._estimate_piece(k0 + start, seg, kind, noise, (k0 + start, k0 + start + whole))
                    continue
            self._estimate_piece(k0 + piece.start, seg, kind, noise,
                                 (k0 + piece.active_start, k0 + piece.active_end))

    def _estimate_piece(self, k_start: int, seg: np.ndarray, kind: str, noise: float,
                        active: tuple[int, int]) -> None:
        """Estimate one record (``seg`` from sample ``k_start``); ``active`` is the manoeuvre's own span, the
        time reported for it (the record adds trim before and after)."""
        self._longest_n = max(self._longest_n, seg.shape[1])
        m, p = self._m, self._p
        instruments = seg[m + p:] if seg.shape[0] > m + p else None
        rates = self.stream_rates_hz
        limit_hz, _ = resolved_hz(rates, m, p, self._opts["sample_rate_hz"])
        sums, status = record_bands(seg[:m], seg[m:m + p], self._dt, self._w, instruments=instruments,
                                    noise_floor=noise ** 2, background=self._background(instruments is not None),
                                    stepped=kind in _STEPPED_KINDS,
                                    options=self._spectra_opts,
                                    max_rad_s=float(2.0 * math.pi * limit_hz), rates_hz=rates,
                                    cubic=self._opts["cubic_interpolation"])
        counted = status == 0
        for i in range(len(NOT_ESTIMABLE_REASONS)):
            self._reasons[i] += status == i + 1
        if not counted.any():
            return
        self._tot.add(sums, counted)
        self._tot_changes += 1
        amplitude = record_amplitude(seg[0, max(active[0] - k_start, 0):max(active[1] - k_start, 0)])
        k_start, k_end = active
        if not self._own_record:
            self._n_sweeps += 1
            self._other_records += 1
            return
        if self._n_sweeps == self._other_records:
            self._span[0] = k_start
        self._span[1] = k_end
        self._n_sweeps += 1
        self._counted[kind] += 1
        if not self._declared:     # detected manoeuvres are flown where they gave a response (else: trim wander)
            self._flown[kind] += 1
        raw = SpectralEstimate.from_sums(self._w, sums, self._dt, self._opts["band_fraction"])
        self._raw.append((raw.rows(), k_start, k_end, kind))
        self._raw_changes += 1
        self._raw_amplitude.append(amplitude)
        if len(self._raw) > self._opts["max_raw_sweeps"]:
            self._raw.pop(0)
            self._raw_amplitude.pop(0)

    def between_manoeuvres(self) -> TrimResponse:
        """The response from the first input to the first output between the manoeuvres (the trim motion
        measured outside every record), its coherence and averages, and the input's trim motion per frequency in
        the units of the records' input power (:class:`~gap_validation.core.background.TrimResponse`)."""
        h, coherence, bins = self._trim.response(0, self._m)
        gain = interpolation_gain(self._w, self.stream_rates_hz[0], self._opts["cubic_interpolation"])
        return TrimResponse(h, coherence, bins / HANN_BINS_PER_AVERAGE,
                            self._trim.power([0]) / np.maximum(gain, 1e-3) ** 2)

    def surface_led(self) -> "LeadResult | None":
        """Whether the rate leads the surface between the manoeuvres (the first input and output;
        :class:`~gap_validation.core.background.LeadTest`); None before enough trim."""
        return self._trim.lead.result() if self._trim.lead is not None else None

    def _background(self, instruments: bool) -> np.ndarray:
        """The excitation's trim motion between the records per frequency (the instruments', else the inputs'
        summed), as :func:`~gap_validation.core.spectra.record_bands` sees a record: restored for the
        interpolation of each stream onto the grid, as the records are."""
        streams = range(self._m + self._p, self._S) if instruments else range(self._m)
        rates = self.stream_rates_hz
        gain = {j: interpolation_gain(self._w, rates[j], self._opts["cubic_interpolation"]) for j in streams}
        return sum(self._trim.power([j]) / np.maximum(gain[j], 1e-3) ** 2 for j in streams)

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """Complete state as a flat dict of numpy arrays and numbers (bounded size, whatever the flight length).

        :meth:`from_state` rebuilds an estimator that continues exactly where this one stopped.
        """
        st: dict = {"version": _STATE_VERSION, "w_rad_s": self._w.copy(),
                    "streams": np.array(self._names), "inputs": self._m, "outputs": self._p}
        if self._trim_airspeed is not None:
            st["trim_airspeed"] = self._trim_airspeed
            st["q_stats"] = self._q_stats.copy()
            st["u_trim"] = self._u_trim.copy()
        for name, value in self._opts.items():
            st["opt." + name] = int(value) if name in _BOOL_OPTIONS + _INT_OPTIONS else float(value)
        ev = np.zeros((_EVENT_CAP, 3), np.int64)
        for i, e in enumerate(self._events):
            ev[i] = e
        st.update({
            "t0": self._t0, "last_k": NO_INDEX if self._last_k is None else self._last_k,
            "trigger_mode": int(self._trigger_mode), "epoch": self._epoch, "epoch_offset": self._epoch_offset,
            "events": ev, "n_events": len(self._events), "events_dropped": self._events_dropped,
            "det_on": np.array(self._det_on, np.int64),
            "dl": self._dl.copy(), "dl_n": self._dl_n, "dl_k0": self._dl_k0,
            "buf": self._buf.copy(), "buf_n": np.array(self._buf_n, np.int64), "spacing": self._spacing.copy(),
            "rate_steps": self._steps.copy(),
            "n_sweeps": self._n_sweeps, "span": np.array(self._span, np.int64),
            "reasons": self._reasons.copy(), "n_raw": len(self._raw),
            **self._raw_state(),
            "kind_counts": np.array([self._kinds[k] for k in KINDS], np.int64),
            "counted_counts": np.array([self._counted[k] for k in KINDS], np.int64),
            "flown_counts": np.array([self._flown[k] for k in KINDS], np.int64),
            "longest_n": self._longest_n, "saturated": self._saturated,
        })
        if self._other_records:
            st["other_records"] = self._other_records
        st["pending_n"] = len(self._pending)
        for i, (k0, data, src, act0, act1) in enumerate(self._pending):
            st[f"pending{i}.data"] = data.copy()
            st[f"pending{i}.meta"] = np.array([k0, src, act0, act1], np.int64)
        st.update(self._tot.state_dict("tot."))
        parts = {"align": self._align, "trig": self._trig, "tbase": self._trig_base, "man": self._man,
                 "rec": self._rec, "trim": self._trim}
        parts.update({f"s{i}": s for i, s in enumerate(self._streams)})
        parts.update({f"det{i}": d for i, d in enumerate(self._dets)})
        for prefix, part in parts.items():
            for key, value in part.state_dict().items():
                st[f"{prefix}.{key}"] = value
        return st

    def _raw_state(self) -> dict:
        """The raw estimates in fixed-size arrays (``max_raw_sweeps`` slots)."""
        slots, F = self._opts["max_raw_sweeps"], self._w.size
        rows = np.full((slots, len(SpectralEstimate.ROWS), F), np.nan)
        meta = np.zeros((slots, 2), np.int64)
        kinds = np.full(slots, "", dtype="<U16")
        for i, (r, k0, k1, kind) in enumerate(self._raw):
            rows[i], meta[i], kinds[i] = r, (k0, k1), kind
        amplitude = np.full(slots, np.nan)
        amplitude[:len(self._raw_amplitude)] = self._raw_amplitude[:slots]
        return {"raw_rows": rows, "raw_meta": meta, "raw_kind": kinds, "raw_amplitude": amplitude}

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
            self = cls(np.asarray(state["w_rad_s"], float), names, int(state["inputs"]), int(state["outputs"]),
                       trim_airspeed, **opts)
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
        if self._trim_airspeed is not None:
            self._q_stats[:] = np.asarray(st["q_stats"], float)
            self._u_trim[:] = np.asarray(st["u_trim"], float)
        self._t0 = float(st["t0"])
        last_k = int(st["last_k"])
        self._last_k = None if last_k == NO_INDEX else last_k
        self._trigger_mode = bool(st["trigger_mode"])
        self._epoch, self._epoch_offset = int(st["epoch"]), float(st["epoch_offset"])
        ev = np.asarray(st["events"], np.int64)
        self._events = [(int(k), bool(on), int(src)) for k, on, src in ev[: int(st["n_events"])]]
        self._events_dropped = int(st["events_dropped"])
        self._det_on = [bool(v) for v in np.asarray(st["det_on"])]
        self._buf[:] = st["buf"]
        self._buf_n = [int(n) for n in st["buf_n"]]
        self._spacing[:] = st["spacing"]
        self._steps[:] = st["rate_steps"]
        self._dl[:] = st["dl"]
        self._dl_n, self._dl_k0 = int(st["dl_n"]), int(st["dl_k0"])
        self._n_sweeps = int(st["n_sweeps"])
        self._span = [int(v) for v in st["span"]]
        reasons = np.asarray(st["reasons"], np.int64)           # older checkpoints hold fewer reasons
        self._reasons[:] = 0
        self._reasons[:reasons.shape[0]] = reasons
        self._longest_n = int(st["longest_n"])
        self._saturated = int(st["saturated"])
        self._other_records = int(st.get("other_records", 0))
        self._pending = []
        for i in range(int(st.get("pending_n", 0))):
            k0, src, act0, act1 = (int(v) for v in np.asarray(st[f"pending{i}.meta"], np.int64))
            data = np.asarray(st[f"pending{i}.data"], float).reshape(self._S, -1)
            self._pending.append((k0, data.copy(), src, act0, act1))
        self._tot = BandSums.from_state(st, "tot.")
        self._averaged = None
        meta = np.asarray(st["raw_meta"], np.int64).reshape(-1, 2)
        kinds = [str(k) for k in np.atleast_1d(st["raw_kind"])]
        rows = np.asarray(st["raw_rows"], float)
        self._raw = [(rows[i].copy(), int(meta[i, 0]), int(meta[i, 1]), kinds[i]) for i in range(int(st["n_raw"]))]
        self._raw_changes += 1
        amplitude = np.asarray(st.get("raw_amplitude", np.full(int(st["n_raw"]), np.nan)), float).ravel()
        self._raw_amplitude = [float(amplitude[i]) if i < amplitude.size else float("nan")
                               for i in range(int(st["n_raw"]))]
        self._kinds = Counter({k: int(v) for k, v in zip(KINDS, st["kind_counts"]) if int(v)})
        self._counted = Counter({k: int(v) for k, v in zip(KINDS, st["counted_counts"]) if int(v)})
        # checkpoints before the count of manoeuvres flown: those that gave a response
        self._flown = Counter({k: int(v) for k, v in zip(KINDS, st.get("flown_counts", st["counted_counts"]))
                               if int(v)})
        parts = {"align": self._align, "trig": self._trig, "tbase": self._trig_base, "man": self._man,
                 "rec": self._rec}
        if any(k.startswith("trim.") for k in st):     # checkpoints before the trim spectrum start without it
            parts["trim"] = self._trim
        parts.update({f"s{i}": s for i, s in enumerate(self._streams)})
        parts.update({f"det{i}": d for i, d in enumerate(self._dets)})
        for prefix, part in parts.items():
            n = len(prefix) + 1
            part.load_state({k[n:]: v for k, v in st.items() if k.startswith(prefix + ".")})
