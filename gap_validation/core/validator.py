"""The online validator: the single data path shared by replay, the ROS 2 node and the library.

Samples of each channel's input (surface), output (rate) and optional trigger arrive in time-ordered batches;
each channel's :class:`~gap_validation.core.estimator.FrequencyResponseEstimator` turns them into spectra
during sweeps. :meth:`OnlineValidator.results` compares the current models with the spectra gathered so far
(nu-gap, epsilon averaged and raw, margins, eqs. 13-17) and asks the diagnosis where and why the model fails.
Changing the model (:meth:`set_config`) keeps the spectra, so the error is recomputed without flying again.
"""
from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core import metrics, robust, wording
from gap_validation.core.closed_loop import (
    CouplingMonitor,
    SurfaceHistory,
    feedback_bias,
    feedback_evidence,
    near_minus_inverse,
    rate_leads,
    with_bias_allowance,
)
from gap_validation.core.config import (
    AIRSPEED_STREAM,
    EXCITATION_STREAM,
    OTHER_INPUT_STREAM,
    STREAMS,
    ChannelConfig,
    SignalSpec,
    ValidationConfig,
)
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.estimator import ESTIMATOR_DEFAULTS, FrequencyResponseEstimator, SpectralEstimate
from gap_validation.core.evidence import confident_points
from gap_validation.core.margins import margins_from_epsilon
from gap_validation.core.records import SATURATED_SHARE
from gap_validation.core.results import ChannelResult, SweepResult, ValidationResult
from gap_validation.core.spectra import sweep_points
from gap_validation.core.uncertainty import time_domain_check

log = logging.getLogger(__name__)

STATE_VERSION = 1


def _sup(metric, w: np.ndarray, p_model: np.ndarray, p_meas: np.ndarray,
         mask: np.ndarray) -> tuple[float | None, float | None]:
    """``metric`` (a sup over frequency points from :mod:`metrics`) over the masked points, or (None,
    None)."""
    if not np.any(mask):
        return None, None
    value, w_peak = metric(w[mask], p_model[mask], p_meas[mask])
    return (None, None) if np.isnan(value) else (float(value), float(w_peak))


def _estimator_for(channel: ChannelConfig) -> FrequencyResponseEstimator:
    # the airspeed (the flight condition), when the channel has one, is the last stream: it scales the inputs
    airspeed = [AIRSPEED_STREAM] if channel.airspeed is not None else []
    trim = channel.trim_airspeed_m_s if channel.airspeed is not None else None
    if channel.is_mimo:   # streams inputs[j], outputs[i]: the whole matrix from the pooled sums
        return FrequencyResponseEstimator(
            channel.frequencies.values(),
            channel.input_streams + channel.output_streams + tuple(airspeed),
            len(channel.inputs),
            len(channel.outputs),
            trim,
            **channel.estimator,
        )
    # other_inputs are more inputs (the channel's response is the first input's column); the excitation is the
    # instrument (instrumental variables) and the detection signal
    others = [OTHER_INPUT_STREAM.format(j) for j in range(len(channel.other_inputs))]
    streams = ["input", *others, "output"] + ([EXCITATION_STREAM] if channel.excitation is not None else [])
    return FrequencyResponseEstimator(
        channel.frequencies.values(),
        streams + airspeed,
        inputs=1 + len(others),
        outputs=1,
        trim_airspeed=trim,
        **channel.estimator,
    )


def _same_measurement(a: ChannelConfig, b: ChannelConfig) -> bool:
    """True when spectra gathered for ``a`` stay valid for ``b`` (only the model may differ)."""
    return _measurement_key(a) == _measurement_key(b)


