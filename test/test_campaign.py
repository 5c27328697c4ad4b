"""``gap-validate campaign`` end to end on a simulated fleet (benchmarks/make_fleet.py, pitch only, short
flights): a campaign on one Dask worker equals single replays; the drifting airframe is found and named in
words; a worker killed mid-task loses nothing; a re-run redoes only what changed; a failing flight costs only
itself; bad manifests are one line, exit 2; the index renders in headless Chromium."""
import csv
import importlib.util
import json
import os
import re
import shutil
import signal
import sys
import threading
import time
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
import yaml

from gap_validation.bag.replay import replay
from gap_validation.campaign.manifest import load_manifest
from gap_validation.campaign.results import REUSED, VALIDATED
from gap_validation.campaign.runner import run_campaign
from gap_validation.cli.main import main
from gap_validation.core.config import load_config

distributed = pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[1]
AIRCRAFT, WEEKS, DRIFTING = 3, 5, "UAV-3"
GROWTH_MS_PER_WEEK = 6.0


def _load_script(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """3 aircraft x 5 weekly flights, pitch only; UAV-3's delay grows 6 ms per week."""
    make_fleet = _load_script("make_fleet")
    out = tmp_path_factory.mktemp("fleet")
    return make_fleet.make_fleet(out, aircraft=AIRCRAFT, weeks=WEEKS, drifting=DRIFTING, channels=["pitch"],
                                 growth_s_per_week=GROWTH_MS_PER_WEEK / 1e3)


@pytest.fixture(scope="module")
def cluster():
    """A local Dask cluster with one worker process (one thread)."""
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=40) as local, distributed.Client(local) as client:
        yield local, client


@pytest.fixture(scope="module")
def campaign(fleet, cluster, tmp_path_factory):
    out = tmp_path_factory.mktemp("campaign")
    return run_campaign(load_manifest(fleet), out, client=cluster[1])


def test_one_worker_gives_the_epsilons_of_single_replays(campaign):
    assert campaign.ok and campaign.count(VALIDATED) == AIRCRAFT * WEEKS
    data = json.loads((campaign.out_dir / "campaign.json").read_text())
    assert [f["name"] for f in data["flights"]] == [f.name for f in campaign.manifest.flights]
    # 4 of the 15, each aircraft
    for flight, saved in list(zip(campaign.manifest.flights, data["flights"]))[::4]:
        single = replay(flight.bags, load_config(flight.config)).result.to_json_dict()["channels"]
        assert set(saved["channels"]) == set(single) == {"pitch"}
        ours, theirs = saved["channels"]["pitch"], single["pitch"]
        for key in ("epsilon", "epsilon_raw", "nu_gap"):
            assert ours[key] == pytest.approx(theirs[key], rel=0, abs=1e-9), (flight.name, key)
        # null where a frequency was not excited: NaN on both sides
        np.testing.assert_allclose(np.array(ours["epsilon_per_frequency"], float),
                                   np.array(theirs["epsilon_per_frequency"], float), rtol=0, atol=1e-9)
        assert ours["diagnosis"][0]["parameters"] == theirs["diagnosis"][0]["parameters"]
        assert saved["aircraft"] == flight.aircraft and saved["date"] == flight.date_text
        assert saved["tags"] == ["weekly", f"week-{saved['tags'][1].split('-')[1]}"]


def test_the_drifting_airframe_is_found_and_said_in_words(campaign):
    real = [f for f in campaign.findings if f.significant]
    assert {(f.series.aircraft, f.series.channel) for f in real} == {(DRIFTING, "pitch")}
    delay = next(f for f in real if f.series.quantity == "time_delay.seconds")
    text = delay.sentence()
    match = re.match(
        r"UAV-3 pitch: delay grows ([\d.]+) ms per week, from (\d+) to (\d+) ms \(5 flights", text
    )
    assert match, text
    assert float(match.group(1)) == pytest.approx(GROWTH_MS_PER_WEEK, rel=0.15)
    assert 17 <= int(match.group(2)) <= 23 and 40 <= int(match.group(3)) <= 48
    # the healthy airframes have the same constant 20 ms servo delay: diagnosed, but no trend
    healthy = [f for f in campaign.findings if f.series.aircraft != DRIFTING]
    assert {f.series.quantity for f in healthy} == {"epsilon", "time_delay.seconds"}
    assert not any(f.significant for f in healthy)
    page = (campaign.out_dir / "index.html").read_text()
    assert text in page
    trends = json.loads((campaign.out_dir / "campaign.json").read_text())["trends"]
    assert [t["sentence"] for t in trends if t["significant"]] == [f.sentence() for f in real]


