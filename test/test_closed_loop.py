"""Issue 13: closed-loop sweeps and surfaces that move together (core/closed_loop.py, the ``excitation`` and
``other_inputs`` keys, the simulator's closed loop and coupling). Seeded simulated flights, in memory
(simulator -> validator, the library path of the one data path) and once through a bag and the CLI."""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from _flights import config_from, raw_config, write_config
from scipy import signal

from gap_validation.cli.main import main
from gap_validation.core.closed_loop import CouplingMonitor, SurfaceHistory, near_minus_inverse
from gap_validation.core.errors import ConfigError
from gap_validation.core.loop_flight import _discrete
from gap_validation.core.models import LinearModel
from gap_validation.core.simulation import damper_gain, simulate_flight, with_options
from gap_validation.core.spectra import BandSums, partial_coherence, record_bands
from gap_validation.core.validator import OnlineValidator

EXCITATION = {"topic": "/sysid/excitation", "field": "position[aileron]"}
RUDDER = {"topic": "/control_surfaces", "field": "position[rudder]"}
#: A closed-loop card: three 90 s roll sweeps inside a rate damper with a 6 dB gain margin, 12 s of trim
#: between manoeuvres, turbulence, the injected signal logged.
CLOSED_LOOP = dict(
    closed_loop_gain_margin_db=6.0,
    turbulence_rms_rad_s=0.05,
    log_excitation_topic="/sysid/excitation",
    sweeps_per_channel=3,
    sweep_duration_s=90.0,
    quiet_s=12.0,
)
#: Rudder = own + 0.3 x aileron (an interconnect); the roll rate also answers the rudder (a Dutch-roll-like
#: term).
COUPLED = dict(coupling=(("roll", "yaw", 0.3),), cross_responses=(("roll", "yaw", -3.0, 3.0, 0.15),),
               sweeps_per_channel=2, sweep_duration_s=60.0)


def roll_config(excitation: bool = False, channels=("roll",), other_inputs: bool = False):
    data = raw_config()
    data["channels"] = {k: v for k, v in data["channels"].items() if k in channels}
    if excitation:
        data["channels"]["roll"]["excitation"] = dict(EXCITATION)
    if other_inputs:
        data["channels"]["roll"]["other_inputs"] = [dict(RUDDER)]
    return config_from(data, "closed_loop.yaml")


def validate(config, flight):
    """Feed every stream of every channel of ``config`` from ``flight`` (whole histories) and validate."""
    validator = OnlineValidator(config)
    for name, ch in config.channels.items():
        streams = [("input", ch.input), ("output", ch.output), *ch.extra_streams()]
        validator.add_histories(name, {stream: (flight.topics[spec.topic].stamp_s,
                                                flight.topics[spec.topic].values[spec.field] * spec.scale)
                                       for stream, spec in streams})
    validator.finish()
    return validator.results()


@pytest.fixture(scope="module")
def clean_loop():
    return simulate_flight(roll_config(), {}, with_options(**CLOSED_LOOP), seed=1)


@pytest.fixture(scope="module")
def delayed_loop():
    hidden = {"roll": [{"type": "time_delay", "seconds": 0.035}]}
    return simulate_flight(roll_config(), hidden, with_options(**CLOSED_LOOP), seed=1)


@pytest.fixture(scope="module")
def coupled():
    return simulate_flight(roll_config(channels=("roll", "yaw")), {}, with_options(**COUPLED), seed=1)


# ------------------------------------------------------------------------------------------ excitation
def test_closed_loop_with_excitation_gives_the_plant(clean_loop):
    ch = validate(roll_config(excitation=True), clean_loop).channels["roll"]
    assert ch.limited_by != "model" and not ch.diagnosis, ch.message
    assert ch.epsilon is not None and ch.epsilon < 0.3
    assert not ch.warnings
    r_u, r_y = ch.excitation_coherence["r_to_u"], ch.excitation_coherence["r_to_y"]
    assert r_u.shape == r_y.shape == ch.frequency_rad_s.shape
    assert np.median(r_u) > 0.8 and np.median(r_y) > 0.8 and np.all((r_u >= 0) & (r_u <= 1))
    assert ch.to_json_dict()["excitation_coherence"]["r_to_u"][0] == pytest.approx(r_u[0])