class OnlineValidator:
    """Gathers spectra per channel and validates the config's models against them.

    Parameters
    ----------
    config : ValidationConfig
        Channels, models and analysis settings.
    diagnose : bool
        Run the diagnosis (effect fitting) in :meth:`results` by default.

    Examples
    --------
    A pitch model that misses the aircraft's 30 ms delay, one logarithmic sweep flown between two trims:

    >>> import numpy as np
    >>> from gap_validation.core import LinearModel, OnlineValidator, parse_config
    >>> cfg = parse_config({"channels": {"pitch": {
    ...     "input": {"topic": "/servos", "field": "position[elevator]"},
    ...     "output": {"topic": "/imu", "field": "angular_velocity.y"},
    ...     "model": {"numerator": [40.0], "denominator": [1.0, 12.0, 40.0]}}}}, "example.yaml")
    >>> t = np.arange(0.0, 130.0, 0.01)
    >>> chirp = 0.05 * np.sin(np.cumsum(0.5 * 60.0 ** ((t - 20.0) / 90.0) * 0.01))
    >>> u = np.where((t > 20.0) & (t < 110.0), chirp, 0.0)
    >>> u += 1e-4 * np.random.default_rng(0).standard_normal(t.size)   # the surface at trim
    >>> y = LinearModel([40.0], [1.0, 12.0, 40.0], delay_s=0.03).simulate(t, u)   # the aircraft
    >>> validator = OnlineValidator(cfg)
    >>> validator.add_time_histories("pitch", t, u, t, y)
    >>> validator.finish()   # the flight is over: close the manoeuvre still open
    >>> pitch = validator.results().channels["pitch"]
    >>> pitch.sweeps, round(pitch.epsilon, 2), pitch.limited_by
    (1, 0.44, 'model')
    >>> print(pitch.diagnosis[0].sentence)
    missing: time delay of 30 ms; adding it brings epsilon from 0.44 to 0.00, which explains the mismatch
    (the rest is within the data's errors)
    """

    def __init__(self, config: ValidationConfig, *, diagnose: bool = True) -> None:
        self._config = config
        self._diagnose = diagnose
        self._estimators = {name: _estimator_for(ch) for name, ch in config.channels.items()}
        self._monitors = _monitors_for(config)
        self._watch()
        self._bad: dict[str, Counter] = {name: Counter() for name in config.channels}
        self._previous: dict[str, float | None] = {}
        self._versions: dict[str, int] = {name: 0 for name in config.channels}
        self._diagnosis_cache: dict[str, tuple[Any, dict]] = {}
        # channel -> (identity of its estimates, them, _estimate_key)
        self._key_memo: dict[str, tuple] = {}
        self._time_domain_cache: dict[str, tuple] = {}
        self._margin_cache: dict[str, tuple] = {}   # channel -> (model and controller specs, b(P1, C))
        self.sources: list[str] = []

    # ------------------------------------------------------------------ data in
    @property
    def config(self) -> ValidationConfig:
        """The config whose models are validated (replaced by :meth:`set_config`)."""
        return self._config

    def add_samples(self, channel: str, stream: str, t_s: ArrayLike, values: ArrayLike) -> None:
        """Feed a time-ordered batch of samples of one stream of one channel.

        Parameters
        ----------
        channel : str
            Channel name from the config.
        stream : str
            ``input`` (surface deflection [rad]), ``output`` (body rate [rad/s]) or ``trigger`` (the explicit
            sweep trigger, bool); a MIMO channel's ``inputs[j]`` and ``outputs[i]``
            (:attr:`~gap_validation.core.config.ChannelConfig.input_streams`).
        t_s, values : array_like
            Sample times [s] and values (already scaled to SI units).
        """
        est = self._estimators.get(channel)
        if est is None:
            raise ConfigError(f"no channel {channel!r} in the config")
        t_s = _numbers(channel, stream, "times", t_s)
        if t_s.size == 0:
            return
        mimo = self._config.channels[channel].is_mimo
        if stream != "trigger":
            values = _numbers(channel, stream, "values", values)
        if mimo and stream != "trigger":
            est.add_samples(stream, t_s, values)
        elif stream == "input":
            est.add_input(t_s, values)
            self._feed_monitors(channel, {"input": (t_s, values)})
        elif stream == "output":
            est.add_output(t_s, values)
            self._feed_monitors(channel, {"output": (t_s, values)})
        elif stream == "trigger":
            values = np.asarray(values)
            if values.dtype.kind not in "biuf":  # "false" would be True as a string
                raise DataError(
                    f"channel {channel}: trigger values must be booleans or numbers, got {values.dtype}"
                )
            est.add_trigger(t_s, values.astype(bool))
        elif stream in est.streams:                     # other_input<j>, excitation
            est.add_samples(stream, t_s, values)
        else:
            raise ConfigError(f"unknown stream {stream!r} (expected one of {', '.join(STREAMS)})")
        self._versions[channel] += 1

    def add_time_histories(self, channel: str, t_input_s: ArrayLike, u: ArrayLike, t_output_s: ArrayLike,
                           y: ArrayLike) -> None:
        """Feed whole recorded time histories of one channel at once (library use: arrays already in memory).

        Equivalent to feeding both streams interleaved in time order; the streams may have different,
        irregular sample times.

        Parameters
        ----------
        channel : str
            Channel name from the config.
        t_input_s, u : array_like
            Input sample times [s] and surface deflections [rad].
        t_output_s, y : array_like
            Output sample times [s] and body rates [rad/s].
        """
        est = self._estimators.get(channel)
        if est is None:
            raise ConfigError(f"no channel {channel!r} in the config")
        est.add_time_histories(np.asarray(t_input_s, float), np.asarray(u, float),
                               np.asarray(t_output_s, float), np.asarray(y, float))
        self._versions[channel] += 1
        self._feed_monitors(channel, {"input": (t_input_s, u), "output": (t_output_s, y)}, whole=True)

    def add_histories(self, channel: str, histories: dict) -> None:
        """Feed whole recorded time histories of any of a channel's streams at once, interleaved in time
        (library use; e.g. with ``excitation`` or ``other_inputs``: ``{"input": (t, u), "output": (t, y),
        "excitation": (t, r)}``; a MIMO channel's ``inputs[j]`` and ``outputs[i]``).

        Parameters
        ----------
        channel : str
            Channel name from the config.
        histories : dict
            Stream name (``input``, ``output``, ``excitation``, ``other_input0`` ...) -> ``(t_s, values)`` in
            SI units.
        """
        est = self._estimators.get(channel)
        if est is None:
            raise ConfigError(f"no channel {channel!r} in the config")
        est.add_histories({stream: (np.asarray(t, float), np.asarray(v, float))
                           for stream, (t, v) in histories.items()})
        self._versions[channel] += 1
        self._feed_monitors(channel, histories, whole=True)

    def _feed_monitors(self, channel: str, histories: dict, whole: bool = False) -> None:
        """The coupling monitors (:mod:`gap_validation.core.closed_loop`) see the channel's input too: the
        history of its surface (other channels' coupling monitors read it at the times of their manoeuvres).
        ``whole``: whole recorded histories (library use)."""
        mon = self._monitors.get(channel)
        if mon is None:
            return
        for stream, (t, v) in histories.items():
            if stream != "input":
                continue
            t, v = np.asarray(t, float), np.asarray(v, float)
            if stream == "input":
                mon.history.add(t, v, whole=whole)
                for other in self._monitors.values():
                    coupling = other.coupling.get(channel)
                    if coupling is not None and coupling.pending:
                        coupling.catch_up(mon.history)

    def _observer(self, channel: str):
        """The channel estimator's ``record_observer``: each manoeuvre to the channel's coupling monitors."""
        def observe(samples: np.ndarray, kind: str, t0_s: float, dt_s: float) -> bool:
            monitors = self._monitors[channel].coupling
            own = self._trim_motion(channel)
            for other, coupling in monitors.items():     # another surface's manoeuvre: not this channel's
                if coupling.leads(samples[0], t0_s, dt_s, self._monitors[other].history, own,
                                  self._trim_motion(other)):
                    return False
            for other, coupling in monitors.items():
                coupling.observe(samples[0], t0_s, dt_s, self._monitors[other].history)
            return True
        return observe

    def _trim_motion(self, channel: str) -> float:
        """The channel's surface trim motion between manoeuvres (its estimator's; 0 before any)."""
        est = self._estimators.get(channel)
        return (
            float(est.input_trim_motion()) if est is not None and hasattr(est, "input_trim_motion") else 0.0
        )

    def _watch(self) -> None:
        """Hook the coupling monitors to the channels' estimators (after any estimator was made)."""
        for name, est in self._estimators.items():
            est.record_observer = self._observer(name) if self._monitors.get(name) is not None and \
                self._monitors[name].coupling else None

    def count_bad(self, channel: str, stream: str, reason: str, count: int = 1) -> None:
        """Count samples that could not be used (NaN, missing joint, wrong length ...), per reason.

        Parameters
        ----------
        channel : str
            Channel name (others are ignored).
        stream : {"input", "output", "trigger"}
            The stream.
        reason : str
            Short tag (``not finite``, ``missing joint`` ...).
        count : int
            Samples.
        """
        if channel in self._bad:
            self._bad[channel][f"{stream}: {reason}"] += int(count)

    def finish(self, channels: Sequence[str] | None = None) -> None:
        """End of data: close the open manoeuvres (of ``channels``, default all).

        Parameters
        ----------
        channels : sequence of str, optional
            The channels whose data ended (the node: those whose inputs went silent).
        """
        for name, est in self._estimators.items():
            if channels is None or name in channels:
                est.flush()
                self._versions[name] += 1

    def reset(self) -> None:
        """Forget every spectrum gathered (keeps the models)."""
        self._estimators = {name: _estimator_for(ch) for name, ch in self._config.channels.items()}
        self._monitors = _monitors_for(self._config)
        self._watch()
        self._bad = {name: Counter() for name in self._config.channels}
        self._previous = {}
        self._versions = {name: v + 1 for name, v in self._versions.items()}
        self._diagnosis_cache.clear()
        self._time_domain_cache.clear()

    def set_config(self, config: ValidationConfig) -> list[str]:
        """Swap in new models (live model update); spectra are kept where the measurement is unchanged.

        The epsilon of the old model becomes ``epsilon_previous`` in the next results. Returns the channels
        whose spectra had to be restarted (their topics, fields, frequencies or estimator options changed).

        Parameters
        ----------
        config : ValidationConfig
            The new config (models, and possibly topics, fields or analysis settings).
        """
        old = self.results(diagnose=False)
        restarted = []
        estimators, bad = {}, {}
        for name, ch in config.channels.items():
            prev = self._config.channels.get(name)
            if prev is not None and _same_measurement(prev, ch):
                estimators[name] = self._estimators[name]
                bad[name] = self._bad[name]
            else:
                estimators[name] = _estimator_for(ch)
                bad[name] = Counter()
                restarted.append(name)
        self._previous = {name: old.channels[name].epsilon for name in config.channels if name in old.channels
                          and name not in restarted}
        monitors = _monitors_for(config)
        # kept where the channel's measurement and the surfaces are unchanged
        for name in config.channels:
            if name not in restarted and name in self._monitors and \
                    set(self._monitors[name].coupling) == set(monitors[name].coupling):
                monitors[name] = self._monitors[name]
        self._config = config
        self._estimators, self._bad, self._monitors = estimators, bad, monitors
        self._watch()
        self._versions = {name: self._versions.get(name, 0) + 1 for name in config.channels}
        self._diagnosis_cache.clear()
        self._time_domain_cache.clear()
        return restarted

    # ------------------------------------------------------------------ results
    def estimate(self, channel: str) -> SpectralEstimate | None:
        """The averaged spectral estimate of ``channel`` so far (None before the first sweep).

        Parameters
        ----------
        channel : str
            Channel name.
        """
        return self._estimators[channel].averaged()

    def sweep_estimates(self, channel: str) -> list[SpectralEstimate]:
        """The per-sweep (raw) estimates of ``channel`` kept so far.

        Parameters
        ----------
        channel : str
            Channel name.
        """
        return list(self._estimators[channel].sweeps)

    def results(self, diagnose: bool | None = None) -> ValidationResult:
        """Validate every channel's model against the spectra gathered so far.

        Parameters
        ----------
        diagnose : bool, optional
            Run the diagnosis (effect fitting); default: as constructed.
        """
        diagnose = self._diagnose if diagnose is None else diagnose
        self._found_conventions: dict = {}
        channels = {
            name: self._channel_result(name, ch, diagnose) for name, ch in self._config.channels.items()
        }
        _name_conventions(self._config, channels, self._found_conventions)
        for name, channel in self._config.channels.items():
            self._check_controller(channel, channels[name])
        return ValidationResult(
            channels=channels, config_source=self._config.source, sources=list(self.sources)
        )

    def _channel_result(self, name: str, channel: ChannelConfig, diagnose: bool) -> ChannelResult:
        if channel.is_mimo:
            return self._mimo_result(name, channel, diagnose)
        est = self._estimators[name]
        sweeps = list(est.sweeps)
        pooled_sweeps = sweeps
        result = ChannelResult(name=name, sweeps=int(getattr(est, "n_sweeps", len(sweeps))),
                               coherence_threshold=channel.coherence_threshold,
                               bad_samples=dict(self._bad[name]), epsilon_previous=self._previous.get(name),
                               model_description=_describe_model(channel), model_spec=channel.model_spec)
        result.excitation = est.excitation
        resolved = est.resolved_rad_s
        result.resolved_rad_s = resolved if math.isfinite(resolved) and resolved > 0 else None
        result.dynamic_pressure_ratio = est.dynamic_pressure_ratio
        result.warnings.extend(_condition_warnings(result.dynamic_pressure_ratio))
        result.warnings.extend(_lag_warnings(est))
        _count_estimator_rejects(est, result.bad_samples)
        result.manoeuvres_by_kind = est.counted_kinds
        result.manoeuvres_flown = dict(getattr(est, "flown_kinds", {}))
        lead = est.surface_led()
        result.rate_leads_surface = (
            None
            if lead is None
            else {
                "share": lead.share,
                "f": lead.f,
                "p_value": lead.p_value,
                "rows": lead.rows,
                "lags_s": lead.lags_s,
            }
        )
        self._time_domain(name, channel, est, result)
        avg = est.averaged()
        if avg is None:
            result.message = "no sweep found: " + _why_nothing(est, channel)
            if channel.excitation is None:       # a loop can leave the manoeuvres nothing: say so if it shows
                result.warnings.extend(_feedback_warnings(channel, est, None, None, None)[0])
            return result
        full = avg
        excited = np.flatnonzero(avg.excited)
        if excited.size:
            result.excited_band_rad_s = (float(avg.w_rad_s[excited[0]]), float(avg.w_rad_s[excited[-1]]))
            if not channel.frequencies.configured:         # the grid spans the flown excitation
                span = slice(int(excited[0]), int(excited[-1]) + 1)
                avg, sweeps = avg.select(span), [s.select(span) for s in sweeps]
        w = np.asarray(avg.w_rad_s, dtype=float)
        p_model = _flown_model(channel, avg, sweeps).freqresp(w)
        p_meas = np.asarray(avg.response, dtype=complex)
        confident = confident_points(avg, channel.coherence_threshold)
        kappa = metrics.chordal_distance(p_model, p_meas)
        eps_w = metrics.epsilon_per_frequency(p_model, p_meas)
        result.frequency_rad_s, result.coherence = w, np.asarray(avg.coherence, dtype=float)
        result.random_error = np.asarray(avg.random_error, dtype=float)
        result.degrees_of_freedom = np.asarray(avg.n_averages, dtype=float)
        result.trim_spectra = est.trim_spectra().take(_grid_index(est.w_rad_s, w))
        result.frequency_reasons = _frequency_reasons(avg, confident, channel.coherence_threshold)
        result.kappa, result.epsilon_per_frequency = kappa, eps_w
        _closed_loop_coherences(channel, avg, result)
        result.measured, result.model, result.confident = p_meas, p_model, confident
        result.points_excluded = int(w.size - np.count_nonzero(confident))
        result.nu_gap, result.nu_gap_frequency_rad_s = _sup(metrics.nugap_frequency_data, w, p_model, p_meas,
                                                            confident)
        result.epsilon, result.worst_frequency_rad_s = _sup(
            metrics.epsilon_frequency_data, w, p_model, p_meas, confident
        )
        result.margins = margins_from_epsilon(result.epsilon if result.epsilon is not None else float("nan"))
        result.sweep_results = [self._sweep_result(channel, s, p_model, confident) for s in sweeps]
        result.sweep_measured = [np.asarray(s.response, dtype=complex) for s in sweeps]
        raw = [(s.epsilon, s.worst_frequency_rad_s) for s in result.sweep_results if s.epsilon is not None]
        if raw:
            result.epsilon_raw, result.epsilon_raw_frequency_rad_s = max(raw, key=lambda r: r[0])
            result.margins_raw = margins_from_epsilon(result.epsilon_raw)
        suspect, warnings = _closed_loop_checks(
            channel, self._monitors[name], self._config, est, full, w, p_meas, p_model, confident
        )
        result.warnings.extend(warnings)
        if suspect.any():
            result.frequency_reasons = [BIASED if s else r for s, r in zip(suspect, result.frequency_reasons)]
            avg = with_bias_allowance(avg, suspect)
        self._apply_diagnosis(name, channel, avg, sweeps, result, diagnose,
                              self._memo_estimate_key(name, full, pooled_sweeps, avg, sweeps))
        return result

    def _mimo_result(self, name: str, channel: ChannelConfig, diagnose: bool) -> ChannelResult:
        """A MIMO channel: the whole response matrix pooled over the manoeuvres against the MIMO model
        (:mod:`gap_validation.core.mimo`). ``kappa``, ``nu_gap``, ``limited_by``, ``bands`` and ``diagnosis``
        as for SISO; ``coherence`` is the worst output's multiple coherence; epsilon and its margins are SISO
        notions (null); the per-element responses are in ``mimo``."""
        from gap_validation.core import mimo
        from gap_validation.core.spectra import expected_matrix

        est = self._estimators[name]
        result = ChannelResult(
            name=name,
            sweeps=int(est.n_sweeps),
            coherence_threshold=channel.coherence_threshold,
            bad_samples=dict(self._bad[name]),
            epsilon_previous=None,
            model_description=_describe_model(channel),
            model_spec=channel.model_spec,
        )
        result.excitation = est.excitation
        result.dynamic_pressure_ratio = est.dynamic_pressure_ratio
        result.warnings.extend(_condition_warnings(result.dynamic_pressure_ratio))
        result.warnings.extend(_lag_warnings(est))
        _count_estimator_rejects(est, result.bad_samples)
        result.manoeuvres_by_kind = est.counted_kinds
        result.manoeuvres_flown = dict(getattr(est, "flown_kinds", {}))
        avg, matrix = est.averaged(), est.averaged_matrix()
        if avg is None or matrix is None:
            result.message = "no sweep found: " + _why_nothing(est, channel)
            return result
        index = np.arange(avg.w_rad_s.size)
        excited = np.all(np.isfinite(matrix.response), axis=(1, 2))
        if excited.any():
            on = np.flatnonzero(excited)
            result.excited_band_rad_s = (float(avg.w_rad_s[on[0]]), float(avg.w_rad_s[on[-1]]))
            if not channel.frequencies.configured:
                index = np.arange(on[0], on[-1] + 1)
        w = np.asarray(avg.w_rad_s, float)[index]
        matrix = mimo.take_frequencies(matrix, index)
        sums = est.pooled_sums.take(index)
        band_fraction = est.options["band_fraction"]
        key = (self._versions[name], repr(channel.model_spec), diagnose)
        cached = self._diagnosis_cache.get(name)
        if cached is not None and cached[0] == key:
            found = cached[1]
        else:
            found = mimo.analyse_mimo(
                channel.model,
                matrix,
                w,
                channel.coherence_threshold,
                [f"{s.topic} {s.field}" for s in channel.inputs],
                [f"{s.topic} {s.field}" for s in channel.outputs],
                coefficients=len(channel.inputs) * (est.options["order"] + 1),
                expected=lambda response: expected_matrix(sums, w, band_fraction, response),
                excited=excited[index],
                diagnose=diagnose,
            )
            self._diagnosis_cache[name] = (key, found)
        result.frequency_rad_s, result.coherence, result.kappa = w, found.coherence, found.kappa
        result.degrees_of_freedom, result.confident = found.dof, found.confident
        result.points_excluded = int(w.size - np.count_nonzero(found.confident))
        result.nu_gap, result.nu_gap_frequency_rad_s = found.nu_gap, found.nu_gap_frequency_rad_s
        result.limited_by, result.frequency_flags, result.bands = found.limited_by, list(found.flags), \
            list(found.bands)
        result.diagnosis, result.message, result.mimo = list(found.diagnosis), found.message, found.detail
        result.frequency_reasons = [None if c else ("not_excited" if f == "not_excited" else "low_coherence")
                                    for c, f in zip(found.confident, found.flags)]
        return result

    def _check_controller(self, channel: ChannelConfig, result: ChannelResult) -> None:
        """The controller check (issue 14): b(P1, C) of the model and the controller (cached per model and
        controller) against the measured nu-gap: ``guaranteed_stable = b > nu-gap``."""
        if channel.controller is None:
            return
        key = (repr(channel.model_spec), repr(channel.controller_spec))
        cached = self._margin_cache.get(channel.name)
        if cached is None or cached[0] != key:
            cached = (key, robust.margin_of(channel.model, channel.controller))
            self._margin_cache[channel.name] = cached
        check = robust.controller_check(channel.model, channel.controller, result.nu_gap, measured=True,
                                        margin=cached[1])
        result.stability_margin_b, result.stability_margin_frequency_rad_s = check.stability_margin_b, \
            check.frequency_rad_s
        result.guaranteed_stable, result.stability_note = check.guaranteed_stable, check.sentence

    def _time_domain(self, name: str, channel: ChannelConfig, est: FrequencyResponseEstimator,
                     result: ChannelResult) -> None:
        """Doublets kept from the flight, and the TIC of the model against each (paper eqs. 1, 3; Fig. 6)."""
        key = (est.manoeuvres_key, repr(channel.model_spec))
        cached = self._time_domain_cache.get(name)
        if cached is None or cached[0] != key:
            manoeuvres = est.manoeuvres
            checks = [time_domain_check(channel.model, m) for m in manoeuvres]
            cached = (key, manoeuvres, [{"tic": c.tic, "tic_input_augmented": c.tic_input_augmented}
                                        for c in checks])
            self._time_domain_cache[name] = cached
        result.manoeuvres, result.time_domain = list(cached[1]), [dict(c) for c in cached[2]]

    @staticmethod
    def _sweep_result(channel: ChannelConfig, sweep: SpectralEstimate, p_model: np.ndarray,
                      average_confident: np.ndarray) -> SweepResult:
        w = np.asarray(sweep.w_rad_s, dtype=float)
        p_meas = np.asarray(sweep.response, dtype=complex)
        ok = sweep_points(sweep, average_confident, channel.coherence_threshold)
        eps, w_eps = _sup(metrics.epsilon_frequency_data, w, p_model, p_meas, ok)
        return SweepResult(start_s=float(getattr(sweep, "start_s", np.nan)),
                           end_s=float(getattr(sweep, "end_s", np.nan)), epsilon=eps,
                           worst_frequency_rad_s=w_eps, points_used=int(np.count_nonzero(ok)))

    def _memo_estimate_key(self, name: str, full: SpectralEstimate, full_sweeps: list[SpectralEstimate],
                           avg: SpectralEstimate, sweeps: list[SpectralEstimate]) -> bytes:
        """:func:`_estimate_key` of ``avg`` and ``sweeps`` (``full`` and ``full_sweeps`` as the estimator gave
        them, before the flown band was selected), digested again only when the estimator gave new estimates:
        it keeps its pooled arrays and its sweeps until a manoeuvre changes them, and they are never written
        in place (the memo holds them, so their ids are not reused)."""
        ident = (id(full.response), tuple(id(s) for s in full_sweeps), np.asarray(avg.w_rad_s).tobytes())
        memo = self._key_memo.get(name)
        if memo is not None and memo[0] == ident:
            return memo[2]
        key = _estimate_key(avg, sweeps)
        self._key_memo[name] = (ident, (full.response, list(full_sweeps)), key)
        return key

    def _apply_diagnosis(self, name: str, channel: ChannelConfig, avg: SpectralEstimate,
                         sweeps: list[SpectralEstimate], result: ChannelResult, fit: bool,
                         estimate_key: bytes | None = None) -> None:
        from gap_validation.core import diagnosis

        # keyed on what the analysis reads, not on the samples fed: between two manoeuvres the samples change
        # the version every batch but not the estimate, and the analysis (the convention fits of a
        # model-limited channel among them) would run again at each of the node's diagnostics ticks (0.5-1.3 s
        # each, measured)
        key = (
            estimate_key if estimate_key is not None else _estimate_key(avg, sweeps),
            repr(channel.model_spec),
            fit,
        )
        cached = self._diagnosis_cache.get(name)
        if cached is not None and cached[0] == key:
            found = cached[1]
        else:
            found = diagnosis.analyse_channel(
                channel.model, avg, sweeps, channel.coherence_threshold, fit=fit
            )
            self._diagnosis_cache[name] = (key, found)
        result.limited_by = found.limited_by
        if found.convention is not None:
            self._found_conventions[name] = found.convention
        result.frequency_flags = list(found.frequency_flags)
        result.bands = list(found.bands)
        result.diagnosis = list(found.candidates)
        result.beyond_range = list(found.beyond_range)
        result.within_tolerance = found.within_tolerance
        result.warnings.extend(w for w in found.warnings if w not in result.warnings)
        result.margins_caveat = found.margins_caveat if result.margins.guaranteed else ""
        _nonlinearity_result(found, sweeps, result)
        if found.message:
            result.message = found.message
        if result.nonlinearity and any(_COUPLED in w for w in result.warnings):
            # sweeps that mix another surface differ for that reason, not for their amplitude: no verdict
            result.message = result.message.replace(
                f"; {result.nonlinearity}: {result.nonlinearity_evidence}", ""
            )
            result.nonlinearity = None
            result.nonlinearity_evidence = (
                f"not judged: another surface moved with this input in some manoeuvres "
                f"({result.nonlinearity_evidence})"
            )

    # ------------------------------------------------------------------ checkpoint
    def analysis_cache(self) -> dict:
        """What the analyses computed, each keyed on what it read (a digest of the estimates, the kept
        manoeuvres, the model): for a validator of the same config resumed from a later state
        (:meth:`adopt_analysis_cache`), so a channel whose estimates did not change is not analysed again (the
        node's diagnosis worker). Entries keyed on this validator's own update counters (MIMO channels) are
        left out."""
        return {"diagnosis": {name: entry for name, entry in self._diagnosis_cache.items()
                              if isinstance(entry[0][0], bytes)},
                "time_domain": dict(self._time_domain_cache), "margin": dict(self._margin_cache)}

    def adopt_analysis_cache(self, cache: dict) -> None:
        """Reuse another validator's :meth:`analysis_cache` (same config): an entry is used only where its key
        equals what this validator reads.

        Parameters
        ----------
        cache : dict
            From :meth:`analysis_cache`.
        """
        for name, entry in cache.get("diagnosis", {}).items():
            if name in self._config.channels and not self._config.channels[name].is_mimo:
                self._diagnosis_cache.setdefault(name, entry)
        for name, entry in cache.get("time_domain", {}).items():
            self._time_domain_cache.setdefault(name, entry)
        for name, entry in cache.get("margin", {}).items():
            self._margin_cache.setdefault(name, entry)

    def state_dict(self) -> dict:
        """Everything gathered so far, as plain numbers and numpy arrays (size independent of flight
        length)."""
        return {
            "version": STATE_VERSION,
            "channels": {name: est.state_dict() for name, est in self._estimators.items()},
            "bad": {name: dict(c) for name, c in self._bad.items()},
            "previous": dict(self._previous),
            "measurement": {name: _measurement_key(ch) for name, ch in self._config.channels.items()},
        }

    @classmethod
    def from_state(cls, config: ValidationConfig, state: dict, **kwargs: Any) -> "OnlineValidator":
        """A validator for ``config`` resuming from :meth:`state_dict`; channels whose measurement settings
        changed since the checkpoint start empty.

        Parameters
        ----------
        config : ValidationConfig
            The config to validate.
        state : dict
            From :meth:`state_dict` (e.g. a checkpoint).
        **kwargs
            Passed to the constructor (``diagnose``).
        """
        if not isinstance(state, dict) or state.get("version") != STATE_VERSION:
            raise ConfigError(
                "checkpoint state has version "
                f"{state.get('version') if isinstance(state, dict) else None!r}, "
                f"expected {STATE_VERSION}"
            )
        self = cls(config, **kwargs)
        try:
            resumed = []
            for name, ch in config.channels.items():
                saved = state["channels"].get(name)
                if saved is not None and state.get("measurement", {}).get(name) == _measurement_key(ch):
                    self._estimators[name] = FrequencyResponseEstimator.from_state(saved)
                    self._watch()
                    self._bad[name] = Counter(state.get("bad", {}).get(name, {}))
                    resumed.append(name)
            # as in set_config: a restarted channel has no previous epsilon (it was of other spectra)
            self._previous = {k: v for k, v in state.get("previous", {}).items() if k in resumed}
        except (KeyError, AttributeError, TypeError) as err:
            raise DataError(f"checkpoint state: malformed ({type(err).__name__}: {err})") from None
        return self


