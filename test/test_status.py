"""Channel statuses without ROS (gap_validation.ros.status): levels, messages and values of one channel."""
import json
import math

import pytest

from gap_validation.ros.status import channel_status


def test_channel_status_levels_and_messages():
    from gap_validation.core.margins import margins_from_epsilon
    from gap_validation.core.results import ChannelResult

    ch = ChannelResult(
        name="pitch",
        sweeps=3,
        epsilon=0.62,
        epsilon_previous=0.71,
        nu_gap=0.4,
        worst_frequency_rad_s=25.0,
        limited_by="model",
        bands=[{"min_rad_s": 20.0, "max_rad_s": 40.0, "limited_by": "model"}],
        margins=margins_from_epsilon(0.62),
        bad_samples={"input: not finite": 2},
        rate_leads_surface={"share": 0.004, "f": 1.2, "p_value": 0.3, "rows": 9000, "lags_s": 0.23},
    )
    top = {"effect": "time_delay", "effects": [{"type": "time_delay", "seconds": 0.045}], "epsilon": 0.06,
           "sentence": "missing: time delay of 45 ms; adding it brings epsilon from 0.62 to 0.06"}
    status = channel_status(ch, candidate=top, diagnosis_state="done")
    assert status.level == "ERROR"
    assert status.message == (
        "epsilon 0.62 (was 0.71): ERROR, model-limited at 20-40 rad/s; missing: time delay "
        "of 45 ms; adding it brings epsilon from 0.62 to 0.06"
    )
    values = dict(status.values)
    assert values["bad_samples"] == "2" and json.loads(values["bad_samples_by_reason"]) == {
        "input: not finite": 2
    }
    assert json.loads(values["diagnosis_effects"]) == [{"type": "time_delay", "seconds": 0.045}]
    assert float(values["phase_margin_deg"]) == pytest.approx(2 * math.degrees(math.asin(0.62)))
    assert json.loads(values["rate_leads_surface"])["rows"] == 9000      # the lead test, as in the JSON
    ch.epsilon = 0.3
    assert channel_status(ch).level == "WARN"
    ch.epsilon = 0.1
    assert channel_status(ch).level == "OK"
    assert channel_status(ch, warn_epsilon=0.05, error_epsilon=0.08).level == "ERROR"
    ch.epsilon = 1.2
    ch.margins = margins_from_epsilon(1.2)
    values = dict(channel_status(ch).values)
    assert values["gain_margin_db"] == "null" and values["phase_margin_deg"] == "null"
    # data flow, no sweep yet: nothing wrong, nothing to judge (not STALE)
    empty = ChannelResult(name="roll")
    assert channel_status(empty).level == "OK"
    assert channel_status(empty).message == "receiving data, waiting for a sweep (no estimate yet)"
    assert dict(channel_status(empty).values)["diagnosis"] == "pending"
    assert dict(channel_status(empty).values)["epsilon"] == "null"
    assert channel_status(empty, waiting_reason="waiting for data on /imu (output)").level == "STALE"
    assert channel_status(empty, stale_reason="no data for 4.0 s on /imu (output)").level == "STALE"
    flat = ChannelResult(name="roll", sweeps=2, message="no frequency with coherence >= 0.6 yet")
    assert channel_status(flat).level == "WARN" and "data-limited" in channel_status(flat).message


def test_a_publisher_that_cannot_be_matched_is_named_first_and_raises_the_level():
    from gap_validation.core.margins import margins_from_epsilon
    from gap_validation.core.results import ChannelResult

    note = "publisher on /imu offers BEST_EFFORT; set qos_reliability to auto or best_effort"
    empty = ChannelResult(name="pitch")
    silent = channel_status(empty, waiting_reason="waiting for data on /imu (output)", notes=[note])
    assert silent.level == "ERROR" and silent.message == f"{note}; waiting for data on /imu (output)"
    flowing = channel_status(empty, notes=[note])        # another publisher feeds the topic: a warning
    assert flowing.level == "WARN" and flowing.message.startswith(note)
    bad = ChannelResult(name="pitch", sweeps=1, epsilon=0.5, margins=margins_from_epsilon(0.5))
    assert channel_status(bad, notes=[note]).level == "ERROR"


