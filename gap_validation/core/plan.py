"""What to fly next (issue 25): the test card that turns each data-limited band into a verdict. ROS-free.

A replay says per frequency whether the model is validated there (a *verdict*: the model fits within the
threshold, or it is model-limited) or not (data-limited, not excited, too few degrees of freedom, low
coherence). This module plans, per channel and per run of frequencies without a verdict, one manoeuvre that
brings the random error there to what a verdict needs, and says what it costs in flight time and what error it
is expected to give.

The principle: the estimator's own formula, run forward
------------------------------------------------------
The random error the validator reports (``random_error``) is that of the local polynomial fit
(:mod:`gap_validation.core.spectra`, :meth:`~gap_validation.core.estimator.SpectralEstimate.from_sums`)::

    e(w)^2 = Var(H) / (2 |H|^2),      Var(H) = sigma^2 [(Phi^H Phi)^-1]_00

with ``sigma^2`` the output noise per DFT bin and ``Phi`` the input's DFT bins around ``w`` times the response
polynomial (after each record's transient is projected out), summed over the records. Its two factors separate
what the flight's disturbances do (``q = sigma^2 / |H|^2``, the noise-to-signal ratio per unit of input power)
from what the manoeuvre puts in (``Phi^H Phi``, which grows with the amplitude squared and with the time spent
near ``w``). To first order it is Bendat and Piersol's ``e^2 = (1 - g^2) / (2 n_d g^2)``
(:func:`~gap_validation.core.evidence.bendat_piersol_random_error`) times the variance inflation of the
fitted polynomial at the band's centre (2.25 for a quadratic over evenly filled bins: the measured
``random_error`` is 1.5 times Bendat and Piersol's on the same coherence and degrees of freedom): the error
falls as one over the square root of the degrees of freedom and grows as the coherence falls. Hence:

1. The noise from the flight flown (:func:`_rebuild_flight`, :func:`_fill_noise`): ``q = 2 e1^2 /
   [(Phi1^H Phi1)^-1]_00`` (:func:`noise_ratio`), with ``Phi1`` the first flight's manoeuvres rebuilt from the
   results (each chirp's amplitude, length and excited band; the doublets and multisteps kept for the time
   domain from their own samples). The estimator's noise ``q |H_meas|^2`` less the surface's trim motion seen
   through the response (errors in variables) is the output's own noise, smoothed over frequency (a local
   linear fit of its logarithm in log w, chi-square bias removed) from the frequencies whose rebuild is
   trustworthy, continued with its slope beyond them or taken from the output's trim before the kept
   manoeuvres. From a config alone (a first flight) the noise is the stated assumption of
   :class:`PlanOptions`.
2. For a candidate manoeuvre (a log chirp, :func:`chirp`) its own ``Phi2^H Phi2`` and degrees of freedom come
   from the estimator's code on its samples (:func:`~gap_validation.core.spectra.record_bands`): which target
   frequencies it counts at (excited, long enough, enough bins) and with what information; its ``|H|`` is the
   model seen through the same bands (:func:`~gap_validation.core.spectra.expected_estimate`) times the
   measured ratio to it, pooled over neighbouring frequencies until its random error is :data:`RESPONSE_ERROR`
   (:func:`_pool_response`: the first flight's ``|H|`` at its data-limited low end is off by the random error
   that made it data-limited, and enters the prediction one for one; neighbouring frequencies that share DFT
   bins count once). The predicted error is ``e2 = sqrt(q2 [(n A^2 Phi2^H Phi2)^-1]_00 / 2)``
   (:func:`predicted_random_error`) for ``n`` repeats at amplitude ``A``, ``q2`` the output's noise over
   ``|H|^2`` plus the input's trim motion; the predicted coherence ``1 - d q / (n A^2 |Phi2|^2_00 + D q)``
   (``D`` the bins less the transients, ``d = D - 3``) must pass the channel's threshold with the validator's
   Beta law (:func:`~gap_validation.core.evidence.confident_points`).
3. The target (:func:`verdict_error`): the largest random error at which a mismatch at the channel's epsilon
   threshold (0.15) would be model-limited, i.e. ``normalised_mismatch(0.15, sigma, d) = 4`` with ``sigma =
   hypot(e, 0.01) / 2`` (:func:`~gap_validation.core.evidence.normalised_mismatch`,
   :data:`~gap_validation.core.evidence.SIGMA_FACTOR`,
   :data:`~gap_validation.core.evidence.BIAS_ERROR`): about 0.067 on 20 degrees of freedom, 0.075 on many. At
   that error a correct model stays within the threshold (noise reaches it with probability exp(-8)) and a
   wrong one is called model-limited: either way a verdict. The plan aims :data:`PLAN_MARGIN` below it.
4. The manoeuvre (:func:`plan_card`): for every swept band (the targets with margins, at least 5:1 so the
   estimator calls it a chirp), sweep length and number of repeats, the smallest amplitude that meets the
   target, the coherence, the sweep detector (:func:`~gap_validation.core.sweeps.detrended_std` of the sweep
   over its ``on_ratio`` and ``off_ratio`` thresholds) and the input's own noise (20 dB, as
   :func:`~gap_validation.core.spectra.band_excited`: over the trim motion between the manoeuvres, and over
   the record's own noise at its ends taken as white, the floor a record meets when it is judged before the
   flight's own trim is known, :data:`~gap_validation.core.tracking.TRIM_KNOWN_S`: the first manoeuvres of a
   short flight, at a break in the data); the one of least flight time whose amplitude stays
   under the cap is flown. Bands that no such manoeuvre reaches say why (above what the logs resolve; the
   amplitude cap; too slow for the sweep detector).

The chirp is ArduPilot's waveform (``AP_Math/chirp.cpp``: an exponential sweep, half-cosine fade in and out
within the record) without its dwell at the start frequency, which the estimator's sweep detector follows
badly (ArduPilot's mode flies two cycles there first: :func:`ardupilot_parameters` adds them to
``SID_T_REC``). It is the simulator's
:func:`~gap_validation.core.signals.log_sweep` with 1 s fades, so a simulated flight flies the card
exactly.
"""
from __future__ import annotations

import functools
import inspect
import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np
from scipy.special import digamma, polygamma
from scipy.stats import chi2, norm

from gap_validation.core.background import MIN_TRIM_AVERAGES, TrimSpectra
from gap_validation.core.config import ChannelConfig, ValidationConfig
from gap_validation.core.diagnosis import analyse_channel
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.estimator import ESTIMATOR_DEFAULTS, LOOKBACK_S, RESOLVED_FRACTION
from gap_validation.core.evidence import BIAS_ERROR, SIGMA_FACTOR, confident_points
from gap_validation.core.flight_options import FlightOptions
from gap_validation.core.numbers import NON_NEGATIVE, POSITIVE, Interval, check_number
from gap_validation.core.records import TRIM_LEVEL_S, trim_tolerance
from gap_validation.core.results import response_from_json
from gap_validation.core.spectra import SPECTRA_DEFAULTS, BandSums, expected_estimate, record_bands
from gap_validation.core.sweeps import DETECTOR_DEFAULTS, detrended_std

__all__ = [
    "PlanOptions", "PlannedManoeuvre", "Unreachable", "ChannelPlan", "TestCard", "ParameterBlock", "chirp",
    "manoeuvre_signal", "card_signal", "verdict_error", "predicted_random_error", "expected_worst",
    "noise_ratio", "estimator_record", "plan_card", "check_results", "ardupilot_parameters", "px4_parameters",
    "EPSILON_THRESHOLD", "PLAN_MARGIN", "ARDUPILOT_RANGES", "PX4_RANGES", "DWELL_CYCLES",
]

#: The epsilon threshold the validator judges bands at:
#: :func:`~gap_validation.core.diagnosis.analyse_channel`'s default, which the validator uses (read from its
#: signature: one definition).
EPSILON_THRESHOLD = float(inspect.signature(analyse_channel).parameters["epsilon_threshold"].default)
#: The plan aims this factor below the target error (and above the coherence and detection thresholds): the
#: measured error scatters about the prediction (the noise estimate of the first flight on few degrees of
#: freedom, the new flight's own noise estimate; ``benchmarks/plan_campaigns.py`` measures it).
PLAN_MARGIN = 1.25
#: Cycles ArduPilot's chirp dwells at the start frequency (``time_const_freq = 2 / frequency_start``); the
#: card's own sweeps do not dwell (the sweep detector follows a slow start badly: a 0.6 rad/s dwell split into
#: pulses).
DWELL_CYCLES = 2.0
#: Below this frequency times 2 s / ``energy_window_s`` [rad/s] the sweep detector sees a sine by its
#: curvature only (:mod:`gap_validation.core.sweeps`): a sweep may spend there at most what a record reaches
#: back (:data:`~gap_validation.core.estimator.LOOKBACK_S`, 10 s). Measured: a 0.5-2.5 rad/s sweep of 80 s at
#: 0.05 rad fell apart into steps and pulses (no response), of 30 s it held; from 0.8 rad/s, 80 s held.
SLOW_SWEEP = 0.8
#: Shortest sweep planned [s].
MIN_SWEEP_S = 10.0
#: The estimator calls a manoeuvre a chirp when the 90th percentile of its half-periods is 3 times the 10th
#: (:mod:`gap_validation.core.records`, ``_is_chirp``); a log sweep's zero crossings fall evenly in frequency,
#: so that takes a sweep of (1 + 0.9 (k - 1)) / (1 + 0.1 (k - 1)) >= 3, k >= 4.3: 5:1 at least (a 3:1 sweep at
#: 0.6-1.7 rad/s was called a multistep).
MIN_SWEEP_RATIO = 5.0
#: ... and at least 13 zero crossings (``_is_chirp``): with a margin, 16 half-periods.
MIN_HALF_PERIODS = 16
#: Swept band around the targets: (below the lowest, above the highest) factors tried; the estimator's own
#: counting (:func:`~gap_validation.core.spectra.record_bands`) decides which margin suffices.
SWEEP_MARGINS = ((1.4, 1.3), (1.8, 1.5), (2.5, 2.0))
#: Sweep lengths tried: geometric steps from the shortest the band allows to ``PlanOptions.max_sweep_s``.
SWEEP_LENGTH_STEP = 1.2
#: The sweep must stand this many times over the detector's thresholds (``on_ratio``, ``off_ratio`` times the
#: trim's level) ...
DETECTION_MARGIN = 1.25
#: ... and its input power near every target this many times over 20 dB above the input's noise (power ratio).
EXCITATION_MARGIN = 4.0
#: Half-width of the kernel the output's noise spectrum is smoothed over [decades] (:func:`_fill_noise`): the
#: grid's points within a factor 1.45, about four on each side of a 25-per-decade grid. Not widened to reach
#: the degrees of freedom the error budget asks of the noise (11, :data:`RESPONSE_ERROR`): at the low end of a
#: short first card the grid's neighbours share most of their DFT bins (a 7-bin band moves by about one bin
#: per grid step), so those lie half a decade and more away, over which the noise falls ten- to a hundredfold;
#: pooled that far (nearest first, to 6, 11 or 21 degrees of freedom) the planned error came out worse, not
#: better (docs/PLAN.md, "The first flight's |H|").
NOISE_WIDTH = 0.25
#: Slopes (log-log) a noise spectrum is continued with beyond the frequencies it was measured at: turbulence
#: falls as w^-4 at most above its corner (a second-order low-pass, as Dryden's); rising faster than w^2 is no
#: noise.
SLOPE_RANGE = (-4.0, 2.0)
#: A first-flight frequency within this factor of its excited band's edges is not used for the noise: the
#: band's edge is where the flight's input is least known (a sweep whose slow start the detector lost counted
#: a band below it).
EDGE_CORE = 1.25
#: The predicted random error is to hold within this factor of the one measured after flying the manoeuvre ...
PREDICTION_FACTOR = 1.5
#: ... on this share of the bands (issue 25).
PREDICTION_SHARE = 0.9
#: Degrees of freedom the error budget of :data:`RESPONSE_ERROR` assumes for a planned manoeuvre's estimate:
#: those the target is quoted on (a verdict needs about 0.067 on 20; :func:`verdict_error`). A nominal value,
#: not each manoeuvre's own (its ``predicted_dof``, known only once the manoeuvre is designed from the
#: response this budget sets): on 10 the budget would be 0.131, on 40 0.165.
DESIGN_DOF = 20.0
#: Largest random error of ``ln |H|`` the measured response may carry into a prediction
#: (:func:`_pool_response`), from the budget of :data:`PREDICTION_FACTOR`: log-normal scatter of at most ``ln
#: 1.5 / z(0.95) = 0.246`` between the predicted and the measured error. The measured error scatters by
#: ``sqrt(psi'(20)) / 2 = 0.113`` on its own (its noise variance on :data:`DESIGN_DOF` degrees of freedom goes
#: as ``chi2(40) / 40``, the error as its square root); what is left, ``sqrt(0.246^2 - 0.113^2) = 0.219``, is
#: shared evenly by the two numbers the prediction takes from the first flight, the noise level and the
#: response's magnitude (the error goes as ``sigma / |H|``): 0.155 each. (For a noise variance that is
#: ``sqrt(psi'(N)) / 2 = 0.155``: N = 11 degrees of freedom.)
RESPONSE_ERROR = float(math.sqrt(((math.log(PREDICTION_FACTOR) / norm.ppf(0.5 + PREDICTION_SHARE / 2.0)) ** 2
                                  - float(polygamma(1, DESIGN_DOF)) / 4.0) / 2.0))
#: 20 dB: what :func:`~gap_validation.core.spectra.band_excited` asks of a manoeuvre over the input's noise.
_EXCITATION_SNR = 1e2
#: Why a frequency has no verdict, from the results' ``frequency_reasons`` and ``frequency_flags``, in words.
REASON_WORDS = {
    "data": "data-limited",
    "not_excited": "not excited",
    "too_short": "records too short",
    "too_few_bins": "too few excited bins",
    "below_trim": "below the surface's trim motion",
    "too_few_dof": "too few degrees of freedom",
    "low_coherence": "low coherence",
    "biased": "biased (feedback)",
    "above_resolution": "above what the logs resolve",
    "first_flight": "not flown yet",
}

