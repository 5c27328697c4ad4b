"""Tests of the ROS 2 node ``gap_validator`` (in-process rclpy with an explicit context).

Data path: the bundled flight (``bags/``; a simulated flight with the same hidden effects when none is
bundled) is read with :mod:`gap_validation.bag.reader`, and its raw CDR records are handed to the node's
decoding step (``ValidatorNode.on_raw``, what the intake timer does with every message it drains) or
deserialised into rclpy messages (``ValidatorNode.on_message``). That is the quick route for the full flight;
other tests send the flight through real DDS publishers: the whole flight from a BEST_EFFORT publisher in
another participant with the node's default parameters (the epsilon of replay), and the first part from
RELIABLE publishers (the node starts best effort, re-subscribes reliable when it sees them, and neither loses
nor repeats a message).
"""
from __future__ import annotations

import copy
import gc
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from _parity import json_differences
from _ros import isolated_ros

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from rclpy.task import Future  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from gap_validation.bag.reader import open_bag  # noqa: E402
from gap_validation.bag.replay import replay  # noqa: E402
from gap_validation.core.checkpoint import load_state  # noqa: E402
from gap_validation.core.config import load_config  # noqa: E402
from gap_validation.core.validator import OnlineValidator  # noqa: E402
from gap_validation.messages.router import stamp_seconds  # noqa: E402
from gap_validation.ros.message_types import message_class  # noqa: E402
from gap_validation.ros.node import ValidatorNode  # noqa: E402
from gap_validation.ros.parameters import PARAMETERS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "ultrastick25e.yaml"
#: Message types of the bundled flight (DESIGN.md defaults); a typed config subscribes without discovery.
TYPES = {"/imu": "sensor_msgs/msg/Imu", "/control_surfaces": "sensor_msgs/msg/JointState"}
#: The lab's servo lag (6 Hz) and delay: what the airframe-only model misses in the bundled flight.
MISSING = [{"type": "first_order_lag", "bandwidth_rad_s": 37.7}, {"type": "time_delay", "seconds": 0.05}]
LEVELS = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR, DiagnosticStatus.STALE)


# ------------------------------------------------------------------------------------------------ environment
@pytest.fixture(scope="module", autouse=True)
def ros_environment():
    """Isolated DDS traffic: random domain, localhost only, strict field checks (restored afterwards)."""
    with isolated_ros():
        yield


class Ros:
    """One rclpy context with a single-threaded executor; nodes made here are destroyed at the end."""

    def __init__(self):
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []
        self.helper = self.plain("gap_test_helper")

    def plain(self, name: str):
        node = rclpy.create_node(name, context=self.context)
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def validator(
        self,
        config=CONFIG,
        spin: bool = False,
        name: str | None = None,
        namespace: str | None = None,
        **params,
    ) -> ValidatorNode:
        overrides = [Parameter("config_file", value=str(config))]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        remap = (["-r", f"__node:={name}"] if name else []) + (
            ["-r", f"__ns:={namespace}"] if namespace else []
        )
        remap = ["--ros-args", *remap] if remap else None
        node = ValidatorNode(context=self.context, parameter_overrides=overrides, cli_args=remap)
        self.nodes.append(node)
        if spin:
            self.executor.add_node(node)
        return node

    def drop(self, node) -> None:
        """Close and destroy one node now."""
        if isinstance(node, ValidatorNode):
            node.close()
        if node in self.executor.get_nodes():
            self.executor.remove_node(node)
        self.nodes.remove(node)
        node.destroy_node()

    def wait(self, predicate, timeout_s: float = 10.0) -> None:
        """Spin until ``predicate()`` holds (checked by a timer that completes a future)."""
        future = Future()

        def check():
            if not future.done() and predicate():
                future.set_result(True)

        timer = self.helper.create_timer(0.01, check)
        try:
            self.executor.spin_until_future_complete(future, timeout_sec=timeout_s)
        finally:
            self.helper.destroy_timer(timer)
        assert future.done(), "timed out waiting"

    def call(self, client, request, timeout_s: float = 60.0):
        assert client.wait_for_service(timeout_sec=10.0), f"{client.srv_name} not available"
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=timeout_s)
        assert future.done(), f"{client.srv_name} did not answer"
        return future.result()

    def close(self):
        for node in reversed(self.nodes):
            if isinstance(node, ValidatorNode):
                node.close()
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown()
        rclpy.shutdown(context=self.context)


@pytest.fixture
def ros():
    session = Ros()
    yield session
    session.close()


# ------------------------------------------------------------------------------------------------ the flight
def _bundled_bag() -> Path | None:
    folder = ROOT / "bags"
    if not folder.is_dir():
        return None
    for path in sorted(folder.iterdir()):
        if path.is_dir() and (path / "metadata.yaml").exists() or path.suffix in (".mcap", ".db3"):
            return path
    return None


def _hidden_of(bag: Path) -> dict:
    """Channel -> hidden effects recorded in the bag's metadata by ``gap-validate simulate``."""
    meta = bag / "metadata.yaml"
    if bag.is_dir() and meta.exists():
        info = yaml.safe_load(meta.read_text()).get("rosbag2_bagfile_information", {})
        text = (info.get("custom_data") or {}).get("gap_validation.hidden")
        if text:
            return json.loads(text)
    return {}


class Flight:
    """Raw records of a flight and the replay module's result on it."""

    def __init__(self, bag: Path):
        self.bag = bag
        self.config = load_config(CONFIG)
        self.topics = {}
        with open_bag(bag) as opened:
            info = opened.topics
            self.records = [
                (topic, bytes(raw)) for topic, _, _, raw in opened.records(list(self.config.topics()))
            ]
        self.types = {topic: info[topic].msgtype for topic in self.config.topics()}
        assert self.types == TYPES
        self.classes = {topic: message_class(t) for topic, t in self.types.items()}
        self.hidden = _hidden_of(bag)
        started = time.perf_counter()
        outcome = replay([bag], self.config, diagnose=False)
        self.replayed, self.replay_validator = outcome.result, outcome.validator
        self.replay_s = time.perf_counter() - started

    @property
    def last_stamp_s(self) -> float:
        """Latest header stamp of the flight [s]."""
        return max(stamp_seconds(msg) or 0.0 for _, msg in self.messages(len(self.records) - 50))

    def messages(self, start: int = 0, stop: int | None = None):
        for topic, raw in self.records[start:stop]:
            yield topic, deserialize_message(raw, self.classes[topic])

    def feed(self, node: ValidatorNode, start: int = 0, stop: int | None = None) -> None:
        """Hand the records, deserialised, to the node's message callback, in bag order."""
        for topic, msg in self.messages(start, stop):
            node.on_message(topic, msg)

    def feed_raw(self, node: ValidatorNode, start: int = 0, stop: int | None = None) -> None:
        """Hand the serialized records to the node's raw subscription callback (its default path)."""
        assert set(node.topics.raw) == set(self.types), "the node must have raw subscriptions"
        for topic, raw in self.records[start:stop]:
            node.on_raw(topic, raw)



