"""Tests of MIMO validation from flight data (issue 14): gap_validation.core.mimo, spectra.solve_matrix and
the MIMO paths of the estimator, validator and simulator.

References: plain least squares over the DFT bins of the pooled records (numpy.linalg.lstsq), the Ultra Stick
25e's lateral-directional state space of the paper's lab (../shared/reference/ultrastick25e.yaml) simulated by
scipy.signal.lsim, and the chordal-distance inequality kappa(H, H + dH) <= sigma_max(dH).
"""
import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from gap_validation.core import metrics
from gap_validation.core.config import parse_config
from gap_validation.core.mimo import MimoDetail, element_kappa, kappa_noise_scale
from gap_validation.core.results import ValidationResult
from gap_validation.core.simulation import FlightOptions, simulate_flight
from gap_validation.core.spectra import BandSums, record_bands, solve_bands, solve_matrix
from gap_validation.core.validator import OnlineValidator

DT = 0.01
W = np.geomspace(1.0, 30.0, 12)

# The lateral-directional model (states v, p, r, phi): symmetric aileron (left +a, right -a) and rudder to
# roll and yaw rate; B columns are the published (left - right) aileron column and the rudder column.
A_LAT = [[-0.8726, 0.8968, -16.82, 9.791], [-2.757, -16.09, 3.368, 0.0], [1.708, 0.514, -2.775, 0.0],
         [0.0, 1.0, 0.05511, -1.507e-08]]