def test_csv_has_one_row_per_flight_and_channel(campaign):
    with open(campaign.out_dir / "campaign.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == AIRCRAFT * WEEKS
    first = rows[0]
    assert (
        first["flight"] == "UAV-1 2025-03-03"
        and first["channel"] == "pitch"
        and first["tags"] == "weekly;week-0"
    )
    assert float(first["epsilon"]) == campaign.flights[0].channels["pitch"]["epsilon"]
    assert first["diagnosis"] == "time_delay" and re.fullmatch(
        r"seconds=0\.0\d+", first["diagnosis_parameters"]
    )
    assert first["sweeps"] == "2" and first["limited_by"] == "model" and first["excitation"] == "chirp"


class _Killer(distributed.WorkerPlugin):
    """Kills its worker process (SIGKILL) while the first task of a flight runs, once (a marker file
    remembers)."""

    def __init__(self, marker: str, flight: str):
        self.marker, self.flight = marker, flight

    def transition(self, key, start, finish, **kwargs):
        if finish == "executing" and self.flight in str(key) and not os.path.exists(self.marker):
            with open(self.marker, "w") as handle:
                handle.write(str(os.getpid()))
            threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGKILL)).start()   # mid-task


def _subset(fleet: Path, names: list[str], path: Path) -> Path:
    """A manifest with some of the fleet's flights (absolute paths)."""
    flights = [f for f in yaml.safe_load(fleet.read_text())["flights"] if f["name"] in names]
    for entry in flights:
        entry["bag"] = str(fleet.parent / entry["bag"])
        entry["config"] = str(fleet.parent / entry["config"])
    path.write_text(yaml.safe_dump({"flights": flights}))
    return path


def test_a_worker_killed_mid_task_loses_nothing(fleet, cluster, campaign, tmp_path):
    import cloudpickle

    local, client = cluster
    names = ["UAV-1 2025-03-10", "UAV-2 2025-03-18", "UAV-3 2025-03-26"]
    manifest = load_manifest(_subset(fleet, names, tmp_path / "manifest.yaml"))
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    marker = tmp_path / "killed"
    client.register_plugin(_Killer(str(marker), "UAV-2_2025-03-18"), name="killer")
    try:
        outcome = run_campaign(manifest, tmp_path / "out", client=client)
    finally:
        client.unregister_worker_plugin("killer")
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    killed = int(marker.read_text())
    assert killed not in client.run(os.getpid).values()          # that worker process is gone ...
    assert outcome.workers_lost == 1                             # ... and the campaign noticed
    assert outcome.ok and outcome.count(VALIDATED) == len(names)
    rerun = next(o for o in outcome.flights if o.flight.name == names[1])
    assert int(rerun.worker.rsplit(":", 1)[1]) != killed  # its result came from the new worker
    before = {
        o.flight.name: o.channels["pitch"]["epsilon"] for o in campaign.flights if o.flight.name in names
    }
    assert {o.flight.name: o.channels["pitch"]["epsilon"] for o in outcome.flights} == before


