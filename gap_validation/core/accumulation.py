"""Record accumulation: the local polynomial sums of every manoeuvre, pooled, and the latest ones kept one by
one.

:class:`RecordAccumulator` holds what the estimator has learnt from the manoeuvres so far: the pooled
:class:`~gap_validation.core.spectra.BandSums` (the averaged estimate, Fig. 4's dark curve, is solved from
them), the raw estimate rows of the latest ``max_raw_sweeps`` records (the light curves), why frequencies of a
record gave nothing (:data:`~gap_validation.core.estimates.NOT_ESTIMABLE_REASONS`), the manoeuvres counted per
kind and the span they cover. Each record is judged against the trim motion between the records (its
background, from the :class:`~gap_validation.core.background.TrimSpectrum` it was given) and resolved only
below what the streams' rates allow (:func:`~gap_validation.core.spectra.resolved_hz`).
"""
from __future__ import annotations

import math
from collections import Counter
from typing import Callable

import numpy as np

from gap_validation.core.background import TrimSpectrum
from gap_validation.core.estimates import NOT_ESTIMABLE_REASONS, SpectralEstimate, record_amplitude
from gap_validation.core.records import KINDS
from gap_validation.core.spectra import (
    SPECTRA_DEFAULTS,
    BandSums,
    interpolation_gain,
    record_bands,
    resolved_hz,
)

__all__ = ["RecordAccumulator", "STEPPED_KINDS"]

#: Manoeuvres made of steps: not band-limited (:data:`gap_validation.core.spectra.ALIAS_MARGIN`).
STEPPED_KINDS = ("doublet", "pulse", "multistep")