def test_the_last_diagnosis_nonlinearity_verdict_is_a_value():
    """issue 15's left item: the node shows the full diagnosis' amplitude-dependence verdict (value
    ``nonlinearity``, the JSON key's name), empty before a diagnosis and after the model or spectra change."""
    from pathlib import Path

    from gap_validation.core.config import load_config
    from gap_validation.core.margins import margins_from_epsilon
    from gap_validation.core.results import ChannelResult
    from gap_validation.core.validator import OnlineValidator
    from gap_validation.messages.router import MessageRouter
    from gap_validation.ros.status import ChannelTask

    config = load_config(Path(__file__).resolve().parents[1] / "config" / "ultrastick25e.yaml")
    ch = ChannelResult(name="pitch", sweeps=2, epsilon=0.5, nu_gap=0.4, limited_by="model",
                       margins=margins_from_epsilon(0.5))
    verdict = "nonlinear, amplitude-dependent (rate limit, backlash or saturation?)"
    assert dict(channel_status(ch).values)["nonlinearity"] == ""
    assert dict(channel_status(ch, nonlinearity=verdict).values)["nonlinearity"] == verdict
    task = ChannelTask("pitch", config.channels["pitch"])
    router = MessageRouter(config, OnlineValidator(config, diagnose=False))

    def status():
        return dict(task.run(ch, 0.0, router, lambda topic: 0, stale_timeout_s=1e9).values)

    assert status()["nonlinearity"] == ""
    task.take_diagnosis(None, verdict)
    assert status()["nonlinearity"] == verdict and status()["diagnosis"] == "none"
    task.forget_diagnosis()
    assert status()["nonlinearity"] == ""

    # the full diagnosis' constant factor within the tolerance rides along the same way (value
    # ``within_tolerance``)
    from gap_validation.core.results import ConstantFactor
    from gap_validation.ros.status import verdict_mapping

    factor = ConstantFactor(gain=0.92, phase_deg=-10.1, error=0.011, noise_scales=17.0, min_rad_s=1.4,
                            max_rad_s=44.0, free_play_rad=0.0148, amplitude=0.05)
    assert status()["within_tolerance"] == "null"
    task.take_diagnosis(None, None, within_tolerance=factor)
    assert json.loads(status()["within_tolerance"])["free_play_rad"] == pytest.approx(0.0148)
    mapping = verdict_mapping(task.run(ch, 0.0, router, lambda topic: 0, stale_timeout_s=1e9))
    assert mapping["within_tolerance"]["gain"] == pytest.approx(0.92)
    task.forget_diagnosis()
    assert status()["within_tolerance"] == "null"


def test_the_run_ends_on_silence_the_node_heard_not_on_old_reception_stamps():
    """A node stalled (start-up under load, a long computation) takes messages whose transport reception times
    are already older than ``end_of_data_timeout``: the data did not stop, so the run does not end; it ends
    once the node has counted nothing new for the timeout (seen flaking under CI load: a run cut after the
    first 500 messages of a flight)."""
    from pathlib import Path

    import numpy as np

    from gap_validation.core.config import load_config
    from gap_validation.core.validator import OnlineValidator
    from gap_validation.messages.router import MessageRouter
    from gap_validation.ros.status import ChannelTask

    config = load_config(Path(__file__).resolve().parents[1] / "config" / "ultrastick25e.yaml")
    task = ChannelTask("pitch", config.channels["pitch"])
    router = MessageRouter(config, OnlineValidator(config, diagnose=False))
    t = np.arange(0.0, 1.0, 0.01)
    for stream in ("input", "output"):
        router.validator.add_samples("pitch", stream, t, np.zeros_like(t))
    counts = {"input": 100, "output": 100}
    router.samples = lambda channel, stream: counts[stream]
    arrivals = {config.channels["pitch"].signal(s).topic: 100.0 for s in ("input", "output")}
    taken = {topic: 112.0 for topic in arrivals}
    # received at 100 s, taken at 112 s (the node was stalled)
    task.update_seen(router, arrivals, 112.5, taken)
    assert task.last_seen == {"input": 100.0, "output": 100.0}      # the age is the reception's
    assert not task.run_ended(112.5, 10.0)
    task.update_seen(router, arrivals, 121.0, taken)
    assert not task.run_ended(121.0, 10.0)
    task.update_seen(router, arrivals, 122.5, taken)
    assert task.run_ended(122.5, 10.0) and not task.run_ended(130.0, 10.0)      # once


def test_what_the_full_diagnosis_adds_joins_the_status_as_in_replay():
    """Parity with replay (issue 26): the node's status comes from the cheap result, the diagnosis from a
    worker; the warnings and the margins caveat the diagnosis adds (the diagnosed model failing the
    winding-number condition) must reach the status, once, and go when the diagnosis is forgotten."""
    from gap_validation.core.config import parse_config
    from gap_validation.core.margins import margins_from_epsilon
    from gap_validation.core.results import ChannelResult
    from gap_validation.core.validator import OnlineValidator
    from gap_validation.messages.router import MessageRouter
    from gap_validation.ros.status import ChannelTask

    config = parse_config({"channels": {"pitch": {
        "input": {"topic": "/s", "field": "data"}, "output": {"topic": "/imu", "field": "angular_velocity.y"},
        "model": {"numerator": [1.0], "denominator": [1.0, 1.0]}}}}, "cfg.yaml")
    task = ChannelTask("pitch", config.channels["pitch"])
    router = MessageRouter(config, OnlineValidator(config, diagnose=False))
    cheap = ChannelResult(name="pitch", sweeps=3, epsilon=0.3, nu_gap=0.25, limited_by="model",
                          margins=margins_from_epsilon(0.3), warnings=["the manoeuvres' edge warning"])
    winding = (
        "the model and the diagnosed model (time_delay) fail the winding-number condition (...): if the "
        "diagnosis is right, the nu-gap between the model and the aircraft is 1"
    )

    def values():
        status = task.run(cheap, 0.0, router, lambda topic: 0, stale_timeout_s=1e9)
        return dict(status.values)

    before = values()
    assert (
        json.loads(before["warnings"]) == ["the manoeuvres' edge warning"]
        and before["margins_guaranteed"] == "true"
    )
    task.take_diagnosis(
        None, None, ["the manoeuvres' edge warning", winding], "the diagnosed model fails ..."
    )
    after = values()
    assert json.loads(after["warnings"]) == ["the manoeuvres' edge warning", winding]
    assert after["margins_guaranteed"] == "false" and "the diagnosed model fails" in after["margins_note"]
    # not changed in place
    assert cheap.warnings == ["the manoeuvres' edge warning"] and not cheap.margins_caveat
    task.forget_diagnosis()
    assert values() == before
