"""``gap-validate replay BAG --config CFG --annotate OUT.mcap`` (issue 26): one MCAP file with the flight and,
on the same timeline, what the node would have published (``/diagnostics`` every second of bag time, the
plottable topics when they change; docs/NODE_TOPICS.md). Read back with the ``mcap`` package's reader."""
from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from _flights import make_bag, ultrastick

from gap_validation.bag.reader import open_bag
from gap_validation.cli.main import main
from gap_validation.core.plottable import CURVES, read_table

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "ultrastick25e.yaml"

mcap_reader = pytest.importorskip("mcap.reader")


@pytest.fixture(scope="module")
def annotated(tmp_path_factory):
    where = tmp_path_factory.mktemp("annotate")
    bag = where / "flight"
    make_bag(bag, ultrastick(), hidden=["pitch:time_delay:seconds=0.05"], seed=3, sweeps_per_channel=1)
    out, results = where / "flight.mcap", where / "results.json"
    assert main(["replay", str(bag), "--config", str(CONFIG), "--annotate", str(out), "--json", str(results),
                 "--no-history", "--no-progress"]) == 0
    return bag, out, json.loads(results.read_text())


def _messages(path: Path) -> list:
    with open(path, "rb") as f:
        return [
            (channel.topic, schema.name, message.log_time, bytes(message.data))
            for schema, channel, message in mcap_reader.make_reader(f).iter_messages(log_time_order=False)
        ]


def test_the_flight_is_all_there_and_everything_in_time_order(annotated):
    bag, out, _ = annotated
    got = _messages(out)
    times = [t for _, _, t, _ in got]
    assert times == sorted(times)
    with open_bag(bag) as opened:
        flight = Counter(topic for topic, *_ in opened.records(None))
    counts = Counter(topic for topic, *_ in got)
    for topic, n in flight.items():
        assert counts[topic] == n, topic
    # the node's: /diagnostics every second of bag time, the plot topics of each channel
    diag = [t for topic, _, t, _ in got if topic == "/diagnostics"]
    gaps = np.diff(diag[:-1]) * 1e-9          # (the last: at the end of the data)
    assert gaps.size > 100 and np.allclose(gaps, 1.0)
    for name in ("roll", "pitch", "yaw"):
        assert counts[f"/gap_validator/{name}/frequency_response"] >= 1
        assert counts[f"/gap_validator/{name}/verdict"] >= 1


def test_the_last_curves_and_verdicts_are_the_json_of_the_replay(annotated):
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    _, out, data = annotated
    got = _messages(out)
    last = {}
    for topic, msgtype, _, raw in got:
        last[topic] = store.deserialize_cdr(raw, msgtype)
    for name, ch in data["channels"].items():
        table = last[f"/gap_validator/{name}/frequency_response"]
        labels = table.layout.dim[0].label.split(",")
        assert labels == list(CURVES)
        curves = read_table(table.data, labels)
        cols = [int(np.argmin(np.abs(curves["frequency_rad_s"] - w))) for w in ch["frequency_rad_s"]]
        want = np.array([np.nan if v is None else v for v in ch["measured"]["magnitude_db"]], dtype=float)
        np.testing.assert_allclose(curves["measured_magnitude_db"][cols], want, rtol=1e-9, atol=1e-12)
        verdict = json.loads(last[f"/gap_validator/{name}/verdict"].data)
        assert verdict["epsilon"] == pytest.approx(ch["epsilon"], rel=1e-9)
        assert verdict["limited_by"] == ch["limited_by"] and verdict["sweeps"] == ch["sweeps"]
        top = ch["diagnosis"][0]["sentence"] if ch["diagnosis"] else None
        if top:
            assert verdict["diagnosis"] == " ".join(top.split())
    pitch = json.loads(last["/gap_validator/pitch/verdict"].data)
    assert "time delay" in pitch["diagnosis"]                   # the hidden delay, named on the timeline
    statuses = {s.name: s for s in last["/diagnostics"].status}
    assert set(statuses) == {"gap_validator: roll", "gap_validator: pitch", "gap_validator: yaw"}


def test_annotate_takes_one_bag(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "a"), str(tmp_path / "b"), "--config", str(CONFIG), "--annotate",
                 str(tmp_path / "out.mcap"), "--no-history"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--annotate" in err[0] and "one bag" in err[0]
