"""Campaign manifests (paths relative to the manifest, dates, tags, one-line errors) and flight fingerprints
(content, not size and mtime)."""
import datetime as dt
import os
import shutil
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gap_validation.campaign.fingerprint import flight_fingerprint
from gap_validation.campaign.manifest import load_manifest, parse_manifest
from gap_validation.core.errors import ConfigError, DataError

ENTRY = {
    "name": "UAV-1 week 0",
    "bag": "bags/a",
    "config": "cfg.yaml",
    "aircraft": "UAV-1",
    "date": "2025-03-03",
}


def test_paths_are_relative_to_the_manifest(tmp_path, monkeypatch):
    (tmp_path / "sub").mkdir()
    manifest = tmp_path / "sub" / "m.yaml"
    manifest.write_text(
        "flights:\n  - {name: f1, bag: [a.mcap, /abs/b.mcap], config: ../cfg.yaml, aircraft: UAV-1,"
        " date: 2025-03-03, tags: [weekly, card-A]}\n"
        "  - {name: f2, bag: c, config: ../cfg.yaml, aircraft: 7, date: '2025-03-10T14:30:00',"
        " tags: solo}\n"
    )
    monkeypatch.chdir("/")
    m = load_manifest(manifest)
    f1, f2 = m.flights
    assert f1.bags == (tmp_path / "sub" / "a.mcap", Path("/abs/b.mcap"))
    assert f1.config == tmp_path / "sub" / ".." / "cfg.yaml" and m.configs == (f1.config,)
    assert (
        f1.date == dt.datetime(2025, 3, 3)
        and f1.date_text == "2025-03-03"
        and f1.tags == ("weekly", "card-A")
    )
    assert f2.aircraft == "7" and f2.date_text == "2025-03-10T14:30:00" and f2.tags == ("solo",)
    assert m.aircraft == ["UAV-1", "7"]
    assert f1.metadata()["date"] == "2025-03-03" and f1.metadata()["tags"] == ["weekly", "card-A"]


@pytest.mark.parametrize("change, needle", [
    ({"bag": 3}, "flights[0].bag: expected a path, got 3"),
    ({"bag": ["a", None]}, "flights[0].bag[1]: expected a path, got None"),
    ({"date": "2025-13-01"}, "flights[0].date: '2025-13-01' is not a date"),
    ({"date": True}, "flights[0].date: True is not a date"),
    ({"aircraft": ""}, "flights[0].aircraft: expected a non-empty string, got ''"),
    ({"tags": {"a": 1}}, "flights[0].tags: expected a list of strings, got {'a': 1}"),
    ({"name": "x\ny"}, None),
])
def test_wrong_types_name_the_key_and_value(change, needle):
    # a line break in a value is fine for a name, errors stay one line
    if needle is None:
        assert parse_manifest({"flights": [dict(ENTRY, **change)]}, "m.yaml").flights[0].name == "x\ny"
        return
    with pytest.raises(ConfigError) as err:
        parse_manifest({"flights": [dict(ENTRY, **change)]}, "m.yaml")
    assert str(err.value).startswith("m.yaml: ") and needle in str(err.value)


@pytest.mark.parametrize(
    "data, needle",
    [
        (None, "m.yaml: expected a mapping with a 'flights' list, got None"),
        ({"flight": []}, "m.yaml: flight: unknown key (allowed: flights)"),
        (
            {"flights": ["x"]},
            "m.yaml: flights[0]: expected a mapping with keys name, bag, config, aircraft, date",
        ),
        ({"flights": [{k: v for k, v in ENTRY.items() if k != "bag"}]}, "m.yaml: flights[0].bag: missing"),
    ],
)
def test_structure_errors(data, needle):
    with pytest.raises(
        ConfigError,
        match="^" + needle.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(").replace(")", r"\)"),
    ):
        parse_manifest(data, "m.yaml")


@settings(max_examples=150, deadline=None)
@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.text(max_size=8) | st.dates(),
        lambda inner: (
            st.lists(inner, max_size=3)
            | st.dictionaries(
                st.sampled_from(["flights", "name", "bag", "config", "aircraft", "date", "tags", "x"]),
                inner,
                max_size=6,
            )
        ),
        max_leaves=20,
    )
)
def test_any_yaml_value_gives_a_manifest_or_a_one_line_config_error(data):
    try:
        parse_manifest(data, "m.yaml", base="/base")
    except ConfigError as err:
        assert "\n" not in str(err) and str(err).startswith("m.yaml: ")


def _bag(directory: Path, content: bytes) -> Path:
    directory.mkdir(parents=True)
    (directory / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (directory / "flight_0.mcap").write_bytes(content)
    return directory


def test_fingerprint_follows_content_not_size_or_mtime(tmp_path):
    config = tmp_path / "cfg.yaml"
    config.write_text("channels: {}\n")
    bag = _bag(tmp_path / "bag", b"A" * 5000)
    first = flight_fingerprint([bag], config)
    copy = tmp_path / "copy"
    shutil.copytree(bag, copy)
    os.utime(copy / "flight_0.mcap", (1e9, 1e9))
    assert flight_fingerprint([copy], config) == first                     # copied, touched: same
    (copy / "flight_0.mcap").write_bytes(b"A" * 4999 + b"B")               # same size, one byte: different
    os.utime(copy / "flight_0.mcap", (1e9, 1e9))
    assert flight_fingerprint([copy], config) != first
    assert flight_fingerprint([bag, copy], config) != flight_fingerprint([copy, bag], config)   # order counts
    config.write_text("channels: {}\n# comment\n")
    assert flight_fingerprint([bag], config) != first                      # config content counts
    assert flight_fingerprint([bag], config, {"diagnose": False}) != flight_fingerprint([bag], config)


def test_fingerprint_of_missing_or_empty_bags_is_a_one_line_data_error(tmp_path):
    config = tmp_path / "cfg.yaml"
    config.write_text("channels: {}\n")
    (tmp_path / "empty").mkdir()
    for bag, needle in ((tmp_path / "nope", "no such bag"), (tmp_path / "empty", "empty directory")):
        with pytest.raises(DataError, match=needle):
            flight_fingerprint([bag], config)
    with pytest.raises(DataError, match="cannot read"):
        flight_fingerprint([tmp_path / "empty"], tmp_path / "missing.yaml")
