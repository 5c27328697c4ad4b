"""Flight logs replayed block by block (issue 24: streaming and constant memory as for bags): a log read in
tiny blocks gives the results of one block holding the whole file, the blocks joined are the whole read, the
merge of the topics is the stable time sort of all their samples, and the logging checks gathered in pieces
are those of the whole series."""
import json
import math

import numpy as np
import pytest
from _flights import SHORT, config_from, single_channel

from gap_validation.bag.replay import replay
from gap_validation.cli.arguments import hidden_effects
from gap_validation.core.config import load_config
from gap_validation.core.simulation import simulate_flight, with_options
from gap_validation.logs import checks, csvlog, dataflash, ulog
from gap_validation.logs.base import WriteTopic, join_blocks
from gap_validation.logs.checks import StampStats, check_stamps
from gap_validation.logs.flight import BOOT_S, write_flight_log
from gap_validation.logs.formats import open_log
from gap_validation.logs.merge import merge_in_time_order

#: One 30 s pitch sweep and a doublet, the gyro at 250 Hz and the servos at 50 Hz (about 0.5 MB as a ULog).
CARD = with_options(SHORT, sweeps_per_channel=1, sweep_duration_s=30.0, quiet_s=3.0, surface_rate_hz=50.0,
                    imu_rate_hz=250.0)
#: Each format's block size: the module constant the reader's default comes from (bytes; CSV characters).
KNOBS = {"ulog": (ulog, "_BLOCK"), "dataflash": (dataflash, "_WINDOW"), "csv": (csvlog, "_CHUNK")}
TINY = 4096


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """The flight (a hidden 40 ms delay on pitch) in every log format, with its config."""
    root = tmp_path_factory.mktemp("stream")
    pitch = config_from(single_channel("pitch"))
    flight = simulate_flight(pitch, hidden_effects(["pitch:time_delay:seconds=0.04"], pitch), CARD, seed=5)
    out = {"flight": flight}
    for fmt in KNOBS:
        log, config_path, _ = write_flight_log(flight, pitch, root / f"flight_{fmt}", fmt)
        out[fmt] = (log, load_config(config_path))
    return out


def _replayed(log, config, monkeypatch, fmt, block):
    module, name = KNOBS[fmt]
    monkeypatch.setattr(module, name, block)
    outcome = replay([log], config)
    result = json.dumps(outcome.result.to_json_dict(), sort_keys=True)
    return result, outcome.errors, outcome.warnings, outcome.messages


def _block_starts(log, config, block):
    """Log time [s] of the first sample of every block, reading the config's topics in blocks of ``block``."""
    wanted = {}
    for topic, routes in config.topics().items():
        wanted[topic.lstrip("/")] = sorted({spec.field for _, _, spec in routes})
    path = log / "imu.csv" if log.is_dir() else log
    with open_log(path) as f:
        return [min(float(s.t_s[0]) for s in b.values()) for b in f.blocks(wanted, block_bytes=block)]


@pytest.mark.parametrize("fmt", list(KNOBS))
def test_tiny_blocks_give_the_results_of_one_block_holding_the_whole_log(logs, monkeypatch, fmt):
    """A block boundary every 4 KiB (inside every manoeuvre, between a servo sample and the gyro samples
    around it) changes nothing: the same JSON results to the last bit, the same warnings, errors and samples,
    as one block holding the whole file (what the replay of the whole series in memory did) and the default
    blocks."""
    log, config = logs[fmt]
    whole = _replayed(log, config, monkeypatch, fmt, 1 << 30)
    tiny = _replayed(log, config, monkeypatch, fmt, TINY)
    monkeypatch.undo()
    default = _replayed(log, config, monkeypatch, fmt, KNOBS[fmt][0].__dict__[KNOBS[fmt][1]])
    assert whole[1] == [] and whole[2] == []
    assert tiny == whole and default == whole
    pitch = json.loads(whole[0])["channels"]["pitch"]
    assert pitch["sweeps"] == 1 and pitch["epsilon"] is not None
    # the boundaries did fall inside the sweep: many blocks start between its start and its end
    flight = logs["flight"]
    sweep = next(s for s in flight.segments if s.kind == "sweep")
    starts = np.array(_block_starts(log, config, TINY)) - BOOT_S
    assert np.count_nonzero((starts > sweep.start_s) & (starts < sweep.end_s)) > 10


