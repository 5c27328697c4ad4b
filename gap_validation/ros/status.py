"""What each channel's ``DiagnosticStatus`` says, without ROS types: levels, wording, values.

diagnostic_updater style: one :class:`ChannelTask` per channel owns what the node saw of that channel (when
its input and output last brought a sample, the top candidate of the last full diagnosis)
and :meth:`ChannelTask.run` fills its :class:`ChannelStatus`; the node names it ``<node name>: <channel>`` and
turns those into a ``DiagnosticArray``. No rclpy import.

Level (STALE means "the inputs are silent", as diagnostic_aggregator reads it; nothing else is STALE):

* STALE before any data (message "waiting for data on ..."), when a topic's type is still being discovered,
  and when the input or output had no sample for ``stale_timeout`` s (the last numbers stay in the values).
* OK while data flow and no sweep has completed yet ("receiving data, waiting for a sweep (no estimate yet)";
  ``epsilon`` null): nothing is wrong, there is nothing to judge yet. On a test card that sweeps one axis at a
  time the other channels wait OK, so an aggregator group does not turn ERROR for some STALE items.
* WARN when sweeps were flown but no frequency reached the coherence threshold (data-limited: fly better
  sweeps), or when ``warn_epsilon <= epsilon < error_epsilon``.
* ERROR when ``epsilon >= error_epsilon``; OK below ``warn_epsilon`` (thresholds of
  :mod:`gap_validation.core.margins`, eq. 16).
* A publisher that cannot reach the subscription (QoS or
  type, :func:`gap_validation.ros.intake.publisher_note`) is named first in the message: ERROR while its topic
  brings no data (the channel cannot be validated until the setting is fixed), at least WARN otherwise.

Values are strings under the JSON key names (``nu_gap``, ``epsilon``, ``epsilon_raw``, ``epsilon_previous``,
``gain_margin_db``, ``phase_margin_deg``, ``disk_margin``, ``worst_frequency_rad_s``, ``sweeps``,
``limited_by``, ``points_excluded``, ``bad_samples`` (total; ``bad_samples_by_reason`` has the JSON dict),
``diagnosis`` (top candidate sentence; ``pending`` before the first fit, ``none`` when no effect helps,
``off`` when disabled), ``diagnosis_effects`` (the JSON list to append to the model's effects),
``samples_input``/``samples_output``, ``samples_dropped`` ...). ``samples_dropped`` counts the messages
missing from the channel's topics, inferred from gaps in their ``header.stamp``
(:class:`~gap_validation.ros.stamp_gaps.StampGaps`; DDS does not tell the node when a queue overflows; topics
without a header are not counted). Numbers are Python ``repr`` (round-trip exact); missing numbers are
``null`` (margins for epsilon >= 1: no guarantee).
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any, Callable, Collection, Mapping, Sequence

import numpy as np

from gap_validation.core import wording
from gap_validation.core.config import ChannelConfig
from gap_validation.core.margins import STANDARD_EPSILON, WARN_EPSILON
from gap_validation.core.plottable import frequency_response_table
from gap_validation.core.results import Candidate, ChannelResult
from gap_validation.messages.router import MessageRouter

__all__ = [
    "ChannelStatus",
    "ChannelTask",
    "channel_status",
    "candidate_sentence",
    "verdict_mapping",
    "STREAMS",
    "VERDICT_KEYS",
    "PlotChanges",
]

_JSON_VALUES = ("nu_gap", "epsilon", "epsilon_raw", "epsilon_previous", "gain_margin_db", "phase_margin_deg",
                "disk_margin", "worst_frequency_rad_s", "sweeps", "limited_by", "points_excluded")
#: The streams whose silence makes a channel STALE.
STREAMS = ("input", "output")


def _value_text(value: Any) -> str:
    """A status value string: ``repr`` of numbers (round-trip exact), ``null`` for None, JSON otherwise."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return value
    return json.dumps(value, sort_keys=True)


#: A diagnosis candidate on one line (:func:`gap_validation.core.wording.candidate_line`).
candidate_sentence = wording.candidate_line

_ORDER = ("OK", "WARN", "ERROR")


def _level_for(epsilon: float, warn_epsilon: float, error_epsilon: float) -> str:
    if epsilon >= error_epsilon:
        return "ERROR"
    return "WARN" if epsilon >= warn_epsilon else "OK"


@dataclass
class ChannelStatus:
    """What one ``DiagnosticStatus`` says, without ROS types: level name, message and string values."""

    channel: str
    level: str
    message: str
    values: list[tuple[str, str]] = field(default_factory=list)


