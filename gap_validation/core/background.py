"""The trim motion between manoeuvres, per frequency: what the flight does when nobody flies a manoeuvre.

Between manoeuvres the surfaces are not still: a pilot corrects the trim, turbulence is answered by a damper
or an autopilot, a vibration line rides on a rate controller's output. That motion is the background against
which a manoeuvre must stand out, and it says something of its own: in open loop the surface's trim motion
drives the airframe like any input (the response between manoeuvres is the plant), in closed loop the loop
drives the surface from the measured rate (the response between manoeuvres tends to ``-1/C``).

:class:`TrimSpectrum` measures it on the flight itself. The estimator hands it every grid sample that lies
outside its records (manoeuvres with their trim margins); a stretch of trim is cut into segments of at most
:data:`SEGMENT_S` (half overlapping; the last part of a stretch as a shorter segment of at least
:data:`MIN_SEGMENT_S`), each segment's straight line is removed, it is Hann-windowed and transformed, and per
analysis frequency the cross-spectral matrix of every stream over the segment's bins near that frequency is
added up (Welch's method, with the local bands of :mod:`gap_validation.core.spectra`: ``|w_k - w| <=
band_fraction w``, at least the nearest bins within :data:`NEAR_BINS` spacings; a segment too short to resolve
``w`` adds nothing there).

Units: the transform is normalised by the window's energy (``sqrt(sum w^2)``), so white noise of variance
``s^2`` gives ``E |X_k|^2 = s^2`` per bin, whatever the segment length, and a stationary process the same
``|X_k|^2`` as the normalised whole-record DFT of :func:`gap_validation.core.spectra.record_bands` (which
divides by ``sqrt(N)``): the two are compared directly.

The last :data:`GUARD_S` of trim before the newest sample is held back: a manoeuvre is detected up to several
seconds after it began (a slow sweep), and the record that then opens reaches back into what looked like trim.
Nothing grows with the flight: a bounded buffer of pending samples and a few small matrices per frequency.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = [
    "TrimSpectrum",
    "TrimResponse",
    "TrimSpectra",
    "LeadTest",
    "LeadResult",
    "LEAD_LAGS_S",
    "LEAD_LAGS",
    "LEAD_MIN_S",
    "SEGMENT_S",
    "MIN_SEGMENT_S",
    "GUARD_S",
    "NEAR_BINS",
    "TRIM_COHERENCE",
    "TRIM_CHANCE",
    "MIN_TRIM_AVERAGES",
    "HANN_BINS_PER_AVERAGE",
]

#: Longest segment of trim transformed at once [s] (half-overlapping segments in a longer stretch).
SEGMENT_S = 20.0
#: Shortest stretch of trim that adds anything [s].
MIN_SEGMENT_S = 2.0
#: Trim this recent is held back until no record reaches back into it [s] (the estimator's look-back, 10 s).
GUARD_S = 10.0
#: A frequency's band holds the bins within ``band_fraction w`` of it, and at least those within this many bin
#: spacings (Hann: the main lobe is 2 spacings wide); a segment whose band would reach past
#: ``max_band_fraction w`` does not resolve the frequency.
NEAR_BINS = 1.5
#: Segments whose powers and spreads are kept for the medians (the latest ones: with half-overlapping 20 s
#: segments, the last 10 minutes of trim).
SEGMENTS_KEPT = 64
#: Trim coherence a frequency needs before its response between manoeuvres counts, and the chance that noise
#: alone reaches it (the magnitude-squared coherence of n independent averages with none there: ``P = (1 -
#: c)^(n - 1)``, Carter 1973).
TRIM_COHERENCE = 0.6
TRIM_CHANCE = 1e-3
#: ... on at least this many independent averages: below, the coherence estimate is biased high (one average
#: gives exactly 1) and the error formula of :meth:`TrimResponse.relative_variance` does not hold.
MIN_TRIM_AVERAGES = 8
#: Adjacent bins of a Hann-windowed segment are correlated (|rho| = 1/2): a band of b bins holds about b / 1.5
#: independent averages.
HANN_BINS_PER_AVERAGE = 1.5


#: The lead test regresses the surface on its own past and the rate's over this long [s] (a damper or an
#: autopilot answers within it; a pilot's corrections and the airframe's response are in the surface's own
#: past) ...
LEAD_LAGS_S = 0.25
#: ... in at least and at most this many lags of each (spaced further apart on a fine grid).
LEAD_LAGS = (3, 16)
#: Trim regressed before the test says anything [s]: a few seconds after one manoeuvre hold one transient, not
#: a process (a slow mode settling in the rate can stand in for the surface's own slow shape).
LEAD_MIN_S = 30.0


@dataclass(frozen=True)
class LeadResult:
    """What the rate's past says of the surface's next move between manoeuvres (:class:`LeadTest`).

    Attributes
    ----------
    share : float
        Fraction of the surface's motion unpredictable from its own past that the rate's past explains.
    f : float
        The nested F statistic of the rate's lags.
    p_value : float
        Its chance under "the rate does not lead the surface" (F with ``lags`` and ``rows - 2 lags`` degrees).
    rows : int
        Samples regressed.
    lags : int
        Lags of each signal.
    lags_s : float
        The span they cover [s].
    """

    share: float
    f: float
    p_value: float
    rows: int
    lags: int
    lags_s: float


class LeadTest:
    """Which signal leads between the manoeuvres: does the rate's past predict the surface's next move?

    In open loop the surface's trim motion (a pilot's corrections, sensor noise) is made without looking at
    the rate: once the surface's own past is known, the rate's past adds nothing (Granger 1969); the F
    statistic of the rate's lags then follows its F law. A loop (damper, autopilot, a pilot holding an
    attitude) moves the surface from the rate: the rate's past explains a share of what the surface's own past
    does not. Each trim sample is regressed once (the spectra's half-overlapping segments are not counted
    twice), on its segment's detrended values. The lags span :data:`LEAD_LAGS_S`: the newest sample, then at
    most ``LEAD_LAGS[1]`` in all, spaced further apart on a fine grid.

    Parameters
    ----------
    dt : float
        Grid step [s].
    inp, out : int
        Stream indices of the surface and the rate.
    """

    def __init__(self, dt: float, inp: int, out: int) -> None:
        self.dt = float(dt)
        # on a fine grid the lags are spaced so that they still span LEAD_LAGS_S
        self.step = max(1, int(math.ceil(LEAD_LAGS_S / self.dt / LEAD_LAGS[1])))
        self.lags = int(np.clip(round(LEAD_LAGS_S / (self.dt * self.step)), *LEAD_LAGS))
        # the newest sample of each first: a loop's surface answers the rate's newest innovation, which the
        # surface's own past does not hold yet
        self.back = 1 + self.step * np.arange(self.lags)
        self.inp, self.out = int(inp), int(out)
        k = 2 * self.lags + 1
        self.gram = np.zeros((k, k))
        self.rows = 0
        self._result: tuple | None = None           # (rows, result) of the last result()

    def add(self, x: np.ndarray, fresh: int = 0) -> None:
        """Regress the samples of ``x`` (streams x n) from index ``fresh`` on (each on the ``lags`` before
        it).

        Parameters
        ----------
        x : ndarray
            A detrended stretch of trim.
        fresh : int
            First sample not regressed before.
        """
        n = x.shape[1]
        first = max(int(self.back[-1]), int(fresh))
        if n - first < 1:
            return
        t = np.arange(first, n)[:, None]
        z = np.hstack((x[self.inp][t - self.back], x[self.out][t - self.back], x[self.inp][t]))
        self.gram += z.T @ z
        self.rows += z.shape[0]

    def result(self) -> LeadResult | None:
        """The test on everything regressed so far (None before :data:`LEAD_MIN_S` of trim); computed again
        only after new rows."""
        if self._result is not None and self._result[0] == self.rows:
            return self._result[1]
        out = self._compute()
        self._result = (self.rows, out)
        return out

    def _compute(self) -> LeadResult | None:
        p = self.lags
        if self.rows < max(20 * p, LEAD_MIN_S / self.dt):
            return None
        g = self.gram
        target = 2 * p

        def residual(cols: np.ndarray) -> float:
            a = g[np.ix_(cols, cols)]
            b = g[cols, target]
            coef = np.linalg.lstsq(a, b, rcond=1e-12)[0]
            return float(g[target, target] - b @ coef)

        own = residual(np.arange(p))
        both = residual(np.arange(2 * p))
        if not (own > 0.0 and both > 0.0):
            return None
        dof = self.rows - 2 * p
        f = max(own - both, 0.0) / p / (both / dof)
        from scipy.special import fdtrc

        return LeadResult(max(own - both, 0.0) / own, f, float(fdtrc(p, dof, f)), int(self.rows), p,
                          float(self.back[-1]) * self.dt)

    def state_dict(self) -> dict:
        """State as arrays and numbers (fixed size)."""
        return {"gram": self.gram.copy(), "rows": self.rows}

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict` (a state without it: nothing regressed).

        Parameters
        ----------
        st : dict
            From :meth:`state_dict`.
        """
        self._result = None
        if "gram" in st and np.shape(st["gram"]) == self.gram.shape:
            self.gram[:] = st["gram"]
            self.rows = int(st["rows"])