# ArduPilot's SystemID parameters (AP_SystemID::var_info, ArduPlane/systemid.cpp, and ModeSystemId::var_info,
# ArduCopter/mode_systemid.cpp: the @Range of each; SID_MAGNITUDE has none: "Magnitude of sweep in deg, deg/s
# and 0-1 for mixer outputs"; SID_AXIS @Values 0-13, 10-12 the mixer's roll, pitch, yaw). The waveform:
# AP_Math/chirp.cpp (Chirp::update); the mode stops with "SystemID Parameter Error" unless SID_T_REC > 2 /
# SID_F_START_HZ.
ARDUPILOT_RANGES = {
    "SID_AXIS": (0, 13), "SID_MAGNITUDE": (0.0, 1.0), "SID_F_START_HZ": (0.01, 100.0),
    "SID_F_STOP_HZ": (0.01, 100.0), "SID_T_FADE_IN": (0.0, 20.0), "SID_T_REC": (0.0, 255.0),
    "SID_T_FADE_OUT": (0.0, 5.0),
}
#: ``SID_AXIS`` of the mixer input per body axis (the surface itself: the plant the model describes).
ARDUPILOT_MIXER_AXIS = {"roll": 10, "pitch": 11, "yaw": 12}
#: ArduPilot's fixed-wing convention: a full mixer output is 4500 centidegrees of notional surface travel
#: (AP_RollController IMAX: "Servos are assumed to have +/- 4500 centi-degrees of travel").
ARDUPILOT_THROW_RAD = math.radians(45.0)
# PX4's fixed-wing autotune (src/modules/fw_autotune_attitude_control/fw_autotune_attitude_control_params.c
# and _params.yaml): FW_AT_SYSID_F0/F1 0.1-30 Hz (one decimal), FW_AT_SYSID_TIME 5-120 s, FW_AT_SYSID_TYPE 0
# step, 1 linear, 2 logarithmic sine sweep, FW_AT_AXES bitmask 1-7 (roll, pitch, yaw), FW_AT_APPLY 0 logging
# only, FW_AT_SYSID_AMP 0.1-6 scales a rate setpoint (signal_generator.hpp: getLogSineSweep, no dwell, no
# fades).
PX4_RANGES = {
    "FW_AT_SYSID_F0": (0.1, 30.0), "FW_AT_SYSID_F1": (0.1, 30.0), "FW_AT_SYSID_TIME": (5.0, 120.0),
    "FW_AT_SYSID_TYPE": (0, 2), "FW_AT_AXES": (1, 7), "FW_AT_APPLY": (0, 2),
}
PX4_AXIS_BIT = {"roll": 1, "pitch": 2, "yaw": 4}


# ------------------------------------------------------------------------------------------------ options,
# results
@dataclass(frozen=True)
class PlanOptions:
    """How the card is planned.

    Attributes
    ----------
    target_error : float, optional
        Random error to reach at every planned frequency; None: what a verdict at the channel's threshold
        needs (:func:`verdict_error`).
    max_amplitude_rad : float, optional
        Largest sweep amplitude allowed [rad]. With results the cap is the smaller of this and the largest
        deflection the flight already flew (both when given); from a config alone it defaults to the
        simulator's sweep amplitude (0.06 rad).
    log_rate_hz : float, optional
        Rate of the slowest logged stream of the channels [Hz]: the estimator resolves up to a quarter of it.
        None: from the results' ``resolved_rad_s`` (results written before that key: known only where they
        say ``above_resolution``; a config alone: not known). Given with results, the lower of the two.
    fade_s : float
        Fade in and out of each chirp [s] (ArduPilot's ``SID_T_FADE_IN``/``SID_T_FADE_OUT``; the simulator's 1
        s).
    trim_before_s, trim_between_s : float
        Trim before a manoeuvre's first sweep and after each sweep [s]. The estimator keeps ``pre_s`` before
        and ``post_s`` after a manoeuvre; its sweep detector ends a stretch ``hold_s`` after the energy over
        ``energy_window_s`` falls, so identical sweeps 5 s apart stayed one stretch, cut at ``max_record_s``
        in the middle of a sweep (its level there then looked like trim: every sweep fell apart); 6 s apart
        they did not.
    max_sweep_s : float
        Longest single sweep [s] (PX4's ``FW_AT_SYSID_TIME`` allows 120 s).
    max_repeats : int
        Most repeats of one sweep.
    margin : float
        :data:`PLAN_MARGIN`.
    noise_rms_rad_s, noise_corner_rad_s, gyro_noise_rad_s, gyro_rate_hz, surface_noise_rad : float
        From a config alone: the assumed output disturbance (a second-order low-pass of this rms and corner,
        as light turbulence), the gyro's white noise at its rate, and the surface sensor's noise (the
        simulator's defaults, :class:`~gap_validation.core.flight_options.FlightOptions`).
    """

    target_error: float | None = None
    max_amplitude_rad: float | None = None
    log_rate_hz: float | None = None
    fade_s: float = 1.0
    trim_before_s: float = 5.0
    trim_between_s: float = 6.0
    max_sweep_s: float = 120.0
    max_repeats: int = 6
    margin: float = PLAN_MARGIN
    noise_rms_rad_s: float = FlightOptions.gust_rms_rad_s
    noise_corner_rad_s: float = FlightOptions.gust_bandwidth_rad_s
    gyro_noise_rad_s: float = FlightOptions.gyro_noise_rad_s
    gyro_rate_hz: float = FlightOptions.imu_rate_hz
    surface_noise_rad: float = FlightOptions.surface_noise_rad

    def check(self) -> "PlanOptions":
        """Raise :class:`ConfigError` naming the first option out of range; return self."""
        for name in ("target_error", "max_amplitude_rad", "log_rate_hz"):
            value = getattr(self, name)
            if value is not None:
                check_number(value, f"--{name.replace('_', '-')}", POSITIVE, expected="a number > 0")
        for name in ("max_sweep_s", "margin", "noise_corner_rad_s", "gyro_rate_hz"):
            check_number(getattr(self, name), f"plan option {name}", POSITIVE, expected="a number > 0")
        for name in ("fade_s", "trim_before_s", "trim_between_s", "noise_rms_rad_s", "gyro_noise_rad_s",
                     "surface_noise_rad"):
            check_number(getattr(self, name), f"plan option {name}", NON_NEGATIVE, expected="a number >= 0")
        if self.fade_s > ARDUPILOT_RANGES["SID_T_FADE_OUT"][1]:
            raise ConfigError(
                f"--fade-s {self.fade_s:g}: expected at most 5 s (ArduPilot's SID_T_FADE_OUT range)"
            )
        if not isinstance(self.max_repeats, int) or self.max_repeats < 1:
            raise ConfigError(f"plan option max_repeats: expected an integer >= 1, got {self.max_repeats!r}")
        return self


@dataclass(frozen=True)
class PlannedManoeuvre:
    """One manoeuvre of the card: a log chirp flown ``repeats`` times with trim before and between.

    Attributes
    ----------
    channel : str
        The channel whose input (surface) it excites.
    index : int
        Its place in the card (0, 1, ... over all channels, in flying order).
    closes_rad_s : (float, float)
        The lowest and highest grid frequency it brings to a verdict [rad/s].
    reasons : tuple of str
        Why those frequencies had no verdict (:data:`REASON_WORDS`).
    band_rad_s : (float, float)
        The swept band, margins included [rad/s].
    amplitude_rad : float
        Sweep amplitude (surface deflection from trim) [rad].
    duration_s : float
        One sweep, fades included [s] (ArduPilot's ``SID_T_REC`` adds its two cycles at the start frequency).
    repeats : int
        Sweeps flown.
    fade_in_s, fade_out_s : float
        Half-cosine fades inside ``duration_s`` [s].
    trim_before_s, trim_between_s : float
        Trim before the first sweep and after each sweep [s].
    amplitude_set_by : str
        What the amplitude is the least of: ``random error``, ``coherence``, ``sweep detection``, ``input
        noise``.
    frequencies_rad_s : tuple of float
        The grid frequencies it closes [rad/s].
    error_now : tuple of float or None
        Their random error before (None where nothing was estimated).
    predicted_error, predicted_coherence, predicted_dof, target_error : tuple of float
        Per frequency: the random error, coherence and degrees of freedom this manoeuvre is expected to give
        when replayed on its own, and the error a verdict needs there.
        (:attr:`expected_worst_error`: the band's worst error as the estimator will report it, from them.)
    kind : str
        ``chirp``: a log sweep without a dwell (:func:`chirp`).
    """

    channel: str
    index: int
    closes_rad_s: tuple[float, float]
    reasons: tuple[str, ...]
    band_rad_s: tuple[float, float]
    amplitude_rad: float
    duration_s: float
    repeats: int
    fade_in_s: float
    fade_out_s: float
    trim_before_s: float
    trim_between_s: float
    amplitude_set_by: str
    frequencies_rad_s: tuple[float, ...]
    error_now: tuple[float | None, ...]
    predicted_error: tuple[float, ...]
    predicted_coherence: tuple[float, ...]
    predicted_dof: tuple[float, ...]
    target_error: tuple[float, ...]
    kind: str = "chirp"

    @property
    def flight_time_s(self) -> float:
        """Trim before, the sweeps and the trim after each [s]."""
        return self.trim_before_s + self.repeats * (self.duration_s + self.trim_between_s)

    @property
    def f_start_hz(self) -> float:
        """Start frequency [Hz]."""
        return self.band_rad_s[0] / (2.0 * math.pi)

    @property
    def f_stop_hz(self) -> float:
        """Stop frequency [Hz]."""
        return self.band_rad_s[1] / (2.0 * math.pi)

    @property
    def worst_predicted_error(self) -> float:
        """The largest predicted random error over the frequencies it closes."""
        return float(max(self.predicted_error))

    @property
    def expected_worst_error(self) -> float:
        """The worst random error the estimator is expected to report over the frequencies it closes
        (:func:`expected_worst`: each frequency's error estimated on its predicted degrees of freedom)."""
        return expected_worst(self.predicted_error, self.predicted_dof)

    def to_dict(self) -> dict:
        """The card's YAML mapping of the manoeuvre (docs/PLAN.md): the numbers that define the signal (band,
        amplitude, lengths) exactly as planned, the rest to 4 digits."""
        return {
            "index": self.index, "kind": self.kind,
            "closes_rad_s": [_r(v) for v in self.closes_rad_s], "reasons": list(self.reasons),
            "band_rad_s": [float(v) for v in self.band_rad_s], "f_start_hz": _r(self.f_start_hz),
            "f_stop_hz": _r(self.f_stop_hz), "amplitude_rad": float(self.amplitude_rad),
            "amplitude_deg": _r(math.degrees(self.amplitude_rad)), "amplitude_set_by": self.amplitude_set_by,
            "duration_s": float(self.duration_s), "repeats": self.repeats, "fade_in_s": float(self.fade_in_s),
            "fade_out_s": float(self.fade_out_s),
            "trim_before_s": float(self.trim_before_s), "trim_between_s": float(self.trim_between_s),
            "flight_time_s": _r(self.flight_time_s),
            "frequencies_rad_s": [_r(v) for v in self.frequencies_rad_s],
            "error_now": [None if v is None else _r(v) for v in self.error_now],
            "predicted_error": [_r(v) for v in self.predicted_error],
            "predicted_coherence": [_r(v) for v in self.predicted_coherence],
            "predicted_dof": [int(v) for v in self.predicted_dof],
            "target_error": [_r(v) for v in self.target_error],
            # from the errors as written, so that a card read back states the same number
            "expected_worst_error": _r(
                expected_worst([_r(v) for v in self.predicted_error], self.predicted_dof)
            ),
        }

    @classmethod
    def from_dict(cls, channel: str, data: dict) -> "PlannedManoeuvre":
        """Inverse of :meth:`to_dict` (a card read back, e.g. by the node).

        Parameters
        ----------
        channel : str
            The channel the manoeuvre belongs to.
        data : dict
            The manoeuvre's mapping.
        """
        return cls(
            channel=channel,
            index=int(data["index"]),
            closes_rad_s=tuple(data["closes_rad_s"]),
            reasons=tuple(data.get("reasons") or ()),
            band_rad_s=tuple(float(v) for v in data["band_rad_s"]),
            amplitude_rad=float(data["amplitude_rad"]),
            duration_s=float(data["duration_s"]),
            repeats=int(data["repeats"]),
            fade_in_s=float(data["fade_in_s"]),
            fade_out_s=float(data["fade_out_s"]),
            trim_before_s=float(data["trim_before_s"]),
            trim_between_s=float(data["trim_between_s"]),
            amplitude_set_by=str(data.get("amplitude_set_by", "")),
            frequencies_rad_s=tuple(data.get("frequencies_rad_s") or ()),
            error_now=tuple(data.get("error_now") or ()),
            predicted_error=tuple(data.get("predicted_error") or ()),
            predicted_coherence=tuple(data.get("predicted_coherence") or ()),
            predicted_dof=tuple(data.get("predicted_dof") or ()),
            target_error=tuple(data.get("target_error") or ()),
            kind=str(data.get("kind", "chirp")),
        )


@dataclass(frozen=True)
class Unreachable:
    """Frequencies no manoeuvre of the card can bring to a verdict, and why.

    Attributes
    ----------
    channel : str
        The channel.
    band_rad_s : (float, float)
        Lowest and highest such grid frequency [rad/s].
    reason : str
        One sentence.
    """

    channel: str
    band_rad_s: tuple[float, float]
    reason: str

    def to_dict(self) -> dict:
        """The card's YAML mapping."""
        return {"band_rad_s": [_r(v) for v in self.band_rad_s], "reason": self.reason}