def write_typed(path: Path, effects: dict | None = None, aircraft: str | None = "ultrastick25e") -> Path:
    """The Ultra Stick config with the message types set, its ``aircraft`` and, optionally, effects per
    channel."""
    data = yaml.safe_load(CONFIG.read_text())
    if aircraft is not None:
        data = {"aircraft": aircraft, **data}
    for name, channel in data["channels"].items():
        for stream in ("input", "output"):
            channel[stream]["type"] = TYPES[channel[stream]["topic"]]
        if effects is not None:
            channel["model"]["effects"] = copy.deepcopy(effects.get(name, []))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def typed(tmp_path_factory) -> Path:
    """The typed Ultra Stick config with ``aircraft: ultrastick25e`` (its hardware_id)."""
    return write_typed(tmp_path_factory.mktemp("typed") / "ultrastick25e.yaml")


@pytest.fixture(scope="module")
def flight(tmp_path_factory, ros_environment):
    bag = _bundled_bag()
    if bag is None:  # no bundled bag in this checkout: the same kind of flight, simulated here
        from _flights import make_bag, ultrastick

        bag = tmp_path_factory.mktemp("flight") / "flight"
        config = ultrastick()
        make_bag(bag, config, hidden=[f"{ch}:first_order_lag:bandwidth_rad_s=37.7" for ch in config.channels]
                 + [f"{ch}:time_delay:seconds=0.05" for ch in config.channels], seed=7)
    return Flight(bag)


@pytest.fixture(scope="module")
def fed(flight, typed, tmp_path_factory):
    """The whole flight fed into a node; its results and checkpoint (other tests resume from it)."""
    session = Ros()
    try:
        state = tmp_path_factory.mktemp("fed") / "fed.npz"
        node = session.validator(typed, state_file=str(state), end_of_data_timeout=0.5)
        flight.feed_raw(node)
        # fast decoding verified and used
        assert all(raw.decoder is not None for raw in node.topics.raw.values())
        node.router.flush()
        # the flight's last manoeuvre ends a few seconds before the data: its record closes when the inputs
        # have been silent for end_of_data_timeout (the end of the run), as replay closes it at the end of the
        # bag
        before = node.validator.results(diagnose=False)
        time.sleep(0.6)
        array = node.publish_diagnostics()
        result = node.validator.results(diagnose=False)
        assert sum(ch.sweeps for ch in result.channels.values()) > sum(
            ch.sweeps for ch in before.channels.values()
        )
        assert node.checkpoint() == str(state)
    finally:
        session.close()
    return {"state": state, "result": result, "array": array}


def statuses(array: DiagnosticArray, node_name: str = "gap_validator") -> dict:
    """Channel -> (status, values dict) of a DiagnosticArray whose statuses are named ``<node_name>:
    <channel>``."""
    out = {}
    for status in array.status:
        assert status.name.startswith(f"{node_name}: "), status.name
        out[status.name.split(": ", 1)[1]] = (status, {kv.key: kv.value for kv in status.values})
    return out


def end_of_data(*nodes: ValidatorNode) -> None:
    """The flight is over: the router's pending samples to the validator, and the last manoeuvre closed --
    what the node does once its inputs have been silent for ``end_of_data_timeout`` (the ``fed`` fixture goes
    that way)."""
    for node in nodes:
        node.router.flush()
        node.validator.finish()


def number(text: str) -> float | None:
    return None if text == "null" else float(text)


def resume(ros: Ros, fed: dict, tmp_path: Path, config: Path, **params) -> ValidatorNode:
    state = tmp_path / "state.npz"
    shutil.copy(fed["state"], state)
    return ros.validator(config, state_file=str(state), **params)


# ------------------------------------------------------------------------------------------------ one data
# path
def test_flight_through_the_node_equals_replay(flight, fed):
    """Same samples, same validator: the node's epsilon per channel equals the replay module's."""
    ours, theirs = fed["result"], flight.replayed
    assert list(ours.channels) == list(theirs.channels) == ["roll", "pitch", "yaw"]
    published = statuses(fed["array"])
    for name, ch in theirs.channels.items():
        mine = ours.channels[name]
        assert ch.sweeps >= 1 and ch.epsilon is not None, f"{name}: the flight has no usable sweep"
        assert mine.sweeps == ch.sweeps
        assert mine.epsilon == pytest.approx(ch.epsilon, abs=1e-9)
        assert mine.nu_gap == pytest.approx(ch.nu_gap, abs=1e-9)
        assert mine.epsilon_raw == pytest.approx(ch.epsilon_raw, abs=1e-9)
        assert mine.worst_frequency_rad_s == ch.worst_frequency_rad_s
        status, values = published[name]
        assert number(values["epsilon"]) == pytest.approx(ch.epsilon, abs=1e-9)
        assert int(values["sweeps"]) == ch.sweeps
        assert isinstance(status.level, bytes) and status.level in LEVELS


class OtherParticipant:
    """Publishers in their own rclpy context (another DDS participant, as another process would be)."""

    def __init__(self, qos: "QoSProfile", types: dict, name: str = "gap_test_flight_stack"):
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.pubs = {
            topic: self.node.create_publisher(message_class(t) if isinstance(t, str) else t, topic, qos)
            for topic, t in types.items()
        }

    def matched(self) -> bool:
        return all(p.get_subscription_count() >= 1 for p in self.pubs.values())

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


BEST_EFFORT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT
)


def test_best_effort_publisher_with_default_parameters_gives_the_epsilon_of_replay(flight, ros):
    """The issue's case: the flight stack publishes BEST_EFFORT (IMU drivers, PX4's bridge) from another
    participant, the node runs with its default parameters and the shipped config (no ``type:``). It
    subscribes at once (types implied by the fields), best effort, receives every message and gives replay's
    epsilon."""
    node = ros.validator(CONFIG, spin=True, diagnostic_period=1000.0)
    # no publisher known yet: reliable and best effort, drained as one
    for intake in node.topics.intakes.values():
        assert set(intake.subscriptions) == {"reliable", "best_effort"} and intake.reliability is None
    stack = OtherParticipant(BEST_EFFORT_QOS, flight.types)
    try:
        ros.wait(stack.matched)
        sent = 0
        for k, (topic, raw) in enumerate(flight.records):   # serialized, as recorded; paced below the queues
            stack.pubs[topic].publish(raw)
            sent += 1
            if k % 300 == 299 and sent - sum(node.router.messages.values()) > 600:
                ros.wait(lambda: sent - sum(node.router.messages.values()) <= 300, timeout_s=30.0)
        ros.wait(lambda: sum(node.router.messages.values()) >= sent, timeout_s=30.0)
    finally:
        stack.close()
    expected = {topic: sum(1 for t, _ in flight.records if t == topic) for topic in flight.types}
    assert node.router.messages == expected                       # none lost, none twice
    assert ({t: list(i.subscriptions) for t, i in node.topics.intakes.items()}
            == {t: ["best_effort"] for t in flight.types})
    end_of_data(node)
    mine = node.validator.results(diagnose=False)
    for name, ch in flight.replayed.channels.items():
        assert mine.channels[name].sweeps == ch.sweeps >= 1
        assert mine.channels[name].epsilon == pytest.approx(ch.epsilon, abs=1e-9), name
        assert mine.channels[name].nu_gap == pytest.approx(ch.nu_gap, abs=1e-9), name


