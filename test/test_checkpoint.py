"""Tests of gap_validation.core.checkpoint: exact round trips, atomic writes, corrupt files, no pickle."""
from __future__ import annotations

import io
import json
import math
import os
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from gap_validation.core import checkpoint
from gap_validation.core.checkpoint import load_state, save_state
from gap_validation.core.errors import DataError


def assert_same(a, b, path="root"):
    """Structural, dtype- and bit-exact equality (NaN equals NaN, key types matter)."""
    assert type(a) is type(b), f"{path}: {type(a)} != {type(b)}"
    if isinstance(a, np.ndarray) or isinstance(a, np.generic):
        assert a.dtype == b.dtype, path
        assert np.shape(a) == np.shape(b), path
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes(), path
    elif isinstance(a, dict):
        assert list(a.keys()) == list(b.keys()), path
        for key in a:
            assert_same(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, float):
        assert (math.isnan(a) and math.isnan(b)) or a == b and math.copysign(1, a) == math.copysign(1, b), (
            path
        )
    elif isinstance(a, complex):
        assert_same(a.real, b.real, path)
        assert_same(a.imag, b.imag, path)
    else:
        assert a == b, path


def example_state():
    rng = np.random.default_rng(3)
    return {
        "version": 1,
        "channels": {
            "pitch": {"gxx": rng.random(40), "gxy": rng.random(40) + 1j * rng.random(40),
                      "n": np.arange(40, dtype=np.int64), "open": np.bool_(True), "t_s": np.float64(12.5),
                      "sweeps": [{"start_s": 1.0, "end_s": float("nan")}], "empty": np.zeros((0, 3))},
            "roll": {"gxx": np.full(3, np.inf), "mask": np.array([True, False]), "note": "ok"},
        },
        "bad": {"pitch": {"input: not finite": 3}, "roll": {}},
        "previous": {"pitch": 0.62, "roll": None},
        "ints": {1: "one", 2: (2.0, -0.0, 1e-300)},
        "c": 1 + 2j,
    }


def test_round_trip_is_exact(tmp_path):
    state = example_state()
    path = save_state(state, tmp_path / "state.npz", meta={"config": "cfg.yaml"})
    back, meta = load_state(path, with_meta=True)
    assert_same(state, back)
    assert meta == {"config": "cfg.yaml"}


def test_file_is_a_zip_of_npy_members_and_json_without_pickle(tmp_path):
    path = save_state(example_state(), tmp_path / "state.npz")
    with zipfile.ZipFile(path) as archive:
        names = archive.namelist()
        doc = json.loads(archive.read("state.json"))
    assert doc["format"] == checkpoint.FORMAT and doc["version"] == checkpoint.VERSION
    assert all(n == "state.json" or n.endswith(".npy") for n in names)
    # numpy itself reads the arrays with pickle disabled
    with np.load(path, allow_pickle=False) as npz:
        assert any("gxx" in name for name in npz.files)
        gxx = [npz[name] for name in npz.files if "pitch.gxx" in name][0]
    np.testing.assert_array_equal(gxx, example_state()["channels"]["pitch"]["gxx"])


def test_object_leaves_are_refused_not_pickled(tmp_path):
    with pytest.raises(TypeError, match="channels.x"):
        save_state({"channels": {"x": np.array([object()], dtype=object)}}, tmp_path / "s.npz")
    with pytest.raises(TypeError, match="set"):
        save_state({"a": {1, 2}}, tmp_path / "s.npz")
    assert not (tmp_path / "s.npz").exists()
    assert list(tmp_path.iterdir()) == []


def test_write_is_atomic_old_checkpoint_survives_a_failed_write(tmp_path, monkeypatch):
    path = tmp_path / "state.npz"
    save_state({"a": np.arange(3.0)}, path)
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np.lib.format, "write_array", boom)
    with pytest.raises(DataError, match="state.npz: cannot write checkpoint"):
        save_state({"a": np.arange(5.0)}, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["state.npz"]  # no temporary file left behind


def test_replace_is_the_last_step(tmp_path, monkeypatch):
    path = tmp_path / "state.npz"
    save_state({"a": 1}, path)
    seen = []
    real_replace = os.replace

    def spy(src, dst):
        # the new file is complete and loadable before it replaces the old one
        seen.append(load_state(src))
        real_replace(src, dst)

    monkeypatch.setattr(checkpoint.os, "replace", spy)
    save_state({"a": 2}, path)
    assert seen == [{"a": 2}] and load_state(path) == {"a": 2}


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty", "json", "foreign", "missing_member"])
def test_corrupt_files_raise_one_line_data_error(tmp_path, damage):
    path = tmp_path / "state.npz"
    save_state(example_state(), path)
    raw = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(raw[: len(raw) // 2])
    elif damage == "garbage":
        path.write_bytes(b"\x00not a zip" * 10)
    elif damage == "empty":
        path.write_bytes(b"")
    else:
        with zipfile.ZipFile(path) as archive:
            members = {n: archive.read(n) for n in archive.namelist()}
        if damage == "json":
            members["state.json"] = b"{not json"
        elif damage == "foreign":
            members["state.json"] = json.dumps({"format": "something else"}).encode()
        else:
            members.pop(next(n for n in members if n.endswith(".npy")))
        with zipfile.ZipFile(path, "w") as archive:
            for name, data in members.items():
                archive.writestr(name, data)
    with pytest.raises(DataError) as info:
        load_state(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message and "corrupt checkpoint" in message


def test_pickled_arrays_are_not_loaded(tmp_path):
    path = tmp_path / "state.npz"
    save_state({"a": np.arange(2.0)}, path)
    with zipfile.ZipFile(path) as archive:
        members = {n: archive.read(n) for n in archive.namelist()}
    name = next(n for n in members if n.endswith(".npy"))
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.array([{"evil": 1}], dtype=object), allow_pickle=True)
    members[name] = buffer.getvalue()
    with zipfile.ZipFile(path, "w") as archive:
        for n, data in members.items():
            archive.writestr(n, data)
    with pytest.raises(DataError, match="corrupt checkpoint"):
        load_state(path)


def test_missing_file():
    with pytest.raises(DataError, match="checkpoint not found"):
        load_state("/nonexistent/dir/state.npz")


def test_unwritable_directory_is_one_line_error(tmp_path):
    with pytest.raises(DataError, match="cannot write checkpoint"):
        save_state({"a": 1}, tmp_path / "no_such_dir" / "state.npz")


# ---------------------------------------------------------------- property: any state tree round-trips
# exactly
_keys = st.one_of(st.text(max_size=8), st.integers(-5, 5))
_floats = st.floats(allow_nan=True, allow_infinity=True)
_arrays = hnp.arrays(
    dtype=st.sampled_from([np.float64, np.float32, np.complex128, np.int64, np.int8, np.bool_, np.uint16]),
    shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4),
)
_leaves = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70), _floats, st.text(max_size=10),
                    st.complex_numbers(allow_nan=True, allow_infinity=True), _arrays,
                    _arrays.filter(lambda a: a.ndim == 0).map(lambda a: a[()]))
_trees = st.recursive(_leaves, lambda children: st.one_of(
    st.lists(children, max_size=4), st.lists(children, max_size=3).map(tuple),
    st.dictionaries(_keys, children, max_size=4)), max_leaves=20)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(state=_trees)
def test_any_tree_round_trips_bit_exactly(tmp_path, state):
    path = tmp_path / "prop.npz"
    save_state(state, path)
    assert_same(state, load_state(path))