#: Why a frequency has no (confident) estimate, in words (JSON ``frequency_reasons`` holds the keys).
REASON_WORDS = {
    "not_excited": "the input is not excited there",
    "too_short": "the manoeuvres are too short to resolve it",
    "above_resolution": "above what the streams' sample rates resolve",
    "too_few_bins": "too few spectral lines of the excitation there",
    "below_trim": "the manoeuvres do not stand 20 dB above the surface's own motion between them there",
    "too_few_dof": "too few degrees of freedom",
    "low_coherence": "low coherence",
    "biased": "the response may be biased by feedback or another surface (see the warnings)",
}


def _estimate_key(avg: SpectralEstimate, sweeps: list[SpectralEstimate]) -> bytes:
    """A digest of everything in the pooled and per-sweep estimates (their arrays byte for byte): equal when
    the analysis would see the same estimates."""
    import hashlib
    import pickle

    return hashlib.blake2b(
        pickle.dumps((avg, sweeps), protocol=pickle.HIGHEST_PROTOCOL), digest_size=20
    ).digest()


def _flown_model(channel: ChannelConfig, avg: SpectralEstimate, sweeps: list[SpectralEstimate]):
    """The channel's model at the input amplitude flown (only a model with an amplitude-dependent effect,
    ``rate_limit`` or ``backlash``, changes: its describing functions need the amplitude)."""
    if not channel.model.nonlinear:
        return channel.model
    from gap_validation.core.diagnosis import flown_model

    return flown_model(channel.model, avg, sweeps)[0]