def test_closed_loop_hidden_delay_is_found_with_excitation(delayed_loop):
    ch = validate(roll_config(excitation=True), delayed_loop).channels["roll"]
    assert ch.limited_by == "model" and ch.diagnosis and ch.diagnosis[0].effect == "time_delay", ch.message
    assert ch.diagnosis[0].parameters["seconds"] == pytest.approx(0.035, rel=0.2)


@pytest.mark.parametrize("flight", ["clean_loop", "delayed_loop"])
def test_closed_loop_without_excitation_warns_and_names_nothing_wrong(flight, request):
    """Without the excitation logged the loop is warned of; only the frequencies where the manoeuvres stand 20
    dB above the surface's motion between them (the loop answering turbulence) count, and those are not
    biased: the clean airframe gets nothing named, the delayed one at most its delay (issue 22)."""
    ch = validate(roll_config(), request.getfixturevalue(flight)).channels["roll"]
    assert any("feedback" in w and "channels.roll.excitation" in w for w in ch.warnings), ch.warnings
    if flight == "clean_loop":
        assert ch.limited_by != "model" and not ch.diagnosis, ch.message
    else:
        assert [c.effect for c in ch.diagnosis[:1]] in ([], ["time_delay"]), ch.message
        if ch.diagnosis:
            assert ch.diagnosis[0].parameters["seconds"] == pytest.approx(0.035, rel=0.25)


def test_excitation_coherence_is_absent_without_the_key(clean_loop):
    assert "excitation_coherence" not in validate(roll_config(), clean_loop).channels["roll"].to_json_dict()


# ------------------------------------------------------------------------------------------ other inputs
def test_coupled_surfaces_with_other_inputs_give_the_roll_response(coupled):
    ch = validate(roll_config(channels=("roll", "yaw"), other_inputs=True), coupled).channels["roll"]
    assert ch.limited_by != "model" and not ch.diagnosis and not ch.warnings, ch.message
    assert ch.epsilon is not None and ch.epsilon < 0.15
    assert ch.partial_coherence is not None and np.median(ch.partial_coherence) > 0.8
    assert ch.sweeps == 2                       # the rudder's own sweeps pool in, but are not roll sweeps


def test_coupled_surfaces_without_other_inputs_warn_naming_the_rudder(coupled):
    result = validate(roll_config(channels=("roll", "yaw")), coupled)
    roll = result.channels["roll"]
    assert roll.limited_by != "model" and not roll.diagnosis, roll.message
    assert any("position[rudder]" in w and "channels.roll.other_inputs" in w for w in roll.warnings), (
        roll.warnings
    )
    assert "biased" in roll.frequency_reasons
    # the rudder's own sweeps move no aileron; the roll sweeps move the rudder (the interconnect), too little
    # of the rudder's energy to bias its response: said, not called biased
    yaw = result.channels["yaw"]
    assert all("not validated" not in w for w in yaw.warnings), yaw.warnings
    assert "biased" not in yaw.frequency_reasons
    # and those roll sweeps are the aileron's: left out of the rudder's estimate, which keeps its own 2 sweeps
    # (4 counted, the aileron's pooled in, before the rudder was seen to follow)
    assert yaw.sweeps == 2
    assert any("position[aileron]" in w and "left out of its estimate" in w for w in yaw.warnings), (
        yaw.warnings
    )


@pytest.mark.parametrize(
    "options",
    [
        dict(excitation="chirp", sweeps_per_channel=1, sweep_duration_s=30.0, quiet_s=12.0),
        dict(
            excitation="multisine-orthogonal",
            sweeps_per_channel=1,
            multisine_period_s=15.0,
            multisine_periods=3,
        ),
    ],
    ids=["chirps", "orthogonal multisines"],
)
def test_open_loop_flights_of_uncoupled_surfaces_warn_of_nothing(options):
    config = config_from(raw_config())
    result = validate(config, simulate_flight(config, {}, with_options(**options), seed=2))
    for name, ch in result.channels.items():
        assert not ch.warnings, (name, ch.warnings)