def test_flight_over_dds_arrives_complete_and_gives_the_same_state(flight, typed, ros):
    """RELIABLE publishers, deep queue, paced publishing: the node (``qos_reliability: auto``) starts best
    effort, sees the publishers and re-subscribes reliable while the flight flows; every message arrives once,
    and the raw path over DDS gives the same spectra as rclpy messages handed to the message callback."""
    over_dds = ros.validator(typed, spin=True, diagnostic_period=1000.0, discovery_period=0.2)
    direct = ros.validator(typed, name="gap_validator_direct", diagnostic_period=1000.0, raw_decoding=False)
    # typed: subscribed at once
    assert set(over_dds.topics.raw) == set(over_dds.topics.intakes) == set(flight.types)
    assert not direct.topics.raw
    publisher = ros.plain("gap_test_publisher")
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {topic: publisher.create_publisher(cls, topic, qos) for topic, cls in flight.classes.items()}
    ros.wait(lambda: all(p.get_subscription_count() >= 1 for p in pubs.values()))
    # up to a few seconds after the end of the first sweep (so that there is an estimate to compare)
    first_end = min(s.end_s for ch in flight.replayed.channels.values() for s in ch.sweep_results)
    count = next(
        i for i, (_, msg) in enumerate(flight.messages()) if (stamp_seconds(msg) or 0) > first_end + 5.0
    )
    sent, chunk = 0, 400
    for topic, msg in flight.messages(0, count):
        pubs[topic].publish(msg)
        sent += 1
        if sent % chunk == 0 or sent == count:
            ros.wait(lambda: sum(over_dds.router.messages.values()) >= sent, timeout_s=30.0)
    flight.feed(direct, 0, count)
    assert over_dds.router.messages == direct.router.messages
    assert {t: i.reliability for t, i in over_dds.topics.intakes.items()} == {
        t: "reliable" for t in flight.types
    }
    end_of_data(over_dds, direct)
    for name in flight.config.channels:
        for stream in ("input", "output"):
            assert over_dds.router.samples(name, stream) == direct.router.samples(name, stream) > 0
    # DDS keeps the order within a topic, not across topics: batches may reach the estimator in another
    # order, so the spectra agree to rounding rather than bit for bit
    a, b = over_dds.validator.results(diagnose=False), direct.validator.results(diagnose=False)
    assert sum(ch.sweeps for ch in a.channels.values()) >= 1
    for name in flight.config.channels:
        assert a.channels[name].sweeps == b.channels[name].sweeps
        est_a, est_b = over_dds.validator.estimate(name), direct.validator.estimate(name)
        assert (est_a is None) == (est_b is None)
        if est_a is not None:
            for key in ("gxx", "gyy", "gxy"):
                np.testing.assert_allclose(getattr(est_a, key), getattr(est_b, key), rtol=1e-12, atol=0)
            assert a.channels[name].epsilon == pytest.approx(b.channels[name].epsilon, abs=1e-12)


# ------------------------------------------------------------------------------------------------ checkpoint
def test_node_and_replay_give_the_same_json_field_by_field_and_the_same_trim(flight, fed, typed):
    """Parity (one data path): after the flight the node (messages as they come, pushed every 2048 samples or
    2 s) and replay (its own batches) give the same JSON, every number, warning and verdict (1e-9), and the
    same spectra of the trim between the manoeuvres, which the JSON shows only through its judgements and
    which once depended on where a batch ended (the samples after a record's end that came before the block
    that closed it were lost)."""
    node = OnlineValidator.from_state(load_config(typed), load_state(fed["state"]), diagnose=False)
    mine = node.results(diagnose=False).to_json_dict()
    theirs = flight.replayed.to_json_dict()
    for key in ("sources", "config"):      # the files: replay's bag; the node's config is the typed copy
        mine.pop(key), theirs.pop(key)
    assert json_differences(mine, theirs) == []
    for name in flight.config.channels:
        a, b = node._estimators[name]._trim, flight.replay_validator._estimators[name]._trim
        assert (a.samples, a.segments, a.lead.rows) == (b.samples, b.segments, b.lead.rows), name
        np.testing.assert_allclose(a.sums, b.sums, rtol=1e-9, atol=1e-18, err_msg=name)
        np.testing.assert_allclose(a.lead.gram, b.lead.gram, rtol=1e-9, atol=1e-18, err_msg=name)


def test_plot_topics_redraw_the_replayed_curves_are_latched_and_sent_only_on_change(flight, typed, fed, ros,
                                                                                   tmp_path):
    """``~/<channel>/frequency_response`` and ``~/<channel>/verdict`` (docs/NODE_TOPICS.md): a subscriber that
    comes after the node published gets them (transient local); read back, the curves equal replay's JSON of
    the same flight point for point, NaN elsewhere on the grid; the verdict's numbers equal replay's;
    publishing again without new data sends nothing."""
    from std_msgs.msg import Float64MultiArray, String

    from gap_validation.core.plottable import CURVES, flags_from_codes, read_table
    from gap_validation.ros.plots import LATCHED

    node = resume(ros, fed, tmp_path, typed)
    node.publish_diagnostics()
    tables, verdicts = {}, {}
    for name in flight.replayed.channels:
        ros.helper.create_subscription(Float64MultiArray, f"/gap_validator/{name}/frequency_response",
                                       lambda m, n=name: tables.setdefault(n, []).append(m), LATCHED)
        ros.helper.create_subscription(String, f"/gap_validator/{name}/verdict",
                                       lambda m, n=name: verdicts.setdefault(n, []).append(m), LATCHED)
    ros.wait(lambda: len(tables) == len(verdicts) == len(flight.replayed.channels))
    for name, ch in flight.replayed.channels.items():
        (msg,) = tables[name]
        rows, freqs = msg.layout.dim
        assert rows.label.split(",") == list(CURVES) and freqs.label == "frequency"
        curves = read_table(msg.data, rows.label.split(","))
        grid = load_config(typed).channels[name].frequencies.values()
        np.testing.assert_allclose(curves["frequency_rad_s"], grid, rtol=1e-12)
        np.testing.assert_allclose(curves["log10_frequency_rad_s"], np.log10(grid), rtol=1e-12)
        data = ch.to_json_dict(samples=False)
        cols = [int(np.argmin(np.abs(grid - w))) for w in data["frequency_rad_s"]]
        np.testing.assert_allclose(grid[cols], data["frequency_rad_s"], rtol=1e-12)
        expect = {
            "measured_magnitude_db": data["measured"]["magnitude_db"],
            "measured_phase_deg": data["measured"]["phase_deg"],
            "model_magnitude_db": data["model"]["magnitude_db"],
            "model_phase_deg": data["model"]["phase_deg"],
            "coherence": data["coherence"],
            "epsilon": data["epsilon_per_frequency"],
            "kappa": data["kappa"],
            "random_error": data["random_error"],
        }
        others = np.setdiff1d(np.arange(grid.size), cols)
        for curve, values in expect.items():
            want = np.array([np.nan if v is None else v for v in values], dtype=float)
            np.testing.assert_allclose(
                curves[curve][cols], want, rtol=1e-9, atol=1e-12, err_msg=f"{name} {curve}"
            )
            assert np.isnan(curves[curve][others]).all(), f"{name} {curve}"
        assert flags_from_codes(curves["flag"][cols]) == data["frequency_flags"]
        verdict = json.loads(verdicts[name][-1].data)
        assert verdict["channel"] == name and verdict["sweeps"] == ch.sweeps
        assert verdict["epsilon"] == pytest.approx(ch.epsilon, abs=1e-9)
        assert verdict["nu_gap"] == pytest.approx(ch.nu_gap, abs=1e-9)
        assert verdict["limited_by"] == ch.limited_by and isinstance(verdict["warnings"], list)
    sent = node.plots.published
    node.publish_diagnostics()
    assert node.plots.published == sent      # nothing changed: nothing sent


