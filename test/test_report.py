"""HTML report: the library path (simulation -> OnlineValidator, no ROS) renders every figure and Table 1."""
import numpy as np

from gap_validation.core.simulation import FlightOptions, hidden_effects, simulate_flight
from gap_validation.core.validator import OnlineValidator
from gap_validation.report import write_report
from gap_validation.core.results import phase_deg

from _flights import ultrastick


def feed(validator, flight):
    """Feed a simulated flight straight into the validator (the library path)."""
    for name, channel in validator.config.channels.items():
        inp, out = flight.topics[channel.input.topic], flight.topics[channel.output.topic]
        validator.add_time_histories(name, inp.stamp_s, inp.values[channel.input.field] * channel.input.scale,
                                     out.stamp_s, out.values[channel.output.field] * channel.output.scale)
    validator.finish()


def test_report_has_table_and_figures(tmp_path):
    config = ultrastick()
    flight = simulate_flight(config, hidden_effects(["pitch:time_delay:seconds=0.04"], config),
                             FlightOptions(sweeps_per_channel=2, sweep_duration_s=40.0, quiet_s=3.0), seed=3)
    validator = OnlineValidator(config, diagnose=False)
    feed(validator, flight)
    result = validator.results()
    assert result.channels["pitch"].epsilon > 0.5 > result.channels["roll"].epsilon
    index = write_report(result, tmp_path / "report")
    text = index.read_text()
    for name in ("roll", "pitch", "yaw"):
        assert f"<h2>{name}</h2>" in text
        for kind in ("bode", "failure", "disk"):
            png = tmp_path / "report" / f"{name}_{kind}.png"
            assert png.stat().st_size > 5000 and png.read_bytes()[:4] == b"\x89PNG"
    assert "gain margin, dB" in text and "epsilon (raw)" in text


def test_phase_follows_reference_branch():
    w = np.geomspace(1, 40, 30)
    model = np.exp(-1j * (np.pi + 0.01 * w))          # starts at -180 deg
    measured = -model * 0 + model * np.exp(-1j * 0.04 * w)
    assert abs(phase_deg(measured, model)[0] - phase_deg(model)[0]) < 5
