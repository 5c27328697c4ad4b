"""Tests of the ROS 2 node ``gap_validator`` (in-process rclpy with an explicit context).

Data path: the bundled flight (``bags/``; a simulated flight with the same hidden effects when none is
bundled) is read with :mod:`gap_validation.bag.reader`, each raw CDR record is deserialised into an rclpy message
and handed to the node's subscription callback ``ValidatorNode.on_message`` -- the function its
subscriptions call. That is the robust route for the full flight (no timing, no DDS queue to pace); a
separate test sends the first part of the flight through real DDS publishers (RELIABLE, paced below the
queue depth) and checks that the node receives every message and ends in the bit-identical state.
"""
from __future__ import annotations

import copy
import json
import os
import random
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

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
from gap_validation.config import load_config  # noqa: E402
from gap_validation.core.checkpoint import load_state  # noqa: E402
from gap_validation.messages.router import stamp_seconds  # noqa: E402
from gap_validation.ros.message_types import message_class  # noqa: E402
from gap_validation.ros.node import ValidatorNode  # noqa: E402
from gap_validation.ros.parameters import PARAMETERS  # noqa: E402
from gap_validation.bag.replay import replay  # noqa: E402

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
    keys = ("ROS_PYTHON_CHECK_FIELDS", "ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")
    saved = {k: os.environ.get(k) for k in keys}
    os.environ.update({"ROS_PYTHON_CHECK_FIELDS": "1", "ROS_DOMAIN_ID": str(random.randint(0, 101)),
                       "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    yield
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


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

    def validator(self, config=CONFIG, spin: bool = False, name: str | None = None, **params) -> ValidatorNode:
        overrides = [Parameter("config_file", value=str(config))]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        remap = ["--ros-args", "-r", f"__node:={name}"] if name else None
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
            self.records = [(topic, bytes(raw)) for topic, _, _, raw in opened.records(list(self.config.topics()))]
        self.types = {topic: info[topic].msgtype for topic in self.config.topics()}
        assert self.types == TYPES
        self.classes = {topic: message_class(t) for topic, t in self.types.items()}
        self.hidden = _hidden_of(bag)
        started = time.perf_counter()
        self.replayed = replay([bag], self.config, diagnose=False).result
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
        assert set(node._raw) == set(self.types), "the node must have raw subscriptions"
        for topic, raw in self.records[start:stop]:
            node.on_raw(topic, raw)



def write_typed(path: Path, effects: dict | None = None) -> Path:
    """The Ultra Stick config with the message types set and, optionally, effects per channel."""
    data = yaml.safe_load(CONFIG.read_text())
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
    """The typed Ultra Stick config, named like the original (hardware_id ultrastick25e)."""
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
        node = session.validator(typed, state_file=str(state))
        flight.feed_raw(node)
        assert all(raw.decoder is not None for raw in node._raw.values())  # fast decoding verified and used
        node.router.flush()
        result = node.validator.results(diagnose=False)
        array = node.publish_diagnostics()
        assert node.checkpoint() == str(state)
    finally:
        session.close()
    return {"state": state, "result": result, "array": array}


def statuses(array: DiagnosticArray) -> dict:
    """Channel -> (status, values dict) of a DiagnosticArray."""
    out = {}
    for status in array.status:
        assert status.name.startswith("gap_validator: ")
        out[status.name.split(": ", 1)[1]] = (status, {kv.key: kv.value for kv in status.values})
    return out


def number(text: str) -> float | None:
    return None if text == "null" else float(text)


def resume(ros: Ros, fed: dict, tmp_path: Path, config: Path, **params) -> ValidatorNode:
    state = tmp_path / "state.npz"
    shutil.copy(fed["state"], state)
    return ros.validator(config, state_file=str(state), **params)


# ------------------------------------------------------------------------------------------------ one data path
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


def test_flight_over_dds_arrives_complete_and_gives_the_same_state(flight, typed, ros):
    """RELIABLE + deep queue, paced publishing: every message arrives, and the raw path over DDS gives the
    same spectra as rclpy messages handed to the message callback."""
    over_dds = ros.validator(typed, spin=True, diagnostic_period=1000.0)
    direct = ros.validator(typed, name="gap_validator_direct", diagnostic_period=1000.0, raw_decoding=False)
    assert set(over_dds._raw) == set(over_dds._subs) == set(flight.types)  # typed: subscribed at once
    assert not direct._raw
    publisher = ros.plain("gap_test_publisher")
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {topic: publisher.create_publisher(cls, topic, qos) for topic, cls in flight.classes.items()}
    ros.wait(lambda: all(p.get_subscription_count() >= 1 for p in pubs.values()))
    # up to a few seconds after the end of the first sweep (so that there is an estimate to compare)
    first_end = min(s.end_s for ch in flight.replayed.channels.values() for s in ch.sweep_results)
    count = next(i for i, (_, msg) in enumerate(flight.messages()) if (stamp_seconds(msg) or 0) > first_end + 5.0)
    sent, chunk = 0, 400
    for topic, msg in flight.messages(0, count):
        pubs[topic].publish(msg)
        sent += 1
        if sent % chunk == 0 or sent == count:
            ros.wait(lambda: sum(over_dds.router.messages.values()) >= sent, timeout_s=30.0)
    flight.feed(direct, 0, count)
    assert over_dds.router.messages == direct.router.messages
    over_dds.router.flush()
    direct.router.flush()
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
    second.router.flush()
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
    ros.wait(lambda: state.exists())
    loaded = load_state(state)
    assert set(loaded["channels"]) == {"roll", "pitch", "yaw"}
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


# ------------------------------------------------------------------------------------------------ model update
def _model_update(node: ValidatorNode, flight: Flight, fed: dict, tmp_path: Path, via: str):
    before = statuses(node.publish_diagnostics())
    for name, ch in fed["result"].channels.items():
        assert number(before[name][1]["epsilon"]) == pytest.approx(ch.epsilon, abs=1e-12)
        assert before[name][1]["epsilon_previous"] == "null"
    hidden = flight.hidden or {name: MISSING for name in flight.config.channels}
    updated = write_typed(tmp_path / "with_effects.yaml", hidden)
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


# ------------------------------------------------------------------------------------------------ levels, STALE
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
        assert relaxed[name][0].level == (DiagnosticStatus.OK if ch.epsilon < 0.9 else
                                          DiagnosticStatus.WARN if ch.epsilon < 0.95 else DiagnosticStatus.ERROR)
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


# ------------------------------------------------------------------------------------------------ bad messages
@pytest.mark.parametrize("path", ["raw", "message"])
def test_bad_messages_are_counted_and_survived(ros, typed, path):
    """NaN rate, JointState without the joint, position array too short: counted per reason, never fatal."""
    node = ros.validator(typed, diagnostic_period=1000.0, raw_decoding=(path == "raw"))
    assert bool(node._raw) == (path == "raw")

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
        assert int(values[name]["bad_samples"]) == sum(json.loads(values[name]["bad_samples_by_reason"]).values())
    # still alive and still counting good samples
    before = node.router.samples("pitch", "output")
    for topic, msg in _fresh_messages(1_700_000_020.0, 2):
        send(topic, msg)
    assert node.router.samples("pitch", "output") == before + 2


# ------------------------------------------------------------------------------------------------ services
def test_services_reload_reset_save_results(flight, typed, fed, ros, tmp_path):
    config = tmp_path / "live.yaml"
    shutil.copy(typed, config)
    results = tmp_path / "results"
    state = tmp_path / "state.npz"
    shutil.copy(fed["state"], state)
    node = ros.validator(config, spin=True, state_file=str(state), results_dir=str(results),
                         diagnostic_period=1000.0)
    client = ros.plain("gap_test_client")
    reload_ = client.create_client(Trigger, "/gap_validator/reload")
    reset = client.create_client(Trigger, "/gap_validator/reset")
    save = client.create_client(Trigger, "/gap_validator/save_results")

    answer = ros.call(save, Trigger.Request())
    assert answer.success, answer.message
    path = Path(answer.message)
    assert path.parent == results and path.suffix == ".json"
    saved = json.loads(path.read_text())
    for name, ch in fed["result"].channels.items():
        assert saved["channels"][name]["epsilon"] == pytest.approx(ch.epsilon, abs=1e-12)
        assert isinstance(saved["channels"][name]["diagnosis"], list)
    report = path.with_suffix("") / "index.html"
    try:
        import gap_validation.report.html  # noqa: F401
    except ImportError:
        pass
    else:
        assert report.exists()
        for name in fed["result"].channels:      # the paper's figures from the live spectra, doublets included
            for kind in ("bode", "disk", "failure", "nichols", "nyquist", "time"):
                assert (report.parent / f"{name}_{kind}.png").stat().st_size > 10_000

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

    # reset: spectra gone (and the checkpoint says so)
    answer = ros.call(reset, Trigger.Request())
    assert answer.success
    cleared = node.validator.results(diagnose=False)
    assert all(ch.sweeps == 0 and ch.epsilon is None for ch in cleared.channels.values())
    resumed = ros.validator(typed, name="gap_validator_resumed", state_file=str(state))
    assert all(ch.sweeps == 0 for ch in resumed.validator.results(diagnose=False).channels.values())
    # diagnostics still work after all that
    assert set(statuses(node.publish_diagnostics())) == {"roll", "pitch", "yaw"}


def test_full_diagnosis_runs_in_the_background_and_fills_the_message(typed, fed, ros, tmp_path):
    node = resume(ros, fed, tmp_path, typed, diagnosis_period=0.0)
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
    assert node._diagnosis.job is None


# ------------------------------------------------------------------------------------------------ discovery
def test_topic_types_are_discovered_from_the_graph(ros):
    node = ros.validator(CONFIG, spin=True, discovery_period=0.05, diagnostic_period=1000.0)  # no types
    assert set(node._pending) == {"/imu", "/control_surfaces"}
    publisher = ros.plain("gap_test_flight_stack")
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)
    imu = publisher.create_publisher(Imu, "/imu", qos)
    joints = publisher.create_publisher(JointState, "/control_surfaces", qos)
    ros.wait(lambda: not node._pending and imu.get_subscription_count() and joints.get_subscription_count())
    assert node._sub_types == {"/imu": "sensor_msgs/msg/Imu", "/control_surfaces": "sensor_msgs/msg/JointState"}
    for topic, msg in _fresh_messages(1.7e9, 3):
        (imu if topic == "/imu" else joints).publish(msg)
    ros.wait(lambda: node.router.messages["/imu"] == 3 and node.router.messages["/control_surfaces"] == 3)
    assert set(node._raw) == {"/imu", "/control_surfaces"}  # raw subscriptions after discovery too


# ------------------------------------------------------------------------------------------------ params file, main
def test_params_file_matches_the_declared_parameters(ros):
    params = ROOT / "config" / "validator.params.yaml"
    data = yaml.safe_load(params.read_text())
    declared = data["/**/gap_validator"]["ros__parameters"]
    for name, value in declared.items():
        assert name in PARAMETERS, name
        assert value == PARAMETERS[name][0] and type(value) is type(PARAMETERS[name][0]), name
    node = ValidatorNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(params),
                                                        "-p", f"config_file:={CONFIG}"])
    ros.nodes.append(node)
    for name in declared:
        assert node.get_parameter(name).value == PARAMETERS[name][0]
    launch = (ROOT / "launch" / "validator.launch.py").read_text()
    compile(launch, "validator.launch.py", "exec")
    assert "validator_node" in launch and "gap_validator" in launch