def test_restart_from_checkpoint_reproduces_the_estimates(flight, typed, fed, ros, tmp_path):
    full = fed["result"]
    # resume from the checkpoint of the whole flight: identical numbers
    node = resume(ros, fed, tmp_path, typed)
    again = node.validator.results(diagnose=False)
    for name, ch in full.channels.items():
        assert again.channels[name].sweeps == ch.sweeps
        assert again.channels[name].epsilon == pytest.approx(ch.epsilon, abs=1e-12)
        assert again.channels[name].epsilon_raw == pytest.approx(ch.epsilon_raw, abs=1e-12)
        assert again.channels[name].nu_gap == pytest.approx(ch.nu_gap, abs=1e-12)
    # interrupted flight: first half, checkpoint, a new node resumes and gets the second half
    state = tmp_path / "half.npz"
    half = len(flight.records) // 2
    first = ros.validator(typed, state_file=str(state), name="gap_validator_first")
    flight.feed_raw(first, 0, half)
    ros.drop(first)  # writes the final checkpoint, as at shutdown
    second = ros.validator(typed, state_file=str(state), name="gap_validator_second")
    flight.feed_raw(second, half)
    end_of_data(second)
    resumed = second.validator.results(diagnose=False)
    for name, ch in full.channels.items():
        assert resumed.channels[name].sweeps == ch.sweeps
        assert resumed.channels[name].epsilon == pytest.approx(ch.epsilon, abs=1e-12)
        assert resumed.channels[name].epsilon_raw == pytest.approx(ch.epsilon_raw, abs=1e-12)


def test_checkpoint_timer_writes_atomically(flight, ros, tmp_path):
    state = tmp_path / "timer.npz"
    node = ros.validator(CONFIG, spin=True, state_file=str(state), checkpoint_period=0.05,
                         diagnostic_period=1000.0)
    flight.feed(node, 0, 3000)
    ros.wait(lambda: state.exists())      # written by the background thread, from a snapshot
    loaded = load_state(state)
    assert set(loaded["channels"]) == {"roll", "pitch", "yaw"}
    ros.drop(node)                        # waits for the writes under way, then the final checkpoint
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_corrupt_checkpoint_is_set_aside_and_the_node_starts_fresh(ros, tmp_path):
    state = tmp_path / "state.npz"
    state.write_bytes(b"this is not a checkpoint")
    node = ros.validator(CONFIG, state_file=str(state))
    assert not state.exists()
    assert (tmp_path / "state.npz.corrupt").read_bytes() == b"this is not a checkpoint"
    result = node.validator.results(diagnose=False)
    assert all(ch.sweeps == 0 and ch.epsilon is None for ch in result.channels.values())
    assert node.checkpoint() == str(state) and load_state(state)["channels"]


# ------------------------------------------------------------------------------------------------ model
# update
def _model_update(node: ValidatorNode, flight: Flight, fed: dict, tmp_path: Path, via: str):
    before = statuses(node.publish_diagnostics())
    for name, ch in fed["result"].channels.items():
        assert number(before[name][1]["epsilon"]) == pytest.approx(ch.epsilon, abs=1e-12)
        assert before[name][1]["epsilon_previous"] == "null"
    hidden = flight.hidden or {name: MISSING for name in flight.config.channels}
    updated = write_typed(tmp_path / "with_effects.yaml", hidden, aircraft="renamed_in_the_new_config")
    if via == "parameter":
        outcome = node.set_parameters([Parameter("config_file", value=str(updated))])[0]
        assert outcome.successful, outcome.reason
        assert node.get_parameter("config_file").value == str(updated)
    else:
        shutil.copy(updated, node.get_parameter("config_file").value)
        ok, text = node.reload()
        assert ok, text
    after = statuses(node.publish_diagnostics())
    fell = 0
    for name, ch in fed["result"].channels.items():
        assert after[name][0].hardware_id == before[name][0].hardware_id == "ultrastick25e"  # a model update
        values = after[name][1]
        assert number(values["epsilon_previous"]) == pytest.approx(ch.epsilon, abs=1e-12)
        if hidden.get(name):
            assert number(values["epsilon"]) < ch.epsilon - 0.05, name
            assert f"(was {ch.epsilon:.2f})" in after[name][0].message
            fell += 1
    assert fell >= 1
    return before, after


def test_model_update_by_parameter_lowers_epsilon_and_keeps_the_previous(flight, typed, fed, ros, tmp_path):
    node = resume(ros, fed, tmp_path, typed)
    _model_update(node, flight, fed, tmp_path, via="parameter")


def test_bad_config_on_parameter_set_is_refused_and_the_old_model_kept(typed, fed, ros, tmp_path):
    node = resume(ros, fed, tmp_path, typed)
    bad = tmp_path / "bad.yaml"
    bad.write_text("channels: {pitch: {input: {topic: /x, field: 'a..b'}}}\n")
    outcome = node.set_parameters([Parameter("config_file", value=str(bad))])[0]
    assert not outcome.successful
    assert "\n" not in outcome.reason and "bad.yaml" in outcome.reason
    assert node.get_parameter("config_file").value == str(typed)
    assert node.config.source == str(typed)
    after = statuses(node.publish_diagnostics())
    assert set(after) == {"roll", "pitch", "yaw"}
    assert after["pitch"][1]["epsilon_previous"] == "null"


# ------------------------------------------------------------------------------------------------ levels,
# STALE
def _fresh_messages(start_s: float, count: int, rate_hz: float = 100.0):
    """Imu and JointState messages after ``start_s`` (stamped), alternating."""
    out = []
    for i in range(count):
        t = start_s + (i + 1) / rate_hz
        sec, nanosec = int(t), int(round((t - int(t)) * 1e9)) % 1_000_000_000
        imu = Imu()
        imu.header.stamp.sec, imu.header.stamp.nanosec = sec, nanosec
        imu.angular_velocity.x, imu.angular_velocity.y, imu.angular_velocity.z = 0.01, -0.02, 0.003
        joints = JointState(name=["aileron", "elevator", "rudder"], position=[0.001, 0.002, 0.0])
        joints.header.stamp.sec, joints.header.stamp.nanosec = sec, nanosec
        out += [("/imu", imu), ("/control_surfaces", joints)]
    return out