# ------------------------------------------------------------------------------------------ units
def test_coupling_monitor_sees_an_interconnect_not_an_independent_surface():
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 60.0, 0.01)
    u = 0.05 * np.sin(2.0 * t + 0.02 * t ** 2)
    for other, expected in (
        (0.3 * u + 1e-3 * rng.standard_normal(t.size), True),
        (0.05 * np.sin(7.0 * t + 1.0), False),
        (1e-3 * rng.standard_normal(t.size), False),
    ):
        history, monitor = SurfaceHistory(), CouplingMonitor()
        monitor.observe(u, 0.0, 0.01, history)            # the surface's samples come later: it waits
        assert monitor.pending and not monitor.records
        history.add(t, other)
        monitor.catch_up(history)
        coupled, r2, gain = monitor.coupled()
        assert coupled is expected and monitor.records == 1
        if expected:
            assert r2 > 0.99 and gain == pytest.approx(0.3, rel=0.02)


def test_a_manoeuvre_is_the_other_surfaces_where_it_moves_more_against_its_own_trim_motion():
    """``leads``: the other surface follows the input (an interconnect either way) and moves more, each
    against its own trim motion: the manoeuvre is the other surface's. Where it moves less, or moves
    independently, or its samples do not cover the manoeuvre yet, it is the channel's own."""
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 30.0, 0.01)
    u = 0.015 * np.sin(2.0 * t + 0.02 * t ** 2)            # the rudder, 0.3 x the aileron's sweep
    aileron = u / 0.3 + 1e-4 * rng.standard_normal(t.size)
    history = SurfaceHistory()
    history.add(t, aileron)
    for own_trim, other_trim, expected in ((0.0, 0.0, True),        # unknown trims: in their own units
                                           # the same trim motion: the aileron moves more
                                           (0.003, 0.003, True),
                                           # an aileron ten times as restless: the rudder
                                           (0.001, 0.01, False)):
        monitor = CouplingMonitor()
        assert monitor.leads(u, 0.0, 0.01, history, own_trim, other_trim) is expected
        assert monitor.followed()[0] == int(expected) and not monitor.records
    monitor = CouplingMonitor()
    assert not monitor.leads(aileron, 0.0, 0.01, _history(t, u), 0.0, 0.0)                  # the smaller one
    # independent
    assert not monitor.leads(u, 0.0, 0.01, _history(t, 0.05 * np.sin(7.0 * t + 1.0)), 0.0, 0.0)
    assert not monitor.leads(u, 0.0, 0.01, _history(t[:1000], aileron[:1000]), 0.0, 0.0)   # not arrived yet
    count, r2, gain = CouplingMonitor().followed()
    assert count == 0


def _history(t, v):
    history = SurfaceHistory()
    history.add(t, v)
    return history


def test_near_minus_inverse_marks_a_response_that_is_minus_one_over_c():
    w = np.geomspace(1.0, 40.0, 20)
    controller = LinearModel.from_tf([0.2, 0.0], [1.0, 0.3])
    model = LinearModel.from_tf([156.0], [1.0, 16.0]).freqresp(w)
    assert near_minus_inverse(controller, w, -1.0 / controller.freqresp(w), model).all()
    assert not near_minus_inverse(controller, w, model * 1.05, model).any()


def test_partial_coherence_separates_the_inputs():
    rng = np.random.default_rng(3)
    n, dt = 60000, 0.01
    x1, x2 = rng.standard_normal(n), rng.standard_normal(n)
    w = np.geomspace(2.0, 30.0, 8)
    for y, low, high in ((np.convolve(x2, [0.0, 1.0], "same"), 0.0, 0.15),      # noise level: 3 / (dof + 3)
                         (np.convolve(x1, [0.0, 1.0], "same"), 0.95, 1.0)):
        y = y + 0.05 * rng.standard_normal(n)
        sums, status = record_bands(np.stack([x1, x2]), y[None, :], dt, w)
        assert (status == 0).all()
        gamma = partial_coherence(sums)
        assert np.all((gamma >= low) & (gamma <= high)), gamma
    assert not partial_coherence(BandSums.zeros(4)).any()          # one input: nothing to condition on


