"""Result dataclasses: JSON rendering of measured responses."""
import numpy as np

from gap_validation.core.results import ChannelResult, phase_deg


def test_a_frequency_without_estimate_does_not_wipe_the_other_phases():
    """Regression: the averaged response is NaN where a frequency has no average (window longer than the
    sweeps); np.unwrap spread that NaN to every later frequency, so the JSON phase was null everywhere."""
    measured = np.array([np.nan, 1.0, 1j, -1.0, -1j], dtype=complex)
    model = np.ones(5, dtype=complex)
    np.testing.assert_allclose(phase_deg(measured)[1:], [0.0, 90.0, 180.0, 270.0])
    np.testing.assert_allclose(phase_deg(measured, model)[1:], [0.0, 90.0, 180.0, 270.0])
    assert np.isnan(phase_deg(measured)[0])
    phase = ChannelResult(name="pitch", measured=measured, model=model).to_json_dict()["measured"][
        "phase_deg"
    ]
    assert phase == [None, 0.0, 90.0, 180.0, 270.0]


def test_phase_without_missing_points_is_plain_unwrap():
    response = np.exp(1j * np.linspace(0.0, -12.0, 30))
    np.testing.assert_allclose(phase_deg(response), np.degrees(np.linspace(0.0, -12.0, 30)), atol=1e-9)


def test_doublets_round_trip_and_are_left_out_without_samples():
    from gap_validation.core.manoeuvres import Manoeuvre
    from gap_validation.core.results import ValidationResult

    t = 1.7e9 + np.arange(300) * 0.01
    m = Manoeuvre("doublet", t, np.sin(t - t[0]), np.cos(t - t[0]), t[100], t[150], 100)
    ch = ChannelResult(
        name="roll",
        sweeps=1,
        manoeuvres=[m],
        time_domain=[{"tic": 0.2, "tic_input_augmented": 0.1}],
        sweep_measured=[np.ones(3, complex)],
        model=np.ones(3, complex),
        measured=np.ones(3, complex),
    )
    full = ch.to_json_dict()
    back = ValidationResult.from_json_dict({"channels": {"roll": full}}).channels["roll"]
    assert back.manoeuvres[0].kind == "doublet" and back.manoeuvres[0].trim_samples == 100
    np.testing.assert_allclose(back.manoeuvres[0].u, m.u)
    np.testing.assert_allclose(back.manoeuvres[0].t_s, m.t_s, atol=1e-5)
    assert back.time_domain == [{"tic": 0.2, "tic_input_augmented": 0.1}]
    light = ch.to_json_dict(samples=False)
    assert light["time_domain"] == [{"kind": "doublet", "start_s": m.start_s, "end_s": m.end_s, "tic": 0.2,
                                     "tic_input_augmented": 0.1}]
    assert light["epsilon"] == full["epsilon"] and light["sweeps"] == full["sweeps"]


def test_warnings_reach_the_json_the_table_the_report_text_and_the_diagnostics():
    """A channel's one-line ``warnings`` (DESIGN.md's JSON extension) round-trip through the JSON and are
    shown wherever the channel's sentences are: the table's footnotes and the node's diagnostic values."""
    import json

    from gap_validation.core.results import ValidationResult
    from gap_validation.report.terminal import format_table
    from gap_validation.ros.status import channel_status

    warning = (
        "the rudder moved with the aileron during the roll sweeps (coherence 0.92): add it to other_inputs"
    )
    ch = ChannelResult(name="roll", sweeps=2, epsilon=0.1, nu_gap=0.08, warnings=[warning])
    data = ch.to_json_dict()
    assert data["warnings"] == [warning]
    back = ValidationResult.from_json_dict({"channels": {"roll": data}})
    assert back.channels["roll"].warnings == [warning]
    assert f"  roll: warning: {warning}" in format_table(back).splitlines()
    values = dict(channel_status(ch).values)
    assert json.loads(values["warnings"]) == [warning]
    assert ChannelResult(name="pitch").to_json_dict()["warnings"] == []


def test_margins_caveat_reaches_the_json_the_table_the_report_and_the_diagnostics(tmp_path):
    """issue 15: margins from epsilon < 1 with a caveat (a mismatch peaking at a band edge) are given as
    numbers but never presented as guaranteed: ``margins_guaranteed`` false with the reason in
    ``margins_note`` (round trip), starred cells and a footnote in the table, a 'NOT guaranteed' verdict in
    the report, the node's values."""
    from gap_validation.core.margins import margins_from_epsilon
    from gap_validation.core.results import ValidationResult
    from gap_validation.report.html import table1_html, verdict
    from gap_validation.report.terminal import format_table
    from gap_validation.ros.status import channel_status

    caveat = ("the mismatch peaks at the edge of the measured band and may continue outside it: the margins "
              "then do not hold")
    ch = ChannelResult(name="roll", sweeps=2, epsilon=0.33, nu_gap=0.18, margins=margins_from_epsilon(0.33),
                       margins_caveat=caveat)
    data = ch.to_json_dict()
    assert data["gain_margin_db"] == margins_from_epsilon(0.33).gain_margin_db      # 5.96 dB: given, ...
    assert data["margins_guaranteed"] is False and data["margins_note"] == f"margins not guaranteed: {caveat}"
    back = ValidationResult.from_json_dict({"channels": {"roll": data}})
    assert back.channels["roll"].margins_caveat == caveat and not back.channels["roll"].margins_guaranteed
    table = format_table(back)
    assert "5.96*" in table and "38.5*" in table and f"  * roll: margins NOT guaranteed: {caveat}" in table
    assert "guaranteed stable on the aircraft" not in table
    assert "over the measured band (the winding-number condition assumed" in table
    text, cls = verdict(back.channels["roll"])
    assert cls == "bad" and "NOT guaranteed stable on the aircraft" in text and caveat in text
    assert "margins NOT guaranteed" in table1_html(
        back
    ) and "winding-number condition assumed" in table1_html(back)
    values = dict(channel_status(ch).values)
    assert values["margins_guaranteed"] == "false" and values["margins_note"].startswith(
        "margins not guaranteed"
    )
    fine = ChannelResult(name="roll", epsilon=0.1, margins=margins_from_epsilon(0.1)).to_json_dict()
    assert fine["margins_guaranteed"] is True and fine["margins_note"] is None


def test_trim_spectra_round_trip_and_are_null_without_trim():
    from gap_validation.core.background import TrimSpectra
    from gap_validation.core.results import ValidationResult

    trim = TrimSpectra(np.array([1e-4, np.nan]), np.array([2e-3, np.nan]), np.array([3e-4 - 1e-4j, np.nan]),
                       np.array([24.0, 0.0]))
    ch = ChannelResult(name="pitch", trim_spectra=trim)
    data = ch.to_json_dict()
    assert data["trim_spectra"]["cross_imag"] == [-1e-4, None]
    back = ValidationResult.from_json_dict({"channels": {"pitch": data}}).channels["pitch"]
    np.testing.assert_array_equal(back.trim_spectra.cross, trim.cross)
    np.testing.assert_array_equal(back.trim_spectra.output_error(np.ones(2)), trim.output_error(np.ones(2)))
    assert ChannelResult(name="pitch").to_json_dict()["trim_spectra"] is None