def test_levels_are_byte_constants_and_inputs_stopping_make_stale(flight, typed, fed, ros, tmp_path):
    node = resume(ros, fed, tmp_path, typed, stale_timeout=0.3, diagnostic_period=1000.0)
    # resumed, no data yet this session: STALE, waiting, the last numbers kept
    waiting = statuses(node.publish_diagnostics())
    for name, (status, values) in waiting.items():
        assert isinstance(status.level, bytes) and status.level == DiagnosticStatus.STALE
        assert status.message.startswith("waiting for data on") and "resumed" in status.message
        assert number(values["epsilon"]) == pytest.approx(fed["result"].channels[name].epsilon, abs=1e-12)
        assert status.hardware_id == "ultrastick25e"
    start = flight.last_stamp_s + 100.0
    for topic, msg in _fresh_messages(start, 20):
        node.on_message(topic, msg)
    live = statuses(node.publish_diagnostics())
    for name, ch in node.last_result.channels.items():  # fresh quiet data: the estimate is (about) the same
        assert ch.epsilon == pytest.approx(fed["result"].channels[name].epsilon, abs=1e-3)
        expected = (DiagnosticStatus.ERROR if ch.epsilon >= 0.38 else
                    DiagnosticStatus.WARN if ch.epsilon >= 0.25 else DiagnosticStatus.OK)
        status, values = live[name]
        assert status.level == expected, (name, status.message)
        assert status.message.startswith(f"epsilon {ch.epsilon:.2f}")
        assert float(values["input_age_s"]) < 0.3
    time.sleep(0.4)
    stale = statuses(node.publish_diagnostics())
    for name, (status, values) in stale.items():
        assert status.level == DiagnosticStatus.STALE
        assert status.message.startswith("no data for") and "/imu (output)" in status.message
        assert "; last: epsilon" in status.message
        assert float(values["output_age_s"]) > 0.3
    # warn/error thresholds are live parameters
    assert node.set_parameters_atomically([Parameter("warn_epsilon", value=0.9),
                                           Parameter("error_epsilon", value=0.95)]).successful
    for topic, msg in _fresh_messages(start + 10.0, 5):
        node.on_message(topic, msg)
    relaxed = statuses(node.publish_diagnostics())
    for name, ch in node.last_result.channels.items():
        assert relaxed[name][0].level == (
            DiagnosticStatus.OK
            if ch.epsilon < 0.9
            else DiagnosticStatus.WARN
            if ch.epsilon < 0.95
            else DiagnosticStatus.ERROR
        )
    refused = node.set_parameters([Parameter("warn_epsilon", value=0.99)])[0]
    assert not refused.successful and "error_epsilon" in refused.reason


def test_diagnostics_published_on_the_topic_before_any_data(ros):
    node = ros.validator(CONFIG, spin=True, diagnostic_period=0.05, hardware_id="ultrastick-7")
    got = []
    ros.helper.create_subscription(DiagnosticArray, "/diagnostics", got.append, 10)
    ros.wait(lambda: len(got) >= 2)
    published = statuses(got[-1])
    assert list(published) == ["roll", "pitch", "yaw"]
    for name, (status, values) in published.items():
        assert isinstance(status.level, bytes) and status.level == DiagnosticStatus.STALE
        assert status.hardware_id == "ultrastick-7"
        assert status.message.startswith("waiting for data on /control_surfaces (input")
        for key in ("nu_gap", "epsilon", "epsilon_raw", "epsilon_previous", "gain_margin_db",
                    "phase_margin_deg", "disk_margin", "worst_frequency_rad_s", "sweeps", "limited_by",
                    "points_excluded", "bad_samples", "diagnosis"):
            assert key in values, key
        assert values["sweeps"] == "0" and values["epsilon"] == "null"
    assert node.get_fully_qualified_name() == "/gap_validator"


def test_the_shipped_aggregator_config_expects_the_statuses_the_node_publishes(ros):
    """``config/diagnostic_aggregator.yaml`` groups the bundled config's channels: its ``expected`` names and
    its ``startswith`` are those of the node's statuses (a name off by a character reads STALE for ever)."""
    data = yaml.safe_load((ROOT / "config" / "diagnostic_aggregator.yaml").read_text())
    analyzer = data["analyzers"]["ros__parameters"]["model_validation"]
    node = ros.validator(CONFIG)
    names = [s.name for s in node.publish_diagnostics().status]
    assert sorted(analyzer["expected"]) == sorted(names)
    assert all(name.startswith(tuple(analyzer["startswith"])) for name in names)


def test_statuses_carry_the_node_name_and_are_ok_while_waiting_for_a_sweep(ros):
    """Remapped (``-r __node:=gv2 -r __ns:=/uav1``): statuses ``gv2: <channel>`` (diagnostic_updater's
    naming), hardware_id the node's fully qualified name (the config has no ``aircraft``); receiving data
    without a sweep yet is OK with no epsilon (STALE only when the inputs are silent)."""
    node = ros.validator(CONFIG, name="gv2", namespace="/uav1", diagnostic_period=1000.0)
    assert node.get_fully_qualified_name() == "/uav1/gv2"
    before = statuses(node.publish_diagnostics(), node_name="gv2")
    assert all(status.level == DiagnosticStatus.STALE for status, _ in before.values())   # silent inputs
    for topic, msg in _fresh_messages(1.7e9, 20):
        node.on_message(topic, msg)
    published = statuses(node.publish_diagnostics(), node_name="gv2")
    assert list(published) == ["roll", "pitch", "yaw"]
    for name, (status, values) in published.items():
        assert status.level == DiagnosticStatus.OK, status.message
        assert status.message == "receiving data, waiting for a sweep (no estimate yet)"
        assert values["epsilon"] == "null" and values["sweeps"] == "0"
        assert status.hardware_id == "/uav1/gv2"


@pytest.mark.parametrize("case", ["publisher_first", "node_first", "node_first_use_sim_time"])
def test_no_message_is_lost_from_the_first_one(ros, case):
    """The shipped config (no ``type:``) is subscribed at once; a RELIABLE flight stack started before or
    after the node gets every message it publishes once matched, through the node's switch from best effort to
    reliable while they flow; with ``use_sim_time`` and no /clock at all, too (the intake timer runs on the
    steady clock)."""
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    stack = OtherParticipant(qos, TYPES) if case == "publisher_first" else None
    try:
        node = ros.validator(CONFIG, spin=True, diagnostic_period=1000.0, discovery_period=0.1,
                             use_sim_time=case.endswith("use_sim_time"))
        assert set(node.topics.intakes) == set(TYPES) and not node.pending           # before any publisher
        if stack is None:
            ros.wait(lambda: True)
            stack = OtherParticipant(qos, TYPES)
        ros.wait(stack.matched)
        imu, sent = Imu(), {"/imu": 0, "/control_surfaces": 0}
        joints = JointState(name=["aileron", "elevator", "rudder"], position=[0.0, 0.0, 0.0])
        for k in range(3000):                     # 3 s of a 1 kHz IMU and 100 Hz surfaces, 10 times real time
            t = 1.7e9 + k / 1000.0
            imu.header.stamp.sec, imu.header.stamp.nanosec = int(t), int(round((t - int(t)) * 1e9)) % 10**9
            imu.angular_velocity.y = 0.01 * (k % 7)
            stack.pubs["/imu"].publish(imu)
            sent["/imu"] += 1
            if k % 10 == 0:
                joints.header.stamp = imu.header.stamp
                stack.pubs["/control_surfaces"].publish(joints)
                sent["/control_surfaces"] += 1
            if k % 100 == 99:
                ros.wait(
                    lambda: sum(node.router.messages.values()) >= sum(sent.values()) - 300, timeout_s=30.0
                )
        ros.wait(lambda: node.router.messages == sent, timeout_s=30.0)
        ros.wait(
            lambda: all(i.reliability == "reliable" and not i.changing for i in node.topics.intakes.values()),
            timeout_s=30.0,
        )
        assert node.router.messages == sent
        node.router.flush()
        assert node.router.samples("pitch", "output") == 3000 and node.router.samples("pitch", "input") == 300
        assert not any(node.router.bad.values())  # no message came twice (it would be "time not increasing")
    finally:
        if stack is not None:
            stack.close()