def _nonlinearity_result(found, sweeps: list[SpectralEstimate], result: ChannelResult) -> None:
    """The diagnosis' amplitude-dependence verdict and the records' input amplitudes, into the result."""
    result.nonlinearity = found.nonlinearity
    result.nonlinearity_evidence = found.nonlinearity_evidence
    result.input_amplitudes = [float(getattr(s, "amplitude", float("nan"))) for s in sweeps]


def _frequency_reasons(avg: SpectralEstimate, confident: np.ndarray, coherence_threshold: float) -> list:
    """Per frequency: None where the estimate is confident, else why not (a key of :data:`REASON_WORDS`)."""
    out: list = []
    codes = {"not_excited": "not_excited", "too_short": "too_short", "above_grid": "above_resolution",
             "too_few_bins": "too_few_bins", "below_trim": "below_trim"}
    for i in range(np.size(avg.w_rad_s)):
        if confident[i]:
            out.append(None)
        elif not np.isfinite(avg.response[i]):
            counts = {codes[k]: int(v[i]) for k, v in avg.reasons.items() if k in codes}
            out.append(max(counts, key=counts.get) if counts and max(counts.values()) > 0 else "not_excited")
        elif avg.coherence[i] < coherence_threshold:
            out.append("low_coherence")
        else:
            out.append("too_few_dof")
        continue
    return out