def channel_status(result: ChannelResult, *, warn_epsilon: float = WARN_EPSILON,
                   error_epsilon: float = STANDARD_EPSILON,
                   stale_reason: str | None = None, waiting_reason: str | None = None,
                   candidate: Candidate | dict | None = None, diagnosis_state: str = "pending",
                   extra_values: dict | None = None, notes: Sequence[str] = (),
                   nonlinearity: str | None = None) -> ChannelStatus:
    """The status of one channel from its (cheap) result.

    Parameters
    ----------
    result : ChannelResult
        ``OnlineValidator.results(diagnose=False)`` of the channel.
    warn_epsilon, error_epsilon : float
        Level thresholds on the averaged epsilon (eq. 14).
    stale_reason : str, optional
        Why the inputs count as stopped ("no data for 4.2 s on /imu (output)"): level STALE, numbers kept.
    waiting_reason : str, optional
        Why there is no data yet ("waiting for data on /imu (output)"): level STALE.
    candidate : Candidate or dict, optional
        Top diagnosis candidate of the last full diagnosis (or its JSON object, a ``diagnosis`` entry).
    diagnosis_state : {"pending", "done", "off"}
        Whether a full diagnosis has been run for the current model.
    extra_values : dict, optional
        More values appended (e.g. sample ages).
    notes : sequence of str
        Publishers that cannot reach the channel's subscriptions (``publisher on /imu offers
        BEST_EFFORT; ...``): first in the message; ERROR with ``waiting_reason`` or ``stale_reason``, else at
        least WARN.
    nonlinearity : str, optional
        The last full diagnosis' amplitude-dependence verdict (JSON ``nonlinearity``; value ``nonlinearity``,
        empty when none was found or no diagnosis ran).

    Returns
    -------
    ChannelStatus
    """
    if isinstance(candidate, dict):
        candidate = Candidate.from_json_dict(candidate)
    data = result.headline_json_dict()      # the values below, without the per-frequency lists
    values = [(key, _value_text(data.get(key))) for key in _JSON_VALUES]
    bad = dict(result.bad_samples)
    values.append(("bad_samples", str(int(sum(bad.values())))))
    values.append(("bad_samples_by_reason", json.dumps(bad, sort_keys=True)))
    cand_text = candidate_sentence(candidate)
    if diagnosis_state == "off":
        diagnosis_value = "off"
    elif candidate:
        diagnosis_value = cand_text
    else:
        diagnosis_value = "none" if diagnosis_state == "done" else "pending"
    values.append(("diagnosis", diagnosis_value))
    values.append(("diagnosis_effects", json.dumps(candidate.effects if candidate else [])))
    values.append(("diagnosis_epsilon", _value_text(candidate.epsilon if candidate else None)))
    values.append(("nu_gap_frequency_rad_s", _value_text(data.get("nu_gap_frequency_rad_s"))))
    values.append(("coherence_threshold", _value_text(result.coherence_threshold)))
    values.append(("model_description", result.model_description))
    values.append(("warnings", json.dumps(list(result.warnings))))
    values.append(("margins_guaranteed", "true" if result.margins_guaranteed else "false"))
    values.append(("margins_note", result.margins_text() or ""))
    values.append(("nonlinearity", nonlinearity or result.nonlinearity or ""))
    values.append(("conventions", json.dumps([c.to_json_dict() for c in result.conventions])))
    values.append(("within_tolerance", json.dumps(data.get("within_tolerance"))))
    values.append(("dynamic_pressure_ratio", json.dumps(data.get("dynamic_pressure_ratio"))))
    values.append(("rate_leads_surface", json.dumps(data.get("rate_leads_surface"))))
    for key, value in (extra_values or {}).items():
        values.append((key, _value_text(value)))

    if result.epsilon is not None:
        level = _level_for(result.epsilon, warn_epsilon, error_epsilon)
    elif result.mimo is not None and result.nu_gap is not None:
        # a MIMO channel: epsilon is a SISO notion; its level follows the MIMO nu-gap (kappa <= epsilon)
        level = _level_for(result.nu_gap, warn_epsilon, error_epsilon)
    elif result.sweeps > 0:
        level = "WARN"
    else:
        level = "OK"
    summary = wording.status_summary(result, level, cand_text)
    # a sign, units, the body frame or a clock (issue 23): WARN at once, the fix first
    if result.conventions:
        level = max(level, "WARN", key=_ORDER.index)
        summary = f"{result.conventions[0].sentence}: {level}"
    noted = "; ".join(notes)
    if waiting_reason:
        resumed = f" (resumed: {summary})" if result.epsilon is not None else ""
        if noted:
            return ChannelStatus(result.name, "ERROR", f"{noted}; {waiting_reason}{resumed}", values)
        return ChannelStatus(result.name, "STALE", waiting_reason + resumed, values)
    if stale_reason:
        last = f"; last: {summary}" if result.epsilon is not None or result.sweeps > 0 else ""
        if noted:
            return ChannelStatus(result.name, "ERROR", f"{noted}; {stale_reason}{last}", values)
        return ChannelStatus(result.name, "STALE", stale_reason + last, values)
    if noted:
        return ChannelStatus(result.name, max(level, "WARN", key=_ORDER.index), f"{noted}; {summary}", values)
    return ChannelStatus(result.name, level, summary, values)