# ------------------------------------------------------------------------------------------ simulator
def test_damper_gain_leaves_the_asked_gain_margin():
    """The discretised loop of the simulator is stable at the damper's gain and 3 % below the critical gain,
    and unstable 3 % above it (6 dB: the critical gain is twice the damper's)."""
    model = config_from(raw_config()).channels["roll"].model
    fs, n_c = 400.0, 8
    k = damper_gain(model, 6.0, (n_c + 0.5) / fs)
    num, den, n_p = _discrete(model, fs)
    wash_b, wash_a = signal.bilinear([1.0, 0.0], [1.0, 0.3], fs)

    def largest_root(gain):
        size = den.size + wash_a.size + n_c + n_p
        closed = np.zeros(size)
        closed[:den.size + wash_a.size - 1] += np.convolve(den, wash_a)
        closed[n_c + n_p:n_c + n_p + den.size + wash_b.size - 1] += gain * np.convolve(num, wash_b)
        return np.max(np.abs(np.roots(np.trim_zeros(closed, "b"))))

    critical = k * 10 ** (6.0 / 20.0)
    assert largest_root(k) < 1.0 and largest_root(0.97 * critical) < 1.0 < largest_root(1.03 * critical)


def test_closed_loop_flight_logs_the_injected_signal_and_keeps_open_loop_flights(clean_loop):
    assert set(clean_loop.topics) == {"/control_surfaces", "/imu", "/sysid/excitation"}
    assert clean_loop.loop_gains["roll"] > 0
    logged = clean_loop.topics["/sysid/excitation"].values["position[aileron]"]
    assert np.max(np.abs(logged)) == pytest.approx(0.06, rel=0.02)        # the manoeuvre, before any feedback
    config = roll_config()
    plain = simulate_flight(config, {}, with_options(sweeps_per_channel=1, sweep_duration_s=20.0), seed=4)
    again = simulate_flight(config, {}, with_options(sweeps_per_channel=1, sweep_duration_s=20.0,
                                                      turbulence_rms_rad_s=0.0, coupling=()), seed=4)
    for topic, series in plain.topics.items():
        for field, values in series.values.items():
            np.testing.assert_array_equal(values, again.topics[topic].values[field])


# ------------------------------------------------------------------------------------------ config and CLI
@pytest.mark.parametrize("change,needle", [
    (lambda ch: ch.update(excitation=dict(EXCITATION), other_inputs=[dict(RUDDER)]),
     "channels.roll.other_inputs: 2 inputs but 1 excitation"),
    (lambda ch: ch.update(other_inputs=[{"topic": "/control_surfaces", "field": "position[aileron]"}]),
     "channels.roll.other_inputs[0]: the channel's own input"),
    (lambda ch: ch.update(excitation={"topic": "/sysid"}), "channels.roll.excitation.field: missing"),
    (lambda ch: ch.update(other_inputs=[]), "channels.roll.other_inputs: expected a non-empty list"),
])
def test_bad_closed_loop_keys_are_one_line_errors(change, needle):
    data = raw_config()
    change(data["channels"]["roll"])
    with pytest.raises(ConfigError) as err:
        config_from(data, "cfg.yaml")
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_simulate_closed_loop_and_replay_with_excitation(tmp_path, capsys):
    data = raw_config()
    data["channels"] = {"roll": data["channels"]["roll"]}
    plain = write_config(copy.deepcopy(data), tmp_path / "roll.yaml")
    data["channels"]["roll"]["excitation"] = dict(EXCITATION)
    excited = write_config(data, tmp_path / "roll_excitation.yaml")
    bag = tmp_path / "flight"
    assert main(["simulate", "--config", str(plain), "--out", str(bag), "--closed-loop-gain-margin-db", "6",
                 "--turbulence", "0.05", "--log-excitation", "/sysid/excitation", "--sweeps", "2",
                 "--sweep-duration", "60", "--sweep-gap-s", "12", "--seed", "1"]) == 0
    assert "rate damper K =" in capsys.readouterr().out
    out = tmp_path / "out.json"
    assert main(["replay", str(bag), "--config", str(excited), "--json", str(out), "--no-history",
                 "--no-progress"]) == 0
    roll = json.loads(out.read_text())["channels"]["roll"]
    assert roll["limited_by"] != "model" and not roll["diagnosis"] and roll["epsilon"] < 0.3
    assert len(roll["excitation_coherence"]["r_to_y"]) == len(roll["frequency_rad_s"])