@dataclass
class ChannelPlan:
    """The card of one channel.

    Attributes
    ----------
    channel : str
        The channel.
    manoeuvres : list of PlannedManoeuvre
        What to fly, in order.
    unreachable : list of Unreachable
        What cannot be reached, with the reason.
    amplitude_cap_rad : float or None
        The largest amplitude the plan allowed itself [rad].
    amplitude_cap_reason : str
        Where the cap comes from.
    verdicts : int
        Grid frequencies that already have a verdict.
    notes : list of str
        What the plan assumed or found for this channel, one line each.
    """

    channel: str
    manoeuvres: list[PlannedManoeuvre] = field(default_factory=list)
    unreachable: list[Unreachable] = field(default_factory=list)
    amplitude_cap_rad: float | None = None
    amplitude_cap_reason: str = ""
    verdicts: int = 0
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        """The card's YAML mapping of the channel."""
        return {"amplitude_cap_rad": None if self.amplitude_cap_rad is None else _r(self.amplitude_cap_rad),
                "amplitude_cap_reason": self.amplitude_cap_reason, "verdicts_already": self.verdicts,
                "manoeuvres": [m.to_dict() for m in self.manoeuvres],
                "unreachable": [u.to_dict() for u in self.unreachable], "notes": list(self.notes)}


@dataclass
class TestCard:
    """The whole card.

    Attributes
    ----------
    channels : dict
        Channel -> :class:`ChannelPlan`, in config order.
    source : str
        ``results`` (planned from a replay's results) or ``config`` (a first flight, from the model alone).
    target_rule : str
        How the target error was set, in words.
    assumptions : list of str
        What the predictions assume, one line each.
    """

    __test__ = False      # not a pytest test class

    channels: dict[str, ChannelPlan]
    source: str
    target_rule: str
    assumptions: list[str] = field(default_factory=list)

    @property
    def manoeuvres(self) -> list[PlannedManoeuvre]:
        """Every manoeuvre, in flying order."""
        return sorted((m for plan in self.channels.values() for m in plan.manoeuvres), key=lambda m: m.index)

    @property
    def flight_time_s(self) -> float:
        """The card's flight time [s]."""
        return float(sum(m.flight_time_s for m in self.manoeuvres))

    def to_dict(self) -> dict:
        """The card as the YAML mapping of docs/PLAN.md."""
        return {"card_version": 1, "source": self.source, "target_rule": self.target_rule,
                "flight_time_s": _r(self.flight_time_s), "assumptions": list(self.assumptions),
                "channels": {name: plan.to_dict() for name, plan in self.channels.items()}}

    @classmethod
    def from_dict(cls, data: dict) -> "TestCard":
        """A card from its mapping (:meth:`to_dict`).

        Parameters
        ----------
        data : dict
            The card's YAML document.
        """
        channels = {}
        for name, ch in (data.get("channels") or {}).items():
            channels[name] = ChannelPlan(
                name,
                [PlannedManoeuvre.from_dict(name, m) for m in ch.get("manoeuvres") or []],
                [Unreachable(name, tuple(u["band_rad_s"]), u["reason"]) for u in ch.get("unreachable") or []],
                ch.get("amplitude_cap_rad"),
                ch.get("amplitude_cap_reason", ""),
                int(ch.get("verdicts_already", 0)),
                list(ch.get("notes") or []),
            )
        return cls(channels, str(data.get("source", "")), str(data.get("target_rule", "")),
                   list(data.get("assumptions") or []))


def _r(value: float, digits: int = 4) -> float:
    """A float with ``digits`` significant digits (readable YAML)."""
    value = float(value)
    if not math.isfinite(value) or value == 0.0:
        return value
    return float(f"{value:.{digits}g}")


def _r_up(value: float, digits: int = 4) -> float:
    """:func:`_r` rounded up: an amplitude that still meets every need it was computed from."""
    rounded = _r(value, digits)
    if not math.isfinite(rounded) or rounded >= value or value <= 0.0:
        return rounded
    return float(f"{rounded + 10.0 ** (math.floor(math.log10(value)) - digits + 1):.{digits}g}")


# ------------------------------------------------------------------------------------------------ the signal
def chirp(t_s: np.ndarray, duration_s: float, f_start_hz: float, f_stop_hz: float, fade_in_s: float,
          fade_out_s: float, amplitude: float = 1.0, dwell_cycles: float = 0.0) -> np.ndarray:
    """ArduPilot's system-identification chirp (``AP_Math/chirp.cpp``, ``Chirp::update``), zero outside.

    ``dwell_cycles`` cycles at the start frequency (``t_c = dwell_cycles / f_start``; ArduPilot dwells 2),
    then ``sin(w0 (T - t_c) / B (exp(B (t - t_c) / (T - t_c)) - 1))`` with ``B = ln(f_stop / f_start)``, every
    octave the same time; a half-cosine window rises over ``fade_in_s`` from 0 and falls over the last
    ``fade_out_s`` of ``duration_s``. With equal fades of at most a quarter of the record it is
    :func:`~gap_validation.core.signals.log_sweep` with the same ``dwell_cycles``. The card's manoeuvres
    dwell 0 cycles (the estimator's sweep detector follows a slow start badly); ArduPilot's mode flies its two
    cycles before the same sweep (:func:`ardupilot_parameters`).

    Parameters
    ----------
    t_s : ndarray
        Times from the sweep start [s].
    duration_s : float
        Record length T (``SID_T_REC``) [s], longer than the dwell.
    f_start_hz, f_stop_hz : float
        Start and stop frequencies [Hz].
    fade_in_s, fade_out_s : float
        Fade lengths inside the record [s].
    amplitude : float
        Peak amplitude (``SID_MAGNITUDE`` in the input's units).
    dwell_cycles : float
        Cycles at the start frequency before the sweep.
    """
    t = np.asarray(t_s, dtype=float)
    w0, w1 = 2.0 * math.pi * f_start_hz, 2.0 * math.pi * f_stop_hz
    const_s = dwell_cycles / f_start_hz
    if not duration_s > const_s:
        raise ConfigError(
            f"chirp: duration {duration_s:g} s must exceed the dwell of {dwell_cycles:g} cycles at the "
            f"start frequency ({const_s:g} s)"
        )
    window = np.ones_like(t)
    if fade_in_s > 0:
        window = np.where(
            t <= fade_in_s, 0.5 - 0.5 * np.cos(np.pi * np.clip(t, 0.0, None) / fade_in_s), window
        )
    if fade_out_s > 0:
        tail = duration_s - fade_out_s
        window = np.where(t > tail, 0.5 + 0.5 * np.cos(np.pi * (t - tail) / fade_out_s), window)
    inside = (t > 0.0) & (t <= duration_s)
    b = math.log(w1 / w0) if w1 != w0 else 0.0
    if b == 0.0:
        phase = w0 * t
    else:
        sweep = duration_s - const_s
        rel = np.clip(t - const_s, 0.0, None)
        phase = np.where(t <= const_s, w0 * (t - const_s), (w0 * sweep / b) * np.expm1(b * rel / sweep))
    return np.where(inside, amplitude * window * np.sin(phase), 0.0)


def _sweep(m: PlannedManoeuvre, t_s: np.ndarray, amplitude: float | None = None) -> np.ndarray:
    return chirp(t_s, m.duration_s, m.f_start_hz, m.f_stop_hz, m.fade_in_s, m.fade_out_s,
                 m.amplitude_rad if amplitude is None else amplitude)