#: The status values a channel's ``~/<channel>/verdict`` carries (numbers as numbers, lists as lists): what
#: the model is worth, not the ages and counts that change with every message.
VERDICT_KEYS = _JSON_VALUES + (
    "nu_gap_frequency_rad_s",
    "diagnosis",
    "diagnosis_effects",
    "diagnosis_epsilon",
    "margins_guaranteed",
    "margins_note",
    "warnings",
    "nonlinearity",
    "conventions",
    "within_tolerance",
)


def verdict_mapping(status: ChannelStatus) -> dict:
    """The channel's verdict as one mapping: ``channel``, ``level``, ``message`` and the :data:`VERDICT_KEYS`
    values of its status, read back from their text (``null`` -> None, numbers, JSON lists)."""
    values = dict(status.values)
    out: dict = {"channel": status.channel, "level": status.level, "message": status.message}
    for key in VERDICT_KEYS:
        text = values.get(key)
        if text is None:
            continue
        try:
            out[key] = json.loads(text) if text[:1] in "[{-0123456789" or text in ("null", "true", "false") \
                else text
        except ValueError:
            out[key] = text
    return out


class PlotChanges:
    """What a channel's plottable topics must send (docs/NODE_TOPICS.md): its curves table and its verdict,
    each only when it differs from the last sent (the node's ``~/<channel>/...`` and
    ``replay --annotate``)."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[Any, str | None]] = {}
        self._inputs: dict[str, tuple] = {}      # channel -> what its last table was made of

    @staticmethod
    def _table_inputs(result: ChannelResult, channel: ChannelConfig) -> tuple:
        """Everything :func:`frequency_response_table` reads, bit for bit (between two manoeuvres the pooled
        estimate does not change, nor does the table: it is not made again)."""
        def bits(values: Any) -> Any:
            if values is None:
                return None
            array = np.asarray(values)
            return array.dtype.str, array.shape, array.tobytes()

        arrays = (result.frequency_rad_s, result.measured, result.model, result.coherence,
                  result.epsilon_per_frequency, result.kappa, result.random_error)
        return (getattr(channel, "is_mimo", False), channel.frequencies, result.name,
                tuple(bits(a) for a in arrays), tuple(result.frequency_flags))

    def changed(
        self, result: ChannelResult, channel: ChannelConfig, status: ChannelStatus
    ) -> tuple[Any, str | None]:
        """``(table or None, verdict JSON or None)``: what changed since the last call for this channel.

        Parameters
        ----------
        result : ChannelResult
            The channel's result.
        channel : ChannelConfig
            Its config (the grid).
        status : ChannelStatus
            Its status (the verdict).
        """
        inputs = self._table_inputs(result, channel)
        # the same inputs make the same table as the last call's: that one was sent or equal to the last sent
        table = None
        if self._inputs.get(status.channel) != inputs:
            table = frequency_response_table(result, channel)
            self._inputs[status.channel] = inputs
        verdict = json.dumps(verdict_mapping(status), sort_keys=True)
        last_table, last_verdict = self._last.get(status.channel, (None, None))
        new_table = table if table is not None and (
            last_table is None or not np.array_equal(table, last_table, equal_nan=True)) else None
        new_verdict = verdict if verdict != last_verdict else None
        self._last[status.channel] = (last_table if new_table is None else new_table, verdict)
        return new_table, new_verdict

    def forget(self, channel: str) -> None:
        """The channel left the config."""
        self._last.pop(channel, None)
        self._inputs.pop(channel, None)


class ChannelTask:
    """The diagnostic task of one channel: what the node saw of it, and the status it fills.

    Parameters
    ----------
    name : str
        Channel name.
    channel : ChannelConfig
        Its config (topics of its streams); :attr:`channel` is replaced on a config reload.

    Attributes
    ----------
    last_seen : dict
        Stream -> node time [s] of the arrival that last brought the stream a sample (the transport's
        reception time: the age of the data).
    noticed : dict
        Stream -> node time [s] at which the node took the message that last brought the stream a sample (the
        end of the run is silence the node heard: a node stalled while messages waited in its queues takes
        them late, their reception times are old, yet the data never stopped).
    top : Candidate or None
        Top candidate of the last full diagnosis taken for the current model.
    diagnosed : bool
        Whether a full diagnosis has been taken for the current model.
    nonlinearity : str or None
        That diagnosis' amplitude-dependence verdict (value ``nonlinearity``).
    diagnosis_warnings : list of str
        That diagnosis' result's warnings (those the cheap result lacks join the status's ``warnings``).
    diagnosis_caveat : str
        That diagnosis' margins caveat (the status's ``margins_guaranteed``, ``margins_note``).
    within_tolerance : ConstantFactor or None
        That diagnosis' constant factor resolved within the tolerance (value ``within_tolerance``).
    """

    def __init__(self, name: str, channel: ChannelConfig):
        self.name = name
        self.channel = channel
        self.last_seen: dict[str, float] = {}
        self.noticed: dict[str, float] = {}
        self._seen_count: dict[str, int] = {}
        self.top: Candidate | None = None
        self.diagnosed = False
        self.nonlinearity: str | None = None
        self.diagnosis_warnings: list[str] = []
        self.diagnosis_caveat = ""
        self.within_tolerance = None
        self._run_open = False

    def run_ended(self, now_s: float, timeout_s: float) -> bool:
        """True once when every stream of the channel has been silent for ``timeout_s`` since the node counted
        its last sample (:attr:`noticed`, not the reception time of a message taken late): the run of data
        ended (landing, a stopped bag), so the manoeuvre in progress can be closed, as the estimator would
        when the next sample came after the gap.

        Parameters
        ----------
        now_s : float
            Node time [s].
        timeout_s : float
            Silence that ends the run [s] (the node's ``end_of_data_timeout``).
        """
        if not self._run_open or len(self.noticed) < len(self.streams):
            return False
        if all(now_s - seen > timeout_s for seen in self.noticed.values()):
            self._run_open = False
            return True
        return False

    @property
    def topics(self) -> list[str]:
        """The topics of the channel's input and output, sorted."""
        return sorted({self.channel.signal(stream).topic for stream in self.streams})

    @property
    def streams(self) -> tuple[str, ...]:
        """The channel's streams watched for data: :data:`STREAMS`, or a MIMO channel's ``inputs[j]`` and
        ``outputs[i]``."""
        if getattr(self.channel, "is_mimo", False):
            return self.channel.input_streams + self.channel.output_streams
        return STREAMS

    def new_router(self) -> None:
        """The node's router was replaced (reload, reset): its sample counts start again."""
        self._seen_count = {}

    def take_diagnosis(self, candidate: Candidate | None, nonlinearity: str | None = None,
                       warnings: Sequence[str] = (), margins_caveat: str = "", within_tolerance=None) -> None:
        """A full diagnosis finished for the current model; ``candidate`` is its top (None: no effect helps).

        Parameters
        ----------
        candidate : Candidate or None
            The top candidate.
        nonlinearity : str, optional
            Its amplitude-dependence verdict (sweeps at different amplitudes disagree), None when not found.
        warnings : sequence of str
            The full result's warnings: those the diagnosis adds (e.g. the diagnosed model failing the
            winding-number condition) join the cheap result's in :meth:`run`, as in replay's result.
        margins_caveat : str
            The full result's margins caveat (the same).
        within_tolerance : ConstantFactor, optional
            The full result's constant factor resolved within the tolerance (JSON ``within_tolerance``).
        """
        self.top, self.diagnosed, self.nonlinearity = candidate, True, nonlinearity
        self.diagnosis_warnings, self.diagnosis_caveat = list(warnings), margins_caveat
        self.within_tolerance = within_tolerance

    def forget_diagnosis(self) -> None:
        """The model or the spectra changed: the last diagnosis no longer holds."""
        self.top, self.diagnosed, self.nonlinearity = None, False, None
        self.diagnosis_warnings, self.diagnosis_caveat, self.within_tolerance = [], "", None

    def update_seen(self, router: MessageRouter, arrivals: Mapping[str, float], now_s: float,
                    taken: Mapping[str, float] | None = None) -> None:
        """Note which streams got new samples since the last call, stamped with their topic's last arrival
        (and the time the node took it).

        Parameters
        ----------
        router : MessageRouter
            Counts the samples of each stream.
        arrivals : mapping
            Topic -> node time [s] of its last message.
        now_s : float
            Node time [s] (for a topic without an arrival).
        taken : mapping, optional
            Topic -> node time [s] at which its last message was taken (default: ``now_s``).
        """
        taken = {} if taken is None else taken
        for stream in self.streams:
            count = router.samples(self.name, stream)
            if count > self._seen_count.get(stream, 0):
                topic = self.channel.signal(stream).topic
                self.last_seen[stream] = arrivals.get(topic, now_s)
                self.noticed[stream] = max(taken.get(topic, now_s), self.last_seen[stream])
                self._run_open = True
            self._seen_count[stream] = count

    def reasons(self, now_s: float, stale_timeout_s: float,
                pending: Collection[str] = ()) -> tuple[str | None, str | None, dict]:
        """(waiting reason, stale reason, age values) of the channel at node time ``now_s``.

        Parameters
        ----------
        now_s : float
            Node time [s].
        stale_timeout_s : float
            A stream without a sample for longer is stale [s].
        pending : collection of str
            Topics whose type is still being discovered.
        """
        waiting, stale, ages = [], [], {}
        for stream in self.streams:
            topic = self.channel.signal(stream).topic
            seen = self.last_seen.get(stream)
            if seen is None:
                known = "; type not known yet" if topic in pending else ""
                waiting.append(f"{topic} ({stream}{known})")
            else:
                age = max(0.0, now_s - seen)
                ages[f"{stream}_age_s"] = round(age, 3)
                if age > stale_timeout_s:
                    stale.append((age, f"{topic} ({stream})"))
        waiting_reason = f"waiting for data on {' and '.join(waiting)}" if waiting else None
        stale_reason = None
        if stale:
            age = max(a for a, _ in stale)
            stale_reason = f"no data for {age:.1f} s on {' and '.join(t for _, t in stale)}"
        return waiting_reason, stale_reason, ages

    def run(
        self,
        result: ChannelResult,
        now_s: float,
        router: MessageRouter,
        dropped: Callable[[str], int],
        *,
        stale_timeout_s: float,
        warn_epsilon: float = WARN_EPSILON,
        error_epsilon: float = STANDARD_EPSILON,
        pending: Collection[str] = (),
        diagnosis_off: bool = False,
        notes: Mapping[str, str] | None = None,
    ) -> ChannelStatus:
        """Fill the channel's status from its (cheap) result.

        Parameters
        ----------
        result : ChannelResult
            ``OnlineValidator.results(diagnose=False)`` of the channel.
        now_s : float
            Node time [s].
        router : MessageRouter
            Sample counts (``samples_input``, ``samples_output``).
        dropped : callable
            ``dropped(topic)``: messages missing from a topic (``samples_dropped``).
        stale_timeout_s : float
            Silence [s] after which a stream is stale.
        warn_epsilon, error_epsilon : float
            Level thresholds on the averaged epsilon.
        pending : collection of str
            Topics whose type is still being discovered.
        diagnosis_off : bool
            Full diagnoses are disabled.
        notes : mapping, optional
            Topic -> why a publisher on it cannot reach the subscription (those of the channel's topics are
            shown).
        """
        waiting, stale, ages = self.reasons(now_s, stale_timeout_s, pending)
        state = "off" if diagnosis_off else ("done" if self.diagnosed else "pending")
        added = [w for w in self.diagnosis_warnings if w not in result.warnings]
        if added or (self.diagnosis_caveat and not result.margins_caveat):   # what the full diagnosis adds
            result = dataclasses.replace(result, warnings=list(result.warnings) + added,
                                         margins_caveat=result.margins_caveat or (
                                             self.diagnosis_caveat if result.margins.guaranteed else ""))
        if self.within_tolerance is not None and result.within_tolerance is None:
            result = dataclasses.replace(result, within_tolerance=self.within_tolerance)
        mimo = getattr(self.channel, "is_mimo", False)
        extra = {
            **ages,
            "samples_input": sum(router.samples(self.name, s) for s in self.channel.input_streams)
            if mimo
            else router.samples(self.name, "input"),
            "samples_output": sum(router.samples(self.name, s) for s in self.channel.output_streams)
            if mimo
            else router.samples(self.name, "output"),
            "samples_dropped": sum(dropped(topic) for topic in self.topics),
        }
        mine = [notes[topic] for topic in self.topics if notes and notes.get(topic)]
        return channel_status(
            result,
            warn_epsilon=warn_epsilon,
            error_epsilon=error_epsilon,
            stale_reason=stale,
            waiting_reason=waiting,
            candidate=self.top,
            diagnosis_state=state,
            extra_values=extra,
            notes=mine,
            nonlinearity=self.nonlinearity,
        )
