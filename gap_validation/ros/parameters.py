"""Parameters of the node ``gap_validator``: names, defaults, ranges, documentation and checks (no rclpy).

``config/validator.params.yaml`` lists them with their
defaults; :class:`gap_validation.ros.node.ValidatorNode` declares :data:`PARAMETERS` with a
``ParameterDescriptor`` each (description, read-only flag, and a ``FloatingPointRange`` / ``IntegerRange``
from :attr:`Param.range`, so ``ros2 param describe`` shows them and rclpy refuses values outside), refuses
what :func:`check_parameters` refuses, and warns about parameter overrides that name no parameter
(:func:`unknown_parameters`: ``-p diagnostic_perid:=2`` is reported, with the likely meant
``diagnostic_period``, instead of being silently ignored).

config_file : str
    Validation config (YAML, DESIGN.md). Setting it at run time reloads the model (see "Live model update").
hardware_id : str, "" (the config's ``aircraft`` key, else the node's fully qualified name)
    ``hardware_id`` of every status (diagnostic_updater's ``setHardwareID``). Fixed at start-up: a model
    update (``config_file``, ``~/reload``) does not change it; setting the parameter does.
qos_reliability : {"auto", "reliable", "best_effort"}, "auto"
    Reliability of the subscriptions (read-only). ``auto`` matches what the publishers offer: RELIABLE when
    every publisher on the topic is reliable, BEST_EFFORT when any is best effort; while none is known the
    topic has both subscriptions, drained as one (nothing missed from the first message on, nothing taken
    twice). Re-checked every ``discovery_period``; a change re-subscribes make-before-break
    (:mod:`gap_validation.ros.intake`).
    ``reliable`` or ``best_effort`` fix it; a publisher the fixed choice cannot match is named in the
    channel's status ("publisher on /imu offers BEST_EFFORT; set qos_reliability to auto or best_effort").
qos_depth : int, 1000
    KEEP_LAST depth of every subscription (read-only): one second of a 1 kHz IMU.
intake_period : float, 0.05 s
    The subscriptions' queues are drained every ``intake_period`` (read-only): one wake-up takes every waiting
    message of every topic (``take`` in a loop), instead of one executor callback per message. Must leave room
    in the queue: ``intake_period * rate < qos_depth`` (50 messages of a 1 kHz IMU per drain).
diagnostic_period : float, 1.0 s
    Period of ``/diagnostics`` (read-only).
diagnosis_period : float, 10.0 s
    Shortest interval between two full diagnoses (effect fitting); 0 disables them.
diagnosis_cpu_share : float, 0.06
    Share of one core a full diagnosis may use: the worker sleeps between candidate fits to hold it (a
    channel's diagnosis of 1.6 s of CPU then takes 27 s, and never more than 0.6 s of any 10 s: with the
    node's 3-5 % of steady work, a 10 s window stays near 10 %, under the 15 % a companion computer's flight
    stack can spare); 0 or 1: as fast as it can.
stale_timeout : float, 3.0 s
    A channel whose input or output has had no sample for this long is STALE.
end_of_data_timeout : float, 10.0 s
    A channel whose input and output have both had no sample for this long has ended its run of data (landing,
    a stopped bag): its last manoeuvre is closed and counted, as replay closes it at the end of a bag. Longer
    than any pause of a live stream that resumes without a gap in its stamps (that would split a manoeuvre).
warn_epsilon, error_epsilon : float, 0.25 and 0.38
    Levels: epsilon < warn_epsilon is OK, < error_epsilon WARN, else ERROR. 0.38 is the paper's point of
    "standard stability margins of a 6 dB gain margin and a 45 deg phase margin" (Section III, eqs. 15-16:
    2 asin(0.38) = 44.7 deg): below it a controller with standard margins is guaranteed stable on the
    aircraft. 0.25 (4.4 dB, 29 deg guaranteed) warns before that point is reached.
state_file : str, "" (off)
    Checkpoint of the gathered spectra (:mod:`gap_validation.core.checkpoint`), written atomically every
    ``checkpoint_period`` s (in a worker thread, from a copy) and at shutdown; resumed from at start
    (read-only).
checkpoint_period : float, 5.0 s
    (read-only)
results_dir : str, "" (current directory)
    Where ``~/save_results`` writes.
discovery_period : float, 1.0 s
    Period of the graph check (read-only): publishers' QoS (``qos_reliability: auto``), and the type of topics
    whose type is neither in the config nor implied by their field paths.
raw_decoding : bool, true
    Subscribe to the serialized messages and read only the configured fields with the decoding step replay
    uses (:mod:`gap_validation.messages.decoding`: Imu, JointState, Float64/32, Bool; checked against rclpy's
    deserialisation on the first messages of each topic); other types are deserialised (read-only).
executor : {"events", "single_threaded"}, "events"
    Executor of the console script: rclpy's EventsExecutor where available (the SingleThreadedExecutor
    when ``use_sim_time`` is set, whose /clock-driven timers the EventsExecutor of Jazzy gets wrong). The
    console script drives either with ``spin_once`` in a loop (``EventsExecutor.spin()`` of rclpy 7.1 runs no
    timers and ignores SIGINT). Since messages are drained by a timer, both cost about the same.

plan_card : str, "" (plan from the node's own results)
    A card written by ``gap-validate plan --out`` (docs/PLAN.md): ``~/plan`` answers it and ``~/excite`` flies
    it. Without it ``~/plan`` plans from the node's current results (the JSON ``~/save_results`` would write,
    planned as ``gap-validate plan`` plans that file) and ``~/excite`` flies the card ``~/plan`` answered
    last. Setting it re-reads the card (a bad file is refused, one line).
excitation_enabled : bool, false
    Inject the card's manoeuvres (read-only). Off: the node only listens, and ``~/excite`` and ``~/abort`` do
    not exist. On: the node publishes surface offsets on ``excitation_topic`` at ``excitation_rate_hz`` (zeros
    between manoeuvres) and each flyable channel estimates against what the node injected (its ``excitation``,
    closed-loop estimation; :mod:`gap_validation.ros.injection`).
excitation_topic : str, "~/excitation"
    Where the offsets go (read-only): ``/gap_validator/excitation`` for the default node name. With
    ``excitation_type`` Float64 one topic per channel, ``<excitation_topic>/<channel>``.
excitation_type : {"sensor_msgs/msg/JointState", "std_msgs/msg/Float64"}, JointState
    Message of the offsets (read-only): a stamped JointState with one joint per surface, named as in the
    channel's input field (``position[elevator]`` -> ``elevator``), or an unstamped Float64 per channel (the
    node then stamps the samples with their reception time).
excitation_rate_hz : float, 50.0 Hz
    Rate of the offsets (read-only); the card's samples are ``manoeuvre_signal(manoeuvre,
    excitation_rate_hz)``.
excitation_max_amplitude_rad : float, 0.1 rad
    Hard cap on every published sample (|offset| <= cap; 0.1 rad = 5.7 deg). ``~/excite`` refuses a manoeuvre
    whose amplitude is above it (fly it clipped and it is no longer the card's); lowering it during a
    manoeuvre clips the samples from the next one on.
excite_channel : str, "" (any)
    The channel ``~/excite`` flies a manoeuvre of.
excite_index : int, -1 (the next)
    The card's manoeuvre ``~/excite`` flies (its ``index``); -1: the first, in the card's flying order (of
    ``excite_channel`` when set), not flown to its end yet. ``~/excite`` is a std_srvs/Trigger: the selection
    is in these two parameters (docs/PLAN.md, "The node flies it", says why).

CPU
---
At 1 kHz IMU and 100 Hz surfaces on three channels the node's own work (decoding, diagnostics, checkpoints,
diagnosis) is about 2-4 % of one core (``benchmarks/bench_node.py``). The whole process costs more: DDS
receives every message in its own threads (about 4 % here whatever the node does), and rclpy's executors cost
per callback (one callback per message gave 15 % with the EventsExecutor, 59 % with the
SingleThreadedExecutor). Hence the queues are drained by one timer (``intake_period``), which brings the whole
process under 8 % (docs/benchmarks.md), and ``raw_decoding`` reads the fields straight from the serialized
messages.

QoS choice
----------
KEEP_LAST with a deep queue (``qos_depth`` 1000) and VOLATILE: the usual sensor-data profile (depth 5) drops
samples as soon as the node is busy for a few milliseconds, and every lost sample is a gap in the spectra.
Reliability follows the publishers (``auto``): IMU drivers and PX4's bridge publish BEST_EFFORT, which a
RELIABLE subscription never receives.
"""
from __future__ import annotations