def manoeuvre_signal(manoeuvre: PlannedManoeuvre, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The surface offsets of one manoeuvre sampled at ``rate_hz``: trim, then each sweep followed by trim.

    Parameters
    ----------
    manoeuvre : PlannedManoeuvre
        The manoeuvre.
    rate_hz : float
        Sample rate [Hz].

    Returns
    -------
    t_s : ndarray
        Times from the manoeuvre's start [s] (``k / rate_hz``).
    offset_rad : ndarray
        The offset from trim to add to the surface [rad].
    """
    check_number(rate_hz, "--signal-rate-hz", POSITIVE, expected="a rate > 0 Hz")
    n = int(math.floor(manoeuvre.flight_time_s * rate_hz + 1e-9))
    t = np.arange(n) / rate_hz
    u = np.zeros(n)
    for k in range(manoeuvre.repeats):
        start = manoeuvre.trim_before_s + k * (manoeuvre.duration_s + manoeuvre.trim_between_s)
        u += _sweep(manoeuvre, t - start)
    return t, u


def card_signal(card: TestCard, rate_hz: float) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Every manoeuvre of the card one after the other, sampled at ``rate_hz`` (the ``--signal`` CSV).

    Parameters
    ----------
    card : TestCard
        The card.
    rate_hz : float
        Sample rate [Hz].

    Returns
    -------
    t_s : ndarray
        Times from the card's start [s].
    index : ndarray of int
        The manoeuvre flown at each sample (its ``index``).
    offsets : dict
        Channel -> surface offset from trim [rad] (zero while another channel flies).
    """
    ts, idx, offsets = [], [], {name: [] for name in card.channels}
    t0 = 0.0
    for m in card.manoeuvres:
        t, u = manoeuvre_signal(m, rate_hz)
        ts.append(t0 + t)
        idx.append(np.full(t.size, m.index))
        for name in offsets:
            offsets[name].append(u if name == m.channel else np.zeros(t.size))
        t0 += t.size / rate_hz
    def cat(parts: list, dtype: type = float) -> np.ndarray:
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

    return cat(ts), cat(idx, int), {name: cat(parts) for name, parts in offsets.items()}


# ------------------------------------------------------------------------------------------------ the
# statistics
def verdict_error(epsilon_threshold: float = EPSILON_THRESHOLD, dof: float = math.inf,
                  sigma_factor: float = SIGMA_FACTOR, bias_error: float = BIAS_ERROR) -> float:
    """The largest random error at which a mismatch at the threshold is a verdict.

    Solves ``normalised_mismatch(epsilon_threshold, sigma, dof) = sigma_factor`` with ``sigma =
    epsilon_noise_scale(hypot(e, bias_error))`` (:mod:`gap_validation.core.diagnosis`: the validator's own
    law) for ``e``. With ``k = sqrt(2 d ln(1 + r^2 / (2 d)))``, ``r = epsilon / sigma``, that is ``r^2 = 2 d
    (exp(k^2 / (2 d)) - 1)`` (``r = k`` for infinitely many degrees of freedom), ``sigma = epsilon / r`` and
    ``e = sqrt((2 sigma)^2 - bias^2)``: a point whose epsilon is the threshold is then exactly model-limited,
    and noise alone passes the threshold with probability ``exp(-sigma_factor^2 / 2)``.

    Parameters
    ----------
    epsilon_threshold : float
        epsilon(w) above it makes a band (:data:`EPSILON_THRESHOLD`).
    dof : float
        Degrees of freedom of the estimate (inf: the Rayleigh limit).
    sigma_factor : float
        Noise scales beyond which a point is model-limited.
    bias_error : float
        The validator's systematic floor (relative).

    Returns
    -------
    float
        The random error ``e`` (``random_error``); 0 when the floor alone is too large.
    """
    d = max(float(dof), 0.5)
    ratio = sigma_factor if math.isinf(d) else math.sqrt(2.0 * d * math.expm1(sigma_factor ** 2 / (2.0 * d)))
    total = 2.0 * epsilon_threshold / ratio          # epsilon_noise_scale: sigma = e / 2
    return math.sqrt(total ** 2 - bias_error ** 2) if total > bias_error else 0.0


def expected_worst(errors: Any, dof: Any, points: int = 2001) -> float:
    """The expected largest of the random errors the estimator will report, given the true ones.

    The estimator reports each frequency's error from its noise variance estimated on ``d`` (complex) degrees
    of freedom: ``e_hat = e sqrt(X / 2 d)``, ``X ~ chi^2(2 d)``. A band's worst reported error is the largest
    of them, whose mean exceeds the largest ``e`` (the more so the fewer the degrees of freedom and the more
    frequencies): ``E max = int_0^inf (1 - prod_i P(e_hat_i <= t)) dt``, the frequencies taken as independent.

    Parameters
    ----------
    errors : array_like
        The true (predicted) random error per frequency.
    dof : array_like
        Degrees of freedom of each (at least 1 is used).
    points : int
        Integration points.

    Returns
    -------
    float
        NaN for no frequency; the largest error where one is not finite.
    """
    e = np.asarray(errors, float)
    d = np.maximum(np.asarray(dof, float), 1.0)
    if e.size == 0:
        return math.nan
    if not np.all(np.isfinite(e)) or e.size != d.size or np.any(e <= 0):
        return float(np.max(e))
    top = float(np.max(e * np.sqrt(chi2.ppf(1.0 - 1e-9, 2.0 * d) / (2.0 * d))))
    t = np.linspace(0.0, top, int(points))
    below = chi2.cdf(2.0 * d[:, None] * (t[None, :] / e[:, None]) ** 2, 2.0 * d[:, None])
    return float(np.trapezoid(1.0 - np.prod(below, axis=0), t))


def _inv00(ff: np.ndarray) -> np.ndarray:
    """``[(Phi^H Phi)^-1]_00`` per frequency (inf where singular or empty)."""
    out = np.full(len(ff), np.inf)
    for i, f in enumerate(ff):
        if not np.all(np.isfinite(f)) or abs(f[0, 0]) <= 0:
            continue
        try:
            out[i] = float(np.linalg.inv(f)[0, 0].real)
        except np.linalg.LinAlgError:
            continue
    return np.where(out > 0, out, np.inf)


def predicted_random_error(noise_to_signal: Any, information: Any) -> np.ndarray:
    """The estimator's random error of ``|H|`` for an input whose information is ``Phi^H Phi``.

    ``e = sqrt(q [(Phi^H Phi)^-1]_00 / 2)``: the variance of the local polynomial fit's value at the band's
    centre, ``sigma^2 [(Phi^H Phi)^-1]_00``, over ``2 |H|^2``, with ``q = sigma^2 / |H|^2``
    (:meth:`~gap_validation.core.estimator.SpectralEstimate.from_sums` computes the same from the fitted
    sums).

    Parameters
    ----------
    noise_to_signal : array_like
        ``q(w)``: output noise variance per DFT bin over ``|H|^2`` (normalised DFT of the estimator's grid).
    information : array_like, (F, nh, nh) complex
        ``Phi^H Phi`` per frequency (``BandSums.ff``), every record summed.
    """
    q = np.asarray(noise_to_signal, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.sqrt(q * _inv00(np.asarray(information)) / 2.0)


def noise_ratio(random_error: Any, information: Any) -> np.ndarray:
    """Inverse of :func:`predicted_random_error`: ``q = 2 e^2 / [(Phi^H Phi)^-1]_00``.

    Parameters
    ----------
    random_error : array_like
        The measured ``random_error`` per frequency (inf or NaN where none).
    information : array_like, (F, nh, nh) complex
        ``Phi^H Phi`` of the manoeuvres that gave it.
    """
    e = np.asarray(random_error, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = 2.0 * e ** 2 / _inv00(np.asarray(information))
    return np.where(np.isfinite(q) & (q > 0), q, np.nan)


def _coherence(q: np.ndarray, ff00: np.ndarray, bins: np.ndarray, nh: int) -> np.ndarray:
    """Expected multiple coherence ``1 - E RSS / E |Y|^2 = 1 - d q / (|Phi|^2_00 + D q)``, ``d = D - nh``."""
    with np.errstate(invalid="ignore", divide="ignore"):
        g2 = 1.0 - (bins - nh) * q / (ff00 + bins * q)
    return np.clip(np.nan_to_num(g2, nan=0.0), 0.0, 1.0)


# ------------------------------------------------------------------------------------------------ results in
def check_results(results: dict, config: ValidationConfig, source: str = "results") -> None:
    """Raise a one-line :class:`DataError` when the results are not of this config.

    Every channel of the results must be a channel of the config with the same frequency grid (a configured
    grid: the same points; the flown grid: points within it).

    Parameters
    ----------
    results : dict
        The results JSON (``channels``).
    config : ValidationConfig
        The config to plan with.
    source : str
        The results file's name (for the messages).
    """
    channels = results.get("channels") if isinstance(results, dict) else None
    if not isinstance(channels, dict) or not channels:
        raise DataError(f"{source}: not a results file (no 'channels' object)")
    for name, ch in channels.items():
        if name not in config.channels:
            raise DataError(f"{source}: channel {name!r} is not in {config_name(config)} (channels: "
                            f"{', '.join(config.channels)}): results of another config?")
        resolved = ch.get("resolved_rad_s") if isinstance(ch, dict) else None
        if resolved is not None and (isinstance(resolved, bool) or not isinstance(resolved, (int, float))
                                     or not math.isfinite(resolved) or resolved <= 0):
            raise DataError(f"{source}: channel {name!r}: resolved_rad_s {resolved!r} is not a positive "
                            f"number [rad/s] (null where not known)")
        w = ch.get("frequency_rad_s") if isinstance(ch, dict) else None
        if not w:
            continue
        grid = config.channels[name].frequencies
        w = np.asarray(w, dtype=float)
        if grid.configured:
            same = w.size == grid.count and np.allclose(w, grid.values(), rtol=1e-6)
        else:
            same = bool(np.all(w >= grid.min_rad_s * (1 - 1e-6)) and np.all(w <= grid.max_rad_s * (1 + 1e-6)))
        if not same:
            raise DataError(
                f"{source}: channel {name!r}: frequencies {w[0]:.4g}-{w[-1]:.4g} rad/s ({w.size} points) "
                f"are not the grid of {config_name(config)} ({grid.min_rad_s:g}-{grid.max_rad_s:g} rad/s, "
                f"{grid.count} points): results of another config?"
            )


def config_name(config: ValidationConfig) -> str:
    """The config's file name for messages (``the config`` when it has none).

    Parameters
    ----------
    config : ValidationConfig
        The config.
    """
    return getattr(config, "source", None) or "the config"


def _array(values: Any, fill: float = math.nan) -> np.ndarray:
    return np.array([fill if v is None else float(v) for v in (values or [])], dtype=float)


@dataclass
class _Channel:
    """What the planner knows of one channel."""

    name: str
    w: np.ndarray                      # the grid [rad/s]
    dt: float                          # the estimator's grid step [s]
    spectra: dict                      # band_fraction, min_bins, order, ...
    detector: dict                     # energy_window_s, on_ratio, ...
    pre_s: float
    post_s: float
    model_mag: np.ndarray              # |H| of the model on w
    model: Any = None                  # the model (LinearModel)
    sigma2: np.ndarray = None          # output noise per DFT bin (filled over the grid)
    mag_ratio: np.ndarray = None       # measured |H| over the model's seen through the estimator (pooled)
    mag_ratio_error: np.ndarray = None  # ... its standard error (of the log)
    error_now: np.ndarray = None       # measured random error (NaN: none)
    targets: list = field(default_factory=list)      # (index, reason key)
    unreachable: list = field(default_factory=list)  # (index, reason sentence)
    quiet: float = 0.0                 # the sweep detector's trim level (detrended std over its window)
    # ... over TRIM_LEVEL_S: a record's noise at its ends (records.trim_noise), the 20 dB test's floor (as
    # white noise) where the flight's own trim is not known yet when the record is judged
    record_noise: float = 0.0
    input_noise: np.ndarray = None     # the input's trim motion per DFT bin, per grid frequency (mean)
    input_floor: np.ndarray = None     # ... its largest bin near each frequency (the 20 dB test's floor)
    # the noise a manoeuvre meets per DFT bin, from the trim between the first flight's manoeuvres (its output
    # error: :func:`_trim_output_error`); NaN where the trim does not tell it
    trim_noise: np.ndarray = None
    cap: float = 0.0
    cap_reason: str = ""
    coherence_threshold: float = 0.6
    # the detector sees the (noisy) surface; False with an excitation stream
    detect_on_input: bool = True
    resolved_rad_s: float = math.inf
    verdicts: int = 0
    notes: list = field(default_factory=list)


def _channel_base(name: str, ch: ChannelConfig) -> _Channel:
    est = {**ESTIMATOR_DEFAULTS, **(ch.estimator or {})}
    w = ch.frequencies.values()
    return _Channel(
        name=name,
        w=w,
        dt=1.0 / float(est["sample_rate_hz"]),
        spectra={k: est[k] for k in SPECTRA_DEFAULTS},
        detector={k: est[k] for k in DETECTOR_DEFAULTS},
        pre_s=float(est["pre_s"]),
        post_s=float(est["post_s"]),
        model_mag=np.abs(np.asarray(ch.model.freqresp(w), dtype=complex)).ravel(),
        model=ch.model,
        coherence_threshold=float(ch.coherence_threshold),
        detect_on_input=ch.excitation is None,
    )


def _shared_bins(sums: BandSums, status: np.ndarray, w: np.ndarray, n: int, dt: float,
                 band_fraction: float) -> np.ndarray:
    """``S[i, j]``: the DFT bins one record's bands at the grid frequencies ``i`` and ``j`` have in common
    (``S[i, i]`` its bins at ``i``; 0 where the record does not count). A band is the bins from ``w (1 + r_lo
    f)`` to ``w (1 + r_hi f)`` (:func:`~gap_validation.core.spectra.band_bins`: contiguous for a sweep), ``f``
    the band fraction, on the record's bin spacing ``2 pi / (n dt)``."""
    ok = (status == 0) & (sums.bins > 0)
    spacing = 2.0 * math.pi / (n * dt)
    lo = np.where(ok, np.round(w * (1.0 + np.where(ok, sums.r_lo, 0.0) * band_fraction) / spacing), 0.0)
    hi = np.where(ok, np.round(w * (1.0 + np.where(ok, sums.r_hi, 0.0) * band_fraction) / spacing), -1.0)
    shared = np.minimum(hi[:, None], hi[None, :]) - np.maximum(lo[:, None], lo[None, :]) + 1.0
    return np.where(ok[:, None] & ok[None, :], np.clip(shared, 0.0, None), 0.0)


def _rebuild_flight(c: _Channel, data: dict, opts: PlanOptions) -> tuple[BandSums, list[str], np.ndarray]:
    """The local polynomial sums of the first flight's manoeuvres (``Phi1^H Phi1``, degrees of freedom,
    bands), rebuilt from its results, and the DFT bins the grid frequencies' bands share
    (:func:`_shared_bins`, summed over the records).

    Chirps (the raw sweeps): amplitude ``input_amplitudes``, length from ``raw_sweeps``' spans, input power
    density ``A^2 T / ln(w1 / w0)`` of a log sweep over the excited band widened by the planner's first
    margins (a sweep must pass a frequency to count it); generated over a wider band at the same density, so
    no band edge falls on a grid point. Manoeuvres kept for the time domain (doublets, 3-2-1-1s): their own
    samples."""
    w, notes = c.w, []
    total = BandSums.zeros(w.size, order=int(c.spectra["order"]))
    shared = np.zeros((w.size, w.size))
    fraction = float(c.spectra["band_fraction"])
    scale = 1.0
    raw = list(data.get("raw_sweeps") or [])
    amps = _array(data.get("input_amplitudes"))
    band = data.get("excited_band_rad_s")
    kind = data.get("excitation")
    kept = list(data.get("time_domain") or [])
    kept_starts = {round(float(k.get("start_s") or math.nan), 1) for k in kept}
    if raw and band and None not in band and kind not in ("multistep", "doublet", "pulse"):
        lo, hi = float(band[0]) / SWEEP_MARGINS[0][0], float(band[1]) * SWEEP_MARGINS[0][1]
        wide_lo, wide_hi = lo / 4.0, hi * 4.0
        density = math.sqrt(math.log(wide_hi / wide_lo) / math.log(hi / lo))
        rebuilt = 0
        for r, sweep in enumerate(raw):
            start, end = sweep.get("start_s"), sweep.get("end_s")
            if start is None or end is None or round(float(start), 1) in kept_starts:
                continue
            length = float(end) - float(start)
            amp = (
                amps[r]
                if r < amps.size and math.isfinite(amps[r])
                else np.nanmax(amps)
                if amps.size
                else math.nan
            )
            if not (length > 0 and math.isfinite(amp) and amp > 0):
                continue
            t = np.arange(-min(c.pre_s, opts.trim_before_s), length + c.post_s, c.dt)
            fade = min(1.0, length / 4.0)
            u = chirp(t, length, wide_lo / (2 * math.pi), wide_hi / (2 * math.pi), fade, fade, amp * density)
            sums, status = record_bands(u[None], u[None], c.dt, w, options=c.spectra)
            total.add(sums, where=status == 0)
            shared += _shared_bins(sums, status, w, u.size, c.dt, fraction)
            rebuilt += 1
        # only the last max_raw_sweeps are in the results: the others count as the same again
        scale = max(float(data.get("sweeps") or len(raw)) / max(len(raw), 1), 1.0)
        if scale > 1.0:
            for name in ("zf", "zz", "ff", "zy", "fy", "yy", "input_power"):
                setattr(total, name, getattr(total, name) * scale)
            total.dof = np.round(total.dof * scale).astype(total.dof.dtype)
            total.bins = np.round(total.bins * scale).astype(total.bins.dtype)
            shared *= scale
        if rebuilt:
            notes.append(
                f"the flight's {rebuilt} {kind or 'sweep'} record(s) rebuilt as log sweeps over "
                f"{lo:.3g}-{hi:.3g} rad/s (the excited band {float(band[0]):.3g}-{float(band[1]):.3g} "
                f"rad/s with margins) at their amplitude and length"
            )
    for k in kept:
        u = _array(k.get("input"), 0.0)
        dt = float(k.get("dt_s") or 0.0)
        n0 = int(k.get("trim_samples") or 0)
        if u.size < 8 or not dt > 0:
            continue
        u = u - (float(np.mean(u[:n0])) if n0 > 0 else float(u[0]))
        sums, status = record_bands(u[None], u[None], dt, w, options=c.spectra)
        total.add(sums, where=status == 0)
        shared += _shared_bins(sums, status, w, u.size, dt, fraction)
    return total, notes, shared


def _trim_levels(c: _Channel, data: dict | None, opts: PlanOptions) -> str:
    """The sweep detector's trim level and the input's trim motion per frequency (what a manoeuvre must stand
    20 dB above): from the trim before the manoeuvres kept in the results (their samples: the detector's
    energy over its window; a Hann periodogram normalised as the estimator's DFT, the largest within a factor
    1.5 of each grid frequency; and the median detrended std over
    :data:`~gap_validation.core.records.TRIM_LEVEL_S`, what :func:`~gap_validation.core.records.trim_noise`
    takes at a record's ends), else the assumed surface noise. Returns the sentence saying which."""
    window = float(c.detector["energy_window_s"])
    levels, spectra, ends = [], [], []
    for k in (data or {}).get("time_domain") or []:
        u = _array(k.get("input"), 0.0)
        dt = float(k.get("dt_s") or 0.0)
        n0 = int(k.get("trim_samples") or 0)
        if not dt > 0 or n0 < 16:
            continue
        x = np.arange(n0, dtype=float)
        trim = u[:n0] - np.polyval(np.polyfit(x, u[:n0], 1), x)
        n = max(3, min(n0, int(round(window / dt))))
        levels.append(float(np.median(detrended_std(u[:n0], n))))
        ends.append(float(np.median(detrended_std(u[:n0], max(3, min(n0, int(round(TRIM_LEVEL_S / dt))))))))
        hann = np.hanning(n0)
        power = np.abs(np.fft.rfft(trim * hann)) ** 2 / float(np.sum(hann ** 2))
        w_bins = 2.0 * math.pi * np.fft.rfftfreq(n0, dt)
        white = float(np.mean(power[1:])) if power.size > 1 else 0.0
        near = [power[(w_bins >= wi / 1.5) & (w_bins <= wi * 1.5)] for wi in c.w]
        spectra.append([(float(np.max(p)), float(np.mean(p))) if p.size else (white, white) for p in near])
    if levels:
        c.quiet = float(np.max(levels))
        c.record_noise = float(np.max(ends))
        spectra = np.array(spectra)                      # (manoeuvres, F, [largest, mean])
        c.input_floor, c.input_noise = np.max(spectra[:, :, 0], axis=0), np.mean(spectra[:, :, 1], axis=0)
        return (
            f"{c.name}: the surface's trim motion {float(np.sqrt(np.median(c.input_noise))):.2g} rad per DFT "
            "bin "
            f"(median over the grid), from the trim before the {len(levels)} manoeuvre(s) kept in the results"
        )
    sigma = math.hypot(opts.surface_noise_rad, FlightOptions.surface_lsb_rad / math.sqrt(12.0))
    c.quiet, c.input_noise = sigma, np.full(c.w.shape, 2.0 * sigma ** 2)
    c.record_noise = sigma
    c.input_floor = c.input_noise
    return (
        f"{c.name}: the surface's trim motion assumed {sigma:.2g} rad rms of white noise (its sensor's "
        "noise; no "
        f"trim samples in the results)"
    )


def _output_trim_noise(c: _Channel, data: dict) -> np.ndarray:
    """The output's noise per DFT bin from the trim before the manoeuvres kept in the results (their output
    samples: a Hann periodogram normalised as the estimator's DFT, the mean within a factor 1.25 of each grid
    frequency, the mean over the manoeuvres); NaN where those few seconds resolve nothing (below three
    bins)."""
    rows = []
    for k in data.get("time_domain") or []:
        y = _array(k.get("output"), 0.0)
        dt = float(k.get("dt_s") or 0.0)
        n0 = int(k.get("trim_samples") or 0)
        if not dt > 0 or n0 < 32 or y.size < n0:
            continue
        x = np.arange(n0, dtype=float)
        trim = y[:n0] - np.polyval(np.polyfit(x, y[:n0], 1), x)
        hann = np.hanning(n0)
        power = np.abs(np.fft.rfft(trim * hann)) ** 2 / float(np.sum(hann ** 2))
        w_bins = 2.0 * math.pi * np.fft.rfftfreq(n0, dt)
        resolved = 3.0 * w_bins[1]
        rows.append(
            [
                float(np.mean(p))
                if wi >= resolved and (p := power[(w_bins >= wi / 1.25) & (w_bins <= wi * 1.25)]).size
                else math.nan
                for wi in c.w
            ]
        )
    if not rows:
        return np.full(c.w.shape, np.nan)
    rows = np.array(rows)
    count = np.sum(np.isfinite(rows), axis=0)
    return np.where(count > 0, np.nansum(rows, axis=0) / np.maximum(count, 1), np.nan)


def _trim_spectra(c: _Channel, data: dict) -> TrimSpectra | None:
    """The results' ``trim_spectra`` on the channel's grid (None: none, results written before them or a MIMO
    channel)."""
    raw = data.get("trim_spectra")
    if not isinstance(raw, dict):
        return None
    trim = TrimSpectra.from_json_dict(raw)
    return trim if trim.averages.size == c.w.size else None


def _trim_floor(c: _Channel, trim: TrimSpectra | None) -> None:
    """The 20 dB test's floor where the results' ``trim_spectra`` measured it on tens of averages: the input's
    trim motion between the manoeuvres as the estimator takes it (``input_floor``, the median over its
    segments), in place of the few seconds of trim before the kept manoeuvres (:func:`_trim_levels`), whose
    detrended periodogram does not see a pilot's slow corrections."""
    if trim is None or trim.input_floor is None or trim.input_floor.size != c.w.size:
        return
    known = (trim.averages >= MIN_TRIM_AVERAGES) & np.isfinite(trim.input_floor) & (trim.input_floor > 0)
    c.input_floor = np.where(known, trim.input_floor, c.input_floor)


def _trim_output_error(c: _Channel, data: dict, trim: TrimSpectra | None) -> np.ndarray:
    """The noise a manoeuvre will meet, per DFT bin of the estimator's grid: the output's motion between the
    first flight's manoeuvres that the response does not explain, ``E |Y - H U|^2``
    (:meth:`~gap_validation.core.background.TrimSpectra.output_error` of the results' ``trim_spectra``).

    It holds whatever moves the surface between the manoeuvres (a pilot's corrections are explained by ``H
    U``; a loop answering the gusts leaves the gusts in it), and the surface sensor's noise seen through the
    response, as a manoeuvre's residual does; and it rests on minutes of trim (tens of averages) where the
    first flight's manoeuvres leave a few degrees of freedom per frequency. ``H`` is the measured response
    where the results call it confident, the model's elsewhere. Where a 20 s segment does not resolve the
    frequency (fewer than :data:`~gap_validation.core.background.MIN_TRIM_AVERAGES` averages): the smooth
    continuation of the rest, as the flight's own estimate is continued (:func:`_fill_noise`). NaN everywhere
    when the results hold no trim spectra (results written before them, a MIMO channel)."""
    nothing = np.full(c.w.shape, np.nan)
    if trim is None:
        return nothing
    h = np.asarray(c.model.freqresp(c.w), dtype=complex).ravel()
    confident = np.array(data.get("confident") or [False] * c.w.size, dtype=bool)
    measured = response_from_json(data.get("measured"))
    if measured is not None and confident.size == c.w.size and measured.size == c.w.size:
        h = np.where(confident & np.isfinite(measured), measured, h)
    e, n = trim.output_error(h), trim.averages
    use = (n >= MIN_TRIM_AVERAGES) & np.isfinite(e) & (e > 0)
    if not use.any():
        return nothing
    # each log corrected by its bias psi(n) - ln n
    y = np.log(np.where(use, e, 1.0)) - (digamma(np.maximum(n, 1.0)) - np.log(np.maximum(n, 1.0)))
    smooth = np.exp(_local_linear(np.log10(c.w), y, np.where(use, n, 0.0), NOISE_WIDTH, SLOPE_RANGE))
    return np.where(use, e, smooth)


def _fill_noise(
    c: _Channel,
    q: np.ndarray,
    dof: np.ndarray,
    measured_mag: np.ndarray,
    seen_mag: np.ndarray,
    trusted: np.ndarray,
    trim_noise: np.ndarray | None = None,
    shared: np.ndarray | None = None,
    information: np.ndarray | None = None,
) -> None:
    """``c.sigma2`` (the output's own noise per DFT bin) and ``c.mag_ratio`` on the whole grid.

    Where the first flight measured it, the estimator's noise is ``q |H_meas|^2`` (its own ``rss / d``): the
    output's noise plus the input's, seen through the response (errors in variables: ``|H|^2`` times the
    input's trim motion, :func:`_trim_levels`), which is taken off. The output's noise is smoothed over
    frequency by a local linear fit of its logarithm in log w (tricube kernel of :data:`NOISE_WIDTH` decades,
    weights the degrees of freedom, each log corrected by its chi-square bias ``psi(d) - ln d``): noise
    spectra are smooth, and on 3 degrees of freedom one estimate scatters by 58 %. Only ``trusted`` points
    count (the rebuilt manoeuvres give their degrees of freedom, inside the excited band's core): at a band's
    edge the first flight's input is not known well enough to turn its error into a noise level. Beyond them
    the fit continues with its slope at the edge (between ``-4``, turbulence's fall, and ``+2``), or takes the
    output's noise measured in the trim before the kept manoeuvres (:func:`_output_trim_noise`) where that
    resolves the frequency. The measured ``|H|`` over the model's as the first flight's records see it
    (``seen_mag``: a lightly damped zero is smoothed more by a short record), pooled over neighbouring
    frequencies until its random error is :data:`RESPONSE_ERROR` (:func:`_pool_response`, the bins they share
    from ``shared``): a planned manoeuvre's ``|H|`` is its own view of the model times that ratio. Each
    point's error in that pool is the one the noise level gives it (:func:`_expected_error`, from
    ``information``, the rebuilt ``Phi1^H Phi1``, and ``c.trim_noise``, the trim's output error) or its own
    where that is larger (:func:`_view_error`); without ``information``, its own."""
    measured = np.isfinite(measured_mag) & (measured_mag > 0)
    total = q * np.where(measured, measured_mag, np.nan) ** 2
    use = trusted & measured & np.isfinite(total) & (total > 0) & (dof >= 1)
    lw = np.log10(c.w)
    c.mag_ratio = np.ones(c.w.shape)
    c.sigma2 = np.full(c.w.shape, np.nan)
    if not use.any():
        return
    own = np.maximum(total - np.where(measured, measured_mag, 0.0) ** 2 * c.input_noise, 0.1 * total)
    y = np.log(np.where(use, own, 1.0)) - (digamma(np.maximum(dof, 1.0)) - np.log(np.maximum(dof, 1.0)))
    c.sigma2 = np.exp(_local_linear(lw, y, np.where(use, dof, 0.0), NOISE_WIDTH, SLOPE_RANGE))
    if trim_noise is not None:
        beyond = (lw < lw[use].min()) | (lw > lw[use].max())
        known = beyond & np.isfinite(trim_noise) & (trim_noise > 0)
        c.sigma2[known] = trim_noise[known]
    error = np.asarray(c.error_now, dtype=float) if c.error_now is not None else np.full(c.w.shape, np.nan)
    ok = use & np.isfinite(seen_mag) & (seen_mag > 0) & np.isfinite(error) & (error > 0)
    error = _view_error(error, measured_mag, seen_mag)
    if information is not None:
        expected = _expected_error(c, seen_mag, information)
        ok &= np.isfinite(expected) & (expected > 0)
        error = np.fmax(error, expected)
    if ok.any():
        ratio = np.log(np.where(ok, measured_mag, 1.0) / np.where(ok, seen_mag, 1.0))
        error = np.where(ok, error, np.inf)
        pooled, variance = _pool_response(lw, ratio, error, shared, RESPONSE_ERROR)
        c.mag_ratio, c.mag_ratio_error = np.exp(pooled), np.sqrt(variance)


def _response(model: Any):
    """``model.freqresp`` as a flat complex array (SISO)."""
    return lambda w: np.asarray(model.freqresp(np.asarray(w, float)), dtype=complex).reshape(np.shape(w))


def _local_linear(x: np.ndarray, y: np.ndarray, weight: np.ndarray, width: float,
                  slopes: tuple[float, float]) -> np.ndarray:
    """A local linear fit of ``y(x)`` at every ``x`` (tricube kernel of half-width ``width``, the given
    weights); beyond the weighted points, the fit at the nearest edge continued with its slope clipped to
    ``slopes``."""
    out = np.empty(x.shape)
    have = weight > 0
    lo, hi = x[have].min(), x[have].max()
    for i, xi in enumerate(x):
        at = min(max(xi, lo), hi)
        k = np.clip(1.0 - (np.abs(x - at) / width) ** 3, 0.0, None) ** 3 * weight
        if np.count_nonzero(k) < 2:
            k = weight / np.maximum(np.abs(x - at), 1e-9)
        sw = float(np.sum(k))
        mx = float(np.sum(k * x)) / sw
        my = float(np.sum(k * np.where(have, y, 0.0))) / sw
        sxx = float(np.sum(k * (x - mx) ** 2))
        slope = float(np.sum(k * (x - mx) * (np.where(have, y, 0.0) - my))) / sxx if sxx > 0 else 0.0
        value = my + slope * (at - mx)
        out[i] = value + float(np.clip(slope, *slopes)) * (xi - at)
    return out


def _expected_error(c: _Channel, seen_mag: np.ndarray, information: np.ndarray) -> np.ndarray:
    """Each first-flight point's random error as the smoothed noise says it should be, over the model's view
    of ``|H|``: ``predicted_random_error(sigma^2 / |H_seen|^2 + input noise, Phi1^H Phi1)``, the noise the
    trim's output error where it tells it (``c.trim_noise``: :func:`_trim_output_error`, tens of averages),
    else ``c.sigma2``
    (the flight's own residuals smoothed over frequency). Not the point's own ``random_error``: that is its
    residual on a short card's 3 degrees of freedom, a third of the truth or less one time in five
    (chi-square), and a pool weighted by ``1 / e^2`` leans on exactly those points and believes itself
    precise."""
    view = np.maximum(np.asarray(seen_mag, float), 1e-300) ** 2
    q = c.sigma2 / view + c.input_noise
    if c.trim_noise is not None:
        q = np.where(np.isfinite(c.trim_noise), c.trim_noise / view, q)
    return predicted_random_error(q, information)


def _view_error(error: np.ndarray, measured_mag: np.ndarray, seen_mag: np.ndarray) -> np.ndarray:
    """Each point's random error with the model's view in place of its own ``|H|``: ``e |H_meas| /
    |H_seen|``. The validator's random error is the noise over the estimate's own magnitude, so weights
    ``1 / e^2`` taken from it favour the points whose ``|H|`` came out high, and a pool of them is biased
    upwards (on a short first flight's few degrees of freedom by tens of per cent); the noise itself does not
    depend on which way the estimate fell."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(error, float) * np.asarray(measured_mag, float) / np.asarray(seen_mag, float)


def _pool_response(x: np.ndarray, y: np.ndarray, error: np.ndarray, shared: np.ndarray | None,
                   target: float) -> tuple[np.ndarray, np.ndarray]:
    """Per grid point, the pooled ``ln |H_meas| / |H_model|`` and its variance.

    The points with a finite random error ``error`` (each ``ln |H|``'s standard error: the validator's
    ``random_error`` is ``|H|``'s relative one) are taken nearest first in ``x`` (log frequency) and averaged
    with weights ``1 / error^2`` until the mean's variance ``a^T C a`` is at most ``target^2`` (or every point
    is in). Two estimates that share DFT bins are not independent: ``C_ij = rho_ij e_i e_j`` with ``rho_ij =
    S_ij / sqrt(S_ii S_jj)``, the share of the bins the two bands have in common (``shared``,
    :func:`_shared_bins`; an approximation: the local polynomial weighs a band's bins unevenly). Points
    without bins in ``shared``, or all of them without ``shared``, count as independent. At the low end of a
    short record neighbouring grid points share six of their seven bins: there the pool reaches much further
    than a count of grid points would say. Beyond the points, the nearest are pooled (the ratio continued
    flat). The pool is a local mean: where the measured ``|H|`` departs from the model's in shape (not by a
    constant factor) over the pool's reach, the mean is biased by that slope.

    Parameters
    ----------
    x : ndarray
        log10 of the grid frequencies.
    y : ndarray
        ``ln`` of the measured over the model's magnitude (any value where ``error`` is not finite).
    error : ndarray
        Standard error of each ``y`` (inf where none).
    shared : ndarray or None
        Shared DFT bins between the grid points' bands (F, F).
    target : float
        Largest standard error of the pooled value.

    Returns
    -------
    value, variance : ndarray
        The pooled ``ln`` ratio and its variance at every ``x`` (0 and inf when no point has an error).
    """
    have = np.flatnonzero(np.isfinite(error))
    if not have.size:
        return np.zeros(x.shape), np.full(x.shape, np.inf)
    e, yh = error[have], y[have]
    rho = np.eye(have.size)
    if shared is not None:
        diag = np.diag(shared)[have]
        both = (diag[:, None] > 0) & (diag[None, :] > 0)
        known = np.where(diag > 0, diag, 1.0)
        scale = np.sqrt(np.outer(known, known))
        rho = np.where(both, np.clip(shared[np.ix_(have, have)] / scale, 0.0, 1.0), rho)
    cov = rho * np.outer(e, e)
    weight = 1.0 / e ** 2
    value, variance = np.empty(x.shape), np.empty(x.shape)
    for k, xk in enumerate(x):
        order = np.argsort(np.abs(x[have] - xk), kind="stable")
        wo = weight[order]
        total = np.cumsum(wo)
        # a^T C a of the first m points, a = w / sum(w): the leading m x m block's sum over total(m)^2
        block = np.cumsum(np.cumsum(wo[:, None] * wo[None, :] * cov[np.ix_(order, order)], axis=0), axis=1)
        var = np.diagonal(block) / total ** 2
        m = int(np.argmax(var <= target ** 2)) if np.any(var <= target ** 2) else order.size - 1
        value[k], variance[k] = float(np.cumsum(wo * yh[order])[m] / total[m]), float(var[m])
    return value, variance


def no_verdict_reason(flag: str | None, reason: str | None) -> str | None:
    """Why a frequency of the results has no verdict (a key of :data:`REASON_WORDS`), or None where it has
    one.

    A frequency has a verdict where it is model-limited, or where its estimate is confident and not
    data-limited (``frequency_reasons`` None); a data-limited one is ``data`` whatever its estimate.

    Parameters
    ----------
    flag : str or None
        Its ``frequency_flags`` entry (:func:`~gap_validation.core.evidence.frequency_flags`).
    reason : str or None
        Its ``frequency_reasons`` entry (None: a confident estimate).
    """
    if flag == "model":
        return None
    return "data" if flag == "data" else reason


def _targets(c: _Channel, data: dict) -> None:
    """Which grid frequencies have no verdict (and why), which cannot get one."""
    flags = list(data.get("frequency_flags") or [])
    reasons = list(data.get("frequency_reasons") or [])
    n = c.w.size
    flags += [None] * (n - len(flags))
    reasons += [None] * (n - len(reasons))
    above = [i for i in range(n) if reasons[i] == "above_resolution"]
    if above:
        c.resolved_rad_s = min(
            c.resolved_rad_s, float(c.w[above[0]]) / (1.0 + float(c.spectra["band_fraction"]))
        )
    for i in range(n):
        why = no_verdict_reason(flags[i], reasons[i])
        if why is None:
            c.verdicts += 1
        elif why == "above_resolution" or c.w[i] * (1 + float(c.spectra["band_fraction"])) > c.resolved_rad_s:
            c.unreachable.append((i, _resolution_reason(c)))
        else:
            c.targets.append((i, why))


def _resolution_reason(c: _Channel) -> str:
    limit = c.resolved_rad_s
    return (
        f"above what the logs resolve ({limit:.3g} rad/s here: a quarter of the slowest stream's rate, or "
        "where "
        f"the results say so); log the surface and the rate at 4 x w / 2 pi Hz or faster "
        f"(e.g. {4.0 * c.w.max() / (2 * math.pi):.0f} Hz for {c.w.max():.3g} rad/s)"
    )


# ------------------------------------------------------------------------------------------------ the search
@dataclass
class _Design:
    manoeuvre: PlannedManoeuvre | None
    needed_rad: float = math.inf
    limit: str = ""


def estimator_record(u: np.ndarray, dt: float, pre_s: float, post_s: float) -> np.ndarray:
    """The record the estimator cuts around one manoeuvre of ``u`` (trim before and after it, no noise):
    ``pre_s`` before it first leaves trim and ``post_s`` after it last returns
    (:func:`~gap_validation.core.records.split_record`: trim is within a tenth of its excursion,
    :func:`~gap_validation.core.records.trim_tolerance`), within ``u``.

    A planned sweep's information is computed on this record (:func:`_candidate`). At a sweep's low end a
    frequency has few DFT bins, and its error depends on where the record's length puts them: for a 62 s
    sweep from 0.5 rad/s the error at 0.7 rad/s is 3.3 times the one at 0.93 rad/s on the record the
    estimator cut (67.2 s: 1.5 s before the sweep, whose half-cosine fade leaves trim 0.5 s late, and 3.8 s
    after), 1.7 times on one 0.7 s longer, 3.2 times on one 2.3 s shorter; the flight measured 3.9.

    Parameters
    ----------
    u : ndarray
        The manoeuvre with the trim before and after it (its own and the card's), sampled at ``dt``.
    dt : float
        Sample step [s].
    pre_s, post_s : float
        Trim the estimator keeps before and after a manoeuvre (its options of the same names) [s].
    """
    u = np.asarray(u, dtype=float)
    dev = np.abs(u - u[0])
    moving = np.flatnonzero(dev > trim_tolerance(float(np.max(dev)), 0.0))
    if not moving.size:
        return u
    first = max(int(moving[0]) - int(round(pre_s / dt)), 0)
    last = min(int(moving[-1]) + 1 + int(round(post_s / dt)), u.size)
    return u[first:last]


def _information_record(c: _Channel, opts: PlanOptions, duration_s: float, f0: float, f1: float
                        ) -> np.ndarray:
    """The sweep at amplitude 1 with the card's trim around it, on the record the estimator cuts
    (:func:`estimator_record`): what a planned sweep's information is computed on."""
    t = np.arange(-opts.trim_before_s, duration_s + opts.trim_between_s, c.dt)
    return estimator_record(chirp(t, duration_s, f0, f1, opts.fade_s, opts.fade_s), c.dt, c.pre_s, c.post_s)


def _unit_record(c: _Channel, opts: PlanOptions, duration_s: float, f0: float, f1: float
                 ) -> tuple[np.ndarray, float]:
    """The sweep at amplitude 1 as the estimator will cut it, conservatively: half the trim it may keep before
    (``pre_s``) and after (``post_s``) it (a sweep detected a little late, a record ended a little early: seen
    0.6 s late and 1 s short, enough to lose the lowest frequency to ``max_band_fraction``). Every target must
    count on it; the information is computed on the record the estimator cuts (:func:`estimator_record`)."""
    pre = 0.5 * min(c.pre_s, opts.trim_before_s)
    post = 0.5 * min(c.post_s, opts.trim_between_s)
    t = np.arange(-pre, duration_s + post, c.dt)
    return chirp(t, duration_s, f0, f1, opts.fade_s, opts.fade_s), pre


def _minimum_coherence(threshold: float, dof: np.ndarray, nh: int) -> np.ndarray:
    """Per frequency, the smallest coherence the validator calls confident on ``dof`` degrees of freedom."""
    return np.array([_least_confident(float(threshold), float(d), int(nh)) for d in dof])


@functools.lru_cache(maxsize=4096)
def _least_confident(threshold: float, dof: float, nh: int) -> float:
    """The smallest coherence :func:`~gap_validation.core.evidence.confident_points` calls confident on
    ``dof`` degrees of freedom (a stand-in estimate; bisection); 1 when none is."""
    lo, hi = threshold, 0.99999
    if not _confident(hi, dof, nh, threshold):
        return 1.0
    if _confident(lo, dof, nh, threshold):
        return lo
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if _confident(mid, dof, nh, threshold) else (mid, hi)
    return hi


def _confident(coherence: float, dof: float, nh: int, threshold: float) -> bool:
    stand_in = SimpleNamespace(response=np.array([1.0 + 0j]), coherence=np.array([coherence]),
                               n_averages=np.array([dof]), coefficients=nh)
    return bool(confident_points(stand_in, threshold)[0])


def _design(c: _Channel, idx: list[int], reasons: tuple[str, ...], opts: PlanOptions, index: int) -> _Design:
    """The manoeuvre of least flight time that brings the grid points ``idx`` to the target, or why none does.

    Per swept band, the longest usable sweep with the most repeats is tried first: every need but the sweep
    detector's falls with the time spent (the error as one over its square root), so a band it cannot reach
    under the cap is given up at once (unless the detector was what it lacked: a shorter sweep is faster);
    otherwise the lengths are scanned from the shortest."""
    w = c.w[idx]
    best: PlannedManoeuvre | None = None
    fail = _Design(None)
    slow = SLOW_SWEEP * 2.0 / float(c.detector["energy_window_s"])
    slow_rejected = False
    for (m_lo, m_hi), ratio in _bands_tried(float(w.min()), slow):
        # at least 5:1, widened upwards (a slower start is what the estimator follows worst), below the
        # resolution; a start below the detector's slow limit also 10:1 and 20:1 (through the slow part
        # faster, as densely)
        w0 = float(w.min()) / m_lo
        w1 = min(max(float(w.max()) * m_hi, ratio * w0), c.resolved_rad_s)
        w0 = min(w0, w1 / ratio)
        if w1 <= float(w.max()) or w1 / w0 < ratio * 0.999:
            continue
        lengths, slow_cut = _usable_lengths(c, w, w0, w1, slow, opts)
        slow_rejected = slow_rejected or slow_cut
        if not lengths:
            continue
        probe = _candidate(c, idx, w0, w1, lengths[-1], opts)
        if probe is None:
            continue
        found, needed, limit = _best_repeats(
            c, idx, probe, opts, math.inf, reasons, index, only=opts.max_repeats
        )
        if found is None:
            if needed < fail.needed_rad:
                fail = _Design(None, needed, limit)
            if limit != "sweep detection":          # a shorter sweep is faster, easier to detect: scan it
                continue
        for length in lengths:
            if best is not None and opts.trim_before_s + length + opts.trim_between_s >= best.flight_time_s:
                break                    # longer sweeps cannot beat the best found
            cand = probe if length == lengths[-1] else _candidate(c, idx, w0, w1, length, opts)
            if cand is None:
                continue
            found, needed, limit = _best_repeats(c, idx, cand, opts, best.flight_time_s if best else math.inf,
                                                 reasons, index)
            if found is not None:
                best = found
    if best is not None:
        return _Design(best)
    if math.isinf(fail.needed_rad) and slow_rejected:
        fail.limit = "slow"
    return fail


def _usable_lengths(c: _Channel, w: np.ndarray, w0: float, w1: float, slow: float,
                    opts: PlanOptions) -> tuple[list[float], bool]:
    """Sweep lengths worth trying for the band ``w0``-``w1`` (geometric steps), and whether the sweep
    detector's slow limit cut them short: long enough for ``min_bins`` bins within ``max_band_fraction`` of
    the lowest target and for the chirp test's zero crossings, short enough below the slow limit."""
    shortest_record = (int(c.spectra["min_bins"]) - 1) * 2.0 * math.pi / (
        2.0 * float(c.spectra["max_band_fraction"]) * float(w.min()))
    out, length, cut = [], max(4.0 * opts.fade_s, MIN_SWEEP_S), False
    while length <= opts.max_sweep_s * (1 + 1e-9):
        if c.detect_on_input and w0 < slow and length * math.log(slow / w0) / math.log(w1 / w0) > LOOKBACK_S:
            cut = True
            break                    # dwells too long where the detector sees it by its curvature only
        if (length + opts.trim_before_s + opts.trim_between_s >= 0.9 * shortest_record
                and w0 * length * (w1 / w0 - 1.0) / math.log(w1 / w0) >= MIN_HALF_PERIODS * math.pi):
            out.append(length)
        length *= SWEEP_LENGTH_STEP
    return out, cut


@dataclass
class _Candidate:
    """One sweep at amplitude 1 as the estimator sees it at the targets."""

    w0: float
    w1: float
    length: float
    q: np.ndarray          # noise-to-signal per target (output's over |H|^2, plus the input's)
    inv00: np.ndarray
    ff00: np.ndarray
    dof: np.ndarray        # bins less the transient, per record
    level: np.ndarray      # input power per bin near each target
    detect: float          # amplitude the sweep detector needs


def _candidate(c: _Channel, idx: list[int], w0: float, w1: float, length: float,
               opts: PlanOptions) -> _Candidate | None:
    """The estimator's view of one sweep (None when it does not count at every target)."""
    w = c.w[idx]
    f0, f1 = w0 / (2 * math.pi), w1 / (2 * math.pi)
    u, pre = _unit_record(c, opts, length, f0, f1)
    sums, status = record_bands(u[None], u[None], c.dt, w, options=c.spectra)
    if np.any(status != 0):
        return None
    seen = np.abs(expected_estimate(sums, w, float(c.spectra["band_fraction"]), _response(c.model))[0])
    view = np.maximum(seen * c.mag_ratio[idx], 1e-300) ** 2
    q = c.sigma2[idx] / view + c.input_noise[idx]
    if c.trim_noise is not None:             # the trim's output error, where it tells the noise
        q = np.where(np.isfinite(c.trim_noise[idx]), c.trim_noise[idx] / view, q)
    if not np.all(np.isfinite(q)):
        return None
    info = sums.ff
    cut = _information_record(c, opts, length, f0, f1)
    record, record_status = record_bands(cut[None], cut[None], c.dt, w, options=c.spectra)
    if np.all(record_status == 0):
        info = record.ff
    return _Candidate(w0, w1, length, q, _inv00(info), np.array([f[0, 0].real for f in info]),
                      sums.dof.astype(float), sums.input_power / np.maximum(sums.bins.astype(float), 1.0),
                      _detection_amplitude(c, u, pre, length, opts) if c.detect_on_input else 0.0)


def _best_repeats(c: _Channel, idx: list[int], cand: _Candidate, opts: PlanOptions, beat_s: float,
                  reasons: tuple[str, ...], index: int, only: int | None = None
                  ) -> tuple[PlannedManoeuvre | None, float, str]:
    """The fewest repeats of a candidate whose amplitude stays under the cap (and whose flight time beats
    ``beat_s``): the manoeuvre, else None with the least amplitude needed and by what."""
    nh = int(c.spectra["order"]) + 1
    needed, limit = math.inf, ""
    for n in ([only] if only else range(1, opts.max_repeats + 1)):
        time_s = opts.trim_before_s + n * (cand.length + opts.trim_between_s)
        if time_s >= beat_s:
            break
        d = n * cand.dof - nh
        if np.any(d < 1):
            continue
        target = np.array([opts.target_error or _verdict_error(float(di)) for di in d])
        if np.any(target <= 0):
            continue
        needs = {
            "random error": float(np.max(np.sqrt(cand.q * cand.inv00 / (2.0 * n)) * opts.margin / target)),
            "coherence": _coherence_amplitude(cand.q, cand.ff00, n, cand.dof, d, nh, c.coherence_threshold,
                                              opts.margin),
            "sweep detection": cand.detect,
            "input noise": 0.0 if not c.detect_on_input else float(np.max(np.sqrt(
                _EXCITATION_SNR * EXCITATION_MARGIN * np.maximum(c.input_floor[idx], c.record_noise ** 2)
                / np.maximum(cand.level, 1e-300)))),
        }
        by = max(needs, key=needs.get)
        amplitude = needs[by]
        if not math.isfinite(amplitude):
            continue
        if amplitude > c.cap * (1 + 1e-9):
            if amplitude < needed:
                needed, limit = amplitude, by
            continue
        amplitude = min(_r_up(amplitude, 4), c.cap)      # up: the rounded amplitude still meets every need
        pred = np.sqrt(cand.q * cand.inv00 / (2.0 * n)) / amplitude
        coh = _coherence(cand.q, n * amplitude ** 2 * cand.ff00, n * cand.dof, nh)
        w = c.w[idx]
        return (
            PlannedManoeuvre(
                channel=c.name,
                index=index,
                closes_rad_s=(float(w.min()), float(w.max())),
                reasons=reasons,
                band_rad_s=(_r(cand.w0, 5), _r(cand.w1, 5)),
                amplitude_rad=amplitude,
                duration_s=round(cand.length, 2),
                repeats=n,
                fade_in_s=opts.fade_s,
                fade_out_s=opts.fade_s,
                trim_before_s=opts.trim_before_s,
                trim_between_s=opts.trim_between_s,
                amplitude_set_by=by,
                frequencies_rad_s=tuple(float(x) for x in w),
                error_now=tuple(None if not math.isfinite(e) else float(e) for e in c.error_now[idx]),
                predicted_error=tuple(float(x) for x in pred),
                predicted_coherence=tuple(float(x) for x in coh),
                predicted_dof=tuple(float(x) for x in d),
                target_error=tuple(float(x) for x in target),
            ),
            needed,
            limit,
        )
    return None, needed, limit


def _bands_tried(w_low: float, slow: float) -> list[tuple[tuple[float, float], float]]:
    """(margins, least ratio) of the swept bands tried for targets starting at ``w_low``."""
    ratios = (MIN_SWEEP_RATIO,) + ((10.0, 20.0) if w_low / SWEEP_MARGINS[0][0] < 1.5 * slow else ())
    return [(margins, ratio) for margins in SWEEP_MARGINS for ratio in ratios]


@functools.lru_cache(maxsize=1024)
def _verdict_error(dof: float) -> float:
    return verdict_error(EPSILON_THRESHOLD, dof)


def _detection_amplitude(
    c: _Channel, u: np.ndarray, pre_s: float, length_s: float, opts: PlanOptions
) -> float:
    """The amplitude at which the sweep detector (:mod:`gap_validation.core.sweeps`) holds the whole sweep:
    its energy (:func:`~gap_validation.core.sweeps.detrended_std` over ``energy_window_s``) passes
    ``on_ratio`` times the trim's level within :data:`~gap_validation.core.estimator.LOOKBACK_S` of the start
    (the record reaches back that far) and stays above ``off_ratio`` times it but for runs shorter than
    ``hold_s``, with
    :data:`DETECTION_MARGIN` on the level."""
    window_n = max(3, int(round(float(c.detector["energy_window_s"]) / c.dt)))
    energy = detrended_std(u, window_n)
    # each window's end, from the sweep start
    t = (np.arange(energy.size) + window_n - 1) * c.dt - pre_s
    level = c.quiet * DETECTION_MARGIN
    early = (t >= 0) & (t <= LOOKBACK_S)
    peak = float(np.max(energy[early])) if early.any() else 0.0
    if not peak > 0:
        return math.inf
    amplitude = float(c.detector["on_ratio"]) * level / peak
    hold = int(round(float(c.detector["hold_s"]) / c.dt))
    for _ in range(3):
        on = np.flatnonzero(early & (amplitude * energy > float(c.detector["on_ratio"]) * level))
        start = t[on[0]] if on.size else 0.0
        span = (t >= start) & (t <= length_s - opts.fade_s)
        theta = _largest_level(energy[span], hold)
        if not theta > 0:
            return math.inf
        needed = float(c.detector["off_ratio"]) * level / theta
        if needed <= amplitude * (1 + 1e-9):
            break
        amplitude = needed
    return amplitude


def _largest_level(energy: np.ndarray, hold_n: int) -> float:
    """The largest level below which ``energy`` never stays for ``hold_n`` samples in a row (bisection)."""
    if energy.size == 0:
        return 0.0
    lo, hi = 0.0, float(np.max(energy))
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _longest_run(energy < mid) < hold_n else (lo, mid)
    return lo


def _longest_run(mask: np.ndarray) -> int:
    if not mask.any():
        return 0
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return int(np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)))


def _coherence_amplitude(q: np.ndarray, ff00: np.ndarray, n: int, dof1: np.ndarray, d: np.ndarray, nh: int,
                         threshold: float, margin: float) -> float:
    """The amplitude whose predicted coherence is confident (with ``margin`` on the noise) at every target."""
    need = _minimum_coherence(threshold, d, nh)
    if np.any(need >= 1.0):
        return math.inf
    bins = n * dof1
    # 1 - (D - nh) q m / (n A^2 F + D q m) >= c  <=>  n A^2 F >= q m ((D - nh) / (1 - c) - D)
    a2 = q * margin * ((bins - nh) / (1.0 - need) - bins) / (n * np.maximum(ff00, 1e-300))
    return float(math.sqrt(max(float(np.max(a2)), 0.0)))


def _runs(idx: list[int]) -> list[list[int]]:
    runs: list[list[int]] = []
    for i in idx:
        if runs and i == runs[-1][-1] + 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    return runs


def _plan_run(c: _Channel, run: list[int], why: dict, opts: PlanOptions, index: int,
              depth: int = 0) -> tuple[list[PlannedManoeuvre], list[Unreachable]]:
    """Plan one run of grid points; split it in two when no single chirp reaches it (a narrower sweep puts
    more power per frequency)."""
    reasons = tuple(dict.fromkeys(REASON_WORDS.get(why[i], why[i]) for i in run))
    design = _design(c, run, reasons, opts, index)
    if design.manoeuvre is not None:
        return [design.manoeuvre], []
    if len(run) >= 2 and depth < 3:
        middle = math.sqrt(c.w[run[0]] * c.w[run[-1]])
        half = min(max(1, int(np.searchsorted(c.w[run], middle))), len(run) - 1)
        first, gone_a = _plan_run(c, run[:half], why, opts, index, depth + 1)
        second, gone_b = _plan_run(c, run[half:], why, opts, index + len(first), depth + 1)
        if first or second:
            return first + second, gone_a + gone_b
    band = (float(c.w[run[0]]), float(c.w[run[-1]]))
    if math.isinf(design.needed_rad) and design.limit == "slow":
        slow = SLOW_SWEEP * 2.0 / float(c.detector["energy_window_s"])
        reason = (
            f"too slow for the sweep detector: below {slow:.2g} rad/s it follows a sweep on the surface for "
            f"{LOOKBACK_S:g} s at most, too short a record for {band[0]:.3g} rad/s; log the injected signal "
            "as "
            f"channels.{c.name}.excitation (or a trigger), or raise estimator.energy_window_s"
        )
    elif math.isinf(design.needed_rad):
        reason = (
            f"no chirp of up to {opts.max_sweep_s:g} s x {opts.max_repeats} counts there (too short for the "
            f"estimator's records at these frequencies)"
        )
    else:
        reason = (
            f"amplitude cap: the {design.limit} needs {design.needed_rad:.3g} rad "
            f"({math.degrees(design.needed_rad):.2g} "
            f"deg) even with {opts.max_repeats} sweeps of {opts.max_sweep_s:g} s, above the cap of "
            f"{c.cap:.3g} rad "
            f"({c.cap_reason}); raise --max-amplitude-rad, or fly in calmer air"
        )
    return [], [Unreachable(c.name, band, reason)]


def _merge(c: _Channel, runs: list[list[int]]) -> list[list[int]]:
    """Neighbouring runs whose swept bands (with the first margins) overlap are flown as one sweep."""
    merged: list[list[int]] = []
    for run in runs:
        if merged and c.w[run[0]] / SWEEP_MARGINS[0][0] <= c.w[merged[-1][-1]] * SWEEP_MARGINS[0][1]:
            merged[-1] = merged[-1] + run
            continue
        merged.append(run)
    return merged


# ------------------------------------------------------------------------------------------------ the card
def plan_card(config: ValidationConfig, results: dict | None = None, options: PlanOptions | None = None,
              source: str = "results") -> TestCard:
    """The test card: per channel, the manoeuvres that bring every frequency without a verdict to the target.

    Parameters
    ----------
    config : ValidationConfig
        The config (models, grids, estimator options).
    results : dict, optional
        A replay's results JSON (``replay --json``, the node's ``~/save_results``). None: a first flight,
        planned from the model and the noise assumptions of ``options`` over each channel's whole grid.
    options : PlanOptions, optional
        Target, cap, rates and the card's shape.
    source : str
        The results file's name (messages).

    Returns
    -------
    TestCard

    Raises
    ------
    ConfigError
        A bad option.
    DataError
        Results that are not of this config (:func:`check_results`).
    """
    opts = (options or PlanOptions()).check()
    if results is not None:
        check_results(results, config, source)
    channels: dict[str, ChannelPlan] = {}
    index, first_flights = 0, 0
    for name, ch in config.channels.items():
        plan = ChannelPlan(name)
        channels[name] = plan
        if ch.is_mimo:
            plan.notes.append(f"{name}: a MIMO channel: not planned (plan its inputs as SISO channels)")
            continue
        data = None if results is None else results["channels"].get(name)
        c = _channel_base(name, ch)
        _resolution(c, data, opts)
        if results is not None and data is None:
            c.notes.append(
                f"{name}: not in the results (not flown?): planned as a first flight, from the model"
            )
        if data is None or not _from_results(c, data, opts):
            if data is not None:                 # nothing estimated: start afresh with the model's levels
                c = _channel_base(name, ch)
                _resolution(c, data, opts)
                c.notes.append(
                    f"{name}: nothing estimated in the results ({data.get('message') or 'no sweep'}): "
                    f"planned as a first flight, from the model"
                )
            _first_flight(c, opts)
            first_flights += 1
        plan.amplitude_cap_rad, plan.amplitude_cap_reason, plan.verdicts = c.cap, c.cap_reason, c.verdicts
        plan.notes.extend(c.notes)
        why = dict(c.targets)
        for i, reason in c.unreachable:
            plan.unreachable.append(Unreachable(name, (float(c.w[i]), float(c.w[i])), reason))
        plan.unreachable = _join_unreachable(plan.unreachable, c.w)
        for run in _merge(c, _runs(sorted(why))):
            done, gone = _plan_run(c, run, why, opts, index)
            plan.manoeuvres.extend(done)
            plan.unreachable.extend(gone)
            index += len(done)
        if not c.targets and not c.unreachable:
            plan.notes.append(f"{name}: nothing to fly: every frequency has a verdict")
    rule = (
        f"random error {opts.target_error:g} at every planned frequency (--target-error)"
        if opts.target_error
        else f"what a verdict at epsilon {EPSILON_THRESHOLD:g} needs: a mismatch at the threshold "
             f"{SIGMA_FACTOR:g} "
        f"noise scales out (with the {100 * BIAS_ERROR:g} % systematic floor), about "
        f"{verdict_error(EPSILON_THRESHOLD, DESIGN_DOF):.3f} on {DESIGN_DOF:g} degrees of freedom; planned "
        f"{opts.margin:g} x below it"
    )
    return TestCard(channels, "config" if results is None else "results", rule,
                    _assumptions(results is None, opts, first_flights > 0))


def _resolution(c: _Channel, data: dict | None, opts: PlanOptions) -> None:
    """What the logs resolve: a quarter of ``--log-rate-hz`` and the results' ``resolved_rad_s`` (the
    estimator's own limit from the streams it read), the lower of the two. Without either a sweep may be
    planned past it: a 36 rad/s target swept to 130 rad/s on 50 Hz surface logs (78.5 rad/s) was called
    broadband, not a chirp, and gave nothing."""
    if opts.log_rate_hz is not None:
        c.resolved_rad_s = 2.0 * math.pi * RESOLVED_FRACTION * opts.log_rate_hz
    resolved = (data or {}).get("resolved_rad_s")           # a positive number or None (check_results)
    if resolved is not None:
        c.resolved_rad_s = min(c.resolved_rad_s, float(resolved))


def _join_unreachable(items: list[Unreachable], w: np.ndarray) -> list[Unreachable]:
    out: list[Unreachable] = []
    for item in items:
        if out and out[-1].reason == item.reason:
            out[-1] = Unreachable(item.channel, (out[-1].band_rad_s[0], item.band_rad_s[1]), item.reason)
        else:
            out.append(item)
    return out


def _from_results(c: _Channel, data: dict, opts: PlanOptions) -> bool:
    """Fill the channel from its results; False (with a note) when nothing was estimated."""
    w = _array(data.get("frequency_rad_s"))
    if w.size == 0:
        return False
    if w.size != c.w.size or not np.allclose(w, c.w):        # the flown grid, cut to the excited band
        c.w = w
        c.model_mag = np.abs(np.asarray(c.model.freqresp(w), dtype=complex)).ravel()
    c.error_now = _array(data.get("random_error"))
    c.error_now[~np.isfinite(c.error_now)] = np.nan
    measured = data.get("measured") or {}
    mag = 10.0 ** (_array(measured.get("magnitude_db")) / 20.0)
    if mag.size != c.w.size:
        mag = np.full(c.w.shape, np.nan)
    c.coherence_threshold = float(data.get("coherence_threshold") or c.coherence_threshold)
    c.notes.append(_trim_levels(c, data, opts))
    sums1, notes, shared = _rebuild_flight(c, data, opts)
    c.notes.extend(notes)
    nh = int(c.spectra["order"]) + 1
    dof_pred = np.maximum(sums1.dof - nh, 0.0)
    dof = _array(data.get("degrees_of_freedom"), 0.0)
    q = noise_ratio(c.error_now, sums1.ff)
    seen_mag = np.abs(expected_estimate(sums1, c.w, float(c.spectra["band_fraction"]), _response(c.model))[0])
    seen = np.isfinite(c.error_now) & (dof > 0)
    if seen.any():
        agree = int(np.count_nonzero(np.abs(dof_pred[seen] - dof[seen]) <= 0.25 * np.maximum(dof[seen], 4)))
        c.notes.append(
            f"{c.name}: the rebuilt manoeuvres give the flight's degrees of freedom (within 25 %) at {agree} "
            f"of {int(seen.sum())} estimated frequencies"
        )
    band = data.get("excited_band_rad_s") or [c.w.min(), c.w.max()]
    core = (c.w >= float(band[0]) * EDGE_CORE) & (c.w <= float(band[1]) / EDGE_CORE)
    agrees = np.abs(dof_pred - dof) <= 0.25 * np.maximum(dof, 4.0)
    trim = _trim_spectra(c, data)
    c.trim_noise = _trim_output_error(c, data, trim)
    _fill_noise(c, q, dof, mag, seen_mag, core & agrees, _output_trim_noise(c, data), shared, sums1.ff)
    _trim_floor(c, trim)
    _targets(c, data)
    _cap(c, data, opts)
    return bool(np.isfinite(c.sigma2).any())


def _cap(c: _Channel, data: dict, opts: PlanOptions) -> None:
    """The amplitude cap: the smaller of ``--max-amplitude-rad`` and the largest deflection flown, the
    smallest flown where the response depended on the amplitude."""
    amps = _array(data.get("input_amplitudes"))
    amps = amps[np.isfinite(amps) & (amps > 0)]
    peaks = []
    for k in data.get("time_domain") or []:
        u = _array(k.get("input"), 0.0)
        n0 = int(k.get("trim_samples") or 0)
        if u.size:
            peaks.append(float(np.max(np.abs(u - (np.mean(u[:n0]) if n0 else u[0])))))
    seen = max([*amps.tolist(), *peaks], default=math.nan)
    if data.get("nonlinearity") and amps.size:
        c.cap, c.cap_reason = (
            float(np.min(amps)),
            (
                f"the smallest sweep amplitude flown: the response depends on the "
                f"amplitude ({data['nonlinearity']})"
            ),
        )
    elif math.isfinite(seen):
        c.cap, c.cap_reason = seen, "the largest deflection flown"
    else:
        c.cap, c.cap_reason = (
            FlightOptions.sweep_amplitude_rad,
            "nothing flown: the simulator's sweep amplitude",
        )
    if opts.max_amplitude_rad is not None and opts.max_amplitude_rad < c.cap:
        c.cap, c.cap_reason = float(opts.max_amplitude_rad), "--max-amplitude-rad"


def _first_flight(c: _Channel, opts: PlanOptions) -> None:
    """A channel never flown: the model's response and the assumed noise over the whole grid."""
    # low-pass PSD at 0 [/Hz]
    g = 4.0 * math.sqrt(2.0) * opts.noise_rms_rad_s ** 2 / opts.noise_corner_rad_s
    gust = g / (1.0 + (c.w / opts.noise_corner_rad_s) ** 4)
    gyro = 2.0 * opts.gyro_noise_rad_s ** 2 / opts.gyro_rate_hz
    sigma2 = (gust + gyro) / (2.0 * c.dt)                # noise per bin of the estimator's normalised DFT
    c.sigma2, c.mag_ratio = sigma2, np.ones(c.w.shape)
    c.error_now = np.full(c.w.shape, np.nan)
    c.notes.append(_trim_levels(c, None, opts))
    c.targets = [
        (i, "first_flight")
        for i in range(c.w.size)
        if c.w[i] * (1 + float(c.spectra["band_fraction"])) <= c.resolved_rad_s
    ]
    c.unreachable = [(i, _resolution_reason(c)) for i in range(c.w.size) if i not in dict(c.targets)]
    if opts.max_amplitude_rad is not None:
        c.cap, c.cap_reason = float(opts.max_amplitude_rad), "--max-amplitude-rad"
    else:
        c.cap, c.cap_reason = (
            FlightOptions.sweep_amplitude_rad,
            "nothing flown yet: the simulator's sweep amplitude",
        )


def _assumptions(first: bool, opts: PlanOptions, some_first: bool = False) -> list[str]:
    out = [
        "predicted errors are for the planned card replayed on its own; replayed with the flight already "
        "flown the "
        "records pool and the error is lower where the noise is the same",
        "the noise is the first flight's: the output's own spectrum, smoothed over frequency and continued "
        "with its "
        "slope beyond the frequencies estimated, plus the surface's trim motion seen through the response: "
        "fly in "
        "the same air"
        if not first
        else "fly in air like the assumed",
        "each chirp is a log sweep with half-cosine fades, flown at the surface (an actuator lag or a "
        "feedback loop "
        "changes the input power the estimator sees: log the surface, or the injected signal as the "
        "channel's "
        "excitation)",
    ]
    if first or some_first:
        out.insert(
            0,
            f"{'first flight from the config alone' if first else 'channels not estimated yet'}: output "
            f"disturbance {opts.noise_rms_rad_s:g} rad/s rms below "
            f"{opts.noise_corner_rad_s:g} rad/s (second-order roll-off), gyro noise "
            f"{opts.gyro_noise_rad_s:g} "
            f"rad/s at {opts.gyro_rate_hz:g} Hz, surface noise {opts.surface_noise_rad:g} rad (the "
            f"simulator's defaults); the model's |H| sets the signal",
        )
    if opts.log_rate_hz is None:
        out.append(
            "log rates not given (--log-rate-hz): what the logs resolve is the results' resolved_rad_s "
            "(results written before it: only the frequencies they call above_resolution; a config alone: "
            "not known)"
        )
    return out


# ------------------------------------------------------------------------------------------------ autopilots
@dataclass(frozen=True)
class ParameterBlock:
    """One manoeuvre in an autopilot's parameters.

    Attributes
    ----------
    manoeuvre : PlannedManoeuvre
        The manoeuvre.
    values : dict
        Parameter name -> value, each inside its documented range (empty when it does not fit).
    comment : str
        What it flies (and, when ``values`` is empty, why it does not fit), one line.
    notes : tuple of str
        What the parameters do not carry (repeats, amplitude units), one line each.
    """

    manoeuvre: PlannedManoeuvre
    values: dict
    comment: str
    notes: tuple[str, ...] = ()


def _axis(config: ValidationConfig, channel: str) -> str | None:
    """``roll``, ``pitch`` or ``yaw`` of a channel: its output's body rate (x, y, z), else its name."""
    ch = config.channels[channel]
    field_ = (ch.output.field if ch.output is not None else "").lower()
    for suffix, axis in ((".x", "roll"), (".y", "pitch"), (".z", "yaw")):
        if field_.startswith("angular_velocity") and field_.endswith(suffix):
            return axis
    for axis in ("roll", "pitch", "yaw"):
        if axis in channel.lower():
            return axis
    return None


def _in_range(name: str, value: float, ranges: dict) -> None:
    low, high = ranges[name]
    check_number(
        value, name, Interval(low, high), expected=f"a value in [{low:g}, {high:g}] (its documented range)"
    )


def _block(m: PlannedManoeuvre, how: str, values: dict, ranges: dict, notes: tuple[str, ...] = (),
           problem: str | None = None) -> ParameterBlock:
    """The manoeuvre's block (head: what it closes, then ``how`` to fly it): its values when every one is
    inside its documented range in ``ranges`` and there is no ``problem``, else no values and the first
    reason."""
    head = (f"manoeuvre {m.index}: {m.channel}, closes {m.closes_rad_s[0]:.3g}-{m.closes_rad_s[1]:.3g} "
            f"rad/s; {how}")
    try:
        if problem:
            raise ConfigError(problem)
        for name, value in values.items():
            _in_range(name, value, ranges)
    except ConfigError as err:
        return ParameterBlock(m, {}, f"{head}: does not fit: {err}")
    return ParameterBlock(m, values, head, notes)


def ardupilot_parameters(card: TestCard, config: ValidationConfig,
                         throw_rad: dict[str, float] | None = None) -> list[ParameterBlock]:
    """ArduPilot's SystemID parameters per manoeuvre (injected at the mixer: the surface, as the model's
    input).

    ``SID_MAGNITUDE`` is the amplitude over the surface's deflection at full mixer output (``throw_rad``,
    default
    :data:`ARDUPILOT_THROW_RAD`); ``SID_T_REC`` is the card's sweep plus the two cycles at the start frequency
    ArduPilot flies first (fades inside). Every value
    is checked against :data:`ARDUPILOT_RANGES`; a manoeuvre that does not fit (an unknown axis, a magnitude
    beyond full deflection) gets no values and the reason.

    Parameters
    ----------
    card : TestCard
        The card.
    config : ValidationConfig
        The config (each channel's axis).
    throw_rad : dict, optional
        Channel -> surface deflection at full mixer output [rad].
    """
    blocks = []
    for m in card.manoeuvres:
        axis = _axis(config, m.channel)
        throw = (throw_rad or {}).get(m.channel, ARDUPILOT_THROW_RAD)
        how = f"fly it {m.repeats} time(s), {m.trim_between_s:g} s of trim between"
        if axis is None:
            blocks.append(_block(m, how, {}, ARDUPILOT_RANGES, problem="the channel's axis is unknown (no "
                                 "angular_velocity.x/y/z output, no roll/pitch/yaw in its name)"))
            continue
        f_start = math.floor(m.f_start_hz * 1e4) / 1e4
        values = {"SID_AXIS": ARDUPILOT_MIXER_AXIS[axis], "SID_MAGNITUDE": round(m.amplitude_rad / throw, 4),
                  "SID_F_START_HZ": f_start, "SID_F_STOP_HZ": math.ceil(m.f_stop_hz * 1e4) / 1e4,
                  "SID_T_FADE_IN": m.fade_in_s, "SID_T_REC": round(m.duration_s + DWELL_CYCLES / f_start, 2),
                  "SID_T_FADE_OUT": m.fade_out_s}
        short = (f"SID_T_REC {values['SID_T_REC']:g} s is not longer than 2 / SID_F_START_HZ"
                 if not values["SID_T_REC"] > DWELL_CYCLES / values["SID_F_START_HZ"] else None)
        blocks.append(
            _block(
                m,
                how,
                values,
                ARDUPILOT_RANGES,
                problem=short,
                notes=(
                    f"SID_MAGNITUDE {values['SID_MAGNITUDE']:g} = {m.amplitude_rad:.4g} rad over a "
                    "full-mixer deflection of "
                    f"{throw:.4g} rad ({math.degrees(throw):.3g} deg; --surface-throw-deg)",
                    f"SID_T_REC = the card's {m.duration_s:.4g} s sweep + ArduPilot's two cycles at "
                    "SID_F_START_HZ "
                    f"({DWELL_CYCLES / f_start:.3g} s) flown first; log SIDD.Targ as "
                    f"channels.{m.channel}.excitation so the "
                    f"estimator finds the slow start",
                ),
            )
        )
    return blocks


def px4_parameters(card: TestCard, config: ValidationConfig) -> list[ParameterBlock]:
    """PX4 fixed-wing autotune's system-identification parameters per manoeuvre, where they fit.

    The band (``FW_AT_SYSID_F0``/``F1``, 0.1-30 Hz in steps of 0.1 Hz, rounded outwards), the sweep length
    (``FW_AT_SYSID_TIME``, 5-120 s), the log sweep (``FW_AT_SYSID_TYPE`` 2), the axis (``FW_AT_AXES``) and
    logging only (``FW_AT_APPLY`` 0). What does not fit: the amplitude (``FW_AT_SYSID_AMP`` scales a *rate
    setpoint*, not the surface: the autotune flies the sweep through the rate controller, so log it and give
    the channel an ``excitation`` stream), the repeats (start the autotune once per sweep) and a band below
    0.1 Hz or above 30 Hz (no values then). Checked against :data:`PX4_RANGES`.

    Parameters
    ----------
    card : TestCard
        The card.
    config : ValidationConfig
        The config (each channel's axis).
    """
    blocks = []
    for m in card.manoeuvres:
        axis = _axis(config, m.channel)
        f0, f1 = math.floor(m.f_start_hz * 10) / 10, math.ceil(m.f_stop_hz * 10) / 10
        values = {"FW_AT_SYSID_F0": f0, "FW_AT_SYSID_F1": f1, "FW_AT_SYSID_TIME": float(round(m.duration_s)),
                  "FW_AT_SYSID_TYPE": 2, "FW_AT_AXES": PX4_AXIS_BIT.get(axis or "", 0), "FW_AT_APPLY": 0}
        blocks.append(
            _block(
                m,
                f"start the autotune {m.repeats} time(s)",
                values,
                PX4_RANGES,
                problem="the channel's axis is unknown" if axis is None else None,
                notes=(
                    "FW_AT_SYSID_AMP not set: it scales the rate setpoint the autotune injects, not the "
                    "surface; set it so the "
                    f"surface moves about {m.amplitude_rad:.3g} rad, log the injected signal and give "
                    f"channels.{m.channel}."
                    f"excitation (the sweep is flown in closed loop)",
                    "no dwell and no fades in PX4's sweep (signal_generator.hpp): the band's margins cover "
                    "its ends",
                ),
            )
        )
    return blocks
