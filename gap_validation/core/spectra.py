"""Frequency responses of manoeuvres by the local polynomial method, pooled over manoeuvres.

Every manoeuvre (a sweep, a multisine, a 3-2-1-1, a doublet ...) is one *record*: the grid samples of its
signals from the trim before it to the trim after it. A record is transformed whole (``numpy.fft.rfft``,
normalised by ``sqrt(N)`` so that white noise has the same variance per bin whatever the record length) and
the response at each analysis frequency ``w`` is estimated from the DFT bins around it, the *band*
``|w_k - w| <= max(band_fraction w, min_bins/2 spacing)``, by the local polynomial method (Pintelon and
Schoukens, *System Identification: A Frequency Domain Approach*, 2nd ed., ch. 7; Pintelon et al.,
"Estimation of nonparametric noise and FRF models for multivariable systems", MSSP 24, 2010)::

    Y(w_k) = sum_j H_j(r) X_j(w_k) + T(r) + V(w_k),   r = (w_k - w) / (band_fraction w)

with ``H_j`` (the response from input j) and ``T`` (the transient: initial and final conditions of a record
that is not periodic, leakage) polynomials in ``r`` of low degree and ``V`` the noise. The transient has its
own coefficients in every record; the response polynomial is shared by all records, so the normal equations of
the records add up (the transient is projected out of each record first: Frisch-Waugh-Lovell) and the estimate
is the pooled least-squares (or, with an excitation signal as instrument, instrumental-variable) solution.
What is kept per analysis frequency is a handful of small matrices: memory does not grow with the flight.

What it gives per frequency: the response ``H(w)`` (the polynomial at r = 0), the noise variance from the
residuals with its real degrees of freedom (bins minus every fitted coefficient), the variance of ``H`` and
the multiple coherence ``1 - RSS / |Y|^2`` (fraction of the output explained, after the transient). A record
counts at a frequency only where its input is excited there (:func:`band_excited`: power at the band's centre
within 20 dB of the record's in-band level and 20 dB above the input noise floor, and no extrapolation from
one side of the band) and where the band stays within ``max_band_fraction`` of ``w`` (a short record cannot
resolve a low frequency: its bins are too far apart).

Bias. The local polynomial follows ``H`` only approximately over a wide band, and a lightly damped mode or a
short record makes the band wide. :meth:`PooledBands.expected` therefore gives the estimate a *model* would
produce through the very same estimator (the model expanded as a polynomial of degree ``order + 4`` over the
bands the records used): comparing the data with that, rather than with the model at ``w``, removes the
estimator's smoothing bias from the test whether data and model agree (the diagnosis does this).

Slow streams. The streams reach the grid by interpolation, whose gain :func:`interpolation_gain` restores;
below a stream's Nyquist frequency that is exact (the images of its sampling all lie above it), and the bands
must lie below what every stream resolves (:func:`resolved_hz`): a quarter of its rate, or for a slow stream
whose sampling faster streams witness, its Nyquist frequency (PX4's servos at 10 Hz: 31.4 rad/s, sweeps
validated to 28.6 rad/s). What the sampling folds back from above the Nyquist frequency (aliasing) is in the
logged samples and no filter removes it: a band counts only where the witnesses show it small
(:data:`MIRROR_MARGIN`, :data:`FOLD_NEAR`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

__all__ = [
    "SPECTRA_DEFAULTS",
    "BandSums",
    "record_bands",
    "interpolation_gain",
    "resolved_hz",
    "stream_limit_hz",
    "band_excited",
    "LocalEstimate",
    "solve_bands",
    "expected_estimate",
    "EXTRA_ORDER",
    "MatrixEstimate",
    "solve_matrix",
    "expected_matrix",
    "excitation_coherence",
    "partial_coherence",
    "RESOLVED_FRACTION",
    "SLOW_GRID_FRACTION",
    "MIRROR_MARGIN",
    "FOLD_NEAR",
    "sweep_points",
]

#: Options of the local polynomial estimate (estimator options of the same names).
SPECTRA_DEFAULTS = {
    "band_fraction": 0.1,         # band half-width relative to the frequency (before widening to min_bins)
    "max_band_fraction": 0.6,     # a wider band (a record too short for this frequency) is not used
    "min_bins": 7,                # DFT bins per band at least
    "order": 2,                   # degree of the response polynomial (shared by every record)
    "transient_order": 0,         # degree of the transient polynomial (one per record; -1: none)
}
#: :func:`record_bands` status codes: why a record does not count at a frequency (0: it counts).
STATUS_NOT_EXCITED, STATUS_TOO_SHORT, STATUS_ABOVE_GRID, STATUS_TOO_FEW_BINS, STATUS_BELOW_TRIM = (
    1,
    2,
    3,
    4,
    5,
)
#: Extra polynomial degree over which a model is expanded for :func:`expected_estimate`.
EXTRA_ORDER = 4
#: A band's centre power must be at least this fraction of the record's in-band level (20 dB) ...
_RELATIVE_EXCITATION = 1e-2
#: ... and at least this multiple of the input's noise floor (20 dB), when only the noise at the record's ends
#: is known (white noise from half a second of trim: it says nothing of coloured trim motion) ...
_EXCITATION_SNR = 1e2
#: The floor is the trim motion between the manoeuvres wherever it was measured on this flight at that
#: frequency (:class:`gap_validation.core.background.TrimSpectrum`): the manoeuvre then carries at least 99 %
#: of the input's power there, and what is not the manoeuvre -- sensor noise, which biases the response low by
#: its share (errors in variables), or trim motion -- stays within the 1 % systematic floor of the diagnosis.
#: A line elsewhere in the spectrum (a vibration answered by a rate loop) raises the floor only at its own
#: frequencies. Under "nothing flown" the central bins' mean power over the background is Gamma(n, 1/n) on n
#: >= 1 bins: it never reaches 100. A sampled input carries a frequency only while it is band-limited: its
#: power near the top of what its stream resolves (:data:`ALIAS_BAND`, a fraction of the Nyquist frequency of
#: the input's own rate or of the grid) must stay this far below its power at the frequency (20 dB): what lies
#: there continues, folded back unseen, above the Nyquist frequency. A manoeuvre with steps (a doublet, a
#: 3-2-1-1) has power falling only as 1/w^2 and continues above the Nyquist frequency, folded back unseen: a
#: step sampled between its samples is timed within half a sample interval only, an error in phase of w T/2
#: that grows with frequency (a doublet logged at 50 Hz: 30 deg at 56 rad/s, seen on the second simulator).
#: The error relative to the step's response is about the square root of that power ratio (10 % at 20 dB).
ALIAS_MARGIN = 1e2
#: Band near the top of what a stream resolves whose input power :data:`ALIAS_MARGIN` compares [fraction of
#: the stream's Nyquist frequency].
ALIAS_BAND = (0.6, 0.8)
#: Bins with less than this fraction of the largest input power near a frequency carry no input (between a
#: multisine's lines, another axis' harmonics, the nulls of a doublet): they are left out of its band.
_BIN_FLOOR = 1e-2
#: Highest usable bin relative to the Nyquist frequency of the grid (interpolation droop above).
_NYQUIST_FRACTION = 0.8
#: A stream sampled at fs resolves frequencies up to this fraction of fs (half its Nyquist frequency) when
#: nothing faster shows what its sampling folds back: the interpolation onto the grid loses magnitude below it
#: (cubic: 0.9 % at 0.15 fs, 6 % at 0.25 fs), which :func:`interpolation_gain` restores. A stream at half the
#: grid's rate (50 Hz on the 100 Hz grid) keeps it: the images of its sampling fold back onto the band through
#: the grid's own sampling, 0.6 % at 0.25 fs but 1.4 % at 0.45 fs.
RESOLVED_FRACTION = 0.25
#: A slow stream is read up to its Nyquist frequency (every bin of a band below it) when it is sampled at no
#: more than this fraction of the grid's rate (the images of its sampling then fold back onto the grid by less
#: than 0.1 %) and every stream of the other side (the outputs of an input, the excitation of an output)
#: resolves its whole rate (sampled at least four times faster): those *witnesses* show what its sampling
#: folds back (:data:`MIRROR_MARGIN`). A faster stream resolves at least as much as a slower one would (no
#: step down): ``max(RESOLVED_FRACTION fs, min(fs, SLOW_GRID_FRACTION grid, RESOLVED_FRACTION witness) / 2)``
#: (:func:`resolved_hz`); from twice this fraction of the grid's rate on (40 Hz on the 100 Hz grid, well below
#: the usual 50 Hz surfaces, jitter and all) that is a quarter of its rate, as for every stream before.
SLOW_GRID_FRACTION = 0.2
#: Sampling at fs folds a frequency fs - f above the Nyquist frequency onto f. Where a slow stream is read up
#: to its Nyquist frequency, a band counts only where its witnesses' power at the mirror frequencies ``fs -
#: f`` stays this far (30 dB) below their power in the band: the part of the slow stream folded onto the band
#: then stays below about 3 % of it in amplitude (the response's error: about a third of that, measured on
#: chirps ending near the Nyquist frequency). This replaces :data:`ALIAS_BAND` for such a stream: a sweep may
#: then run up to its Nyquist frequency; its tail past it, a manoeuvre flown past it, a doublet's steps are
#: refused where they fold (with :data:`FOLD_NEAR` below 0.4 of the rate).
MIRROR_MARGIN = 1e3
#: The witnesses' power at the mirror frequency ``fs - f`` tells what folds onto f while the response there is
#: about the response at f: for f above this fraction of fs (fs - f within 1.5 times f). Below it, what folds
#: back comes from beyond ``(1 - FOLD_NEAR) fs``, where a manoeuvre's power only falls off (a sweep's tail,
#: noise): at most what folds onto ``[FOLD_NEAR, 1/2] fs`` (:func:`_fold_bound`: all of the stream's power
#: there where the witnesses cannot tell), which a frequency's own power must exceed by :data:`ALIAS_MARGIN`
#: (20 dB: what folds that far comes from another part of a sweep, so it biases the response by about its
#: power ratio, 1 %). A manoeuvre flown far past the Nyquist frequency therefore counts nowhere, as before;
#: steps are held to :data:`ALIAS_BAND` too.
FOLD_NEAR = 0.4


@dataclass
class BandSums:
    """Sufficient statistics of the local polynomial fits at F frequencies (one record, or pooled).

    With ``m`` inputs, ``q`` instruments (the inputs themselves without an excitation signal) and ``p``
    outputs, ``nh = m (order + 1)`` response coefficients, ``ne = m (order + EXTRA_ORDER + 1)`` extended ones
    and ``nz = q (order + 1)`` instrument columns, per frequency (after the record's transient is projected
    out):

    Attributes
    ----------
    zf : ndarray, (F, nz, ne) complex
        Instruments times extended regressors ``Z^H Phi_ext``.
    zz : ndarray, (F, nz, nz) complex
        ``Z^H Z``.
    ff : ndarray, (F, nh, nh) complex
        ``Phi^H Phi`` (regressors of the response polynomial).
    zy, fy : ndarray, (F, nz, p) and (F, nh, p) complex
        ``Z^H Y`` and ``Phi^H Y``.
    yy : ndarray, (F, p, p) complex
        ``Y^H Y``.
    bins : ndarray, (F,) int
        DFT bins used.
    dof : ndarray, (F,) int
        Bins minus the transient coefficients of every record (the response coefficients are subtracted
        when solving).
    records : ndarray, (F,) int
        Records that contributed.
    r_lo, r_hi : ndarray, (F,)
        Range of the normalised band coordinate ``r`` over the bins used.
    input_power : ndarray, (F,)
        Sum over the bins of ``|X|^2`` of the first input (normalised DFT): spectra for plots.
    """

    zf: np.ndarray
    zz: np.ndarray
    ff: np.ndarray
    zy: np.ndarray
    fy: np.ndarray
    yy: np.ndarray
    bins: np.ndarray
    dof: np.ndarray
    records: np.ndarray
    r_lo: np.ndarray
    r_hi: np.ndarray
    input_power: np.ndarray

    @classmethod
    def zeros(cls, n_freq: int, inputs: int = 1, outputs: int = 1, instruments: int | None = None,
              order: int = 1) -> "BandSums":
        """Empty sums.

        Parameters
        ----------
        n_freq : int
            Frequencies.
        inputs, outputs : int
            Inputs m and outputs p.
        instruments : int, optional
            Instruments q (None: the inputs are their own instruments).
        order : int
            Degree of the response polynomial.
        """
        q = inputs if instruments is None else instruments
        nh, ne, nz = inputs * (order + 1), inputs * (order + EXTRA_ORDER + 1), q * (order + 1)
        c = complex
        return cls(
            np.zeros((n_freq, nz, ne), c),
            np.zeros((n_freq, nz, nz), c),
            np.zeros((n_freq, nh, nh), c),
            np.zeros((n_freq, nz, outputs), c),
            np.zeros((n_freq, nh, outputs), c),
            np.zeros((n_freq, outputs, outputs), c),
            np.zeros(n_freq, np.int64),
            np.zeros(n_freq, np.int64),
            np.zeros(n_freq, np.int64),
            np.full(n_freq, np.inf),
            np.full(n_freq, -np.inf),
            np.zeros(n_freq),
        )

    @property
    def inputs(self) -> int:
        """Number of inputs m (``ne - nh = m EXTRA_ORDER``)."""
        return (self.zf.shape[2] - self.ff.shape[1]) // EXTRA_ORDER

    @property
    def order(self) -> int:
        """Degree of the response polynomial."""
        return self.ff.shape[1] // self.inputs - 1

    def h_columns(self) -> np.ndarray:
        """Columns of the extended regressors that belong to the response polynomial."""
        per_e, per_h = self.order + EXTRA_ORDER + 1, self.order + 1
        return np.concatenate([np.arange(j * per_e, j * per_e + per_h) for j in range(self.inputs)])

    def add(self, other: "BandSums", where: np.ndarray | None = None) -> None:
        """Add another record's sums.

        Parameters
        ----------
        other : BandSums
            The record's sums (same shapes).
        where : ndarray of bool, optional
            Frequencies to add at (default all).
        """
        sel = np.ones(self.bins.size, bool) if where is None else np.asarray(where, bool)
        for name in ("zf", "zz", "ff", "zy", "fy", "yy", "bins", "dof", "records", "input_power"):
            getattr(self, name)[sel] += getattr(other, name)[sel]
        self.r_lo[sel] = np.minimum(self.r_lo[sel], other.r_lo[sel])
        self.r_hi[sel] = np.maximum(self.r_hi[sel], other.r_hi[sel])

    def take(self, index: slice | np.ndarray) -> "BandSums":
        """The sums at the frequencies ``index`` (a slice or index array).

        Parameters
        ----------
        index : slice or array_like
            Frequencies to keep.
        """
        return BandSums(*(np.array(getattr(self, f)[index]) for f in self.__dataclass_fields__))

    def copy(self) -> "BandSums":
        """An independent copy."""
        return BandSums(*(np.array(getattr(self, f)) for f in self.__dataclass_fields__))

    def state_dict(self, prefix: str = "") -> dict:
        """The arrays under ``prefix + name`` (checkpoints).

        Parameters
        ----------
        prefix : str
            Key prefix.
        """
        return {prefix + f: np.array(getattr(self, f)) for f in self.__dataclass_fields__}

    @classmethod
    def from_state(cls, state: dict, prefix: str = "") -> "BandSums":
        """Inverse of :meth:`state_dict`.

        Parameters
        ----------
        state : dict
            A checkpoint's arrays.
        prefix : str
            Key prefix.
        """
        return cls(*(np.array(state[prefix + f]) for f in cls.__dataclass_fields__))


def _line(v: np.ndarray, dt: float) -> np.ndarray:
    """Straight line through the means of the first and the last half second of each row of ``v``."""
    n = v.shape[-1]
    m = max(1, min(n // 4, int(round(0.5 / dt))))
    a, b = v[..., :m].mean(axis=-1), v[..., -m:].mean(axis=-1)
    ta, tb = (m - 1) / 2.0, n - 1 - (m - 1) / 2.0
    t = (np.arange(n) - ta) / max(tb - ta, 1e-12)
    return a[..., None] + (b - a)[..., None] * t


def band_bins(w_bins: np.ndarray, w: float, band_fraction: float, min_bins: int, max_band_fraction: float,
              power: np.ndarray | None = None) -> np.ndarray:
    """Indices of the DFT bins of the band around ``w`` (empty when the record is too short for ``w``).

    Parameters
    ----------
    w_bins : ndarray
        Bin frequencies [rad/s], uniformly spaced from 0.
    w : float
        Analysis frequency [rad/s].
    band_fraction, min_bins, max_band_fraction
        See :data:`SPECTRA_DEFAULTS`.
    power : ndarray, optional
        ``|X|^2`` of the excitation per bin: only bins with input (at least 1 % of the largest within
        ``max_band_fraction``) count, so a multisine's band holds its lines, not the empty bins between them.

    Returns
    -------
    ndarray of int
        The bins with input within ``band_fraction w`` of ``w``, or the nearest ``min_bins`` of them when
        fewer (positive frequencies only); none when those reach beyond ``max_band_fraction w``.
    """
    spacing = w_bins[1] - w_bins[0]
    reach = max_band_fraction * w
    lo = max(1, int(math.ceil((w - reach) / spacing - 1e-9)))
    hi = min(w_bins.size - 1, int(math.floor((w + reach) / spacing + 1e-9)))
    cand = np.arange(lo, hi + 1)
    if power is not None and cand.size:
        cand = cand[power[cand] >= _BIN_FLOOR * np.max(power[cand])]
    if cand.size < min_bins:
        return cand[:0]
    dist = np.abs(w_bins[cand] - w)
    inside = dist <= band_fraction * w
    if np.count_nonzero(inside) >= min_bins:
        return cand[inside]
    return np.sort(cand[np.argsort(dist, kind="stable")[:min_bins]])


def band_excited(
    power: np.ndarray, r: np.ndarray, reference: float, floor: float, alias: float = 0.0
) -> bool:
    """Whether a record excites its input at a band's centre.

    Parameters
    ----------
    power : ndarray
        ``|X_k|^2`` of the excitation (normalised DFT) at the band's bins.
    r : ndarray
        Normalised band coordinate of those bins (0 at the analysis frequency).
    reference : float
        The record's in-band level of ``|X|^2`` (:func:`record_bands`).
    floor : float
        ``|X|^2`` of what is not the manoeuvre at this frequency: the trim motion measured between the
        manoeuvres, else the input's noise (its variance per sample); 0 when unknown.
    alias : float
        The record's mean ``|X|^2`` near the top of what its excitation's stream resolves
        (:data:`ALIAS_BAND`).

    Returns
    -------
    bool
        The mean power of the central bins (``|r| <= 0.25`` of the band, at least the nearest bin) is within
        20 dB of ``reference``, 20 dB above ``floor`` and 20 dB above ``alias`` (:data:`ALIAS_MARGIN`), and
        the band's power is not all on one side (power-weighted mean of ``r`` within half the band's extent):
        no extrapolation past the end of a sweep.
    """
    extent = max(float(np.max(np.abs(r))), 1e-12)
    central = np.abs(r) <= 0.25 * extent
    if not central.any():
        central = np.abs(r) == np.min(np.abs(r))
    level = float(np.mean(power[central]))
    total = float(np.sum(power))
    if not (total > 0.0 and level >= _RELATIVE_EXCITATION * reference and level >= _EXCITATION_SNR * floor
            and level >= ALIAS_MARGIN * alias):
        return False
    return abs(float(np.sum(power * r)) / total) <= 0.5 * extent


def _alias_level(power: np.ndarray, w_bins: np.ndarray, dt: float, rates_hz: Sequence[float]) -> float:
    """Mean excitation power over :data:`ALIAS_BAND` of the lowest Nyquist frequency among the excitation's
    streams (their own rates, and the grid's); 0 when that band holds no bin."""
    nyquist = math.pi / dt
    for rate in rates_hz:
        if math.isfinite(rate) and rate > 0:
            nyquist = min(nyquist, math.pi * rate)
    band = (w_bins >= ALIAS_BAND[0] * nyquist) & (w_bins <= ALIAS_BAND[1] * nyquist)
    return float(np.mean(power[band])) if band.any() else 0.0


def _kernel_gain_table(cubic: bool) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(-2.0, 2.0, 4001)
    a = np.abs(t)
    if cubic:  # Keys' cubic convolution with a = -1/2 (Catmull-Rom on uniform samples)
        h = np.where(
            a < 1, 1.5 * a**3 - 2.5 * a**2 + 1, np.where(a < 2, -0.5 * a**3 + 2.5 * a**2 - 4 * a + 2, 0)
        )
    else:            # linear interpolation: the triangle
        h = np.clip(1.0 - a, 0.0, None)
    nu = np.linspace(0.0, 0.5, 501)
    return nu, np.trapezoid(h[None, :] * np.cos(2.0 * np.pi * nu[:, None] * t[None, :]), t, axis=1)


_GAIN_TABLES: dict[bool, tuple[np.ndarray, np.ndarray]] = {}


def interpolation_gain(w_rad_s: np.ndarray, rate_hz: float, cubic: bool = True) -> np.ndarray:
    """Magnitude a stream sampled at ``rate_hz`` keeps at ``w_rad_s`` once interpolated onto the grid.

    The Fourier transform of the interpolation kernel (Catmull-Rom, or linear) at ``nu = w / (2 pi rate)``
    cycles per sample: the mean over the phases at which the grid falls between samples (0.991 at nu = 0.15,
    0.939 at 0.25). 1 for a stream of unknown rate.

    Parameters
    ----------
    w_rad_s : ndarray
        Frequencies [rad/s].
    rate_hz : float
        The stream's mean sample rate [Hz].
    cubic : bool
        Cubic (the estimator's default) or linear interpolation.
    """
    w = np.asarray(w_rad_s, float)
    if not math.isfinite(rate_hz) or rate_hz <= 0:
        return np.ones(w.shape)
    if cubic not in _GAIN_TABLES:
        _GAIN_TABLES[cubic] = _kernel_gain_table(cubic)
    nu, gain = _GAIN_TABLES[cubic]
    return np.interp(w / (2.0 * math.pi * rate_hz), nu, gain)


def stream_limit_hz(rate_hz: float, grid_hz: float, witness_hz: float) -> float:
    """Highest frequency a band may reach with a stream sampled at ``rate_hz`` [Hz]: ``max(RESOLVED_FRACTION
    rate, min(rate, SLOW_GRID_FRACTION grid_hz, RESOLVED_FRACTION witness_hz) / 2)``
    (:data:`SLOW_GRID_FRACTION`); above ``RESOLVED_FRACTION rate`` the stream is *folded*
    (:data:`MIRROR_MARGIN`).

    Parameters
    ----------
    rate_hz : float
        The stream's rate [Hz].
    grid_hz : float
        The grid's rate [Hz].
    witness_hz : float
        Rate of the slowest stream of the other side [Hz] (0: none known; inf: fast enough).
    """
    return max(RESOLVED_FRACTION * rate_hz, 0.5 * min(rate_hz, SLOW_GRID_FRACTION * grid_hz,
                                                     RESOLVED_FRACTION * witness_hz))


def resolved_hz(rates_hz: Sequence[float], inputs: int, outputs: int,
                grid_hz: float) -> tuple[float, tuple[tuple[int, float, tuple[int, ...]], ...]]:
    """Highest frequency a band may reach with streams at these rates, and the slow streams read up to their
    Nyquist frequency.

    Each stream resolves up to :func:`stream_limit_hz` of its rate, its witness the slowest stream of the
    other side: the outputs for an input or an excitation, the excitation (else the inputs) for an output. A
    stream whose limit is above ``RESOLVED_FRACTION fs`` is *folded*: its bands are checked against what its
    sampling folds back (:data:`MIRROR_MARGIN`). Streams of unknown rate (not finite) limit nothing, nor
    witness anything.

    Parameters
    ----------
    rates_hz : sequence of float
        Sample rate of each stream [Hz]: ``inputs`` inputs, ``outputs`` outputs, then the excitation signals.
    inputs, outputs : int
        How many of them are inputs and outputs.
    grid_hz : float
        The grid's rate [Hz].

    Returns
    -------
    limit_hz : float
        The lowest of the streams' limits [Hz] (inf when no rate is known).
    folded : tuple of (int, float, tuple of int)
        Per folded stream: its index, its rate [Hz] and its witnesses' indices.
    """
    rates = [float(r) for r in rates_hz]
    excitation = tuple(range(inputs + outputs, len(rates))) or tuple(range(inputs))
    outs = tuple(range(inputs, inputs + outputs))
    limit, folded = math.inf, []
    for j, rate in enumerate(rates):
        if not (math.isfinite(rate) and rate > 0):
            continue
        witnesses = excitation if inputs <= j < inputs + outputs else outs
        known = [rates[w] for w in witnesses if math.isfinite(rates[w]) and rates[w] > 0]
        witness = min(known) if len(known) == len(witnesses) and known else 0.0
        own = stream_limit_hz(rate, grid_hz, witness)
        if own > RESOLVED_FRACTION * rate:
            folded.append((j, rate, witnesses))
        limit = min(limit, own)
    return limit, tuple(folded)


def _mirror_excess(power: np.ndarray, floor: float, sel: np.ndarray, w_bins: np.ndarray, rate_hz: float,
                   sigmas: float = -3.0) -> float:
    """What a stream sampled at ``rate_hz`` folds onto a band, seen by its witnesses: their power (``power``
    per bin) at the mirror frequencies ``rate - f`` of the band's bins beyond their noise (``floor`` per bin;
    plus ``sigmas`` standard deviations of its sum over the bins: -3 what is surely there, +3 what may be
    there), relative to their power in the band; inf where a mirror bin lies beyond the spectrum or the band
    holds no power."""
    spacing = w_bins[1] - w_bins[0]
    mirror = np.rint((2.0 * math.pi * rate_hz - w_bins[sel]) / spacing).astype(np.int64)
    if mirror.min() < 0 or mirror.max() >= w_bins.size:
        return math.inf
    inside = float(np.sum(power[sel]))
    excess = float(np.sum(power[mirror])) - floor * (sel.size - sigmas * math.sqrt(sel.size))
    return max(excess, 0.0) / inside if inside > 0 else math.inf


def _fold_bound(own: np.ndarray, seen: np.ndarray, floor: float, w_bins: np.ndarray, rate_hz: float) -> float:
    """Bound of the power per bin a stream sampled at ``rate_hz`` folds onto frequencies below
    :data:`FOLD_NEAR` of its rate: what lies above ``(1 - FOLD_NEAR) rate`` falls off from there on (a sweep's
    tail, steps, noise), so it is at most what folds onto each sub-band of ``[FOLD_NEAR, 1/2] rate``: the
    stream's ``own`` power there times the share of it its witnesses may show folded (their mirror power
    beyond their noise, three standard deviations included, over their power there: the response barely
    changes between f and rate - f; at most all of it, where they see nothing). The least of those."""
    spacing = w_bins[1] - w_bins[0]
    edges = 2.0 * math.pi * rate_hz * np.linspace(FOLD_NEAR, 0.5, 6)
    bound = math.inf
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = np.flatnonzero((w_bins >= lo) & (w_bins < hi))
        if sel.size == 0 or np.rint((2.0 * math.pi * rate_hz - w_bins[sel]) / spacing).max() >= w_bins.size:
            continue
        share = min(1.0, _mirror_excess(seen, floor, sel, w_bins, rate_hz, sigmas=3.0))
        bound = min(bound, share * float(np.mean(own[sel])))
    return bound


def _noise_floor(power: np.ndarray, w_bins: np.ndarray, rate_hz: float, top_rad_s: float) -> float:
    """Median power per bin of the witnesses between the slow stream's rate and twice it (at most
    ``top_rad_s``): above both the manoeuvre and its mirror, their noise; 0 when that holds no bin."""
    lo = 2.0 * math.pi * rate_hz
    band = (w_bins >= lo) & (w_bins <= min(2.0 * lo, top_rad_s))
    return float(np.median(power[band])) if band.any() else 0.0


def _vander(r: np.ndarray, degree: int) -> np.ndarray:
    return np.vander(r, degree + 1, increasing=True)


def record_bands(
    inputs: np.ndarray,
    outputs: np.ndarray,
    dt: float,
    w_rad_s: np.ndarray,
    *,
    instruments: np.ndarray | None = None,
    noise_floor: float = 0.0,
    background: np.ndarray | None = None,
    stepped: bool = False,
    options: dict | None = None,
    max_rad_s: float = math.inf,
    rates_hz: Sequence[float] | None = None,
    cubic: bool = True,
) -> tuple[BandSums, np.ndarray]:
    """Local polynomial sums of one record at every analysis frequency, and where the record is excited.

    Parameters
    ----------
    inputs : ndarray, (m, N)
        Input samples on the uniform grid (m inputs).
    outputs : ndarray, (p, N)
        Output samples on the same grid.
    dt : float
        Grid step [s].
    w_rad_s : ndarray, (F,)
        Analysis frequencies [rad/s].
    instruments : ndarray, (q, N), optional
        Excitation signals (instrumental variables); default: the inputs (least squares).
    noise_floor : float
        Variance per sample of the excitation's noise (0: unknown); see :func:`band_excited`.
    background : ndarray, (F,), optional
        The excitation's trim motion between manoeuvres per analysis frequency, in the same units as the
        record's normalised ``|X|^2`` (:meth:`gap_validation.core.background.TrimSpectrum.power`); NaN where
        it was not measured (``noise_floor`` stands in there).
    options : dict, optional
        :data:`SPECTRA_DEFAULTS` entries.
    max_rad_s : float
        Highest frequency the measured streams resolve [rad/s] (their sample rates, :func:`resolved_hz`):
        bands reaching above it do not count.
    rates_hz : sequence of float, optional
        Mean sample rate of each signal (inputs, outputs, instruments) [Hz]: each spectrum is divided by its
        :func:`interpolation_gain`, so streams sampled at different rates do not bias the response; and a slow
        stream read up to its Nyquist frequency (:func:`resolved_hz`) counts only where its witnesses show
        that little folds back onto the band (:data:`MIRROR_MARGIN`, :data:`FOLD_NEAR`; status 1 otherwise),
        instead of
        :data:`ALIAS_BAND`.
    cubic : bool
        The interpolation onto the grid was cubic (else linear).
    stepped : bool
        The manoeuvre is made of steps (a doublet, a pulse, a multistep): not band-limited, its power near the
        top of what its stream carries continues above it (:data:`ALIAS_MARGIN`); a sweep or a multisine is
        held to that only when its own power reaches the band (flown past what the stream carries).

    Returns
    -------
    sums : BandSums
        The record's sums (zero where it does not count).
    status : ndarray of int, (F,)
        0 where the record counts, else why not: 1 the input is not excited there (:func:`band_excited`, or
        what a slow stream folds back stands too close to it),
        2 the record is too short to resolve the frequency (band beyond ``max_band_fraction``), 3 the band
        reaches above what the streams resolve (``max_rad_s``, or 0.8 of the grid's Nyquist frequency), 4 too
        few bins with input left for a degree of freedom, 5 the input is excited but not 20 dB above its trim
        motion between the manoeuvres (``background``).
    """
    opts = {**SPECTRA_DEFAULTS, **(options or {})}
    order, t_order = int(opts["order"]), int(opts["transient_order"])
    u = np.atleast_2d(np.asarray(inputs, float))
    y = np.atleast_2d(np.asarray(outputs, float))
    z = u if instruments is None else np.atleast_2d(np.asarray(instruments, float))
    n = u.shape[1]
    w = np.asarray(w_rad_s, float)
    m, p, q = u.shape[0], y.shape[0], z.shape[0]
    sums = BandSums.zeros(w.size, m, p, q if instruments is not None else None, order)
    status = np.full(w.size, STATUS_TOO_SHORT, np.int64)
    if n < 2 * int(opts["min_bins"]) + 2:
        return sums, status
    scale = 1.0 / math.sqrt(n)
    fu = np.fft.rfft(u - _line(u, dt), axis=1) * scale
    fy = np.fft.rfft(y - _line(y, dt), axis=1) * scale
    fz = fu if instruments is None else np.fft.rfft(z - _line(z, dt), axis=1) * scale
    w_bins = 2.0 * math.pi * np.fft.rfftfreq(n, dt)
    if rates_hz is not None:
        rates = list(rates_hz)
        for j in range(m):
            fu[j] /= interpolation_gain(w_bins, rates[j], cubic)
        for j in range(p):
            fy[j] /= interpolation_gain(w_bins, rates[m + j], cubic)
        if instruments is not None:
            fz = fz.copy()
            for j in range(q):
                fz[j] /= interpolation_gain(w_bins, rates[m + p + j], cubic)
    usable = w_bins <= min(_NYQUIST_FRACTION * math.pi / dt, max_rad_s)
    power = np.sum(np.abs(fz) ** 2, axis=0)
    bands = [
        band_bins(w_bins, wi, opts["band_fraction"], int(opts["min_bins"]), opts["max_band_fraction"], power)
        for wi in w
    ]
    status[:] = [STATUS_TOO_SHORT if b.size == 0 else STATUS_ABOVE_GRID if not usable[b].all() else 0
                 for b in bands]
    bands = [b if status[i] == 0 else b[:0] for i, b in enumerate(bands)]
    folded: tuple = ()
    if rates_hz is not None:
        folded = resolved_hz(rates, m, p, 1.0 / dt)[1]
    # slow streams read up to their Nyquist frequency: what they fold back is judged from their witnesses'
    # mirror power per band (below), not from their own power near the top (ALIAS_BAND), unless the manoeuvre
    # is made of steps (not band-limited: both)
    excitation = [j for j in (range(m + p, m + p + q) if instruments is not None else range(m))
                  if stepped or j not in {f[0] for f in folded}]
    alias = _alias_level(power, w_bins, dt, [rates[j] for j in excitation] if rates_hz is not None else [])
    mirrors = []

    def spectrum(j: int) -> np.ndarray:
        return fu[j] if j < m else fy[j - m] if j < m + p else fz[j - m - p]

    for j, rate, witnesses in folded:
        seen = sum(np.abs(spectrum(k)) ** 2 for k in witnesses)
        own = np.abs(spectrum(j)) ** 2
        floor = _noise_floor(seen, w_bins, rate, _NYQUIST_FRACTION * math.pi / dt)
        mirrors.append((rate, seen, floor, own, _fold_bound(own, seen, floor, w_bins, rate)))
    centre = [float(np.mean(power[b])) for b in bands if b.size]
    reference = float(np.median([c for c in centre if c >= 1e-3 * max(centre)])) if centre else 0.0
    if rates_hz is None or not (stepped or alias >= _RELATIVE_EXCITATION * reference):
        # samples of the grid itself, or a band-limited manoeuvre that stays below the band
        alias = 0.0
    for i, (wi, sel) in enumerate(zip(w, bands)):
        if sel.size == 0:
            continue
        r = (w_bins[sel] - wi) / (opts["band_fraction"] * wi)
        if not band_excited(power[sel], r, reference, noise_floor, alias):
            status[i] = STATUS_NOT_EXCITED
            continue
        if background is not None and math.isfinite(background[i]) and background[i] > 0 and \
                not band_excited(power[sel], r, reference, float(background[i]), alias):
            status[i] = STATUS_BELOW_TRIM
            continue
        if any(
            _mirror_excess(seen, floor, sel, w_bins, rate) * MIRROR_MARGIN > 1.0
            or (
                wi < 2.0 * math.pi * FOLD_NEAR * rate and not float(np.mean(own[sel])) >= ALIAS_MARGIN * bound
            )
            for rate, seen, floor, own, bound in mirrors
        ):
            status[i] = STATUS_NOT_EXCITED
            continue
        dof = sel.size - (t_order + 1)
        # bins carrying the input (the participation ratio of its power) must outnumber the response's
        # coefficients by one and a half: a few strong lines among weak bins (a sparse multisine in a widened
        # band) fix the response with nothing left to check it against
        carried = float(np.sum(power[sel]) ** 2 / max(np.sum(power[sel] ** 2), 1e-300))
        # several inputs: only those this record excites here carry coefficients it must determine
        # (single-axis sweeps flown in turn, MIMO or other_inputs: each record usually one input; the pooled
        # sums determine them all); with instruments every input's coefficients are solved from this record's
        # instruments
        m_here = m if m == 1 or instruments is not None else 1
        if dof < 1 + m_here * (order + 1) or carried < 1.5 + m_here * (order + 1):
            status[i] = STATUS_TOO_FEW_BINS
            continue
        q_t = np.linalg.qr(_vander(r, t_order))[0] if t_order >= 0 else np.zeros((r.size, 0))

        def project(a: np.ndarray) -> np.ndarray:
            return a - q_t @ (q_t.T @ a)

        v_ext = _vander(r, order + EXTRA_ORDER)
        phi_ext = project(np.concatenate([v_ext * fu[j, sel][:, None] for j in range(m)], axis=1))
        phi = np.concatenate(
            [
                phi_ext[:, j * (order + EXTRA_ORDER + 1) : j * (order + EXTRA_ORDER + 1) + order + 1]
                for j in range(m)
            ],
            axis=1,
        )
        zeta = phi if instruments is None else project(
            np.concatenate([_vander(r, order) * fz[j, sel][:, None] for j in range(q)], axis=1))
        yp = project(fy[:, sel].T)
        zh = zeta.conj().T
        sums.zf[i], sums.zz[i] = zh @ phi_ext, zh @ zeta
        sums.ff[i], sums.zy[i] = phi.conj().T @ phi, zh @ yp
        sums.fy[i], sums.yy[i] = phi.conj().T @ yp, yp.conj().T @ yp
        sums.bins[i], sums.dof[i], sums.records[i] = sel.size, dof, 1
        sums.r_lo[i], sums.r_hi[i] = float(r.min()), float(r.max())
        sums.input_power[i] = float(np.sum(np.abs(fu[0, sel]) ** 2))
    return sums, status


@dataclass(frozen=True)
class LocalEstimate:
    """Responses solved from :class:`BandSums` (SISO view: first input, first output).

    Attributes
    ----------
    response : ndarray, (F,) complex
        ``H(w)``; NaN where nothing was estimated.
    variance : ndarray, (F,)
        ``E |H_est - H|^2`` (complex variance, both components together); inf where unknown.
    dof : ndarray, (F,) int
        Degrees of freedom of the noise variance (bins minus every fitted coefficient).
    coherence : ndarray, (F,)
        Multiple coherence ``1 - RSS / |Y|^2`` of the fit (0 where nothing was estimated).
    noise : ndarray, (F,)
        Noise variance per bin (residual sum of squares over the degrees of freedom), never below its
        neighbours' pooled estimate (:func:`neighbour_noise_floor`).
    """

    response: np.ndarray
    variance: np.ndarray
    dof: np.ndarray
    coherence: np.ndarray
    noise: np.ndarray


def solve_bands(sums: BandSums) -> LocalEstimate:
    """Solve the pooled local polynomial fits of :class:`BandSums` (least squares or instrumental variables).

    Parameters
    ----------
    sums : BandSums

    Returns
    -------
    LocalEstimate
        With ``nh`` response coefficients per frequency the degrees of freedom are ``dof - nh``; a frequency
        with fewer than one degree of freedom or a singular system is NaN / inf / 0. The noise variance (and
        with it the response's) is raised to :func:`neighbour_noise_floor` where the own estimate is lower.
    """
    n_freq = sums.bins.size
    nh = sums.ff.shape[1]
    response = np.full(n_freq, np.nan + 0j)
    variance = np.full(n_freq, np.inf)
    dof = np.zeros(n_freq, np.int64)
    coherence = np.zeros(n_freq)
    noise = np.full(n_freq, np.inf)
    cols = sums.h_columns()
    for i in range(n_freq):
        d = int(sums.dof[i]) - nh
        if sums.records[i] == 0 or d < 1:
            continue
        try:
            inv = np.linalg.inv(sums.zf[i][:, cols])
        except np.linalg.LinAlgError:
            continue
        theta = inv @ sums.zy[i]
        rss = (sums.yy[i] - theta.conj().T @ sums.fy[i] - sums.fy[i].conj().T @ theta
               + theta.conj().T @ sums.ff[i] @ theta)
        rss0 = max(float(rss[0, 0].real), 0.0)
        total = float(sums.yy[i][0, 0].real)
        sigma2 = rss0 / d
        cov = inv @ sums.zz[i] @ inv.conj().T
        response[i] = theta[0, 0]
        variance[i] = sigma2 * float(cov[0, 0].real)
        dof[i] = d
        coherence[i] = min(max(1.0 - rss0 / total, 0.0), 1.0) if total > 0 else 0.0
        noise[i] = sigma2
    raise_by = _noise_raise(noise, dof)
    variance *= raise_by
    noise *= raise_by
    return LocalEstimate(response, variance, dof, coherence, noise)


def _noise_raise(noise: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """Factor per frequency that lifts a noise variance to :func:`neighbour_noise_floor` (1 where it is not
    below)."""
    floor = neighbour_noise_floor(noise, dof)
    low = np.isfinite(floor) & (noise > 0) & (floor > noise)
    factor = np.ones(noise.shape)
    factor[low] = floor[low] / noise[low]
    return factor


def neighbour_noise_floor(noise: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """The noise variance per bin pooled over each analysis frequency and its two neighbours on the grid.

    The noise spectrum of a flight (sensor noise, gusts) is smooth in frequency, and neighbouring bands share
    bins; an estimate on few degrees of freedom, though, scatters (``chi^2(2 d) / 2 d``: on 3 degrees of
    freedom one in 25 is below a quarter of the truth, one in 100 below a seventh). Taken alone, such a chance
    low estimate turns an ordinary error into "well outside the random error" (seen at the lowest lines of
    multisines, where the band widens over few lines: ``benchmarks/false_alarms.py``). A frequency's noise is
    therefore never taken below the degrees-of-freedom-weighted mean of its own and its neighbours' estimates.

    Parameters
    ----------
    noise : ndarray, (F,)
        Noise variance per bin at each analysis frequency (inf or NaN where unknown).
    dof : ndarray, (F,)
        Its degrees of freedom (0 where unknown).

    Returns
    -------
    ndarray, (F,)
        The pooled variance; NaN where the frequency has no estimate of its own.
    """
    noise = np.asarray(noise, float)
    d = np.asarray(dof, float)
    known = np.isfinite(noise) & (d > 0)
    weighted = np.where(known, np.where(known, noise, 0.0) * d, 0.0)
    weight = np.where(known, d, 0.0)
    total, count = weighted.copy(), weight.copy()
    total[1:] += weighted[:-1]
    count[1:] += weight[:-1]
    total[:-1] += weighted[1:]
    count[:-1] += weight[1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(known & (count > 0), total / count, np.nan)


def expected_estimate(sums: BandSums, w_rad_s: np.ndarray, band_fraction: float,
                      model_response: Callable[[np.ndarray], np.ndarray]) -> \
        tuple[np.ndarray, np.ndarray]:
    """The estimate a model would give through this estimator, and how well the expansion holds.

    Under ``Y = P X + T + V`` the pooled estimate's mean is ``(Z^H Phi)^-1 Z^H (P X)``; with ``P`` expanded as
    a polynomial of degree ``order + EXTRA_ORDER`` over the bands used (``r`` in ``[r_lo, r_hi]``) this is
    exact up to the expansion error, which is returned too.

    Parameters
    ----------
    sums : BandSums
    w_rad_s : ndarray, (F,)
        Analysis frequencies [rad/s].
    band_fraction : float
        The ``band_fraction`` the sums were made with.
    model_response : callable
        ``model_response(w_rad_s) -> complex array`` (SISO).

    Returns
    -------
    expected : ndarray, (F,) complex
        NaN where nothing was estimated.
    expansion_error : ndarray, (F,)
        Largest error of the polynomial expansion over the band, relative to ``|P(w)|``.
    """
    w = np.asarray(w_rad_s, float)
    n_freq = w.size
    expected = np.full(n_freq, np.nan + 0j)
    error = np.zeros(n_freq)
    idx = np.flatnonzero(np.asarray(sums.records)[:n_freq] != 0)
    if not idx.size:
        return expected, error
    cols = sums.h_columns()
    degree = sums.order + EXTRA_ORDER
    n_nodes = 3 * (degree + 1)
    cheb = np.cos(np.pi * (np.arange(n_nodes) + 0.5) / n_nodes)
    fine = np.linspace(-1.0, 1.0, 101)
    # every frequency's nodes, check points and centre in one call of the model (its cost is per call)
    lo, hi = np.asarray(sums.r_lo, float)[idx], np.asarray(sums.r_hi, float)[idx]
    mid, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 1e-12)
    nodes = mid[:, None] + half[:, None] * cheb[None, :]
    points = mid[:, None] + half[:, None] * fine[None, :]
    centre_w, scale = w[idx, None], (band_fraction * w[idx])[:, None]
    at = np.concatenate([centre_w + scale * nodes, centre_w + scale * points, centre_w], axis=1)
    values = np.asarray(model_response(at.ravel()), complex).reshape(at.shape)
    on_nodes, on_points, centre = values[:, :n_nodes], values[:, n_nodes:-1], np.abs(values[:, -1])
    powers = np.arange(degree + 1)
    vander = nodes[:, :, None] ** powers                                  # (k, nodes, degree + 1)
    coef = np.einsum("kij,kj->ki", np.linalg.pinv(vander), on_nodes)     # least squares per frequency
    fit_err = np.max(np.abs(np.einsum("kij,kj->ki", points[:, :, None] ** powers, coef) - on_points), axis=1)
    if sums.inputs > 1:      # the first input's column; the others contribute nothing to the model's share
        coef = np.concatenate([coef, np.zeros((idx.size, (sums.inputs - 1) * (degree + 1)), complex)], axis=1)
    zf = np.asarray(sums.zf)[idx]
    rhs = np.einsum("kij,kj->ki", zf, coef)
    square = zf[:, :, cols]
    try:
        theta = np.linalg.solve(square, rhs[:, :, None])[:, :, 0]
        solved = np.ones(idx.size, bool)
    except np.linalg.LinAlgError:            # a singular band: solve the others one by one
        theta = np.full((idx.size, len(cols)), np.nan + 0j)
        solved = np.zeros(idx.size, bool)
        for k in range(idx.size):
            try:
                theta[k] = np.linalg.solve(square[k], rhs[k])
                solved[k] = True
            except np.linalg.LinAlgError:
                continue
    expected[idx[solved]] = theta[solved, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        error[idx[solved]] = np.where(centre[solved] > 0, fit_err[solved] / centre[solved], np.inf)
    return expected, error


@dataclass(frozen=True)
class MatrixEstimate:
    """The whole frequency-response matrix solved from :class:`BandSums` (p outputs x m inputs).

    Attributes
    ----------
    response : ndarray, (F, p, m) complex
        ``H(w)``, element ``[i, j]`` from input j to output i; NaN where nothing was estimated.
    variance : ndarray, (F, p, m)
        ``E |H_ij,est - H_ij|^2`` per element (complex variance); inf where unknown.
    dof : ndarray, (F,) int
        Degrees of freedom of the noise covariance (bins minus every fitted coefficient).
    multiple_coherence : ndarray, (F, p)
        Per output: ``1 - RSS_i / |Y_i|^2``, the fraction of output i explained by all inputs together (after
        the transient); the SISO coherence for m = p = 1.
    partial_coherence : ndarray, (F, p, m)
        Per element: the fraction of what the *other* inputs leave unexplained in output i that input j
        explains, ``(RSS_i without j - RSS_i) / RSS_i without j`` (partial coherence of output i with input j
        given the other inputs, Bendat and Piersol ch. 7); equal to the multiple coherence for m = 1; 0 with
        more instruments than inputs (the reduced fit is not defined then).
    noise : ndarray, (F, p, p) complex
        Noise covariance per bin (residual cross-products over the degrees of freedom).
    """

    response: np.ndarray
    variance: np.ndarray
    dof: np.ndarray
    multiple_coherence: np.ndarray
    partial_coherence: np.ndarray
    noise: np.ndarray


def _residual(sums: BandSums, i: int, rows: np.ndarray, cols_h: np.ndarray, cols_e: np.ndarray):
    """``(theta, inv, rss)`` of the fit with the response columns ``cols_h`` (of ``ff``/``fy``), instrument
    rows ``rows`` (of ``zf``/``zy``) and extended columns ``cols_e`` (of ``zf``); None when singular."""
    try:
        inv = np.linalg.inv(sums.zf[i][np.ix_(rows, cols_e)])
    except np.linalg.LinAlgError:
        return None
    theta = inv @ sums.zy[i][rows]
    ff, fy = sums.ff[i][np.ix_(cols_h, cols_h)], sums.fy[i][cols_h]
    rss = sums.yy[i] - theta.conj().T @ fy - fy.conj().T @ theta + theta.conj().T @ ff @ theta
    return theta, inv, rss


def solve_matrix(sums: BandSums) -> MatrixEstimate:
    """Solve the pooled local polynomial fits of :class:`BandSums` for the whole p x m response matrix.

    The same normal equations as :func:`solve_bands` (least squares, or instrumental variables with an
    excitation signal), read for every input and output: ``H = G_yu G_uu^-1`` pooled over the records (as
    CIFER does for single-axis sweeps flown in turn: each record excites one input, together they determine
    the matrix). The covariance of the coefficients is ``Sigma_v (x) (Z^H Phi)^-1 Z^H Z (Z^H Phi)^-H``; the
    variance of ``H_ij`` is ``Sigma_v[i, i]`` times the diagonal entry of input j's constant coefficient.

    Parameters
    ----------
    sums : BandSums

    Returns
    -------
    MatrixEstimate
        NaN / inf / 0 at a frequency with fewer than one degree of freedom or a singular system. Each output's
        noise is raised to :func:`neighbour_noise_floor` as in :func:`solve_bands`. For m = p = 1
        ``response``, ``variance``, ``dof`` and ``multiple_coherence`` equal :func:`solve_bands`' to the bit.
    """
    n_freq = sums.bins.size
    nh = sums.ff.shape[1]
    m, p = sums.inputs, sums.yy.shape[1]
    per = sums.order + 1
    response = np.full((n_freq, p, m), np.nan + 0j)
    variance = np.full((n_freq, p, m), np.inf)
    dof = np.zeros(n_freq, np.int64)
    multiple = np.zeros((n_freq, p))
    partial = np.zeros((n_freq, p, m))
    noise = np.full((n_freq, p, p), np.inf + 0j)
    own = np.full((n_freq, p), np.inf)      # each output's noise variance, as solve_bands computes it
    cols = sums.h_columns()
    all_h = np.arange(nh)
    rows_all = np.arange(sums.zf.shape[1])
    square = sums.zf.shape[1] == nh          # least squares, or as many instruments as inputs
    for i in range(n_freq):
        d = int(sums.dof[i]) - nh
        if sums.records[i] == 0 or d < 1:
            continue
        full = _residual(sums, i, rows_all, all_h, cols)
        if full is None:
            continue
        theta, inv, rss = full
        rss_diag = np.maximum(np.real(np.diag(rss)), 0.0)
        total = np.real(np.diag(sums.yy[i]))
        sigma = rss / d
        cov = inv @ sums.zz[i] @ inv.conj().T
        response[i] = theta[::per, :].T
        variance[i] = (rss_diag / d)[:, None] * np.real(np.diag(cov))[None, ::per]
        dof[i] = d
        with np.errstate(divide="ignore", invalid="ignore"):
            multiple[i] = np.where(total > 0, np.clip(1.0 - rss_diag / total, 0.0, 1.0), 0.0)
        noise[i] = sigma
        own[i] = rss_diag / d
        for j in range(m):
            if m == 1:
                partial[i, :, 0] = multiple[i]
                break
            keep = np.concatenate([all_h[k * per:(k + 1) * per] for k in range(m) if k != j])
            rows = keep if square else rows_all
            reduced = _residual(sums, i, rows, keep, cols[keep]) if square else None
            if reduced is None:
                continue
            rss_without = np.maximum(np.real(np.diag(reduced[2])), 0.0)
            with np.errstate(divide="ignore", invalid="ignore"):
                partial[i, :, j] = np.where(rss_without > 0,
                                            np.clip(1.0 - rss_diag / rss_without, 0.0, 1.0), 0.0)
    for out in range(p):        # each output's noise never below its neighbours' (as solve_bands)
        raise_by = _noise_raise(own[:, out], dof)
        low = raise_by != 1.0          # only there: a complex inf times 1 would turn its imaginary part NaN
        variance[low, out, :] *= raise_by[low, None]
        noise[low, out, :] *= np.sqrt(raise_by[low])[:, None]
        noise[low, :, out] *= np.sqrt(raise_by[low])[:, None]
    return MatrixEstimate(response, variance, dof, multiple, partial, noise)


def expected_matrix(sums: BandSums, w_rad_s: np.ndarray, band_fraction: float,
                    model_response: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """The response matrix a MIMO model would give through this estimator (:func:`expected_estimate` for every
    element): ``(Z^H Phi)^-1 Z^H Phi_ext c`` with each column of the model expanded over the bands used.

    Parameters
    ----------
    sums : BandSums
    w_rad_s : ndarray, (F,)
        Analysis frequencies [rad/s].
    band_fraction : float
        The ``band_fraction`` the sums were made with.
    model_response : callable
        ``model_response(w_rad_s) -> complex array (len(w), p, m)``.

    Returns
    -------
    ndarray, (F, p, m) complex
        NaN where nothing was estimated.
    """
    w = np.asarray(w_rad_s, float)
    m, p = sums.inputs, sums.yy.shape[1]
    expected = np.full((w.size, p, m), np.nan + 0j)
    cols = sums.h_columns()
    degree = sums.order + EXTRA_ORDER
    n_nodes = 3 * (degree + 1)
    cheb = np.cos(np.pi * (np.arange(n_nodes) + 0.5) / n_nodes)
    per_h = sums.order + 1
    for i in range(w.size):
        if sums.records[i] == 0:
            continue
        lo, hi = float(sums.r_lo[i]), float(sums.r_hi[i])
        mid, half = 0.5 * (lo + hi), max(0.5 * (hi - lo), 1e-12)
        nodes = mid + half * cheb
        values = np.asarray(model_response(w[i] + band_fraction * w[i] * nodes), complex)   # (nodes, p, m)
        vander = _vander(nodes, degree)
        coef = np.concatenate([np.linalg.lstsq(vander, values[:, :, j], rcond=None)[0] for j in range(m)])
        try:
            theta = np.linalg.solve(sums.zf[i][:, cols], sums.zf[i] @ coef)          # (nh, p)
        except np.linalg.LinAlgError:
            continue
        expected[i] = theta[::per_h, :].T
    return expected


def excitation_coherence(sums: BandSums) -> tuple[np.ndarray, np.ndarray]:
    """Coherences of the first input and of the first output with the instruments (the injected excitation r):
    the multiple coherence of the local polynomial fit of u, and of y, on the instrument regressors,
    ``gamma^2 = b^H (Z^H Z)^-1 b / |v|^2`` with ``b = Z^H v`` (Bendat and Piersol, ch. 7).

    Parameters
    ----------
    sums : BandSums
        Sums made with instruments (``record_bands(..., instruments=...)``).

    Returns
    -------
    r_to_u, r_to_y : ndarray, (F,)
        In [0, 1]; 0 where nothing was estimated.
    """
    n_freq = sums.bins.size
    r_u, r_y = np.zeros(n_freq), np.zeros(n_freq)
    for i in range(n_freq):
        if sums.records[i] == 0:
            continue
        try:
            zz_inv = np.linalg.inv(sums.zz[i])
        except np.linalg.LinAlgError:
            continue
        for out, b, total in ((r_u, sums.zf[i][:, 0], sums.ff[i][0, 0].real),
                              (r_y, sums.zy[i][:, 0], sums.yy[i][0, 0].real)):
            if total > 0:
                out[i] = min(max(float((b.conj() @ zz_inv @ b).real) / total, 0.0), 1.0)
    return r_u, r_y


def partial_coherence(sums: BandSums) -> np.ndarray:
    """Partial coherence of the first output with the first input, conditioned on the other inputs (least
    squares): the share of the output power left unexplained by the other inputs that the first input
    explains, ``(RSS_others - RSS_all) / RSS_others`` (Bendat and Piersol, ch. 7).

    Parameters
    ----------
    sums : BandSums
        Sums of m >= 2 inputs.

    Returns
    -------
    ndarray, (F,)
        In [0, 1]; 0 where nothing was estimated, where the pool leaves no degree of freedom, and for a single
        input. With ``d`` degrees of freedom noise alone reaches about ``(order + 1) / (d + order + 1)``.
    """
    n_freq = sums.bins.size
    out = np.zeros(n_freq)
    per = sums.order + 1
    if sums.inputs < 2:
        return out
    others = np.arange(per, sums.ff.shape[1])
    for i in range(n_freq):
        if sums.records[i] == 0 or int(sums.dof[i]) - sums.ff.shape[1] < 1:
            continue
        ff, fy, yy = sums.ff[i], sums.fy[i][:, 0], float(sums.yy[i][0, 0].real)
        try:
            rss_all = yy - float((fy.conj() @ np.linalg.solve(ff, fy)).real)
            fo = fy[others]
            rss_others = yy - float((fo.conj() @ np.linalg.solve(ff[np.ix_(others, others)], fo)).real)
        except np.linalg.LinAlgError:
            continue
        if rss_others > 0:
            out[i] = min(max((rss_others - max(rss_all, 0.0)) / rss_others, 0.0), 1.0)
    return out


def sweep_points(sweep: Any, average_confident: np.ndarray, coherence_threshold: float) -> np.ndarray:
    """Frequencies of one sweep's (raw) estimate that count for the raw epsilon: those confident in the
    average (the validation's frequency set) where the sweep itself is coherent. A single sweep has fewer
    degrees of freedom than the pool, so the minimum rule applies to the average only; raw epsilon is then the
    sup over the same frequencies as the averaged one, and not smaller for want of points (paper, Table 1).

    Parameters
    ----------
    sweep : SpectralEstimate or LocalEstimate
        One sweep's (raw) estimate (its ``response`` and ``coherence`` are read).
    average_confident : ndarray of bool
        Confident points of the averaged estimate (:func:`~gap_validation.core.evidence.confident_points`).
    coherence_threshold : float
        The channel's coherence threshold.
    """
    p = np.asarray(sweep.response, complex)
    return (np.asarray(average_confident, bool) & (np.asarray(sweep.coherence, float) >= coherence_threshold)
            & np.isfinite(p) & (np.abs(p) > 0))
