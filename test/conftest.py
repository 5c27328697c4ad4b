"""Fixtures shared by test modules: the measured pitch-rate flights of ``_pitch_flights`` (estimator,
alignment) and a tiny simulated flight with its bag (reader, writer; a module's own ``flight`` fixture takes
precedence)."""
import pytest
from _flights import TINY, ultrastick
from _pitch_flights import _chunks, estimate, measure
from _pitch_flights import flight as pitch_flight

from gap_validation.core.simulation import simulate_flight


@pytest.fixture(scope="module")
def nominal():
    """The flight measured at 100 Hz (surfaces) and 1 kHz (IMU), and its estimate."""
    t, u, y = pitch_flight()
    streams = measure(t, u, y, 100.0, 1000.0, seed=1)
    return t, u, y, streams, estimate(*streams)


@pytest.fixture(scope="module")
def lap():
    """One 110 s lap with one sweep, measured at 100 Hz / 1 kHz, as 2 s interleaved chunks (replay-like)."""
    t, u, y = pitch_flight(duration_s=110.0, sweeps=((10.0, 70.0),))
    return _chunks(measure(t, u, y, 100.0, 1000.0, seed=1), step_s=2.0)


@pytest.fixture(scope="module")
def flight():
    """A tiny simulated flight of the bundled config (bag I/O tests)."""
    return simulate_flight(ultrastick(), options=TINY, seed=4)


@pytest.fixture(scope="module")
def mcap_bag(tmp_path_factory, flight):
    """``flight`` written as an mcap rosbag2 directory."""
    from gap_validation.bag.writer import write_flight

    path = tmp_path_factory.mktemp("bags") / "flight"
    write_flight(flight, path)
    return path