def _ulog_with_damage(tmp_path):
    """A ULog of three topics (one of two instances, one starting late), and the same cut inside a message."""
    rng = np.random.default_rng(3)
    t = np.arange(4000, dtype=np.int64) * 4000 + 1_000_000
    late = t[2500::5]
    topics = [
        WriteTopic(
            "rates",
            t,
            {
                "timestamp_sample": t - 700,
                "xyz[0]": rng.normal(size=t.size).astype(np.float32),
                "xyz[1]": rng.normal(size=t.size).astype(np.float32),
            },
        ),
        WriteTopic("servo", t[::5], {"control[0]": rng.normal(size=t[::5].size).astype(np.float32)}),
        WriteTopic("servo:1", t[2::5], {"control[0]": rng.normal(size=t[2::5].size).astype(np.float32)}),
        WriteTopic("late", late, {"v": rng.normal(size=late.size)}),
    ]
    whole = ulog.write_ulog(tmp_path / "whole.ulg", topics)
    data = whole.read_bytes()
    # the messages after the header: uint16 size, uint8 type
    pos = 16
    while pos < 0.7 * len(data):
        pos += 3 + int.from_bytes(data[pos:pos + 2], "little")
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[:pos + 7])                        # inside a message
    return whole, cut


@pytest.mark.parametrize("block", [211, 4096, None])
def test_ulog_blocks_joined_are_the_whole_read(tmp_path, block):
    """The whole read (one pass gathering every sample) and the blocks (a pass noting where the messages are,
    then each block read again) are two ways through the file: they give the same numbers, counts, start and
    damage."""
    wanted = {"rates": ["xyz[1]", "xyz[0]"], "servo": ["control[0]"], "servo:1": ["control[0]"],
              "late": ["v"], "servo:0": ["control[0]"], "nothere": ["x"]}
    for path in _ulog_with_damage(tmp_path):
        with ulog.ULogFile(path) as f:
            read, damage = f.read(wanted), f.damage
        with ulog.ULogFile(path) as f:
            blocks = f.blocks(wanted, block_bytes=block)
            assert f.damage == damage and (damage is None) == (path.name == "whole.ulg")
            joined = join_blocks(blocks)
            chunks = sum(1 for _ in blocks)
        assert set(joined) == set(read) == set(wanted) - {"nothere"}
        for topic, series in read.items():
            assert joined[topic].fields == series.fields
            np.testing.assert_array_equal(joined[topic].t_s, series.t_s)
            np.testing.assert_array_equal(joined[topic].values, series.values)
            assert blocks.counts[topic] == series.t_s.size
        assert blocks.start_time_s == min(float(s.t_s.min()) for s in read.values())
        assert chunks > (20 if block == 211 else 1 if block == 4096 else 0)


def _global_sort(series):
    """The reference: every topic's samples at once, stably sorted by the latest finite stamp so far (the
    replay of the whole series in memory)."""
    keys, which, t = [], [], []
    for k, (tk, _) in enumerate(series):
        key = np.fmax.accumulate(tk) if tk.size else tk
        keys.append(np.where(np.isnan(key), -np.inf, key))
        which.append(np.full(tk.size, k))
        t.append(tk)
    order = np.argsort(np.concatenate(keys), kind="stable")
    return np.concatenate(which)[order], np.concatenate(t)[order]


def _random_topic(rng, n, start):
    """Stamps on a 4 ms grid (the topics share stamps, as a gyro's and a servo's do), some repeated."""
    t = (start + np.cumsum(rng.choice([0, 1, 1, 5, 25], n))) * 0.004
    if n > 20:
        t[rng.integers(0, n, 3)] = np.nan                    # not numbers
        t[5:9] = t[1:5]                                      # going back
        t[: int(rng.integers(0, 3))] = np.nan                # before the first finite stamp
    return t


def _split(rng, n, pieces):
    return np.sort(rng.integers(0, n + 1, pieces))


def _merged(out, widths):
    which = np.concatenate([w for w, _, _ in out]) if out else np.zeros(0, int)
    t = np.concatenate([x for _, x, _ in out]) if out else np.zeros(0)
    values = [np.concatenate([v[k] for _, _, v in out]) if out else np.zeros((0, widths[k]))
              for k in range(len(widths))]
    return which, t, values