def test_a_publisher_the_fixed_qos_cannot_match_is_named_in_the_status(ros):
    """``qos_reliability: reliable`` and a BEST_EFFORT flight stack: nothing can arrive; the channel's status
    says why and what to set (ERROR), instead of a warning line in the log and a STALE status."""
    node = ros.validator(CONFIG, spin=True, diagnostic_period=1000.0, discovery_period=0.1,
                         qos_reliability="reliable")
    stack = OtherParticipant(BEST_EFFORT_QOS, TYPES)
    try:
        ros.wait(lambda: all(i.note for i in node.topics.intakes.values()))
    finally:
        stack.close()
    for name, (status, values) in statuses(node.publish_diagnostics()).items():
        assert status.level == DiagnosticStatus.ERROR, status.message
        assert (
            "publisher on /imu offers BEST_EFFORT; set qos_reliability to auto or best_effort (the "
            "subscription "
            "is RELIABLE)"
        ) in status.message
        assert status.message.endswith("waiting for data on /control_surfaces (input) and /imu (output)")


# ------------------------------------------------------------------------------------------------ bad
# messages
@pytest.mark.parametrize("path", ["raw", "message"])
def test_bad_messages_are_counted_and_survived(ros, typed, path):
    """NaN rate, JointState without the joint, position array too short: counted per reason, never fatal."""
    node = ros.validator(typed, diagnostic_period=1000.0, raw_decoding=(path == "raw"))
    assert bool(node.topics.raw) == (path == "raw")

    def send(topic, msg):
        if path == "raw":
            node.on_raw(topic, serialize_message(msg))
        else:
            node.on_message(topic, msg)

    for topic, msg in _fresh_messages(1.7e9, 3):
        send(topic, msg)
    nan_imu = Imu()
    nan_imu.header.stamp.sec = 1_700_000_010
    nan_imu.angular_velocity.x = float("nan")
    no_elevator = JointState(name=["aileron", "rudder"], position=[0.0, 0.0])
    no_elevator.header.stamp.sec = 1_700_000_011
    short = JointState(name=["aileron", "elevator", "rudder"], position=[0.0, 0.0])
    short.header.stamp.sec = 1_700_000_012
    send("/imu", nan_imu)
    send("/control_surfaces", no_elevator)
    send("/control_surfaces", short)
    if path == "raw":
        node.on_raw("/imu", b"\x00\x01\x00\x00garbage")        # undecodable bytes: skipped, logged
    else:
        node.on_message("/imu", Float64(data=1.0))          # wrong message type on a topic: counted, logged
    node.on_message("/unconfigured", Float64(data=1.0))     # not configured: ignored
    values = {name: v for name, (_, v) in statuses(node.publish_diagnostics()).items()}
    roll = json.loads(values["roll"]["bad_samples_by_reason"])
    pitch = json.loads(values["pitch"]["bad_samples_by_reason"])
    yaw = json.loads(values["yaw"]["bad_samples_by_reason"])
    assert roll.get("output: not finite") == 1
    assert pitch.get("input: missing joint") == 1
    assert yaw.get("input: wrong length") == 1
    if path == "message":
        assert all(counts.get("output: missing field") == 1 for counts in (roll, pitch, yaw))
    else:  # a damaged record is counted as replay counts it
        assert all(counts.get("output: undecodable") == 1 for counts in (roll, pitch, yaw))
    for name in ("roll", "pitch", "yaw"):
        assert int(values[name]["bad_samples"]) == sum(
            json.loads(values[name]["bad_samples_by_reason"]).values()
        )
    # still alive and still counting good samples
    before = node.router.samples("pitch", "output")
    for topic, msg in _fresh_messages(1_700_000_020.0, 2):
        send(topic, msg)
    assert node.router.samples("pitch", "output") == before + 2


# ------------------------------------------------------------------------------------------------ services
def _umask() -> int:
    from gap_validation.ros.background import umask

    return umask()


def test_save_results_runs_in_the_background_and_diagnostics_keep_their_period(typed, fed, ros, tmp_path):
    """``~/save_results`` (full diagnosis, JSON, the report's figures: seconds of work) runs on a snapshot in
    a child process: /diagnostics keeps being published meanwhile and, with data flowing, no channel goes
    STALE; the answer comes when the files are written, with the usual permissions.

    A blocked executor shows as one gap the length of the save (over 4 periods) and no publication during it.
    How regular the period stays depends on the machine's load (two test workers on two cores stretched one
    to 1.5 periods in CI, other jobs to 3): the test asserts what blocking would break, not the load."""
    results = tmp_path / "results"
    period = 0.5
    pitch_only = yaml.safe_load(typed.read_text())     # one channel's report: a third of the work, same path
    pitch_only["channels"] = {"pitch": pitch_only["channels"]["pitch"]}
    config = tmp_path / "pitch.yaml"
    config.write_text(yaml.safe_dump(pitch_only, sort_keys=False))
    node = resume(ros, fed, tmp_path, config, spin=True, results_dir=str(results), diagnostic_period=period,
                  stale_timeout=5 * period)
    # validator_node freezes its start-up objects out of the garbage collector's way (ros/main.py); this
    # process also holds the whole flight, whose full collections would otherwise be what stalls the executor
    gc.freeze()
    published = []
    real = node.publish_diagnostics

    def publish():
        array = real()
        published.append((time.monotonic(), array))
        return array

    node.publish_diagnostics = publish
    start_s = [fed["result"].channels["pitch"].sweep_results[-1].end_s + 1000.0]

    def flowing():  # the flight stack keeps publishing while the results are saved
        for topic, msg in _fresh_messages(start_s[0], 5):
            node.on_message(topic, msg)
        start_s[0] += 0.05

    feeder = ros.helper.create_timer(0.05, flowing)
    save = ros.plain("gap_test_client").create_client(Trigger, "/gap_validator/save_results")
    ros.wait(lambda: len(published) >= 2)
    started = time.monotonic()
    # a spawned interpreter drawing figures: slow on a loaded machine
    answer = ros.call(save, Trigger.Request(), timeout_s=240.0)
    finished = time.monotonic()
    ros.helper.destroy_timer(feeder)
    assert answer.success, answer.message
    during = [t for t, _ in published if started <= t <= finished]
    assert finished - started > 4 * period, "the save was too quick to show anything"
    took = finished - started
    gaps = np.diff([started, *during, finished])
    assert len(during) >= 0.4 * took / period, f"{len(during)} /diagnostics in {took:.1f} s of ~/save_results"
    assert gaps.max() <= max(2.0 * period, 0.4 * took), \
        f"/diagnostics stalled {gaps.max():.2f} s during {took:.1f} s of ~/save_results"
    for t, array in published:
        if started <= t <= finished:
            assert all(status.level != DiagnosticStatus.STALE for status in array.status), \
                [status.message for status in array.status]
    path = Path(answer.message)
    assert path.parent == results and path.suffix == ".json" and path.name.startswith("ultrastick25e_")
    assert path.stat().st_mode & 0o777 == 0o666 & ~_umask()          # not the temporary file's 0600
    saved = json.loads(path.read_text())
    assert list(saved["channels"]) == ["pitch"]
    assert saved["channels"]["pitch"]["epsilon"] == pytest.approx(
        fed["result"].channels["pitch"].epsilon, abs=1e-3
    )
    assert isinstance(saved["channels"]["pitch"]["diagnosis"], list)
    report = path.with_suffix("") / "index.html"
    try:
        import gap_validation.report.html  # noqa: F401
    except ImportError:
        pass
    else:
        assert report.exists() and report.stat().st_mode & 0o777 == 0o666 & ~_umask()
        for kind in ("bode", "disk", "failure", "nichols", "nyquist", "time"):   # from the live spectra
            assert (report.parent / f"pitch_{kind}.png").stat().st_size > 10_000
    # the save's full diagnosis fills the statuses' diagnosis value
    assert all(v["diagnosis"] != "pending" for _, v in statuses(real()).values())