def test_a_rerun_redoes_only_what_changed(fleet, cluster, campaign, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(campaign.out_dir, out)
    manifest = load_manifest(fleet)
    touched = manifest.flights[0].bags[0]
    for path in touched.rglob("*"):                               # same content, new mtime: still reused
        os.utime(path, (time.time() + 60, time.time() + 60))
    changed = manifest.flights[1]
    shutil.rmtree(changed.bags[0])
    shutil.copytree(manifest.flights[2].bags[0], changed.bags[0])  # other content: redone
    code = main(["campaign", str(fleet), "--out", str(out), "--scheduler", cluster[0].scheduler_address,
                 "--no-progress"])
    assert code == 0
    data = json.loads((out / "campaign.json").read_text())
    status = {f["name"]: f["status"] for f in data["flights"]}
    assert status.pop(changed.name) == VALIDATED and set(status.values()) == {REUSED}
    redone = next(f for f in data["flights"] if f["name"] == changed.name)["channels"]["pitch"]["epsilon"]
    assert redone == pytest.approx(campaign.flights[2].channels["pitch"]["epsilon"], abs=1e-12)
    # figures are named by their content: the changed aircraft's and the fleet's are new, the others kept
    old, new = ({p.name for p in d.glob("*.png")} for d in (campaign.out_dir, out))
    assert len(new) == 1 + AIRCRAFT and {n for n in old & new} == {n for n in old if "UAV_1" not in n
                                                                   and not n.startswith("fleet")}


def test_a_failing_flight_is_one_line_and_the_others_complete(fleet, tmp_path, capsys):
    """Default path (a local cluster from --workers): two good flights, a corrupt bag and a missing one."""
    flights = yaml.safe_load(_subset(fleet, ["UAV-1 2025-03-03", "UAV-1 2025-03-10"], tmp_path / "m.yaml")
                             .read_text())["flights"]
    (tmp_path / "corrupt.mcap").write_bytes(b"\x89MCAP0\r\n" + os.urandom(4000))
    bad = [
        dict(flights[0], name="corrupt", bag="corrupt.mcap"),
        dict(flights[0], name="missing", bag="nowhere"),
    ]
    manifest = tmp_path / "manifest.yaml"
    manifest.write_text(yaml.safe_dump({"flights": [flights[0], *bad, flights[1]]}))
    code = main(
        ["campaign", str(manifest), "--out", str(tmp_path / "out"), "--workers", "1", "--no-progress"]
    )
    captured = capsys.readouterr()
    assert code == 1
    errors = [line for line in captured.err.splitlines() if "error:" in line]
    assert len(errors) == 2, captured.err
    assert errors[0].startswith("gap-validate: error: corrupt: ") and "corrupt.mcap" in errors[0]
    assert errors[1].startswith("gap-validate: error: missing: ") and "nowhere" in errors[1]
    assert "4 flights of 1 aircraft: 2 validated, 0 reused, 2 failed" in captured.out
    data = json.loads((tmp_path / "out" / "campaign.json").read_text())
    assert [f["status"] for f in data["flights"]] == ["validated", "failed", "failed", "validated"]
    assert data["flights"][0]["channels"]["pitch"]["epsilon"] > 0 and data["flights"][1]["channels"] == {}
    assert len(data["errors"]) == 2
    rows = list(csv.DictReader(open(tmp_path / "out" / "campaign.csv", newline="")))
    assert [r["status"] for r in rows] == ["validated", "failed", "failed", "validated"]
    assert "corrupt.mcap" in rows[1]["error"]


@pytest.mark.parametrize("text, needle", [
    ("flights: []", "manifest.yaml: flights: expected a non-empty list of flights, got []"),
    ("flights:\n  - {name: a, bag: b, config: c, aircraft: X, date: 2025-01-01, colour: red}",
     "manifest.yaml: flights[0].colour: unknown key (allowed: name, bag, config, aircraft, date, tags)"),
    ("flights:\n  - {name: a, bag: b, config: c, aircraft: X}", "manifest.yaml: flights[0].date: missing"),
    ("flights:\n  - {name: a, bag: b, config: c, aircraft: X, date: soon}",
     "manifest.yaml: flights[0].date: 'soon' is not a date (expected YYYY-MM-DD)"),
    ("flights:\n  - {name: a, bag: [], config: c, aircraft: X, date: 2025-01-01}",
     "manifest.yaml: flights[0].bag: expected a path or a non-empty list of paths, got []"),
    ("flights:\n  - {name: a, bag: b, config: c, aircraft: X, date: 2025-01-01}\n"
     "  - {name: a, bag: b, config: c, aircraft: X, date: 2025-01-08}",
     "manifest.yaml: flights[1].name: 'a' is already the name of flights[0]"),
    ("flights: [\n", "manifest.yaml: YAML error at line 2"),
    ("flights:\n  - {name: a, bag: b, config: nope.yaml, aircraft: X, date: 2025-01-01}",
     "manifest.yaml: flights[0].config: "),
])
def test_bad_manifest_is_one_line_exit_2(tmp_path, monkeypatch, capsys, text, needle):
    monkeypatch.chdir(tmp_path)
    Path("manifest.yaml").write_text(text)
    assert main(["campaign", "manifest.yaml", "--out", "out"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gap-validate: error: ") and needle in err[0], err
    assert not Path("out", "campaign.json").exists()


def test_bad_config_is_one_line_exit_2_before_any_work(fleet, tmp_path, capsys):
    config = tmp_path / "cfg.yaml"
    config.write_text(
        (fleet.parent / "config.yaml").read_text().replace("channels:", "colour: red\nchannels:")
    )
    data = yaml.safe_load(fleet.read_text())
    data["flights"] = [dict(data["flights"][0], bag=str(fleet.parent / data["flights"][0]["bag"]),
                            config=str(config))]
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(data))
    assert main(["campaign", str(tmp_path / "m.yaml"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "m.yaml: flights[0].config: " in err[0] and "colour: unknown key" in err[0], err


@pytest.mark.parametrize("args, needle", [
    (["--workers", "0"], "--workers 0: expected an integer >= 1"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers sets the size of the local cluster"),
])
def test_bad_options_are_one_line_exit_2(fleet, tmp_path, capsys, args, needle):
    assert main(["campaign", str(fleet), "--out", str(tmp_path / "o"), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]


def test_index_renders_in_headless_chromium(campaign, tmp_path):
    from test_html import assert_page_renders, assert_real_plot

    assert_page_renders(campaign.out_dir, 1 + AIRCRAFT, tmp_path)   # fleet figure + one per aircraft
    for png in campaign.out_dir.glob("*.png"):
        assert_real_plot(png)


def test_progress_bar_counts_flights():
    import io

    from gap_validation.campaign.manifest import Flight
    from gap_validation.campaign.results import FAILED, FlightOutcome
    from gap_validation.cli.campaign import FlightProgress

    stream = io.StringIO()
    bar = FlightProgress(stream)
    flight = Flight("f", (), Path("c.yaml"), "UAV-1", datetime(2025, 1, 1))
    for done, status in enumerate((REUSED, VALIDATED, FAILED), start=1):
        bar(FlightOutcome(flight, status=status), done, 3)
    bar.close()
    last = stream.getvalue().split("\r")[-1]
    assert re.fullmatch(
        r"campaign \[#{30}\] 100% 3/3 flights \(1 reused, 1 failed\) [\d.]+ flights/s\n", last
    ), last