@pytest.mark.parametrize("args,needle", [
    (["--coupling", "aileron:flap:0.3"], "--coupling 'aileron:flap:0.3': bad part 'flap'"),
    (["--coupling", "aileron:rudder"], "expected FROM:TO:GAIN"),
    (["--cross-response", "roll:rudder:x"], "bad part 'x'"),
    (["--closed-loop-gain-margin-db", "6", "--coupling", "aileron:rudder:0.3"], "not available together"),
])
def test_bad_simulate_loop_options_are_one_line_exit_2(tmp_path, capsys, args, needle):
    code = main(["simulate", "--config", "config/ultrastick25e.yaml", "--out", str(tmp_path / "bag"), *args])
    err = capsys.readouterr().err.strip()
    assert code == 2 and needle in err and len(err.splitlines()) == 1, err


def test_the_node_path_message_by_message_gives_the_replay_result(clean_loop, tmp_path):
    """Replay (batched decoding) and the node's path (the router, message by message, as ``on_message`` feeds
    it) agree on a closed-loop flight with the excitation and on its warnings without it."""
    from gap_validation.bag.reader import open_bag
    from gap_validation.bag.replay import replay
    from gap_validation.bag.writer import write_flight
    from gap_validation.messages.router import MessageRouter

    bag = tmp_path / "flight"
    write_flight(clean_loop, bag)
    for config in (roll_config(excitation=True), roll_config()):
        replayed = replay([bag], config, diagnose=False).result.channels["roll"]
        validator = OnlineValidator(config, diagnose=False)
        router = MessageRouter(config, validator)
        with open_bag(bag) as opened:
            for topic, msg, t_s in opened.messages(list(config.topics())):
                router.on_message(topic, msg, t_s)
        router.flush()
        validator.finish()
        live = validator.results().channels["roll"]
        assert live.epsilon is replayed.epsilon is None or live.epsilon == pytest.approx(
            replayed.epsilon, rel=1e-9
        )
        assert live.warnings == replayed.warnings and live.message == replayed.message
        assert (live.excitation_coherence is None) == (config.channels["roll"].excitation is None)


def test_a_loop_that_drowns_the_manoeuvres_is_found_by_which_signal_leads():
    """A yaw damper answering turbulence moves the rudder more than the sweep flown inside it: no manoeuvre
    stands 20 dB above that motion, and the response between manoeuvres is not on the opposite side of the
    airframe's (the loop's phase is past 90 deg where it is coherent). The rate leading the rudder between the
    manoeuvres says it is a loop (background.LeadTest); the same flight open loop says nothing of the kind
    (issue 22)."""
    data = raw_config()
    data["channels"] = {"yaw": data["channels"]["yaw"]}
    config = config_from(data, "yaw_loop.yaml")
    options = dict(
        excitation="chirp",
        turbulence_rms_rad_s=0.06,
        sweeps_per_channel=1,
        sweep_duration_s=100.0,
        quiet_s=11.0,
        noise=0.8,
    )
    ch = validate(config, simulate_flight(config, {}, with_options(closed_loop_gain_margin_db=9.6, **options),
                                          seed=212670877)).channels["yaw"]
    assert ch.message.startswith("no sweep found") and "stands 20 dB" in ch.message, ch.message
    assert any("the rate leads" in w and "feedback loop" in w for w in ch.warnings), ch.warnings
    open_loop = validate(
        config, simulate_flight(config, {}, with_options(**options), seed=212670877)
    ).channels["yaw"]
    assert not any("feedback" in w for w in open_loop.warnings), open_loop.warnings


@pytest.mark.parametrize(
    "effect", [{"type": "zero_order_hold", "rate_hz": 20.0}, {"type": "rate_limit", "rad_s": 1.0}]
)
def test_a_sampled_effect_in_a_simulated_closed_loop_is_refused_in_one_line(effect):
    """The discretised loop has no surface samples to hold or rate-limit: refused, never silently dropped."""
    with pytest.raises(ConfigError) as err:
        simulate_flight(roll_config(), {"roll": [effect]}, with_options(**CLOSED_LOOP), seed=1)
    assert f"closed loop: channel roll: {effect['type']}" in str(err.value) and "\n" not in str(err.value)