#: Mean dynamic pressure ratios within which the airspeed scaling stands for the flight condition: the scaling
#: corrects the control power; the aerodynamic modes move with the square root of the dynamic pressure, 5 % at
#: the edges of this range.
CONDITION_RANGE = (0.9, 1.1)


def _condition_warnings(ratio: dict | None) -> list[str]:
    """A warning when the flight's mean dynamic pressure is off the model's by more than
    :data:`CONDITION_RANGE`."""
    if not ratio or CONDITION_RANGE[0] <= ratio["mean"] <= CONDITION_RANGE[1]:
        return []
    return [
        f"flown at {ratio['mean']:.2f} of the model's dynamic pressure on average (airspeed "
        f"{ratio['mean'] ** 0.5:.2f} of its trim_m_s): the airspeed scaling corrects the control power, not "
        "the "
        f"modes, which move with speed (about {100 * abs(ratio['mean'] ** 0.5 - 1):.0f} %); this is not the "
        "model's "
        f"flight condition: validate a model of the flown one"
    ]


#: The estimator's own rejects, as the router names them (``bad_samples`` keys ``"<stream>: <reason>"``).
_REJECTS = (("nonfinite", "not finite"), ("non_monotonic", "time not increasing"))


def _count_estimator_rejects(est: FrequencyResponseEstimator, bad: dict) -> None:
    """Add to ``bad`` the samples the estimator itself refused (library calls: replay's and the node's router
    drops non-finite and out-of-order samples before, and counts them; values beyond ``1e100`` reach the
    estimator and are counted here)."""
    for stream, counts in est.bad_sample_counts.items():
        if not isinstance(counts, dict):
            continue
        for key, reason in _REJECTS:
            if counts.get(key):
                name = f"{stream}: {reason}"
                bad[name] = bad.get(name, 0) + int(counts[key])