def _run_main(*args, env_extra=None):
    env = dict(os.environ, **(env_extra or {}))
    return subprocess.run([sys.executable, "-m", "gap_validation.ros.main", *args], env=env, cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("case", ["missing", "invalid", "unset", "qos"])
def test_bad_startup_config_exits_2_with_one_line(tmp_path, case):
    bad = tmp_path / "bad.yaml"
    bad.write_text("channels:\n  pitch: {input: 3}\n")
    args = {"missing": ["--ros-args", "-p", f"config_file:={tmp_path / 'nope.yaml'}"],
            "invalid": ["--ros-args", "-p", f"config_file:={bad}"],
            "unset": [],
            "qos": ["--ros-args", "-p", f"config_file:={CONFIG}", "-p", "qos_reliability:=sometimes"]}[case]
    proc = _run_main(*args)
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("validator_node: error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    expected = {"missing": "config file not found", "invalid": "bad.yaml", "unset": "config_file is not set",
                "qos": "qos_reliability"}[case]
    assert expected in lines[0]


@pytest.mark.parametrize("executor", ["events", "single_threaded"])
def test_console_script_runs_publishes_answers_and_checkpoints_on_sigint(ros, typed, tmp_path, executor):
    """``main`` end to end in a child process: /diagnostics, parameters, a service, clean SIGINT."""
    import signal

    from rcl_interfaces.srv import SetParameters

    state = tmp_path / "state.npz"
    env = dict(os.environ)
    child = subprocess.Popen([sys.executable, "-m", "gap_validation.ros.main", "--ros-args", "-p",
                              f"config_file:={typed}", "-p", "diagnostic_period:=0.1", "-p",
                              f"state_file:={state}", "-p", f"results_dir:={tmp_path}", "-p",
                              f"executor:={executor}"],
                             env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        got = []
        ros.helper.create_subscription(DiagnosticArray, "/diagnostics", got.append, 10)
        ros.wait(lambda: len(got) >= 2, timeout_s=30.0)
        assert set(statuses(got[-1])) == {"roll", "pitch", "yaw"}
        save = ros.helper.create_client(Trigger, "/gap_validator/save_results")
        answer = ros.call(save, Trigger.Request())
        assert answer.success and Path(answer.message).is_file()
        setter = ros.helper.create_client(SetParameters, "/gap_validator/set_parameters")
        request = SetParameters.Request(parameters=[Parameter("hardware_id", value="uav-3").to_parameter_msg()])
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
    assert load_state(state)["channels"]  # final checkpoint at shutdown