def test_services_reload_reset(flight, typed, fed, ros, tmp_path):
    config = tmp_path / "live.yaml"
    shutil.copy(typed, config)
    state = tmp_path / "state.npz"
    shutil.copy(fed["state"], state)
    node = ros.validator(config, spin=True, state_file=str(state), diagnostic_period=1000.0)
    client = ros.plain("gap_test_client")
    reload_ = client.create_client(Trigger, "/gap_validator/reload")
    reset = client.create_client(Trigger, "/gap_validator/reset")

    # reload with a good file that adds the missing effects: epsilon falls, previous kept
    write_typed(config, flight.hidden or {name: MISSING for name in flight.config.channels})
    answer = ros.call(reload_, Trigger.Request())
    assert answer.success, answer.message
    result = node.validator.results(diagnose=False)
    for name, ch in fed["result"].channels.items():
        assert result.channels[name].epsilon_previous == pytest.approx(ch.epsilon, abs=1e-12)

    # reload with a broken file: refused, one line, the good model stays
    config.write_text("channels: [unclosed\n")
    answer = ros.call(reload_, Trigger.Request())
    assert not answer.success
    assert "\n" not in answer.message and "live.yaml" in answer.message and "YAML" in answer.message
    assert node.validator.results(diagnose=False).channels["pitch"].epsilon == \
        pytest.approx(result.channels["pitch"].epsilon, abs=1e-15)

    # reset: spectra gone (and the checkpoint, written in the background, says so)
    answer = ros.call(reset, Trigger.Request())
    assert answer.success
    cleared = node.validator.results(diagnose=False)
    assert all(ch.sweeps == 0 and ch.epsilon is None for ch in cleared.channels.values())
    assert node.wait_for_background(30.0)
    assert state.stat().st_mode & 0o777 == 0o666 & ~_umask()
    resumed = ros.validator(typed, name="gap_validator_resumed", state_file=str(state))
    assert all(ch.sweeps == 0 for ch in resumed.validator.results(diagnose=False).channels.values())
    # diagnostics still work after all that
    assert set(statuses(node.publish_diagnostics())) == {"roll", "pitch", "yaw"}


def test_full_diagnosis_runs_in_the_background_and_fills_the_message(typed, fed, ros, tmp_path):
    # unpaced (share 1): the pacing is test_diagnosis_worker's; at the default 6 % of a core this waits 80 s
    node = resume(ros, fed, tmp_path, typed, diagnosis_period=0.0, diagnosis_cpu_share=1.0)
    values = statuses(node.publish_diagnostics())
    assert all(v["diagnosis"] == "off" for _, v in values.values())
    node.set_parameters([Parameter("diagnosis_period", value=10.0)])
    first = statuses(node.publish_diagnostics())
    assert all(v["diagnosis"] == "pending" for _, v in first.values())
    assert node.wait_for_diagnosis(timeout_s=120.0)
    done = statuses(node.publish_diagnostics())
    found = 0
    for name, (status, values) in done.items():
        assert values["diagnosis"] != "pending"
        if values["diagnosis"] not in ("none",):
            found += 1
            assert values["diagnosis"] in status.message
            assert json.loads(values["diagnosis_effects"])
    assert found >= 1
    # unchanged results: no new diagnosis is started
    node.publish_diagnostics()
    assert node.diagnosis_worker.job is None


# ------------------------------------------------------------------------------------------------ discovery
def test_types_the_fields_do_not_imply_are_discovered_and_wrong_guesses_followed(ros, tmp_path):
    """``twist.angular.y`` implies no type: that topic waits for the graph (geometry_msgs/TwistStamped there);
    ``data`` implies std_msgs/Float64, but the publisher sends Float32: the node follows the publisher."""
    from geometry_msgs.msg import TwistStamped
    from std_msgs.msg import Float32

    data = yaml.safe_load(CONFIG.read_text())
    pitch = data["channels"]["pitch"]
    pitch["input"] = {"topic": "/elevator", "field": "data"}
    pitch["output"] = {"topic": "/rates", "field": "twist.angular.y"}
    config = tmp_path / "scalar.yaml"
    config.write_text(yaml.safe_dump({"channels": {"pitch": pitch}}, sort_keys=False))
    node = ros.validator(config, spin=True, discovery_period=0.05, diagnostic_period=1000.0)
    assert node.pending == ["/rates"] and node.topics.intakes["/elevator"].type_name == "std_msgs/msg/Float64"
    waiting = statuses(node.publish_diagnostics())["pitch"][0]
    assert (
        waiting.level == DiagnosticStatus.STALE and "/rates (output; type not known yet)" in waiting.message
    )
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)
    stack = OtherParticipant(qos, {"/rates": TwistStamped, "/elevator": Float32})
    try:
        ros.wait(
            lambda: (
                not node.pending
                and node.topics.intakes["/elevator"].type_name == "std_msgs/msg/Float32"
                and stack.matched()
            )
        )
        assert {t: (i.type_name, i.type_source) for t, i in node.topics.intakes.items()} == {
            "/elevator": ("std_msgs/msg/Float32", "graph"),
            "/rates": ("geometry_msgs/msg/TwistStamped", "graph"),
        }
        for k in range(3):
            twist = TwistStamped()
            twist.header.stamp.sec = 1_700_000_000 + k
            stack.pubs["/rates"].publish(twist)
            stack.pubs["/elevator"].publish(Float32(data=0.5))
        ros.wait(lambda: node.router.messages == {"/elevator": 3, "/rates": 3})
    finally:
        stack.close()


