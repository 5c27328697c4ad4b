"""Result dataclasses: JSON rendering of measured responses."""
import numpy as np

from gap_validation.core.results import ChannelResult, phase_deg


def test_a_frequency_without_estimate_does_not_wipe_the_other_phases():
    """Regression: the averaged response is NaN where a frequency has no average (window longer than the sweeps);
    np.unwrap spread that NaN to every later frequency, so the JSON phase was null everywhere."""
    measured = np.array([np.nan, 1.0, 1j, -1.0, -1j], dtype=complex)
    model = np.ones(5, dtype=complex)
    np.testing.assert_allclose(phase_deg(measured)[1:], [0.0, 90.0, 180.0, 270.0])
    np.testing.assert_allclose(phase_deg(measured, model)[1:], [0.0, 90.0, 180.0, 270.0])
    assert np.isnan(phase_deg(measured)[0])
    phase = ChannelResult(name="pitch", measured=measured, model=model).to_json_dict()["measured"]["phase_deg"]
    assert phase == [None, 0.0, 90.0, 180.0, 270.0]


def test_phase_without_missing_points_is_plain_unwrap():
    response = np.exp(1j * np.linspace(0.0, -12.0, 30))
    np.testing.assert_allclose(phase_deg(response), np.degrees(np.linspace(0.0, -12.0, 30)), atol=1e-9)
