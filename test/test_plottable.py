"""The plot table of a channel (gap_validation.core.plottable), without ROS: the node's
``~/<channel>/frequency_response`` carries it, so a plot layout's columns must hold all flight long."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from gap_validation.core.config import FrequencyGrid, load_config
from gap_validation.core.plottable import (
    CURVES,
    FLAG_CODES,
    flags_from_codes,
    frequency_response_table,
    read_table,
)
from gap_validation.core.results import ChannelResult

CONFIG = Path(__file__).resolve().parents[1] / "config" / "ultrastick25e.yaml"


def _result(w: np.ndarray, model) -> ChannelResult:
    p = model.freqresp(w)
    measured = p * 0.9 * np.exp(-0.02j * w)
    return ChannelResult(name="pitch", frequency_rad_s=w, measured=measured, model=p,
                         coherence=np.linspace(0.7, 0.99, w.size), kappa=np.full(w.size, 0.05),
                         epsilon_per_frequency=np.full(w.size, 0.1), random_error=np.full(w.size, 0.02),
                         frequency_flags=["ok"] * (w.size - 1) + ["data"])


def test_a_grid_that_follows_the_flight_keeps_its_columns_and_leaves_nan_outside_the_band():
    """A channel without ``frequencies`` cuts its result to the excited band, which grows during the flight:
    the table stays on the whole grid (a layout's indices hold), the band's columns filled, the rest NaN."""
    config = load_config(CONFIG)
    channel = dataclasses.replace(
        config.channels["pitch"], frequencies=FrequencyGrid(0.3, 100.0, 50, configured=False)
    )
    grid = channel.frequencies.values()
    for lo, hi in ((10, 20), (5, 35)):
        table = frequency_response_table(_result(grid[lo:hi], channel.model), channel)
        assert table.shape == (len(CURVES), grid.size)
        curves = read_table(table.ravel(), CURVES)
        np.testing.assert_allclose(curves["frequency_rad_s"], grid)
        np.testing.assert_allclose(curves["log10_frequency_rad_s"], np.log10(grid))
        band = np.zeros(grid.size, bool)
        band[lo:hi] = True
        for name in CURVES[2:]:
            assert np.isfinite(curves[name][band]).all() and np.isnan(curves[name][~band]).all(), name
        # the JSON's numbers: 0.9 x the model, and a lag of 0.02 s
        np.testing.assert_allclose(curves["measured_magnitude_db"][band] - curves["model_magnitude_db"][band],
                                   20 * np.log10(0.9), atol=1e-9)
        np.testing.assert_allclose(curves["measured_phase_deg"][band] - curves["model_phase_deg"][band],
                                   np.degrees(-0.02 * grid[band]), atol=1e-9)
        assert flags_from_codes(curves["flag"][band]) == ["ok"] * (hi - lo - 1) + ["data"]
        assert curves["flag"][band][-1] == FLAG_CODES["data"]


def test_no_estimate_yet_gives_the_grid_alone_and_a_mimo_channel_no_table():
    config = load_config(CONFIG)
    channel = config.channels["roll"]
    table = frequency_response_table(ChannelResult(name="roll"), channel)
    np.testing.assert_allclose(table[0], channel.frequencies.values())
    assert np.isnan(table[2:]).all()
    mimo = dataclasses.replace(
        channel, input=None, output=None, inputs=(channel.input,), outputs=(channel.output,)
    )
    assert mimo.is_mimo and frequency_response_table(ChannelResult(name="roll"), mimo) is None


def test_frequencies_off_the_grid_and_a_table_of_the_wrong_size_are_refused():
    config = load_config(CONFIG)
    channel = config.channels["yaw"]
    with pytest.raises(ValueError, match="not on its analysis grid"):
        frequency_response_table(_result(channel.frequencies.values()[:5] * 1.01, channel.model), channel)
    with pytest.raises(ValueError, match="cannot hold"):
        read_table(np.zeros(10), CURVES)