import difflib
from typing import Any, Iterable, NamedTuple

from gap_validation.core.errors import ConfigError
from gap_validation.core.margins import STANDARD_EPSILON, WARN_EPSILON

__all__ = [
    "Param",
    "PARAMETERS",
    "RELIABILITIES",
    "EXCITATION_TYPES",
    "JOINT_STATE",
    "FLOAT64",
    "check_parameters",
    "unknown_parameters",
]

#: Values of ``qos_reliability``.
RELIABILITIES = ("auto", "reliable", "best_effort")
JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
#: Values of ``excitation_type``.
EXCITATION_TYPES = (JOINT_STATE, FLOAT64)


class Param(NamedTuple):
    """One parameter: default (its type is the parameter's), read-only flag, description, range and
    choices."""

    default: Any
    read_only: bool
    description: str
    #: ``(from, to)`` inclusive, for numbers (``FloatingPointRange`` / ``IntegerRange`` of the descriptor).
    range: tuple[float, float] | None = None
    #: Allowed strings (``additional_constraints`` of the descriptor, checked by :func:`check_parameters`).
    choices: tuple[str, ...] | None = None


_DAY_S = 86400.0

#: The node's parameters. The params YAML mirrors these.
PARAMETERS: dict[str, Param] = {
    "config_file": Param("", False, "validation config (YAML); setting it reloads the model"),
    "hardware_id": Param(
        "",
        False,
        "hardware_id of the statuses (default: the config's 'aircraft' key, else the "
        "node's fully qualified name); a model update keeps it",
    ),
    "qos_reliability": Param(
        "auto",
        True,
        "auto (match the publishers: best effort if any is) | reliable | best_effort",
        choices=RELIABILITIES,
    ),
    "qos_depth": Param(1000, True, "KEEP_LAST depth of the subscriptions", range=(1, 1_000_000)),
    "intake_period": Param(
        0.05,
        True,
        "the subscriptions' queues are drained every intake_period [s] (keep "
        "intake_period * rate below qos_depth)",
        range=(0.001, 1.0),
    ),
    "diagnostic_period": Param(1.0, True, "period of /diagnostics [s]", range=(0.01, 3600.0)),
    "diagnosis_period": Param(
        10.0, False, "shortest interval between full diagnoses [s]; 0 disables them", range=(0.0, _DAY_S)
    ),
    "diagnosis_cpu_share": Param(
        0.06,
        False,
        "share of one core a full diagnosis may use (the worker sleeps between fits); 0 or 1: no limit",
        range=(0.0, 1.0),
    ),
    "stale_timeout": Param(
        3.0, False, "STALE after this long without input or output samples [s]", range=(0.01, _DAY_S)
    ),
    "end_of_data_timeout": Param(
        10.0,
        False,
        "after this long without input and output samples the run of data "
        "has ended: the last manoeuvre is closed and counted [s]",
        range=(0.01, _DAY_S),
    ),
    "warn_epsilon": Param(
        WARN_EPSILON,
        False,
        f"WARN from this epsilon ({WARN_EPSILON:g}: 4.4 dB / 29 deg, eqs. 15-16)",
        range=(0.0, 1.0),
    ),
    "error_epsilon": Param(
        STANDARD_EPSILON,
        False,
        f"ERROR from this epsilon ({STANDARD_EPSILON:g}: the paper's 6 dB / 45 deg point)",
        range=(0.0, 1.0),
    ),
    "state_file": Param("", True, "checkpoint file of the spectra ('' = off); resumed from at start"),
    "checkpoint_period": Param(5.0, True, "checkpoint period [s]", range=(0.01, _DAY_S)),
    "results_dir": Param("", False, "directory of ~/save_results ('' = current directory)"),
    "discovery_period": Param(
        1.0, True, "period of the graph check: publishers' QoS, types not known yet [s]", range=(0.01, 60.0)
    ),
    "raw_decoding": Param(
        True,
        True,
        "read the configured fields straight from the serialized message (Imu, "
        "JointState, Float64/32, Bool) instead of deserialising it in Python",
    ),
    "executor": Param(
        "events",
        True,
        "events (rclpy's EventsExecutor) | single_threaded",
        choices=("events", "single_threaded"),
    ),
    "plan_card": Param(
        "",
        False,
        "card file of gap-validate plan --out: ~/plan answers it, ~/excite flies it ('' = "
        "~/plan plans from the node's results)",
    ),
    "excitation_enabled": Param(
        False,
        True,
        "inject the card's manoeuvres on excitation_topic (~/excite, ~/abort) and estimate against them",
    ),
    "excitation_topic": Param(
        "~/excitation", True, "topic of the surface offsets (Float64: <topic>/<channel>)"
    ),
    "excitation_type": Param(
        JOINT_STATE,
        True,
        "sensor_msgs/msg/JointState (one joint per surface, stamped) | "
        "std_msgs/msg/Float64 (one topic per channel)",
        choices=EXCITATION_TYPES,
    ),
    "excitation_rate_hz": Param(50.0, True, "rate of the surface offsets [Hz]", range=(1.0, 1000.0)),
    "excitation_max_amplitude_rad": Param(
        0.1,
        False,
        "hard cap on every injected sample [rad]; ~/excite refuses a manoeuvre above it",
        range=(0.0, 1.0),
    ),
    "excite_channel": Param("", False, "channel ~/excite flies ('' = any)"),
    "excite_index": Param(
        -1, False, "card index ~/excite flies (-1: the next not flown yet)", range=(-1, 1_000_000)
    ),
}

