"""The estimator's streams as they arrive: buffered, checked, resampled and aligned onto one uniform grid.

:class:`StreamIntake` holds what the estimator knows of each stream before a grid sample exists: the small
calls buffered until ``batch_s`` of data (amortising per-call cost), the time bases (a looped bag's time
jumping back starts a new one), the first sample intervals (the stream's rate), the grid's origin ``t0`` and
the resamplers and aligner of :mod:`gap_validation.core.alignment`. Every grid value that all streams have
reached goes, in time order, to the ``sink`` it was given (the manoeuvre tracker of
:mod:`gap_validation.core.tracking`).
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from gap_validation.core.alignment import GridAligner, StreamResampler, TimeBase, jump_back_s

__all__ = ["StreamIntake", "RATE_STEPS", "BUFFER_CAP"]

#: Sample intervals of each stream whose median gives its rate (the first ones: 2.6 s at 50 Hz).
RATE_STEPS = 128
#: Samples per stream buffered before processing (amortises per-call cost).
BUFFER_CAP = 256


class StreamIntake:
    """Samples of every stream onto the uniform grid ``t_k = t0 + k dt``, aligned across streams.

    Parameters
    ----------
    n_streams : int
        Streams resampled and aligned (the airspeed too, when there is one).
    dt : float
        Grid step [s].
    max_gap_s : float
        A larger sample spacing breaks the data [s].
    cubic : bool
        Cubic Hermite interpolation (else linear).
    max_lag_s : float
        How far one stream may run ahead of another before grid values are dropped [s].
    batch_s : float
        Samples arriving in small calls are processed in batches of this span [s].
    sink : callable
        ``sink(idx, vals)``: grid indices (increasing) and values (streams x n) every stream has reached.
    """

    def __init__(
        self,
        n_streams: int,
        dt: float,
        max_gap_s: float,
        cubic: bool,
        max_lag_s: float,
        batch_s: float,
        sink: Callable[[np.ndarray, np.ndarray], None],
    ) -> None:
        self.dt = dt
        self.max_gap_s = max_gap_s
        self.batch_s = batch_s
        self.sink = sink
        self.resamplers = [StreamResampler(dt, max_gap_s, cubic) for _ in range(n_streams)]
        self.aligner = GridAligner(n_streams, max(16, int(math.ceil(max_lag_s / dt))))
        self.buf = np.zeros((n_streams, 2, BUFFER_CAP))      # stream, (t, value), sample
        self.buf_n = [0] * n_streams
        # per stream: its first RATE_STEPS sample intervals (the rate is their median: fixed by the data
        # alone, not by how the samples were cut into calls), how many, and the last sample time
        self.steps = np.zeros((n_streams, RATE_STEPS))
        self.spacing = np.zeros((n_streams, 2))                 # per stream: intervals kept, last t
        self.spacing[:, 1] = -np.inf
        self._rates: tuple | None = None      # (streams and intervals counted, rates) of the last rates_hz
        self.t0 = float("nan")
        self.trigger_base = TimeBase()
        self.jump_tol_s = jump_back_s(max_gap_s)
        self.jump_gap_s = 2.0 * max_gap_s + 1.0     # between the old and the new time base [s]
        self.epoch = 0
        self.epoch_offset = 0.0

    def time_s(self, k: int) -> float:
        """Time of grid index ``k`` [s].

        Parameters
        ----------
        k : int
            Grid index.

        Returns
        -------
        float
            ``t0 + k dt``.
        """
        return float(self.t0 + k * self.dt)

    def rates_hz(self, streams: int) -> np.ndarray:
        """Sample rate of the first ``streams`` streams [Hz]: one over the median of the first
        :data:`RATE_STEPS` sample intervals, to three significant digits; inf before two samples.

        Parameters
        ----------
        streams : int
            How many streams (the first ones).

        Returns
        -------
        ndarray
            The rates [Hz].
        """
        # the intervals kept are only ever appended to (or loaded): the same counts give the same rates
        key = (streams, tuple(int(n) for n in self.spacing[:streams, 0]))
        if self._rates is not None and self._rates[0] == key:
            return self._rates[1].copy()
        rates = []
        for s in range(streams):
            n = int(self.spacing[s, 0])
            step = float(np.median(self.steps[s, :n])) if n else 0.0
            rates.append(float(f"{1.0 / step:.3g}") if step > 0 else np.inf)
        self._rates = (key, np.array(rates))
        return self._rates[1].copy()

    def bad_sample_counts(self, names: tuple[str, ...]) -> dict:
        """Samples used and not used, per stream (``names``) and for the trigger.

        Parameters
        ----------
        names : tuple of str
            The streams' names, in order.

        Returns
        -------
        dict
            ``{name: {accepted, nonfinite, non_monotonic, time_jumps_back[, dropped_lag]}}``.
        """
        out = {}
        for s, name in enumerate(names):
            b = self.resamplers[s].base
            out[name] = {"accepted": b.accepted, "nonfinite": b.nonfinite, "non_monotonic": b.non_monotonic,
                         "time_jumps_back": b.jumps, "dropped_lag": self.aligner.dropped[s]}
        b = self.trigger_base
        out["trigger"] = {"accepted": b.accepted, "nonfinite": b.nonfinite, "non_monotonic": b.non_monotonic,
                          "time_jumps_back": b.jumps}
        return out

    # ------------------------------------------------------------------ data in
    def add(self, s: int, t: np.ndarray, v: np.ndarray) -> None:
        """Samples of stream ``s`` (buffered until ``batch_s`` of data, unless many).

        Parameters
        ----------
        s : int
            Stream index.
        t, v : ndarray
            Sample times [s] and values (1-D, same length).
        """
        n = self.buf_n[s]
        if n + t.size > BUFFER_CAP or t.size > BUFFER_CAP // 2:
            self.drain(s)                                  # keep time order: older samples first
            n = 0
        if t.size > BUFFER_CAP // 2:
            self.process(s, t, v)
            return
        buf = self.buf[s]
        buf[0, n:n + t.size] = t
        buf[1, n:n + t.size] = v
        self.buf_n[s] = n = n + t.size
        if n and not buf[0, n - 1] - buf[0, 0] < self.batch_s:     # also on NaN times
            self.drain(s)

    def drain(self, s: int) -> None:
        """Process the samples buffered for stream ``s``.

        Parameters
        ----------
        s : int
            Stream index.
        """
        n = self.buf_n[s]
        if n:
            self.buf_n[s] = 0
            self.process(s, self.buf[s, 0, :n].copy(), self.buf[s, 1, :n].copy())

    def drain_all(self) -> None:
        """Process the samples buffered for every stream."""
        for s in range(len(self.resamplers)):
            self.drain(s)

    def process(self, s: int, t: np.ndarray, v: np.ndarray) -> None:
        """Check, resample and align samples of stream ``s``; what every stream reached goes to the sink.

        Parameters
        ----------
        s : int
            Stream index.
        t, v : ndarray
            Sample times [s] and values.
        """
        st = self.resamplers[s]
        t, v = st.base.intake(t, v, self.jump_tol_s, self.new_base, self.jump_tol_s)
        if t.size == 0:
            return
        n = int(self.spacing[s, 0])
        if n < RATE_STEPS:
            steps = np.diff(t, prepend=self.spacing[s, 1])
            steps = steps[(steps > 0) & (steps <= self.max_gap_s)][: RATE_STEPS - n]
            self.steps[s, n:n + steps.size] = steps
            self.spacing[s, 0] = n + steps.size
        self.spacing[s, 1] = t[-1]
        self.ensure_t0(t[0])
        k, vals = st.add(t - self.t0, v)
        self.aligner.push(s, k, vals)
        idx, combined = self.aligner.combine([q.k_next for q in self.resamplers])
        self.sink(idx, combined)

    def trigger_indices(self, t: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Trigger samples on the trigger's time base: the grid index of each (the first at or after it).

        Parameters
        ----------
        t : ndarray
            Sample times [s].
        active : ndarray
            The trigger's values (as floats).

        Returns
        -------
        tuple of ndarray
            Grid indices (int64) and values of the samples kept.
        """
        t, a = self.trigger_base.intake(t, active, self.jump_tol_s, self.new_base)
        if t.size == 0:
            return np.zeros(0, np.int64), a
        self.ensure_t0(t[0])
        return np.ceil((t - self.t0) / self.dt - 1e-9).astype(np.int64), a

    def flush(self) -> None:
        """End of data: every stream's samples processed, those waiting for a confirmation dropped, the grid
        values up to the last sample of each stream to the sink."""
        self.drain_all()
        self.trigger_base.drop_pending()
        for s, st in enumerate(self.resamplers):
            st.base.drop_pending()
            k, v = st.flush()
            self.aligner.push(s, k, v)
        idx, vals = self.aligner.combine([st.k_next for st in self.resamplers])
        self.sink(idx, vals)
        self.aligner.clear()

    def ensure_t0(self, t: float) -> None:
        """Set the grid's origin from the first sample time ``t`` [s] (whole seconds), once.

        Parameters
        ----------
        t : float
            A sample time [s].
        """
        if math.isnan(self.t0):
            self.t0 = float(math.floor(t))

    def new_base(self, base: TimeBase, t_raw: float) -> None:
        """``base``'s time jumped back to ``t_raw`` [s] (confirmed): adopt the new time base another stream
        already opened, or open one just after the latest sample of every stream (a gap: the run ends).

        Parameters
        ----------
        base : TimeBase
            The stream's (or the trigger's) time base.
        t_raw : float
            The sample time after the jump [s].
        """
        if self.epoch > base.epoch and t_raw + self.epoch_offset > base.latest_s + self.max_gap_s:
            base.epoch, base.offset = self.epoch, self.epoch_offset
            return
        latest = max(b.latest_s for b in [st.base for st in self.resamplers] + [self.trigger_base])
        self.epoch += 1
        # a whole number of grid steps: the new base samples the data at the same grid phase as before
        self.epoch_offset = math.ceil((latest + self.jump_gap_s - t_raw) / self.dt) * self.dt
        base.epoch, base.offset = self.epoch, self.epoch_offset

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """The estimator's checkpoint keys of the intake: ``t0``, ``epoch``, ``epoch_offset``, ``buf``,
        ``buf_n``, ``spacing``, ``rate_steps``, and ``align.``, ``tbase.``, ``s<i>.`` parts."""
        st = {"t0": self.t0, "epoch": self.epoch, "epoch_offset": self.epoch_offset, "buf": self.buf.copy(),
              "buf_n": np.array(self.buf_n, np.int64), "spacing": self.spacing.copy(),
              "rate_steps": self.steps.copy()}
        parts = {"align": self.aligner, "tbase": self.trigger_base}
        parts.update({f"s{i}": s for i, s in enumerate(self.resamplers)})
        for prefix, part in parts.items():
            for key, value in part.state_dict().items():
                st[f"{prefix}.{key}"] = value
        return st

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            The estimator's checkpoint (other keys are ignored).
        """
        self.t0 = float(st["t0"])
        self.epoch, self.epoch_offset = int(st["epoch"]), float(st["epoch_offset"])
        self.buf[:] = st["buf"]
        self.buf_n = [int(n) for n in st["buf_n"]]
        self.spacing[:] = st["spacing"]
        self.steps[:] = st["rate_steps"]
        self._rates = None
        parts = {"align": self.aligner, "tbase": self.trigger_base}
        parts.update({f"s{i}": s for i, s in enumerate(self.resamplers)})
        for prefix, part in parts.items():
            n = len(prefix) + 1
            part.load_state({k[n:]: v for k, v in st.items() if k.startswith(prefix + ".")})