class TrimSpectrum:
    """Cross-spectra of a channel's streams between its manoeuvres (see the module docstring).

    Parameters
    ----------
    w_rad_s : ndarray
        Analysis frequencies [rad/s].
    n_streams : int
        Streams per sample (the estimator's: inputs, outputs, instruments).
    dt : float
        Grid step [s].
    band_fraction, max_band_fraction : float
        The estimator's local bands (:data:`gap_validation.core.spectra.SPECTRA_DEFAULTS`).
    guard_s : float
        Trim held back [s] (:data:`GUARD_S`).
    lead : (int, int), optional
        Surface and rate stream indices of a :class:`LeadTest` run on the same trim.
    """

    def __init__(self, w_rad_s: np.ndarray, n_streams: int, dt: float, band_fraction: float = 0.1,
                 max_band_fraction: float = 0.6, guard_s: float = GUARD_S,
                 lead: tuple[int, int] | None = None) -> None:
        self.lead = LeadTest(dt, *lead) if lead is not None else None
        self.w = np.asarray(w_rad_s, float).copy()
        self.n = int(n_streams)
        self.dt = float(dt)
        self.band_fraction = float(band_fraction)
        self.max_band_fraction = float(max_band_fraction)
        self.segment_n = max(8, int(round(SEGMENT_S / dt)))
        self.min_n = max(8, int(round(MIN_SEGMENT_S / dt)))
        self.guard_n = max(0, int(round(guard_s / dt)))
        F, S = self.w.size, self.n
        self.sums = np.zeros((F, S, S), complex)     # sum over segments and bins of X X^H
        self.bins = np.zeros(F, np.int64)            # bins added per frequency
        self.samples = 0                             # samples transformed
        self.segments = 0
        # per kept segment: each stream's mean |X|^2 per frequency (NaN: not resolved) and its detrended std
        self.seg_power = np.full((SEGMENTS_KEPT, F, S), np.nan)
        self.seg_std = np.full((SEGMENTS_KEPT, S), np.nan)
        self.seg_bins = np.zeros((SEGMENTS_KEPT, F))        # bins behind each kept segment's powers
        self._pend = np.zeros((S, self.segment_n + self.guard_n + 1))
        self._pend_n = 0
        self._pend_k = 0                             # grid index of the first pending sample
        self._covered = 0                            # leading pending samples already transformed
        # segments added (power, std, response are kept until then)
        self.version = 0
        self._memo: dict = {}
        self._memo_version = -1

    # ------------------------------------------------------------------ data in
    def feed(self, k_a: int, block: np.ndarray) -> None:
        """Trim samples (streams x n) from grid index ``k_a``; a jump in the index ends the stretch before it.

        Parameters
        ----------
        k_a : int
            Grid index of ``block[:, 0]``.
        block : ndarray
            Samples of every stream.
        """
        block = np.asarray(block, float)
        if block.shape[1] == 0:
            return
        if self._pend_n and k_a != self._pend_k + self._pend_n:
            self.end_stretch()
        if not self._pend_n:
            self._pend_k = int(k_a)
        pos = 0
        while pos < block.shape[1]:
            room = self._pend.shape[1] - self._pend_n
            take = min(room, block.shape[1] - pos)
            self._pend[:, self._pend_n:self._pend_n + take] = block[:, pos:pos + take]
            self._pend_n += take
            pos += take
            self._release()

    def cut(self, k: int) -> None:
        """A record now begins at grid index ``k``: pending trim from ``k`` on belongs to it; the stretch
        before ``k`` is complete.

        Parameters
        ----------
        k : int
            First grid index of the record.
        """
        keep = int(min(max(k - self._pend_k, 0), self._pend_n))
        self._pend_n = keep
        self._covered = min(self._covered, keep)
        self.end_stretch()

    def end_stretch(self) -> None:
        """The stretch of trim in progress ends (a record begins, the data break, or the end of data): what
        has not been transformed yet is, in half-overlapping segments, the last one ending at the stretch's
        end (a remainder shorter than :data:`MIN_SEGMENT_S` after segments already transformed adds
        nothing)."""
        n, covered = self._pend_n, self._covered
        if covered and n - covered >= self.min_n:
            a = max(0, n - self.segment_n)
            self._segment(self._pend[:, a:n], covered - a)
        elif not covered and n >= self.min_n:
            if n <= self.segment_n:
                self._segment(self._pend[:, :n])
            else:   # half-overlapping segments covering the stretch, the last one ending at its end
                step = self.segment_n // 2
                starts = list(range(0, n - self.segment_n + 1, step))
                if starts[-1] + self.segment_n < n:
                    starts.append(n - self.segment_n)
                seen = 0
                for a in starts:
                    self._segment(self._pend[:, a:a + self.segment_n], seen - a)
                    seen = a + self.segment_n
        self._pend_n = 0
        self._covered = 0

    def _release(self) -> None:
        """Transform the segments that the guard no longer holds back (the first ``segment_n`` pending samples
        once ``guard_n`` newer ones exist), half overlapping."""
        while self._pend_n >= self.segment_n + self.guard_n:
            self._segment(self._pend[:, :self.segment_n], self._covered)
            step = self.segment_n // 2
            rest = self._pend_n - step
            self._pend[:, :rest] = self._pend[:, step:self._pend_n]
            self._pend_n, self._pend_k = rest, self._pend_k + step
            self._covered = self.segment_n - step

    def _segment(self, x: np.ndarray, fresh: int = 0) -> None:
        """Add one segment ``x`` (streams x n); its samples from ``fresh`` on were in no segment before (the
        lead test counts each sample once)."""
        self.version += 1
        n = x.shape[1]
        t = np.arange(n, dtype=float)
        t -= t.mean()
        centred = x - x.mean(axis=1, keepdims=True)
        slope = centred @ t / float(t @ t)
        detrended = centred - slope[:, None] * t[None, :]
        if self.lead is not None:
            self.lead.add(detrended, max(int(fresh), 0))
        window = np.hanning(n + 1)[:-1] if n > 1 else np.ones(1)
        spec = np.fft.rfft(detrended * window, axis=1) / math.sqrt(float(window @ window))
        w_bins = 2.0 * math.pi * np.fft.rfftfreq(n, self.dt)
        spacing = w_bins[1] - w_bins[0]
        top = 0.8 * math.pi / self.dt
        half = np.maximum(self.band_fraction * self.w, NEAR_BINS * spacing)
        ok = (half <= self.max_band_fraction * self.w) & (self.w + half <= top)
        if ok.any():
            outer = spec.T[:, :, None] * spec.T.conj()[:, None, :]           # bins x S x S
            cum = np.concatenate((np.zeros((1, self.n, self.n), complex), np.cumsum(outer, axis=0)))
            lo = np.clip(np.ceil((self.w - half) / spacing - 1e-9).astype(np.int64), 1, w_bins.size - 1)
            hi = np.clip(np.floor((self.w + half) / spacing + 1e-9).astype(np.int64), 0, w_bins.size - 1)
            ok &= hi >= lo
            idx = np.flatnonzero(ok)
            band = cum[hi[idx] + 1] - cum[lo[idx]]
            count = hi[idx] - lo[idx] + 1
            self.sums[idx] += band
            self.bins[idx] += count
        slot = self.segments % SEGMENTS_KEPT
        self.seg_power[slot] = np.nan
        self.seg_bins[slot] = 0.0
        if ok.any():
            self.seg_power[slot, idx] = np.real(np.diagonal(band, axis1=1, axis2=2)) / count[:, None]
            self.seg_bins[slot, idx] = count
        self.seg_std[slot] = np.sqrt(np.mean(detrended ** 2, axis=1))
        self.samples += n
        self.segments += 1

    # ------------------------------------------------------------------ results
    @property
    def seconds(self) -> float:
        """Trim transformed so far [s]."""
        return self.samples * self.dt

    def _kept(self, key: tuple, compute):
        """``compute()`` once per :attr:`version` (the node asks every diagnostics tick; the trim changes a
        segment at a time); copies of the arrays."""
        if self._memo_version != self.version:
            self._memo, self._memo_version = {}, self.version
        if key not in self._memo:
            self._memo[key] = compute()
        value = self._memo[key]
        return tuple(np.copy(v) for v in value) if isinstance(value, tuple) else np.copy(value) \
            if isinstance(value, np.ndarray) else value

    def power(self, streams: Sequence[int]) -> np.ndarray:
        """The ``streams``' summed trim power per frequency, mean ``|X|^2`` per bin in
        :func:`~gap_validation.core.spectra.record_bands`' units: the median over the kept segments that
        resolve the frequency (NaN where none does). A median, so that a stretch of manoeuvre the detector
        missed (the slow start of a faint sweep) does not raise the floor the next manoeuvres are measured
        against.

        Parameters
        ----------
        streams : sequence of int
            Stream indices.
        """
        return self._kept(("power", tuple(int(j) for j in streams)), lambda: self._power(streams))

    def _power(self, streams: Sequence[int]) -> np.ndarray:
        per_segment = np.sum(self.seg_power[:, :, list(streams)], axis=2)          # NaN where unresolved
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)                         # all-NaN columns
            median = np.nanmedian(per_segment, axis=0)
            k = (
                np.nanmedian(np.where(self.seg_bins > 0, self.seg_bins, np.nan), axis=0)
                / HANN_BINS_PER_AVERAGE
            )
        # a segment's band power is about Gamma(k, 1/k) on k averages: its median is (1 - 1/(9k))^3 of its
        # mean (Wilson and Hilferty), so the median over segments is raised by that to estimate the mean
        return median / (1.0 - 1.0 / (9.0 * np.maximum(k, 0.5))) ** 3

    def std(self, stream: int) -> float:
        """Standard deviation of one stream's trim motion about a straight line: the median over the kept
        segments (NaN before any).

        Parameters
        ----------
        stream : int
            Stream index.
        """
        def compute() -> float:
            values = self.seg_std[:, stream]
            values = values[np.isfinite(values)]
            return float(np.median(values)) if values.size else float("nan")

        return self._kept(("std", int(stream)), compute)

    def response(self, inp: int, out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The response from stream ``inp`` to stream ``out`` between manoeuvres (``S_yu / S_uu``), its
        coherence and its degrees of freedom (bins; Hann-windowed half-overlapping segments count about 1/1.9
        of that).

        Parameters
        ----------
        inp, out : int
            Stream indices.
        """
        return self._kept(("response", int(inp), int(out)), lambda: self._response(inp, out))

    def _response(self, inp: int, out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        with np.errstate(invalid="ignore", divide="ignore"):
            suu = self.sums[:, inp, inp].real
            syy = self.sums[:, out, out].real
            syu = self.sums[:, out, inp]
            h = np.where(self.bins > 0, syu / suu, np.nan + 0j)
            coherence = np.where(self.bins > 0, np.abs(syu) ** 2 / (suu * syy), 0.0)
        return h, np.nan_to_num(coherence), self.bins.copy()

    def spectra(self, inp: int, out: int) -> "TrimSpectra":
        """Stream ``inp``'s and stream ``out``'s spectra over every segment (Welch's means per bin) and their
        averages (:class:`TrimSpectra`; NaN where no segment resolved the frequency).

        Parameters
        ----------
        inp, out : int
            Stream indices.
        """
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = self.sums / np.where(self.bins > 0, self.bins, np.nan)[:, None, None]
        return TrimSpectra(mean[:, inp, inp].real, mean[:, out, out].real, mean[:, out, inp],
                           self.bins / HANN_BINS_PER_AVERAGE, self.power([inp]))

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """State as numpy arrays and numbers (fixed size)."""
        return {
            "sums": self.sums.copy(),
            "bins": self.bins.copy(),
            "seg_power": self.seg_power.copy(),
            "seg_std": self.seg_std.copy(),
            "seg_bins": self.seg_bins.copy(),
            "samples": self.samples,
            "segments": self.segments,
            "pend": self._pend[:, : self._pend_n].copy(),
            "pend_k": self._pend_k,
            "covered": self._covered,
            **({f"lead_{k}": v for k, v in self.lead.state_dict().items()} if self.lead is not None else {}),
        }

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            From :meth:`state_dict`.
        """
        self.sums[:] = st["sums"]
        self.bins[:] = st["bins"]
        self.seg_power[:] = st["seg_power"]
        self.seg_std[:] = st["seg_std"]
        self.seg_bins[:] = st["seg_bins"]
        self.samples, self.segments = int(st["samples"]), int(st["segments"])
        pend = np.asarray(st["pend"], float).reshape(self.n, -1)
        self._pend_n = pend.shape[1]
        self._pend[:, :self._pend_n] = pend
        self._pend_k = int(st["pend_k"])
        self._covered = int(st.get("covered", 0))
        self.version += 1
        if self.lead is not None:
            self.lead.load_state({k[5:]: v for k, v in st.items() if k.startswith("lead_")})


@dataclass(frozen=True)
class TrimResponse:
    """The response between manoeuvres (first input to first output), from the trim spectra.

    Attributes
    ----------
    response : ndarray, (F,) complex
        ``S_yu / S_uu`` over the trim stretches (NaN where no trim resolved the frequency).
    coherence : ndarray, (F,)
        Its magnitude-squared coherence.
    dof : ndarray, (F,)
        Independent spectral averages behind it (Hann-windowed segments: :data:`HANN_BINS_PER_AVERAGE` bins
        each).
    input_power : ndarray, (F,)
        The input's trim motion, mean ``|X|^2`` per bin in the records' units (NaN where unknown).
    """

    response: np.ndarray
    coherence: np.ndarray
    dof: np.ndarray
    input_power: np.ndarray

    def take(self, index: np.ndarray) -> "TrimResponse":
        """The response at the frequencies ``index`` only.

        Parameters
        ----------
        index : ndarray
            Indices (or a mask) of the frequencies kept.
        """
        return TrimResponse(*(np.asarray(a)[index] for a in (self.response, self.coherence, self.dof,
                                                             self.input_power)))

    def relative_variance(self) -> np.ndarray:
        """``E |dH|^2 / |H|^2`` of the trim response: ``(1 - g^2) / (g^2 n_d)`` (Bendat and Piersol, ch.
        9)."""
        g2 = np.clip(np.asarray(self.coherence, float), 1e-12, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.dof > 0, (1.0 - g2) / (g2 * np.maximum(self.dof, 1e-12)), np.inf)

    def confident(self) -> np.ndarray:
        """Frequencies with at least :data:`MIN_TRIM_AVERAGES` independent averages whose trim coherence
        passes
        :data:`TRIM_COHERENCE` and could not come from noise alone: ``(1 - c)^(n - 1) <= TRIM_CHANCE / F``
        over the F frequencies with enough averages (Bonferroni: noise alone passes somewhere on a channel
        with probability at most :data:`TRIM_CHANCE`)."""
        g2 = np.clip(np.nan_to_num(np.asarray(self.coherence, float)), 0.0, 1.0)
        n = np.asarray(self.dof, float)
        enough = np.isfinite(self.response) & (n >= MIN_TRIM_AVERAGES)
        with np.errstate(invalid="ignore", divide="ignore"):
            chance = np.where(n >= 2, (1.0 - g2) ** np.maximum(n - 1.0, 1.0), 1.0)
        return (
            enough & (g2 >= TRIM_COHERENCE) & (chance <= TRIM_CHANCE / max(int(np.count_nonzero(enough)), 1))
        )


@dataclass
class TrimSpectra:
    """The first input's and first output's spectra between the manoeuvres: Welch's sums over every trim
    segment (not the medians of :meth:`TrimSpectrum.power`: the three must come from the same segments), mean
    per bin in the records' units, each stream's interpolation gain restored as the records restore it.

    What they are for: the noise a manoeuvre flown in the same air will meet. Between the manoeuvres the
    output is ``y = P u + n``, whatever moves the surface (a pilot's corrections, a loop answering the gusts),
    so ``E |Y - P U|^2`` (:meth:`output_error`) is the output's noise ``n`` plus the surface sensor's noise
    seen through ``P``: the residual a manoeuvre's local fit is left with. The regression residual ``S_yy (1
    - coherence)`` is not: where the surface follows the gusts (a pilot or a damper holding the trim) it
    removes them with the surface's motion.

    Attributes
    ----------
    input_power, output_power : ndarray, (F,)
        ``S_uu`` and ``S_yy`` (NaN where no trim resolved the frequency).
    cross : ndarray, (F,) complex
        ``S_yu = E[Y conj(U)]``.
    averages : ndarray, (F,)
        Independent spectral averages behind them (:data:`HANN_BINS_PER_AVERAGE` bins each).
    input_floor : ndarray, (F,), optional
        The input's trim motion as the estimator's 20 dB test takes it (:meth:`TrimSpectrum.power`: the
        median over the kept segments), what a manoeuvre's input must stand 100 times above.
    """

    input_power: np.ndarray
    output_power: np.ndarray
    cross: np.ndarray
    averages: np.ndarray
    input_floor: np.ndarray | None = None

    def take(self, index: np.ndarray) -> "TrimSpectra":
        """The spectra at the frequencies ``index`` only.

        Parameters
        ----------
        index : ndarray
            Indices (or a mask) of the frequencies kept.
        """
        return TrimSpectra(*(np.asarray(a)[index] for a in (self.input_power, self.output_power, self.cross,
                                                             self.averages)),
                           None if self.input_floor is None else np.asarray(self.input_floor)[index])

    def output_error(self, response: np.ndarray) -> np.ndarray:
        """``E |Y - H U|^2 = S_yy - 2 Re(conj(H) S_yu) + |H|^2 S_uu`` per bin for the response ``H`` (the
        trim's motion that ``H`` does not explain; NaN where no trim, never below zero).

        Parameters
        ----------
        response : ndarray, (F,) complex
            ``H`` at the spectra's frequencies.
        """
        h = np.asarray(response, complex)
        with np.errstate(invalid="ignore"):
            e = self.output_power - 2.0 * np.real(np.conj(h) * self.cross) + np.abs(h) ** 2 * self.input_power
        return np.where(np.isfinite(e), np.maximum(e, 0.0), np.nan)

    def to_json_dict(self) -> dict:
        """JSON ``trim_spectra`` (non-finite numbers are null)."""
        def listed(a: np.ndarray) -> list:
            return [float(v) if math.isfinite(v) else None for v in np.asarray(a, float)]

        return {"input_power": listed(self.input_power), "output_power": listed(self.output_power),
                "cross_real": listed(np.real(self.cross)),
                "cross_imag": listed(np.where(np.isfinite(self.cross), np.imag(self.cross), np.nan)),
                "averages": listed(self.averages),
                "input_floor": None if self.input_floor is None else listed(self.input_floor)}

    @classmethod
    def from_json_dict(cls, data: dict) -> "TrimSpectra":
        """Read JSON ``trim_spectra`` back (null is NaN).

        Parameters
        ----------
        data : dict
            What :meth:`to_json_dict` wrote.
        """
        def array(key: str) -> np.ndarray:
            return np.array([math.nan if v is None else float(v) for v in data.get(key) or []], float)

        cross = array("cross_real") + 1j * array("cross_imag")
        floor = array("input_floor") if data.get("input_floor") is not None else None
        return cls(array("input_power"), array("output_power"), cross, array("averages"), floor)
