"""Parity of node and replay on flights the project did not shape (issue 26: ``../shared/flights``, other
topics and rates, a pitch damper): the node's data path (serialized messages as they come, its own batches)
and its ``~/save_results`` JSON -- full diagnosis included -- equal ``gap-validate replay``'s on the same bag
field by field (values, warnings, diagnosis; numbers to 1e-9). The bundled flight: ``test_node.py``."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from _parity import json_differences
from _ros import isolated_ros

rclpy = pytest.importorskip("rclpy")

from rclpy.context import Context  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from gap_validation.bag.reader import open_bag  # noqa: E402
from gap_validation.bag.replay import replay  # noqa: E402
from gap_validation.ros.node import ValidatorNode  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import second_simulator as bench  # noqa: E402

pytestmark = pytest.mark.skipif(not (bench.FLIGHTS / "flightgen.py").exists(),
                                reason="../shared/flights is not beside the checkout")

#: Other topics and rates (200 Hz IMU, 100 Hz surfaces) with a lag to name; a rate damper on pitch (the
#: feedback warnings and the trim between the manoeuvres they read).
CASES = ("lag_roll", "closed_loop_pitch")


@pytest.fixture
def ros_env():
    with isolated_ros():
        yield


@pytest.mark.slow
@pytest.mark.parametrize("name", CASES)
def test_node_save_results_equals_replay_field_by_field(name, ros_env, tmp_path_factory):
    case = bench.load_cases()[name]
    assert not case.get("excitation_topic")            # the node reads the nominal config as it is
    where = bench.make(name, case, tmp_path_factory.mktemp("second_simulator"))
    config = bench.config_for(name, case, where)
    bag = where / "bag"
    with open_bag(bag) as opened:
        records = [(topic, bytes(raw)) for topic, _, _, raw in opened.records(list(config.topics()))]
    assert records, f"{name}: no message on the config's topics"
    results = tmp_path_factory.mktemp("results")
    context = Context()
    rclpy.init(context=context)
    node = ValidatorNode(
        context=context,
        parameter_overrides=[
            Parameter("config_file", value=str(where / "nominal.yaml")),
            Parameter("results_dir", value=str(results)),
        ],
    )
    try:
        # the node's default path: serialized messages
        assert set(node.topics.raw) == set(config.topics())
        for topic, raw in records:
            node.on_raw(topic, raw)
        node.router.flush()
        node.validator.finish()          # the end of the run, as the node closes it after end_of_data_timeout
        mine = json.loads(Path(node.save_results()).read_text())
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown(context=context)
    theirs = replay([bag], config, diagnose=True).result.to_json_dict()
    mine.pop("sources"), theirs.pop("sources")      # replay names the bag; the node has topics, not files
    assert json_differences(mine, theirs) == []
    assert any(ch["diagnosis"] or ch["warnings"] for ch in theirs["channels"].values()), "nothing to compare"