B_LAT = [[-4.198e-10 - 7.984e-10, 5.302], [78.23 + 78.23, -4.972], [-5.752 - 5.752, -82.04], [0.0, 0.0]]
C_LAT = [[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
LATERAL = {
    "inputs": [
        {"topic": "/control_surfaces", "field": "position[aileron]"},
        {"topic": "/control_surfaces", "field": "position[rudder]"},
    ],
    "outputs": [
        {"topic": "/imu", "field": "angular_velocity.x"},
        {"topic": "/imu", "field": "angular_velocity.z"},
    ],
    "frequencies": {"min_rad_s": 1.0, "max_rad_s": 80.0, "count": 40},
    "model": {"state_space": {"A": A_LAT, "B": B_LAT, "C": C_LAT}},
}
#: Two 40 s sweeps and a doublet per surface, aileron then rudder (about 3 minutes of flight).
SHORT = FlightOptions(sweeps_per_channel=2, sweep_duration_s=40.0, quiet_s=3.0)


def lateral_config(aileron_effectiveness=1.0):
    """A config with the lateral MIMO channel; the aileron column of B scaled by ``aileron_effectiveness``."""
    channel = copy.deepcopy(LATERAL)
    b = np.array(B_LAT) * [aileron_effectiveness, 1.0]
    channel["model"]["state_space"]["B"] = b.tolist()
    return parse_config({"channels": {"lateral": channel}}, "lateral.yaml")


def validate(flight, config, diagnose=True):
    """Feed the simulated flight's topics to a validator of ``config`` (as a replay would) and return the
    lateral channel's result."""
    validator = OnlineValidator(config, diagnose=diagnose)
    channel = config.channels["lateral"]
    validator.add_histories("lateral", flight.histories(channel))
    validator.finish()
    return validator.results().channels["lateral"]


@pytest.fixture(scope="module")
def lateral_flight():
    return simulate_flight(lateral_config(), options=SHORT, seed=3)


# ------------------------------------------------------------------------------------------- solve_matrix
def _records(rng, m, p, h_of_w, n=4000, noise=0.02, count=None):
    """Single-axis records: in each only one input moves (white noise, low-passed); outputs from a static
    complex-free FIR per element, plus noise."""
    b, a = signal.butter(4, 0.4)
    out = []
    for r in range(count or m):
        u = np.zeros((m, n))
        u[r % m] = signal.lfilter(b, a, rng.standard_normal(n))
        u[:, :200] = 0.0
        u[:, -400:] = 0.0
        y = np.stack([sum(h_of_w[i][j](u[j]) for j in range(m)) for i in range(p)])
        out.append((u, y + noise * rng.standard_normal((p, n))))
    return out


def _fir(taps):
    return lambda u: signal.lfilter(taps, [1.0], u)


def test_solve_matrix_of_one_input_and_output_is_solve_bands_to_the_bit():
    rng = np.random.default_rng(0)
    sums = BandSums.zeros(W.size, order=2)
    for u, y in _records(rng, 1, 1, [[_fir([0.5, 0.3, -0.2])]], count=3):
        rec, status = record_bands(u, y, DT, W)
        sums.add(rec, status == 0)
    siso, matrix = solve_bands(sums), solve_matrix(sums)
    ok = np.isfinite(siso.response)
    assert ok.sum() >= 8
    assert np.array_equal(matrix.response[:, 0, 0], siso.response, equal_nan=True)
    assert np.array_equal(matrix.variance[:, 0, 0], siso.variance)
    assert np.array_equal(matrix.dof, siso.dof)
    assert np.array_equal(matrix.multiple_coherence[:, 0], siso.coherence)
    assert np.array_equal(matrix.partial_coherence[:, 0, 0], siso.coherence)


def test_solve_matrix_is_least_squares_over_the_pooled_bins(monkeypatch):
    """With a constant response polynomial and no transient term the local polynomial method is plain least
    squares of Y on U over the band's bins of every record: compare with numpy.linalg.lstsq."""
    rng = np.random.default_rng(1)
    h = [[_fir([0.5, 0.3]), _fir([0.1, -0.4])], [_fir([-0.2, 0.2]), _fir([1.0, 0.5, 0.25])]]
    records = _records(rng, 2, 2, h, count=4)
    options = {"order": 0, "transient_order": -1, "min_bins": 7}
    sums = BandSums.zeros(W.size, 2, 2, order=0)
    bands_of = []
    for u, y in records:
        rec, status = record_bands(u, y, DT, W, options=options)
        sums.add(rec, status == 0)
        bands_of.append((u, y, status))
    from gap_validation.core import spectra

    # the least-squares algebra itself: without the neighbour floor on the noise (test_spectra pins that)
    monkeypatch.setattr(spectra, "neighbour_noise_floor", lambda noise, dof: np.full(np.shape(noise), np.nan))
    matrix = solve_matrix(sums)
    checked = 0
    for k, w in enumerate(W):
        if not np.all(np.isfinite(matrix.response[k])):
            continue
        rows_u, rows_y = [], []
        for u, y, status in bands_of:
            if status[k] != 0:
                continue
            n = u.shape[1]
            fu, fy = (
                np.fft.rfft(u - _line(u), axis=1) / math.sqrt(n),
                np.fft.rfft(y - _line(y), axis=1) / math.sqrt(n),
            )
            w_bins = 2 * np.pi * np.fft.rfftfreq(n, DT)
            power = np.sum(np.abs(fu) ** 2, axis=0)
            from gap_validation.core.spectra import band_bins

            sel = band_bins(w_bins, w, 0.1, 7, 0.6, power)
            rows_u.append(fu[:, sel].T)
            rows_y.append(fy[:, sel].T)
        big_u, big_y = np.concatenate(rows_u), np.concatenate(rows_y)
        theta, *_ = np.linalg.lstsq(big_u, big_y, rcond=None)
        assert np.allclose(matrix.response[k], theta.T, rtol=1e-9, atol=1e-12)
        resid = big_y - big_u @ theta
        dof = big_u.shape[0] - 2
        sigma2 = np.sum(np.abs(resid) ** 2, axis=0) / dof
        cov = np.linalg.inv(big_u.conj().T @ big_u)
        assert np.allclose(matrix.variance[k], sigma2[:, None] * np.real(np.diag(cov))[None, :], rtol=1e-6)
        checked += 1
    assert checked >= 8


def _line(v):
    from gap_validation.core.spectra import _line as line

    return line(v, DT)


def test_partial_coherence_is_low_for_an_element_that_is_not_there():
    rng = np.random.default_rng(2)
    zero = lambda u: 0.0 * u  # noqa: E731
    h = [[_fir([0.5, 0.3]), zero], [_fir([-0.2, 0.2]), _fir([1.0, 0.5])]]
    sums = BandSums.zeros(W.size, 2, 2, order=2)
    for u, y in _records(rng, 2, 2, h, count=4, noise=0.05):
        rec, status = record_bands(u, y, DT, W)
        sums.add(rec, status == 0)
    matrix = solve_matrix(sums)
    ok = np.all(np.isfinite(matrix.response), axis=(1, 2))
    assert ok.sum() >= 8
    assert np.all(matrix.partial_coherence[ok, 0, 1] < 0.3)      # output 0 does not depend on input 1
    assert np.all(matrix.partial_coherence[ok, 0, 0] > 0.9)
    assert np.all(matrix.multiple_coherence[ok] > 0.9)


# ------------------------------------------------------------------------------------------- kappa's errors
matrices = st.lists(st.floats(-5, 5), min_size=8, max_size=8).map(
    lambda v: (np.array(v[:4]) + 1j * np.array(v[4:])).reshape(1, 2, 2))


@settings(max_examples=40, deadline=None)
@given(matrices, matrices)
def test_kappa_of_a_perturbation_is_within_sigma_max_and_the_element_bound(h, dh):
    dh = 0.1 * dh
    kappa = metrics.chordal_distance(h, h + dh)[0]
    assert kappa <= np.linalg.norm(dh[0], 2) + 1e-12
    # kappa <= the sum of the element contributions (each element's mismatch alone), the largest of which
    # names the element that dominates
    assert kappa <= np.sum(element_kappa(h, h + dh)) + 1e-12
    assert np.max(element_kappa(h, h + dh)) <= np.linalg.norm(dh[0], 2) + 1e-12


def test_kappa_noise_scale_is_the_rms_of_kappa_for_small_random_errors():
    rng = np.random.default_rng(5)
    h = np.array([[[8.6 - 2j, 1.0 + 0.5j], [0.7j, 5.4 - 3j]]])
    sigma = np.array([[0.2, 0.05], [0.02, 0.1]])
    scale = kappa_noise_scale(h, h, sigma[None] ** 2, bias_error=0.0)[0]
    draws = (rng.standard_normal((4000, 2, 2)) + 1j * rng.standard_normal((4000, 2, 2))) * sigma / np.sqrt(2)
    kappa = metrics.chordal_distance(np.broadcast_to(h, draws.shape), h + draws)
    assert np.sqrt(np.mean(kappa ** 2)) <= scale * 1.02
    assert np.sqrt(np.mean(kappa ** 2)) >= 0.5 * scale        # sigma_max vs Frobenius: within sqrt(2) here
    assert np.mean(kappa > 4 * scale) == 0.0


# ------------------------------------------------------------------------------------------- simulator
def test_simulator_flies_each_input_in_turn_and_writes_the_full_state_space_outputs():
    config = lateral_config()
    flight = simulate_flight(config, options=FlightOptions(sweeps_per_channel=1, sweep_duration_s=20.0,
                                                           quiet_s=2.0, noise=0.0), seed=1)
    kinds = [(s.kind, s.input_index) for s in flight.segments]
    assert kinds == [("sweep", 0), ("doublet", 0), ("sweep", 1), ("doublet", 1)]
    u, y = flight.inputs["lateral"], flight.outputs["lateral"]
    assert u.shape == (2, flight.t_s.size) and y.shape == (2, flight.t_s.size)
    first, second = flight.segments[0], flight.segments[2]
    during_first = (flight.t_s > first.start_s) & (flight.t_s < first.end_s)
    assert np.all(u[1, during_first] == 0.0) and np.ptp(u[0, during_first]) > 0.1
    assert np.all(u[0, (flight.t_s > second.start_s) & (flight.t_s < second.end_s)] == 0.0)
    system = signal.StateSpace(np.array(A_LAT), np.array(B_LAT), np.array(C_LAT), np.zeros((2, 2)))
    _, reference, _ = signal.lsim(system, u.T, flight.t_s, interp=True)
    assert np.allclose(y, reference.T, atol=1e-6 * np.max(np.abs(reference)))
    assert set(flight.topics["/control_surfaces"].values) == {"position[aileron]", "position[rudder]"}
    assert set(flight.topics["/imu"].values) == {"angular_velocity.x", "angular_velocity.z"}


def test_config_topics_name_the_mimo_streams():
    config = lateral_config()
    topics = config.topics()
    assert [(c, s) for c, s, _ in topics["/control_surfaces"]] == [
        ("lateral", "inputs[0]"),
        ("lateral", "inputs[1]"),
    ]
    assert [(c, s) for c, s, _ in topics["/imu"]] == [("lateral", "outputs[0]"), ("lateral", "outputs[1]")]


# ------------------------------------------------------------------------------------------- flights
def test_the_model_that_flew_has_a_small_mimo_nu_gap_and_is_not_model_limited(lateral_flight):
    result = validate(lateral_flight, lateral_config())
    assert result.nu_gap is not None and result.nu_gap < 0.15
    assert result.limited_by != "model"
    assert result.diagnosis == []
    assert result.points_used >= 30
    assert result.mimo.measured.shape == (40, 2, 2)
    # every element of the measured matrix agrees with the truth where the data are confident
    truth = lateral_config().channels["lateral"].model.freqresp(result.frequency_rad_s)
    ok = result.confident
    rel = np.abs(result.mimo.measured[ok] - truth[ok]) / np.abs(truth[ok])
    assert np.median(rel) < 0.05


def test_a_weaker_aileron_column_is_model_limited_and_named(lateral_flight):
    result = validate(lateral_flight, lateral_config(aileron_effectiveness=0.6))
    assert result.limited_by == "model"
    assert any(b.limited_by == "model" for b in result.bands)
    worst = result.mimo.worst_elements[0]
    assert (worst["input_index"], worst["output_index"]) == (0, 0)        # aileron -> roll rate
    top = result.diagnosis[0]
    assert top.effect == "gain" and top.parameters["input_index"] == 0
    assert top.parameters["factor"] == pytest.approx(1 / 0.6, rel=0.05)
    assert "aileron" in result.message and "model-limited" in result.message


def test_mimo_results_serialise_and_come_back(lateral_flight):
    result = validate(lateral_flight, lateral_config(aileron_effectiveness=0.6), diagnose=False)
    data = ValidationResult(channels={"lateral": result}).to_json_dict()
    channel = data["channels"]["lateral"]
    assert channel["nu_gap"] == pytest.approx(result.nu_gap) and channel["limited_by"] == "model"
    assert channel["epsilon"] is None and channel["gain_margin_db"] is None
    mimo = channel["mimo"]
    assert mimo["shape"] == [2, 2] and len(mimo["elements"]) == 4
    assert mimo["elements"][1]["input"] == "/control_surfaces position[rudder]"
    assert len(mimo["singular_values"]["measured"]) == 2
    back = ValidationResult.from_json_dict(data).channels["lateral"]
    ok = result.confident
    assert np.allclose(back.mimo.measured[ok], result.mimo.measured[ok], rtol=1e-9)
    assert np.allclose(back.mimo.partial_coherence[ok], result.mimo.partial_coherence[ok])
    assert back.mimo.worst_elements == result.mimo.worst_elements
    assert isinstance(back.mimo, MimoDetail)


def test_report_of_a_mimo_channel_has_its_bode_matrix_kappa_and_singular_values(lateral_flight, tmp_path):
    from gap_validation.report.html import write_report
    from gap_validation.report.terminal import format_table

    result = validate(lateral_flight, lateral_config(aileron_effectiveness=0.6))
    problems = []
    index = write_report(ValidationResult(channels={"lateral": result}), tmp_path, warn=problems.append)
    assert problems == []
    for kind in ("mimo_bode", "mimo_kappa", "mimo_sv"):
        assert (tmp_path / f"lateral_{kind}.png").stat().st_size > 10_000
    text = index.read_text()
    assert "2x2 MIMO nu-gap" in text and "Model-limited" in text and "gain 1.6" in text
    row = next(line for line in format_table(ValidationResult(channels={"lateral": result})).splitlines()
               if line.startswith("lateral"))
    assert row.split()[:3] == ["lateral", "(2x2)", f"{result.nu_gap:.3f}"]


def test_a_mimo_channel_resumes_from_its_checkpoint_state(lateral_flight):
    config = lateral_config()
    validator = OnlineValidator(config, diagnose=False)
    channel = config.channels["lateral"]
    histories = {s: (lateral_flight.topics[channel.signal(s).topic].stamp_s,
                     lateral_flight.topics[channel.signal(s).topic].values[channel.signal(s).field])
                 for s in channel.input_streams + channel.output_streams}
    validator.add_histories("lateral", histories)
    validator.finish()
    resumed = OnlineValidator.from_state(config, validator.state_dict(), diagnose=False)
    before, after = validator.results().channels["lateral"], resumed.results().channels["lateral"]
    assert after.nu_gap == before.nu_gap and after.sweeps == before.sweeps
    assert np.array_equal(after.mimo.measured, before.mimo.measured, equal_nan=True)


def test_column_diagnosis_finds_a_delay_on_the_rudder_column():
    from gap_validation.core.mimo import diagnose_columns

    model = lateral_config().channels["lateral"].model
    w = np.geomspace(1.0, 60.0, 30)
    h = model.freqresp(w).copy()
    h[:, :, 1] *= np.exp(-1j * w * 0.05)[:, None]                 # 50 ms on the rudder only
    found = diagnose_columns(model, w, h, np.ones(w.size, bool), ["aileron", "rudder"], np.full(w.size, 1e-3))
    top = found[0]
    assert (top.effect, top.parameters["input"]) == ("time_delay", "rudder")
    assert top.parameters["seconds"] == pytest.approx(0.05, rel=1e-3)
    assert top.nu_gap < 1e-3 and top.explains
    # no candidate on data the model explains
    assert diagnose_columns(model, w, model.freqresp(w), np.ones(w.size, bool), ["a", "r"],
                            np.full(w.size, 1e-3)) == []