class RecordAccumulator:
    """The manoeuvres' local polynomial sums, pooled (and the latest ``max_raw_sweeps`` one by one).

    Parameters
    ----------
    w_rad_s : ndarray
        Frequencies [rad/s].
    inputs, outputs : int
        Inputs and outputs among the data streams (the rest are instruments).
    data_streams : int
        Streams a record holds.
    dt : float
        Grid step [s].
    options : dict
        The estimator's validated options (the spectra options, ``max_raw_sweeps``, ``sample_rate_hz``,
        ``cubic_interpolation``).
    trim : TrimSpectrum
        The trim motion between the records (each record's background).
    rates_hz : callable
        ``rates_hz()``: the data streams' sample rates [Hz] (what the records resolve).
    """

    def __init__(
        self,
        w_rad_s: np.ndarray,
        inputs: int,
        outputs: int,
        data_streams: int,
        dt: float,
        options: dict,
        trim: TrimSpectrum,
        rates_hz: Callable[[], np.ndarray],
    ) -> None:
        self._w = w_rad_s
        self._m, self._p, self._S = int(inputs), int(outputs), int(data_streams)
        self._dt = dt
        self._opts = options
        self._spectra_opts = {k: options[k] for k in SPECTRA_DEFAULTS}
        self._trim = trim
        self._rates_hz = rates_hz
        q = self._S - self._m - self._p
        self._tot = BandSums.zeros(w_rad_s.size, self._m, self._p, q or None, options["order"])
        self._tot_changes = 0                      # additions to _tot (part of :attr:`key`)
        self._reasons = np.zeros((len(NOT_ESTIMABLE_REASONS), w_rad_s.size), np.int64)
        self._raw: list[tuple[np.ndarray, int, int, str]] = []    # estimate rows, k0, k1, kind
        self._raw_amplitude: list[float] = []                       # input amplitude of each raw record
        self._raw_changes = 0                                       # records added to or dropped from _raw
        self._n_sweeps = 0
        self._span = [0, 0]
        self._counted: Counter = Counter()
        self._longest_n = 0
        self._other_records = 0

    # ------------------------------------------------------------------ what it holds
    @property
    def sums(self) -> BandSums:
        """The pooled sums (not a copy)."""
        return self._tot

    @property
    def n_records(self) -> int:
        """Manoeuvres pooled (another input's included)."""
        return self._n_sweeps

    @property
    def span(self) -> tuple[int, int]:
        """Grid indices of the first start and the last end of this channel's pooled manoeuvres."""
        return self._span[0], self._span[1]

    @property
    def counted(self) -> Counter:
        """This channel's manoeuvres that gave a response, per kind (a copy)."""
        return Counter(self._counted)

    @property
    def longest_n(self) -> int:
        """Samples of the longest record estimated."""
        return self._longest_n

    @property
    def reasons(self) -> np.ndarray:
        """Records that gave nothing, per reason in :data:`NOT_ESTIMABLE_REASONS` and frequency (a copy)."""
        return self._reasons.copy()

    @property
    def key(self) -> tuple:
        """Changes whenever the pooled estimate may (the cache key of a solved average)."""
        return (id(self._tot), self._tot_changes, self._n_sweeps, tuple(self._span), self._reasons.tobytes())

    @property
    def raw(self) -> list[tuple[np.ndarray, int, int, str, float]]:
        """The raw estimates kept, oldest first: rows (:attr:`SpectralEstimate.ROWS`), first and end grid
        index,
        kind, input amplitude (NaN when unknown)."""
        amplitudes = self._raw_amplitude + [float("nan")] * (len(self._raw) - len(self._raw_amplitude))
        return [(rows, k0, k1, kind, a) for (rows, k0, k1, kind), a in zip(self._raw, amplitudes)]

    @property
    def raw_key(self) -> tuple[int, int]:
        """Changes whenever a raw estimate is added or dropped."""
        return self._raw_changes, len(self._raw)

    # ------------------------------------------------------------------ records in
    def add(self, k_start: int, seg: np.ndarray, kind: str, noise: float, active: tuple[int, int],
            own: bool = True) -> bool:
        """Estimate one manoeuvre's record and pool it where it counts.

        Parameters
        ----------
        k_start : int
            Grid index of the record's first sample.
        seg : ndarray
            The record (data streams x n).
        kind : str
            Its manoeuvre kind (:data:`~gap_validation.core.records.KINDS`).
        noise : float
            The excitation's trim noise (standard deviation) in the record.
        active : tuple of int
            The manoeuvre's own span (grid indices), the time reported for it (the record adds trim around
            it).
        own : bool
            The manoeuvre is this channel's (False: another input's, ``other_inputs``: pooled only, to
            separate the inputs; no raw estimate, not counted per kind).

        Returns
        -------
        bool
            True when it counted at some frequency.
        """
        self._longest_n = max(self._longest_n, seg.shape[1])
        m, p = self._m, self._p
        instruments = seg[m + p:] if seg.shape[0] > m + p else None
        rates = self._rates_hz()
        limit_hz, _ = resolved_hz(rates, m, p, self._opts["sample_rate_hz"])
        sums, status = record_bands(
            seg[:m],
            seg[m : m + p],
            self._dt,
            self._w,
            instruments=instruments,
            noise_floor=noise**2,
            background=self._background(instruments is not None),
            stepped=kind in STEPPED_KINDS,
            options=self._spectra_opts,
            max_rad_s=float(2.0 * math.pi * limit_hz),
            rates_hz=rates,
            cubic=self._opts["cubic_interpolation"],
        )
        counted = status == 0
        for i in range(len(NOT_ESTIMABLE_REASONS)):
            self._reasons[i] += status == i + 1
        if not counted.any():
            return False
        self._tot.add(sums, counted)
        self._tot_changes += 1
        amplitude = record_amplitude(seg[0, max(active[0] - k_start, 0):max(active[1] - k_start, 0)])
        k_start, k_end = active
        if not own:
            self._n_sweeps += 1
            self._other_records += 1
            return True
        if self._n_sweeps == self._other_records:
            self._span[0] = k_start
        self._span[1] = k_end
        self._n_sweeps += 1
        self._counted[kind] += 1
        raw = SpectralEstimate.from_sums(self._w, sums, self._dt, self._opts["band_fraction"])
        self._raw.append((raw.rows(), k_start, k_end, kind))
        self._raw_changes += 1
        self._raw_amplitude.append(amplitude)
        if len(self._raw) > self._opts["max_raw_sweeps"]:
            self._raw.pop(0)
            self._raw_amplitude.pop(0)
        return True

    def _background(self, instruments: bool) -> np.ndarray:
        """The excitation's trim motion between the records per frequency (the instruments', else the inputs'
        summed), as :func:`~gap_validation.core.spectra.record_bands` sees a record: restored for the
        interpolation of each stream onto the grid, as the records are."""
        streams = range(self._m + self._p, self._S) if instruments else range(self._m)
        rates = self._rates_hz()
        gain = {j: interpolation_gain(self._w, rates[j], self._opts["cubic_interpolation"]) for j in streams}
        return sum(self._trim.power([j]) / np.maximum(gain[j], 1e-3) ** 2 for j in streams)

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """The estimator's checkpoint keys of the pooled records: ``n_sweeps``, ``span``, ``reasons``,
        ``n_raw``, ``raw_rows``, ``raw_meta``, ``raw_kind``, ``raw_amplitude`` (``max_raw_sweeps`` slots),
        ``counted_counts``, ``longest_n``, ``other_records`` (only when not 0) and the ``tot.`` sums."""
        slots, F = self._opts["max_raw_sweeps"], self._w.size
        rows = np.full((slots, len(SpectralEstimate.ROWS), F), np.nan)
        meta = np.zeros((slots, 2), np.int64)
        kinds = np.full(slots, "", dtype="<U16")
        for i, (r, k0, k1, kind) in enumerate(self._raw):
            rows[i], meta[i], kinds[i] = r, (k0, k1), kind
        amplitude = np.full(slots, np.nan)
        amplitude[:len(self._raw_amplitude)] = self._raw_amplitude[:slots]
        st: dict = {
            "n_sweeps": self._n_sweeps,
            "span": np.array(self._span, np.int64),
            "reasons": self._reasons.copy(),
            "n_raw": len(self._raw),
            "raw_rows": rows,
            "raw_meta": meta,
            "raw_kind": kinds,
            "raw_amplitude": amplitude,
            "counted_counts": np.array([self._counted[k] for k in KINDS], np.int64),
            "longest_n": self._longest_n,
        }
        if self._other_records:
            st["other_records"] = self._other_records
        st.update(self._tot.state_dict("tot."))
        return st

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            The estimator's checkpoint (other keys are ignored; older checkpoints hold fewer reasons and no
            amplitudes).
        """
        self._n_sweeps = int(st["n_sweeps"])
        self._span = [int(v) for v in st["span"]]
        reasons = np.asarray(st["reasons"], np.int64)           # older checkpoints hold fewer reasons
        self._reasons[:] = 0
        self._reasons[:reasons.shape[0]] = reasons
        self._longest_n = int(st["longest_n"])
        self._other_records = int(st.get("other_records", 0))
        self._tot = BandSums.from_state(st, "tot.")
        meta = np.asarray(st["raw_meta"], np.int64).reshape(-1, 2)
        kinds = [str(k) for k in np.atleast_1d(st["raw_kind"])]
        rows = np.asarray(st["raw_rows"], float)
        self._raw = [
            (rows[i].copy(), int(meta[i, 0]), int(meta[i, 1]), kinds[i]) for i in range(int(st["n_raw"]))
        ]
        self._raw_changes += 1
        amplitude = np.asarray(st.get("raw_amplitude", np.full(int(st["n_raw"]), np.nan)), float).ravel()
        self._raw_amplitude = [float(amplitude[i]) if i < amplitude.size else float("nan")
                               for i in range(int(st["n_raw"]))]
        self._counted = Counter({k: int(v) for k, v in zip(KINDS, st["counted_counts"]) if int(v)})