def _sparse_streams(est: FrequencyResponseEstimator) -> str:
    """Why nothing was estimated when a stream's samples, several of them, are all further apart than
    ``max_gap_s`` (every interval a gap: times in milliseconds, or a log decimated too far); empty
    otherwise."""
    counts = [(n, c) for n, c in est.bad_sample_counts.items() if isinstance(c, dict) and "dropped_lag" in c]
    rates = np.asarray(est.stream_rates_hz, float)
    sparse = [(name, int(c.get("accepted", 0))) for (name, c), rate in zip(counts, rates)
              if not np.isfinite(rate) and c.get("accepted", 0) >= 3]
    return wording.sparse_stream_sentence(sparse, float(est.options["max_gap_s"])) if sparse else ""


def _lag_warnings(est: FrequencyResponseEstimator) -> list[str]:
    """A warning when the estimator gave up grid values because one stream ran too far ahead of another (the
    streams of a library call fed one after the other: the first one's older values are dropped)."""
    dropped = {name: int(c.get("dropped_lag", 0)) for name, c in est.bad_sample_counts.items()
               if isinstance(c, dict) and c.get("dropped_lag")}
    return [wording.dropped_lag_warning(dropped, float(est.options["max_lag_s"]))] if dropped else []


def _why_nothing(est: FrequencyResponseEstimator, channel: ChannelConfig) -> str:
    """One line: why a channel has no frequency response at all."""
    counts = est.bad_sample_counts
    for stream, extra in channel.extra_streams():
        if not counts.get(stream, {}).get("accepted"):
            return (
                f"no samples of the {stream.replace('_', ' ')} {extra.topic} {extra.field!r} (the estimate "
                "needs "
                f"every stream of the channel)"
            )
    spec = channel.input if channel.input is not None else channel.inputs[0]
    where = (f"input {spec.topic} {spec.field!r}" if channel.input is not None else
             "inputs " + ", ".join(f"{s.topic} {s.field!r}" for s in channel.inputs))
    kinds = {k: v for k, v in est.kinds.items() if v}
    sparse = _sparse_streams(est)
    if not kinds and sparse:
        return sparse
    if not kinds and _lag_warnings(est):
        return "no manoeuvre in the samples kept: " + _lag_warnings(est)[0]
    if not kinds:
        return f"the {where} never left trim (no manoeuvre)"
    if set(kinds) == {"step"}:
        return (f"the {where} only changed trim ({kinds['step']} steps; a trim change gives no frequency "
                "response)")
    flown = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items()))
    if est.saturated and not est.n_manoeuvres:
        return (
            f"{flown} flown, {est.saturated} of them with the {where} saturated (pinned at its limits for "
            f"{100 * SATURATED_SHARE:.0f} % of the manoeuvre or more); fly smaller amplitudes"
        )
    w = channel.frequencies.values()
    reasons = est.not_estimable
    worst = max(reasons, key=reasons.get)
    if worst == "too_short" and reasons[worst]:
        return (f"{flown} flown, none long enough to resolve {w.min():.3g}-{w.max():.3g} rad/s (the longest "
                f"record lasts {est.longest_record_s:.1f} s); fly longer manoeuvres")
    if worst == "above_grid" and reasons[worst]:
        return (
            f"{flown} flown, but the streams' sample rates resolve only up to {est.resolved_rad_s:.3g} rad/s"
        )
    if worst == "too_few_bins" and reasons[worst]:
        return (f"{flown} flown, too few degrees of freedom at {w.min():.3g}-{w.max():.3g} rad/s (too few "
                f"excited spectral lines per band); fly longer or more manoeuvres")
    if reasons.get("below_trim"):
        return (
            f"{flown} flown, none stands 20 dB above the surface's own motion between the manoeuvres at "
            f"{w.min():.3g}-{w.max():.3g} rad/s (trim corrections, or a loop answering turbulence: the "
            "manoeuvres do not dominate the surface there); fly larger manoeuvres, or log the injected "
            "signal "
            f"and add channels.{channel.name}.excitation"
        )
    return (f"{flown} flown, none excites {w.min():.3g}-{w.max():.3g} rad/s enough (relative and to the "
            "input noise)")