#: Parameters every rclpy node has, and the prefix of QoS overrides: not unknown.
_NODE_PARAMETERS = ("use_sim_time", "start_type_description_service")
_NODE_PREFIXES = ("qos_overrides.",)


def check_parameters(values: dict[str, Any]) -> None:
    """ConfigError (one line) for a parameter value the node cannot use.

    Parameters
    ----------
    values : dict
        Parameter name -> value (any subset of :data:`PARAMETERS`; ``warn_epsilon`` and ``error_epsilon``
        are checked against each other when both are given).
    """
    for name, value in values.items():
        param = PARAMETERS.get(name)
        if param is None:
            continue
        if param.choices is not None and value not in param.choices:
            raise ConfigError(f"parameter {name}: expected one of {', '.join(param.choices)}, got {value!r}")
        if param.range is not None and not param.range[0] <= value <= param.range[1]:
            raise ConfigError(
                f"parameter {name}: expected a number in [{param.range[0]:g}, {param.range[1]:g}], "
                f"got {value!r}"
            )
    for name in ("warn_epsilon", "error_epsilon", "excitation_max_amplitude_rad"):
        if name in values and not values[name] > 0.0:
            raise ConfigError(f"parameter {name}: expected a number in (0, 1], got {values[name]!r}")
    if "excitation_topic" in values and not str(values["excitation_topic"]).strip():
        raise ConfigError("parameter excitation_topic: expected a topic name, got ''")
    if "warn_epsilon" in values and "error_epsilon" in values \
            and values["warn_epsilon"] > values["error_epsilon"]:
        raise ConfigError(f"parameter warn_epsilon ({values['warn_epsilon']}) is above error_epsilon "
                          f"({values['error_epsilon']})")


def unknown_parameters(overrides: Iterable[str], declared: Iterable[str]) -> list[str]:
    """One line per override that names no parameter, with the parameter it probably meant.

    Parameters
    ----------
    overrides : iterable of str
        Names given with ``-p``, ``--params-file`` or ``parameter_overrides``.
    declared : iterable of str
        Names the node declared.

    Returns
    -------
    list of str
        ``unknown parameter diagnostic_perid (did you mean diagnostic_period?): ignored``, sorted by name.
    """
    known = set(declared) | set(_NODE_PARAMETERS)
    lines = []
    for name in sorted(set(overrides) - known):
        if name.startswith(_NODE_PREFIXES):
            continue
        close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.6)
        hint = f" (did you mean {close[0]}?)" if close else ""
        lines.append(f"unknown parameter {name}{hint}: ignored")
    return lines