# ------------------------------------------------------------------------------------------------ params
# file, main
def test_params_file_matches_the_declared_parameters(ros):
    params = ROOT / "config" / "validator.params.yaml"
    data = yaml.safe_load(params.read_text())
    declared = data["/**"]["ros__parameters"]
    for name, value in declared.items():
        assert name in PARAMETERS, name
        assert value == PARAMETERS[name][0] and type(value) is type(PARAMETERS[name][0]), name
    node = ValidatorNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(params),
                                                        "-p", f"config_file:={CONFIG}"])
    ros.nodes.append(node)
    for name in declared:
        assert node.get_parameter(name).value == PARAMETERS[name][0]
    assert set(declared) == set(PARAMETERS) - {"config_file"}   # every parameter listed with its default


def test_parameters_have_descriptions_ranges_and_read_only_flags(ros):
    """What ``ros2 param describe`` shows; rclpy refuses values outside the ranges."""
    node = ros.validator(CONFIG)
    for name, param in PARAMETERS.items():
        descriptor = node.describe_parameter(name)
        assert descriptor.description == param.description and descriptor.read_only == param.read_only, name
        if param.range is not None and isinstance(param.default, float):
            assert (descriptor.floating_point_range[0].from_value,
                    descriptor.floating_point_range[0].to_value) == param.range, name
        elif param.range is not None:
            assert (
                descriptor.integer_range[0].from_value,
                descriptor.integer_range[0].to_value,
            ) == param.range
    assert (
        node.describe_parameter("qos_depth").read_only
        and not node.describe_parameter("warn_epsilon").read_only
    )
    refused = node.set_parameters([Parameter("stale_timeout", value=-1.0)])[0]
    assert not refused.successful
    assert node.set_parameters([Parameter("stale_timeout", value=2.0)])[0].successful


@pytest.mark.parametrize("case", ["missing", "invalid", "unset", "qos", "range"])
def test_bad_startup_config_exits_2_with_one_line(tmp_path, capfd, case):
    """``main`` in this process (the child-process path is the console-script test's and test_colcon's): exit
    status 2 and exactly one line on stderr, for a bad config and for a bad parameter."""
    from gap_validation.ros.main import main

    bad = tmp_path / "bad.yaml"
    bad.write_text("channels:\n  pitch: {input: 3}\n")
    args = {"missing": ["--ros-args", "-p", f"config_file:={tmp_path / 'nope.yaml'}"],
            "invalid": ["--ros-args", "-p", f"config_file:={bad}"],
            "unset": [],
            "qos": ["--ros-args", "-p", f"config_file:={CONFIG}", "-p", "qos_reliability:=sometimes"],
            "range": ["--ros-args", "-p", f"config_file:={CONFIG}", "-p", "diagnostic_period:=0.0"]}[case]
    assert main(args) == 2
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("validator_node: error: "), err
    assert "Traceback" not in err
    expected = {
        "missing": "config file not found",
        "invalid": "bad.yaml",
        "unset": "config_file is not set",
        "qos": "parameter qos_reliability: expected one of auto, reliable, best_effort, got 'sometimes'",
        "range": "parameter diagnostic_period: expected a number in [0.01, 3600], got 0.0",
    }[case]
    assert expected in lines[0]


@pytest.mark.parametrize("executor", ["events", "single_threaded"])
def test_console_script_runs_publishes_answers_and_checkpoints_on_sigint(ros, typed, tmp_path, executor):
    """``main`` end to end in a child process: /diagnostics, parameters, a service answered from the
    background, a misspelt parameter warned about by name, clean SIGINT."""
    import signal

    from rcl_interfaces.srv import SetParameters

    state = tmp_path / "state.npz"
    env = dict(os.environ)
    child = subprocess.Popen([sys.executable, "-m", "gap_validation.ros.main", "--ros-args", "-p",
                              f"config_file:={typed}", "-p", "diagnostic_period:=0.1", "-p",
                              f"state_file:={state}", "-p", f"results_dir:={tmp_path}", "-p",
                              f"executor:={executor}", "-p", "diagnostic_perid:=2.0"],
                             env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        got = []
        ros.helper.create_subscription(DiagnosticArray, "/diagnostics", got.append, 10)
        ros.wait(lambda: len(got) >= 2, timeout_s=30.0)
        assert set(statuses(got[-1])) == {"roll", "pitch", "yaw"}
        if executor == "events":   # served by the intake timer whatever the executor: once is enough
            save = ros.helper.create_client(Trigger, "/gap_validator/save_results")
            # a spawned interpreter drawing figures: slow on a loaded machine
            answer = ros.call(save, Trigger.Request(), timeout_s=240.0)
            assert answer.success and Path(answer.message).is_file(), answer.message
            assert Path(answer.message).stat().st_mode & 0o777 == 0o666 & ~_umask()
        setter = ros.helper.create_client(SetParameters, "/gap_validator/set_parameters")
        request = SetParameters.Request(
            parameters=[Parameter("hardware_id", value="uav-3").to_parameter_msg()]
        )
        assert ros.call(setter, request).results[0].successful
        ros.wait(lambda: statuses(got[-1])["pitch"][0].hardware_id == "uav-3", timeout_s=30.0)
        child.send_signal(signal.SIGINT)
        out, err = child.communicate(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
            child.communicate()
    assert child.returncode == 0, err
    assert "Traceback" not in err
    assert "unknown parameter diagnostic_perid (did you mean diagnostic_period?): ignored" in err
    assert load_state(state)["channels"]  # final checkpoint at shutdown


def test_a_mimo_channel_through_the_node_equals_replay(ros, tmp_path):
    """Issue 14: a MIMO lateral channel (aileron, rudder -> p, r) from its raw records through the node: the
    same MIMO nu-gap as replay, and a status whose level follows the nu-gap (epsilon is a SISO notion)."""
    from _flights import SHORT, make_bag
    from test_mimo import LATERAL

    channel = copy.deepcopy(LATERAL)
    for signal in channel["inputs"] + channel["outputs"]:
        signal["type"] = TYPES[signal["topic"]]
    config = tmp_path / "lateral.yaml"
    config.write_text(yaml.safe_dump({"channels": {"lateral": channel}}))
    bag = tmp_path / "flight"
    make_bag(bag, load_config(config), seed=3, options=SHORT)
    expected = replay([bag], load_config(config), diagnose=False).result.channels["lateral"]
    node = ros.validator(config, end_of_data_timeout=0.5)
    with open_bag(bag) as opened:
        for topic, _, _, raw in opened.records(list(TYPES)):
            node.on_raw(topic, bytes(raw))
    end_of_data(node)
    mine = node.validator.results(diagnose=False).channels["lateral"]
    assert expected.nu_gap is not None and expected.nu_gap < 0.15
    assert mine.nu_gap == pytest.approx(expected.nu_gap, abs=1e-9) and mine.sweeps == expected.sweeps
    status, values = statuses(node.publish_diagnostics())["lateral"]
    assert status.level == DiagnosticStatus.OK and status.message.startswith("MIMO nu-gap")
    assert number(values["nu_gap"]) == pytest.approx(expected.nu_gap, abs=1e-9)
    assert int(values["samples_input"]) > 0 and int(values["samples_output"]) > 0
