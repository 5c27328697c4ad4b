"""Atomic writes (gap_validation.core.atomic): every result file is either the old one or the new one, never
half.

Covers the helper itself and the four writers built on it (JSON results, ``dump_config``, the history, the
node's checkpoint): an exception mid-write, a failing ``fsync``/rename, and a real ``kill -9`` of a child
process -- once at a chosen point inside the write (with a plain, non-atomic writer as the control that the
check can fail), once at random moments while the child writes in a loop.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from gap_validation.core import atomic
from gap_validation.core import atomic as core_atomic
from gap_validation.core.checkpoint import load_state
from gap_validation.core.config import dump_config
from gap_validation.core.errors import DataError
from gap_validation.history import load_history
from gap_validation.report.terminal import write_json

ROOT = Path(__file__).resolve().parents[1]

#: Child-side writers: ``write(kind, directory, i)`` writes version ``i`` of one file; content checks itself.
CHILD_WRITERS = r'''
import json, os, sys, time
import numpy as np
from pathlib import Path
from gap_validation.core.config import dump_config
from gap_validation.core.checkpoint import save_state
from gap_validation.core.config import parse_config
from gap_validation.core.results import ChannelResult, ValidationResult
from gap_validation.history import append_history
from gap_validation.report.terminal import write_json

CONFIG = parse_config({"channels": {"pitch": {
    "input": {"topic": "/control_surfaces", "field": "position[elevator]"},
    "output": {"topic": "/imu", "field": "angular_velocity.y"},
    "model": {"numerator": [-133.7, -990.76], "denominator": [1.0, 23.37, 235.93]}}}}, "cfg.yaml")

def size(i):
    return 20000 + 7919 * (i % 13)

def write(kind, d, i):
    n = size(i)
    if kind == "json":
        write_json({"i": i, "n": n, "data": list(range(n))}, d / "results.json")
    elif kind == "config":
        dump_config({"i": i, "n": n, "pad": ["x" * 40] * (n // 40)}, d / "config.yaml")
    elif kind == "history":
        ch = ChannelResult(name="pitch", sweeps=1, epsilon=0.1, nu_gap=0.05, epsilon_raw=0.1)
        append_history(d / "h.jsonl", ValidationResult(channels={"pitch": ch}), CONFIG,
                       [f"bag{i}"] * (n // 100))
    elif kind == "checkpoint":
        save_state({"i": i, "a": np.arange(float(n))}, d / "state.npz")
    elif kind == "naive":   # the control: a plain, non-atomic write
        with os.fdopen(os.open(d / "results.json", os.O_WRONLY | os.O_CREAT | os.O_TRUNC), "w") as fh:
            json.dump({"i": i, "n": n, "data": list(range(n))}, fh)
'''

#: Child of the targeted kill: version 0 completely, then version 1 stalls halfway through its first write.
CHILD_STALL = CHILD_WRITERS + r'''
kind, d = sys.argv[1], Path(sys.argv[2])
write(kind, d, 0)
real_fdopen = os.fdopen

class Stalling:
    """File wrapper: from the first 1 kB on, the next write puts half its bytes on disk, says so, and
    hangs."""
    def __init__(self, handle):
        self._h = handle
        self._written = 0
    def write(self, data):
        if self._written + len(data) < 1024:
            self._written += len(data)
            return self._h.write(data)
        self._h.write(data[: len(data) // 2])
        self._h.flush()
        os.fsync(self._h.fileno())
        print("mid", flush=True)
        time.sleep(120)
    def __getattr__(self, name):
        return getattr(self._h, name)
    def __enter__(self):
        return self
    def __exit__(self, *exc):
        return self._h.__exit__(*exc)

os.fdopen = lambda *a, **k: Stalling(real_fdopen(*a, **k))
write(kind, d, 1)
'''

#: Child of the random kills: writes every file in turn, forever, printing the round number.
CHILD_LOOP = CHILD_WRITERS + r'''
d, start = Path(sys.argv[1]), int(sys.argv[2])
i = start
while True:
    for kind in ("json", "config", "history", "checkpoint"):
        write(kind, d, i)
    print(i, flush=True)
    i += 1
'''


def _size(i: int) -> int:
    return 20000 + 7919 * (i % 13)


def check_json(d: Path) -> int:
    data = json.loads((d / "results.json").read_text())
    assert data["n"] == _size(data["i"]) and data["data"] == list(range(data["n"]))
    return data["i"]


def check_config(d: Path) -> int:
    data = yaml.safe_load((d / "config.yaml").read_text())
    assert data["n"] == _size(data["i"]) and data["pad"] == ["x" * 40] * (data["n"] // 40)
    return data["i"]


def check_history(d: Path) -> int:
    records = load_history(d / "h.jsonl")  # DataError on any torn or corrupt line
    for record in records:
        i = int(record["sources"][0][3:])
        assert record["sources"] == [f"bag{i}"] * (_size(i) // 100)
        assert record["channels"]["pitch"]["epsilon"] == 0.1
    return int(records[-1]["sources"][0][3:])


def check_checkpoint(d: Path) -> int:
    state = load_state(d / "state.npz")  # DataError on a truncated zip
    np.testing.assert_array_equal(state["a"], np.arange(float(_size(state["i"]))))
    return state["i"]


CHECKS = {
    "json": check_json,
    "config": check_config,
    "history": check_history,
    "checkpoint": check_checkpoint,
}
TARGETS = {"json": "results.json", "config": "config.yaml", "history": "h.jsonl", "checkpoint": "state.npz"}


@contextlib.contextmanager
def _killed_at_the_end(child: subprocess.Popen):
    """SIGKILL ``child`` when the block ends (also on failure) and close its pipes."""
    try:
        yield child
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        child.stdout.close()
        child.stderr.close()


def _child(code: str, *args) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code), *map(str, args)], env=env, cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _temps(d: Path) -> list[Path]:
    return [p for p in d.iterdir() if p.name.endswith(core_atomic.TEMP_SUFFIX)]


# ------------------------------------------------------------------------------------------------ the helper
def test_helper_writes_replaces_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "out.txt"
    assert atomic.atomic_write_text(path, "first\n") == path
    atomic.atomic_write_bytes(path, b"second\n")
    assert path.read_bytes() == b"second\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_helper_exception_inside_the_block_keeps_the_old_file(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic.atomic_open(path) as handle:
            handle.write("new, half of it")
            handle.flush()
            assert len(_temps(tmp_path)) == 1  # the new content goes to a temporary file beside the target
            raise RuntimeError("boom")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_helper_temporary_is_complete_before_the_rename(tmp_path, monkeypatch):
    path = tmp_path / "out.bin"
    seen = []
    real_replace = os.replace

    def spy(src, dst):
        seen.append((Path(src).parent, Path(src).read_bytes(), Path(dst)))
        real_replace(src, dst)

    monkeypatch.setattr(core_atomic.os, "replace", spy)
    atomic.atomic_write_bytes(path, b"x" * 100_000)
    assert seen == [(tmp_path, b"x" * 100_000, path)]


def test_helper_refuses_append_mode(tmp_path):
    with pytest.raises(ValueError, match="mode"):
        with atomic.atomic_open(tmp_path / "f", "a"):
            pass


# ------------------------------------------------------------------------------------------------ the writers
def _write_in_process(kind: str, d: Path, i: int) -> None:
    namespace: dict = {}
    exec(CHILD_WRITERS, namespace)  # the same writers the children run
    namespace["write"](kind, d, i)


@pytest.mark.parametrize("kind", list(CHECKS))
@pytest.mark.parametrize("failing", ["fsync", "replace"])
def test_failed_write_keeps_the_old_file_and_no_temporary(tmp_path, monkeypatch, kind, failing):
    _write_in_process(kind, tmp_path, 0)
    before = (tmp_path / TARGETS[kind]).read_bytes()

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(core_atomic.os, failing, broken)  # core_atomic.os is the os module: fails everywhere
    with pytest.raises(DataError) as err:
        _write_in_process(kind, tmp_path, 1)
    monkeypatch.undo()
    assert TARGETS[kind] in str(err.value) and "No space left on device" in str(err.value)
    assert "\n" not in str(err.value)
    assert (tmp_path / TARGETS[kind]).read_bytes() == before
    assert CHECKS[kind](tmp_path) == 0
    assert [p.name for p in tmp_path.iterdir()] == [TARGETS[kind]]


def test_json_interrupted_by_a_bad_value_midway_keeps_the_old_file(tmp_path):
    path = tmp_path / "results.json"
    write_json({"i": 0}, path)
    with pytest.raises(ValueError):  # json.dump has written the first entries when it meets the NaN
        write_json({"data": list(range(50_000)) + [math.nan]}, path)
    assert json.loads(path.read_text()) == {"i": 0}
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_config_write_error_is_one_line_naming_the_file(tmp_path):
    with pytest.raises(DataError, match=r"missing/out.yaml: cannot write config"):
        dump_config({"channels": {}}, tmp_path / "missing" / "out.yaml")


# ------------------------------------------------------------------------------------------------ kill -9
@pytest.mark.parametrize("kind", [*CHECKS, "naive"])
def test_kill_9_in_the_middle_of_a_write_leaves_the_old_file(tmp_path, kind):
    """The child stalls with half of version 1 on disk and is SIGKILLed: version 0 stays, complete.

    ``naive`` (open, truncate, write) is the control: the same kill leaves a torn file there.
    """
    child = _child(CHILD_STALL, kind, tmp_path)
    with _killed_at_the_end(child):
        assert child.stdout.readline().strip() == "mid", child.stderr.read()
    assert child.returncode == -signal.SIGKILL
    if kind == "naive":
        with pytest.raises(json.JSONDecodeError):
            check_json(tmp_path)
        return
    assert CHECKS[kind](tmp_path) == 0  # the old version, whole
    temps = _temps(tmp_path)  # the half-written version 1 is only in the hidden temporary file
    assert len(temps) == 1 and temps[0].name.startswith(f".{TARGETS[kind]}.") and temps[0].stat().st_size > 0


def test_kill_9_at_random_moments_of_a_write_loop_leaves_only_complete_files(tmp_path):
    rng = random.Random(8)
    start, kills = 0, 4
    for _ in range(kills):
        child = _child(CHILD_LOOP, tmp_path, start)
        with _killed_at_the_end(child):
            rounds = rng.randint(1, 2)
            for _ in range(rounds):
                line = child.stdout.readline()
                assert line, child.stderr.read()
            time.sleep(rng.uniform(0.0, 0.15))
        versions = {kind: check(tmp_path) for kind, check in CHECKS.items()}
        assert min(versions.values()) >= start + rounds - 1  # every completed round is on disk
        start = max(versions.values()) + 1
    names = {p.name for p in tmp_path.iterdir()} - set(TARGETS.values())
    assert all(n.startswith(".") and n.endswith(core_atomic.TEMP_SUFFIX) for n in names)  # orphans are hidden


# ------------------------------------------------------------------------------------------------ torn
# history
def _history_with_records(d: Path, count: int) -> Path:
    for i in range(count):
        _write_in_process("history", d, i)
    return d / "h.jsonl"


def test_torn_last_history_line_is_skipped_with_a_warning_naming_file_and_line(tmp_path, caplog):
    path = _history_with_records(tmp_path, 2)
    whole = path.read_bytes()
    path.write_bytes(whole + whole.splitlines(keepends=True)[0][:57])  # an append killed after 57 bytes
    with caplog.at_level("WARNING", logger="gap_validation.history"):
        records = load_history(path)
    assert [r["sources"][0] for r in records] == ["bag0", "bag1"]
    assert f"{path}:3: torn last line" in caplog.text


def test_torn_line_followed_by_more_lines_is_still_an_error(tmp_path):
    path = _history_with_records(tmp_path, 1)
    path.write_bytes(path.read_bytes() + b'{"timestamp": "x", "chan\n' + path.read_bytes())
    with pytest.raises(DataError, match=r"h.jsonl:2: corrupt validation history line"):
        load_history(path)


def test_append_after_a_torn_line_drops_it_and_keeps_a_complete_unterminated_record(tmp_path):
    path = _history_with_records(tmp_path, 1)
    first = path.read_bytes()
    path.write_bytes(first + b'{"timestamp": "2024-')  # torn
    _write_in_process("history", tmp_path, 1)
    assert [r["sources"][0] for r in load_history(path)] == ["bag0", "bag1"]
    path.write_bytes(path.read_bytes().rstrip(b"\n"))  # complete record, newline lost (edited by hand)
    _write_in_process("history", tmp_path, 2)
    assert [r["sources"][0] for r in load_history(path)] == ["bag0", "bag1", "bag2"]
    assert path.read_bytes().count(b"\n") == 3