def _measurement_key(channel: ChannelConfig) -> str:
    """What the gathered spectra depend on: signals (not their declared message type), grid, estimator."""
    def signal(spec: SignalSpec | None) -> tuple | None:
        return None if spec is None else (spec.topic, spec.field, spec.scale)

    key = (signal(channel.input), signal(channel.output), signal(channel.trigger), channel.frequencies,
           sorted(channel.estimator.items()))
    if channel.is_mimo:
        key += (tuple(signal(s) for s in channel.inputs), tuple(signal(s) for s in channel.outputs))
    if channel.excitation is not None or channel.other_inputs:     # only then: older checkpoints stay valid
        key += (signal(channel.excitation), tuple(signal(s) for s in channel.other_inputs))
    if channel.airspeed is not None:
        key += (signal(channel.airspeed), channel.trim_airspeed_m_s)
    return repr(key)


@dataclass
class _Monitors:
    """The latest samples of a channel's surface (other channels' coupling monitors read them) and its
    coupling monitors (other channel -> monitor of that channel's surface)."""

    history: SurfaceHistory
    coupling: dict = field(default_factory=dict)


def _monitors_for(config: ValidationConfig) -> dict[str, _Monitors]:
    """Per SISO channel: a trim monitor (without ``excitation``) and a coupling monitor of every other
    channel's surface that is not among its ``other_inputs`` nor its own input."""
    out = {}
    surfaces = {name: (ch.input.topic, ch.input.field) for name, ch in config.channels.items()
                if ch.input is not None}
    for name, ch in config.channels.items():
        if ch.input is None:
            continue
        listed = {(s.topic, s.field) for s in ch.other_inputs} | {surfaces[name]}
        coupling = {other: CouplingMonitor() for other, signal in surfaces.items()
                    if other != name and signal not in listed}
        options = {**ESTIMATOR_DEFAULTS, **ch.estimator}
        keep_s = float(options["max_record_s"]) + float(options["max_lag_s"]) + 60.0
        out[name] = _Monitors(SurfaceHistory(keep_s), coupling)
    return out


#: Manoeuvres in which another surface follows the input that make the light coupling warning: an interconnect
#: moves the other surface in every manoeuvre of the axis that drives it; one chance alignment (two re-trims
#: at once) is no interconnect.
COUPLED_RECORDS = 2
#: Words every coupling warning holds (:func:`_closed_loop_checks`).
_COUPLED = "with this channel's input"
#: The ``frequency_reasons`` key of the points a closed-loop or coupling warning covers.
BIASED = "biased"


def _closed_loop_checks(
    channel: ChannelConfig,
    monitors: _Monitors,
    config: ValidationConfig,
    est: FrequencyResponseEstimator,
    full: SpectralEstimate,
    w: np.ndarray,
    p_meas: np.ndarray,
    p_model: np.ndarray,
    confident: np.ndarray,
) -> tuple[np.ndarray, list[str]]:
    """Warnings instead of guesses (:mod:`gap_validation.core.closed_loop`): the points whose response may be
    biased by another surface or by feedback, and one line per cause naming what to add to the config.
    ``full`` is the pooled estimate on the estimator's whole grid; ``w`` the validated frequencies."""
    suspect = np.zeros(w.size, bool)
    warnings = []
    where = f"channels.{channel.name}"
    for other, monitor in monitors.coupling.items():
        coupled, coherence, gain = monitor.coupled()
        spec = config.channels[other].input
        if coupled:
            suspect |= np.isfinite(p_meas)
            warnings.append(
                f"the {other} surface ({spec.topic} {spec.field}) moves with this channel's input during "
                f"its manoeuvres (coherence {coherence:.2f}, {gain:.2g} x the input): the measured "
                f"response mixes both surfaces and is not validated; add it to {where}.other_inputs (and "
                f"fly its own sweeps)"
            )
        followed, f_coherence, f_gain = monitor.followed()
        if followed:
            warnings.append(
                f"for {monitor.followed_s:.0f} s ({followed} stretch{'es' if followed > 1 else ''} the "
                f"detector found) the {other} surface ({spec.topic} {spec.field}) moved and this "
                f"channel's input followed it (coherence {f_coherence:.2f}, "
                f"the {other} surface {f_gain:.2g} x the input; each against its own trim motion the "
                f"{other} surface moved more): an interconnect's manoeuvres, not this channel's, left out "
                f"of its estimate and its sweeps; add it to {where}.other_inputs to use them"
            )
        if not coupled and monitor.coupled_records >= COUPLED_RECORDS:
            warnings.append(
                f"the {other} surface ({spec.topic} {spec.field}) moved with this channel's input in "
                f"{monitor.coupled_records} of its {monitor.records} manoeuvres (an interconnect, or this "
                f"surface flown through another axis' manoeuvres): those mix both surfaces, though too "
                f"little of the input's energy to bias the pooled response beyond its errors; add it to "
                f"{where}.other_inputs to separate them"
            )
    if channel.excitation is None:
        found, biased = _feedback_warnings(channel, est, full, w, p_meas)
        suspect |= biased
        warnings.extend(found)
        if channel.controller is not None and not channel.is_mimo:
            inverse = near_minus_inverse(channel.controller, w, p_meas, p_model) & confident
            if inverse.any():
                suspect |= inverse
                band = w[inverse]
                warnings.append(f"the measured response looks like -1/C of the configured controller at "
                                f"{band[0]:.3g}-{band[-1]:.3g} rad/s: feedback drives the surface there, not "
                                f"validated; log the injected signal and add {where}.excitation")
    return suspect, warnings