@pytest.mark.parametrize("seed", range(8))
def test_the_merge_is_the_stable_time_sort_of_all_samples(seed):
    """Random topics (repeated stamps, stamps going back, not numbers, topics starting late and stopping
    early), split into random blocks, in one stream (a ULog, a DataFlash log) and one stream per topic (CSV
    files): the merge gives exactly the order of the global sort, and each topic's values in its logged
    order."""
    rng = np.random.default_rng(seed)
    n_topics = int(rng.integers(1, 5))
    series = []
    for k in range(n_topics):
        n = int(rng.integers(0, 400))
        t = _random_topic(rng, n, int(rng.integers(0, 50)))
        series.append((t, np.column_stack([np.arange(n) + 1000 * k] * (k + 1)).astype(float)))
    widths = [k + 1 for k in range(n_topics)]
    ref_which, ref_t = _global_sort(series)
    counts = [t.size for t, _ in series]

    def one_stream():
        cuts = [_split(rng, t.size, 6) for t, _ in series]
        parts = [(np.split(t, c), np.split(v, c)) for (t, v), c in zip(series, cuts)]
        for b in range(7):
            yield {k: (p[0][b], p[1][b]) for k, p in enumerate(parts) if p[0][b].size or rng.random() < 0.5}

    def own_stream(k):
        t, v = series[k]
        cut = _split(rng, t.size, 5)
        for a, b in zip(np.split(t, cut), np.split(v, cut)):
            yield {k: (a, b)}

    for streams, known in (([(list(range(n_topics)), one_stream())], counts),
                           ([(list(range(n_topics)), one_stream())], None),
                           ([([k], own_stream(k)) for k in range(n_topics)], None)):
        which, t, values = _merged(list(merge_in_time_order(streams, widths, known, lag_s=math.inf)), widths)
        np.testing.assert_array_equal(which, ref_which)
        np.testing.assert_array_equal(t, ref_t)
        for k, (_, v) in enumerate(series):
            np.testing.assert_array_equal(values[k], v)


def test_the_merge_holds_a_block_or_two_not_the_log():
    """Blocks of a time-ordered log: every sample of block i is handed out before block i + 2 is read, even
    with a topic that has not started (it lags its stream by more than ``lag_s``) and one that stopped early;
    the topic that starts late still comes in time order."""
    read = []
    out_after = []                                        # blocks read when each run came out

    def blocks():
        for i in range(50):
            t = 10.0 * i + np.arange(100) * 0.1
            block = {0: (t, np.zeros((100, 1)))}
            if i < 5:
                block[1] = (t[::10], np.ones((10, 1)))        # stops after 50 s
            if i >= 40:
                block[2] = (t[::2], np.full((50, 1), 2.0))    # starts at 400 s
            read.append(i)
            yield block

    runs = []
    for which, t, values in merge_in_time_order([([0, 1, 2], blocks())], [1, 1, 1], [5000, 50, 500]):
        runs.append((which, t))
        out_after.append((len(read), float(np.min(t))))
    assert len(out_after) >= 49                           # a run after every block (not all at the end)
    for n_read, oldest in out_after:
        assert oldest >= 10.0 * (n_read - 2)              # nothing older than the last two blocks waited
    which = np.concatenate([w for w, _ in runs])
    t = np.concatenate([x for _, x in runs])
    assert which.size == 5000 + 50 + 500 and np.all(np.diff(t) >= 0)


@pytest.mark.parametrize("batch", [checks.STAMP_BATCH, 100])
def test_stamp_checks_in_pieces_are_those_of_the_whole_series(monkeypatch, batch):
    """Counts of repeated, earlier and missing stamps and of gaps, the longest gap, exactly; the rate within a
    relative 1e-9 of the median of the exact spacings (numpy's); the same result in any split (the stamps
    counted as they come, or gathered up to ``STAMP_BATCH`` first)."""
    monkeypatch.setattr(checks, "STAMP_BATCH", batch)
    rng = np.random.default_rng(11)
    us = 60_000_000 + np.cumsum(rng.integers(3990, 4010, 20000))
    t = us / 1e6
    t[100:130] = t[70:100]                                 # 30 stamps again: the last equal, 29 earlier, and
    t[5000:] += 2.0                                        # the step forward after them (0.12 s); a 2 s gap
    t[rng.integers(0, t.size, 7)] = np.nan
    whole = check_stamps(t)
    for cuts in ([], [1], [100, 115, 5000, 5001], list(range(0, t.size, 997))):
        stats = StampStats()
        for piece in np.split(t, cuts):
            stats.add(piece)
        assert stats.result() == whole
    finite = t[np.isfinite(t)]
    step = np.diff(finite)
    median = np.median(step[step > 0])
    assert whole.rate_hz == pytest.approx(1.0 / median, rel=1e-9)
    assert (whole.samples, whole.not_finite, whole.duplicates, whole.back) == (t.size, 7, 1, 29)
    assert whole.gaps == np.count_nonzero(step > 5 * median) == 2
    assert whole.longest_gap_s == float(step.max())
