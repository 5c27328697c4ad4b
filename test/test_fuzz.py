"""Fuzzing (hypothesis) of the three places where outside data enter: the config loader, the field-path parser
and the estimator's sample intake. Properties: only the documented errors (ConfigError for configs and paths,
DataError for malformed calls), and never a non-finite number in a result.
"""
from __future__ import annotations

import copy
import json
import math

import numpy as np
from _flights import raw_config, single_channel
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gap_validation.core.config import load_config, parse_config
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.fields import FieldPath
from gap_validation.core.validator import OnlineValidator

FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                     HealthCheck.function_scoped_fixture])

# ------------------------------------------------------------------------------------------------ config
scalars = st.one_of(st.none(), st.booleans(), st.integers(-10 ** 6, 10 ** 6),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12))
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)


def _paths(data, prefix=()):
    """Every key path of a nested mapping/list (where a mutation can go)."""
    yield prefix
    if isinstance(data, dict):
        for key, value in data.items():
            yield from _paths(value, prefix + (key,))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            yield from _paths(value, prefix + (i,))


BASE = raw_config()
PATHS = [p for p in _paths(BASE) if p]


@FAST
@given(st.lists(st.tuples(st.sampled_from(PATHS), values, st.booleans()), min_size=1, max_size=4))
def test_config_mutations_give_a_config_or_a_config_error(mutations):
    data = copy.deepcopy(BASE)
    for path, value, delete in mutations:
        parent = data
        try:
            for key in path[:-1]:
                parent = parent[key]
            if delete and isinstance(parent, dict):
                parent.pop(path[-1], None)
            else:
                parent[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            continue                                       # an earlier mutation removed the place
    try:
        config = parse_config(data, "fuzz.yaml")
    except ConfigError as err:
        assert "\n" not in str(err) and str(err).startswith("fuzz.yaml")
        return
    for channel in config.channels.values():              # accepted: a usable model
        response = channel.model.freqresp(channel.frequencies.values())
        assert np.all(np.isfinite(response) | np.isnan(response))


@FAST
@given(values)
def test_any_yaml_value_gives_a_config_or_a_config_error(value):
    try:
        parse_config(value, "fuzz.yaml")
    except ConfigError as err:
        assert "\n" not in str(err)


@FAST
@given(st.one_of(st.text(max_size=200), st.binary(max_size=200).map(lambda b: b.decode("latin-1"))),
       st.booleans())
def test_any_file_content_gives_a_config_or_a_config_error(tmp_path_factory, text, as_bytes):
    path = tmp_path_factory.mktemp("fuzz") / "cfg.yaml"
    if as_bytes:
        path.write_bytes(text.encode("latin-1", errors="replace"))
    else:
        path.write_text(text, encoding="utf-8")
    try:
        load_config(path)
    except ConfigError as err:
        assert str(path) in str(err) and "\n" not in str(err)


# ------------------------------------------------------------------------------------------------ field paths
path_text = st.one_of(st.text(max_size=30),
                      st.text(alphabet="ab_.[]0123456789-'\" ", max_size=30))


@settings(max_examples=300, deadline=None)
@given(path_text)
def test_field_path_parse_gives_a_path_or_a_config_error(text):
    try:
        path = FieldPath.parse(text)
    except ConfigError as err:
        assert "\n" not in str(err)
        return
    assert path.steps and FieldPath.parse(path.text) == path  # parsing its own text gives the same path


# ------------------------------------------------------------------------------------------------ sample
# intake
CONFIG = parse_config({**single_channel("pitch"), "channels": {"pitch": {
    **single_channel("pitch")["channels"]["pitch"],
    "frequencies": {"min_rad_s": 1.0, "max_rad_s": 20.0, "count": 8},
    "estimator": {"min_sweep_s": 2.0, "hold_s": 0.5, "energy_window_s": 0.5, "quiet_window_s": 2.0}}}},
    "fuzz.yaml")


@st.composite
def stream(draw, t0, f):
    """A sensor stream (a sweep from 5 to 20 s after ``t0`` [s], start frequency ``f`` [Hz]) with trouble:
    NaN/inf, absurd values and stamps, duplicates, reversals, jumps back and forward."""
    dt = draw(st.floats(0.01, 0.05))
    full = int(30.0 / dt)
    n = draw(st.one_of(st.just(full), st.just(full), st.just(full), st.integers(0, full)))
    t = t0 + np.arange(n) * dt
    v = np.where(
        (t - t0 > 5.0) & (t - t0 < 20.0), np.sin(2 * np.pi * f * (t - t0) * (1 + (t - t0) / 10)), 0.0
    )
    v = v + np.random.default_rng(draw(st.integers(0, 99))).normal(0.0, 1e-3, n)
    for _ in range(draw(st.integers(0, 4))):
        if n == 0:
            break
        i = draw(st.integers(0, n - 1))
        kind = draw(st.sampled_from(["nan", "inf", "dup", "swap", "jump_back", "jump_fwd", "stray"]))
        if kind == "nan":
            (t if draw(st.booleans()) else v)[i] = np.nan
        elif kind == "inf":
            v[i] = draw(st.sampled_from([np.inf, -np.inf, 1e308]))
        elif kind == "dup" and i > 0:
            t[i] = t[i - 1]
        elif kind == "swap" and i > 0:
            t[i - 1], t[i] = t[i], t[i - 1]
        elif kind == "jump_back":
            t[i:] -= draw(st.floats(1.5, 500.0))
        elif kind == "jump_fwd":
            t[i:] += draw(st.floats(0.6, 500.0))
        elif kind == "stray":
            t[i] -= draw(st.sampled_from([draw(st.floats(-1e4, 1e4)), 1e300, -1e19, 2.0 ** 63]))
    return t, v


def _batches(draw, t, v):
    cuts = sorted(draw(st.lists(st.integers(0, max(t.size, 1)), max_size=8)))
    edges = [0, *cuts, t.size]
    return [(t[a:b], v[a:b]) for a, b in zip(edges[:-1], edges[1:])]


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_sample_intake_never_raises_and_never_gives_non_finite_results(data):
    validator = OnlineValidator(CONFIG, diagnose=False)
    t0, f = data.draw(st.sampled_from([0.0, 1.7e9, -50.0])), data.draw(st.floats(0.2, 3.0))
    t_in, u = data.draw(stream(t0, f))
    t_out, y = data.draw(stream(t0, f))
    ins, outs = _batches(data.draw, t_in, u), _batches(data.draw, t_out, y)
    if data.draw(st.sampled_from([True, True, False])):     # an explicit sweep trigger, with its own trouble
        t_tr, _ = data.draw(stream(t0, f))
        validator.add_samples("pitch", "trigger", t_tr, ((t_tr - t0) > 5.0) & ((t_tr - t0) < 20.0))
    for i in range(max(len(ins), len(outs))):
        if i < len(ins):
            validator.add_samples("pitch", "input", *ins[i])
        if i < len(outs):
            validator.add_samples("pitch", "output", *outs[i])
        if data.draw(st.booleans()):
            state = validator.state_dict()                    # checkpoint and resume anywhere
            validator = OnlineValidator.from_state(CONFIG, state, diagnose=False)
    validator.finish()
    result = validator.results()
    text = json.dumps(result.to_json_dict(), allow_nan=False)  # raises on NaN or inf anywhere
    ch = result.channels["pitch"]
    for value in (ch.epsilon, ch.nu_gap, ch.epsilon_raw):
        assert value is None or math.isfinite(value)
    assert text
    avg = validator.estimate("pitch")
    if avg is not None:                                    # spectra never poisoned by one absurd sample
        assert np.all(np.isfinite(avg.gxx)) and np.all(np.isfinite(avg.gyy)) and np.all(np.isfinite(avg.gxy))
    counts = validator._estimators["pitch"].bad_sample_counts
    assert counts["input"]["accepted"] + counts["input"]["nonfinite"] + counts["input"]["non_monotonic"] \
        <= t_in.size


def test_mismatched_batch_is_a_data_error():
    validator = OnlineValidator(CONFIG, diagnose=False)
    try:
        validator.add_samples("pitch", "input", [1.0, 2.0], [1.0])
    except DataError as err:
        assert "input" in str(err)
    else:
        raise AssertionError("expected a DataError")