def _name_conventions(config: ValidationConfig, channels: dict[str, ChannelResult], found: dict) -> None:
    """The convention errors the channels' data showed (a sign, units, a clock: issue 23), looked at together
    (:func:`gap_validation.core.conventions.resolve`: pitch and yaw reversed with roll right is the body
    frame), into each channel's ``conventions``, its message, and no margins until fixed."""
    if not found:
        return
    from gap_validation.core.conventions import resolve

    fitting = {name for name, ch in channels.items() if ch.limited_by == "none" and ch.epsilon is not None}
    named = resolve(found, lambda ch, stream: config.channels[ch].signal(stream), fitting)
    for name, conventions in named.items():
        ch = channels[name]
        ch.conventions = conventions
        ch.message = (ch.message + "; " if ch.message else "") + "not physics: " + conventions[0].sentence
        ch.margins = ch.margins_raw = margins_from_epsilon(float("nan"))
        ch.margins_caveat = (
            f"a {conventions[0].kind.replace('_', ' ')} error in the config: not given until it is fixed"
        )


def _feedback_warnings(channel: ChannelConfig, est: FrequencyResponseEstimator, full: SpectralEstimate | None,
                       w: np.ndarray | None, p_meas: np.ndarray | None) -> tuple[list[str], np.ndarray]:
    """The feedback test (:func:`~gap_validation.core.closed_loop.feedback_evidence`) on the estimator's whole
    grid: the response between the manoeuvres against the pooled response of the manoeuvres, and the model
    where they give none (or nothing at all): the warning (none or one line) and, on the validated grid ``w``
    with response ``p_meas``, the points the loop may bias
    (:func:`~gap_validation.core.closed_loop.feedback_bias`). ``full`` is the estimator's pooled estimate on
    its whole grid (None before any manoeuvre)."""
    biased = np.zeros(0 if w is None else np.size(w), bool)
    trim = est.between_manoeuvres()
    grid = est.w_rad_s
    if full is None:
        nothing = np.full(grid.shape, np.nan + 0j)
        response, variance, confident = nothing, np.full(grid.shape, np.inf), np.zeros(grid.shape, bool)
        model = channel.model.freqresp(grid)
    else:
        response, variance = full.response, full.variance
        confident = confident_points(full, channel.coherence_threshold)
        model = _flown_model(channel, full, list(est.sweeps)).freqresp(grid)
    evidence = feedback_evidence(trim, response, variance, confident, model)
    lead = est.surface_led()
    # the lead test speaks where the trim motion drowns the manoeuvres (or no manoeuvre left it): elsewhere a
    # manoeuvre 20 dB above that motion is not biased by it, whatever moves the surface between manoeuvres
    drowned = est.not_estimable.get("below_trim", 0) > 0 or not any(est.kinds.values())
    led = not evidence.detected and drowned and rate_leads(lead)
    if not (evidence.detected or led):
        return [], biased
    if w is not None and full is not None:
        index = _grid_index(grid, w)
        picked = trim.take(index)
        power = np.asarray(full.sums.input_power, float)[index] / np.maximum(full.sums.bins[index], 1)
        biased = feedback_bias(picked, p_meas, np.asarray(full.variance, float)[index], power)
    surface = f"the surface ({channel.input.topic} {channel.input.field})"
    if led:
        return [
            f"between the manoeuvres the rate leads {surface}: its last {lead.lags_s:.2g} s explain "
            f"{100 * lead.share:.0f} % of the surface's motion that the surface's own past does not (F test: "
            f"chance {max(lead.p_value, 1e-300):.1g}): a feedback loop (damper, autopilot, a pilot holding "
            "an "
            f"attitude) drives it, and that motion drowns the manoeuvres, so the measured response is biased "
            f"towards -1/C where they do not dominate it (those points are not validated); log the injected "
            f"signal and add channels.{channel.name}.excitation"
        ], biased
    return [
        f"between the manoeuvres {surface} moves against the "
        f"rate, opposite to the airframe's response, at {_span(grid[evidence.opposite])}: a feedback loop "
        "(damper, "
        f"autopilot) drives it, so the measured response is biased towards -1/C where the manoeuvres do not "
        f"dominate the surface's motion (those points are not validated); log the injected signal and add "
        f"channels.{channel.name}.excitation"
    ], biased


def _numbers(channel: str, stream: str, what: str, data: ArrayLike) -> np.ndarray:
    """``data`` as floats, or a one-line :class:`DataError` naming the channel and stream (strings,
    objects)."""
    try:
        return np.asarray(data, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"channel {channel}: {stream} {what} are not numbers ({exc})") from None


def _grid_index(w_all: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Indices of the frequencies ``w`` (a selection of the estimator's grid) in ``w_all``."""
    return np.searchsorted(np.asarray(w_all, float), np.asarray(w, float))


def _span(w: np.ndarray) -> str:
    return f"{w[0]:.3g} rad/s" if w.size == 1 or w[0] == w[-1] else f"{w[0]:.3g}-{w[-1]:.3g} rad/s"


def _closed_loop_coherences(channel: ChannelConfig, avg: SpectralEstimate, result: ChannelResult) -> None:
    """JSON ``excitation_coherence`` (r -> u and r -> y) with an ``excitation``, ``partial_coherence`` with
    ``other_inputs`` (:mod:`gap_validation.core.spectra`)."""
    if avg.sums is None:
        return
    from gap_validation.core.spectra import excitation_coherence, partial_coherence

    if channel.excitation is not None:
        r_u, r_y = excitation_coherence(avg.sums)
        result.excitation_coherence = {"r_to_u": r_u, "r_to_y": r_y}
    if channel.other_inputs:
        result.partial_coherence = partial_coherence(avg.sums)


def _describe_model(channel: ChannelConfig) -> str:
    effects = channel.model.effects
    if not effects:
        return "airframe only"
    try:
        from gap_validation.core.effects import describe_effect

        return "airframe + " + " + ".join(describe_effect(e) for e in effects)
    except Exception:  # pragma: no cover - description is cosmetic
        return f"airframe + {len(effects)} effect(s)"
