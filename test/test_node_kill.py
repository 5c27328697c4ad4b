"""``kill -9`` of the node: it restarts from its checkpoint with identical spectra and carries on.

The console script runs as a child process (``python -m gap_validation.ros.main``, checkpoint every 0.3 s);
the test publishes the bundled flight over DDS from its own rclpy Context: the first 60 s (in the middle of
the first sweep), waits until /diagnostics show every sample arrived and a checkpoint was written after that,
SIGKILLs the node, restarts it on the same ``state_file`` and checks that its state equals the checkpoint (bit
for bit) and its /diagnostics the numbers of that state; then the flight goes on to 120 s (the sweep
completes) and, once the node has closed the run (its inputs silent for ``end_of_data_timeout`` since it took
their last message), the state matches an uninterrupted in-process run of the same messages (checkpoints are
polled until then: under load the node takes messages late).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from _ros import domain_id

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.event_handler import PublisherEventCallbacks  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402

from gap_validation.bag.reader import open_bag  # noqa: E402
from gap_validation.core.checkpoint import load_state  # noqa: E402
from gap_validation.core.config import load_config  # noqa: E402
from gap_validation.core.validator import OnlineValidator  # noqa: E402
from gap_validation.messages.router import MessageRouter, stamp_seconds  # noqa: E402
from gap_validation.ros.message_types import message_class  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "bags" / "ultrastick25e_flight"
TYPES = {"/imu": "sensor_msgs/msg/Imu", "/control_surfaces": "sensor_msgs/msg/JointState"}


def assert_same_tree(a, b, where="state"):
    """Identical state trees: same keys and types, arrays bit for bit."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        assert isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype, where
        np.testing.assert_array_equal(a, b, err_msg=where, strict=True)
    elif isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for key in a:
            assert_same_tree(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same_tree(x, y, f"{where}[{i}]")
    else:
        assert a == b or (a != a and b != b), f"{where}: {a!r} != {b!r}"


@pytest.fixture
def env(tmp_path):
    saved = dict(os.environ)
    os.environ.update({"ROS_PYTHON_CHECK_FIELDS": "1", "ROS_DOMAIN_ID": domain_id(),
                       "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    data = yaml.safe_load((ROOT / "config" / "ultrastick25e.yaml").read_text())
    for channel in data["channels"].values():
        for stream in ("input", "output"):
            channel[stream]["type"] = TYPES[channel[stream]["topic"]]
    config = tmp_path / "ultrastick25e.yaml"
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    yield config
    os.environ.clear()
    os.environ.update(saved)


def _messages(until_s: float):
    classes = {topic: message_class(t) for topic, t in TYPES.items()}
    out, t0 = [], None
    with open_bag(BAG) as bag:
        for topic, _, _, raw in bag.records(list(TYPES)):
            msg = deserialize_message(bytes(raw), classes[topic])
            t = stamp_seconds(msg)
            t0 = t if t0 is None else t0
            if t - t0 > until_s:
                break
            out.append((topic, msg))
    return out


def _start(config: Path, state: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "gap_validation.ros.main",
            "--ros-args",
            "-p",
            f"config_file:={config}",
            "-p",
            f"state_file:={state}",
            "-p",
            "checkpoint_period:=0.3",
            "-p",
            "diagnostic_period:=0.2",
            "-p",
            "diagnosis_period:=0.0",
        ],
        env=dict(os.environ),
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


class Peer:
    """The test's side: publishers of the flight topics and the latest /diagnostics."""

    def __init__(self):
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.node = rclpy.create_node("kill_test_peer", context=self.context)
        self.executor.add_node(self.node)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        # subscriptions matched so far (the killed node's too)
        self.matches = {topic: 0 for topic in TYPES}
        self.pubs = {topic: self.node.create_publisher(message_class(t), topic, qos,
                                                       event_callbacks=self._matched_callbacks(topic))
                     for topic, t in TYPES.items()}
        self.last: dict[str, dict] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)

    def _matched_callbacks(self, topic: str) -> PublisherEventCallbacks:
        def on_matched(info) -> None:
            self.matches[topic] = max(self.matches[topic], info.total_count)

        return PublisherEventCallbacks(matched=on_matched)

    def wait_new_subscriber(self, before: dict[str, int]) -> None:
        """Until every publisher matched one more subscription than ``before``: a restarted node's (the killed
        node's stays counted until its DDS lease expires, so the subscription count alone cannot tell)."""
        self.wait(
            lambda: all(self.matches[t] > before[t] for t in TYPES), what="the restarted node's subscriptions"
        )

    def _on_diagnostics(self, array) -> None:
        for status in array.status:
            self.last[status.name.split(": ", 1)[1]] = {kv.key: kv.value for kv in status.values}

    def wait(self, predicate, timeout_s: float = 30.0, what: str = "") -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            assert time.monotonic() < deadline, (
                f"timed out waiting for {what} ({self.last.get('pitch', {}).get('samples_output')}, "
                f"{self.last.get('pitch', {}).get('samples_input')})"
            )
            self.executor.spin_once(timeout_sec=0.02)

    def publish(self, messages) -> None:
        self.wait(lambda: all(p.get_subscription_count() >= 1 for p in self.pubs.values()), what="the node")
        for start in range(0, len(messages), 500):  # paced below the queue depth of 1000: nothing dropped
            for topic, msg in messages[start:start + 500]:
                self.pubs[topic].publish(msg)
            sent = _counts(messages[:start + 500])
            self.wait(lambda: self.arrived(*sent), what="the messages sent")

    def arrived(self, imu: int, surfaces: int) -> bool:
        return self.last.get("pitch", {}).get("samples_output") == str(imu) and \
            self.last["pitch"].get("samples_input") == str(surfaces)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def _counts(messages) -> tuple[int, int]:
    imu = sum(1 for topic, _ in messages if topic == "/imu")
    return imu, len(messages) - imu


def _same_spectra(config: Path, state: dict, whole: OnlineValidator) -> bool:
    a = OnlineValidator.from_state(load_config(config), state, diagnose=False)
    for name in whole.config.channels:
        est_a, est_b = a.estimate(name), whole.estimate(name)
        if (est_a is None) != (est_b is None) or (
            est_a is not None
            and not all(
                np.allclose(getattr(est_a, k), getattr(est_b, k), rtol=1e-9, atol=0)
                for k in ("gxx", "gyy", "gxy")
            )
        ):
            return False
    return True


def _checkpoint_after(peer: Peer, state: Path, t: float) -> dict:
    peer.wait(lambda: state.exists() and state.stat().st_mtime > t + 0.05, what="a checkpoint")
    return load_state(state)


@pytest.mark.slow
def test_kill_9_restart_resumes_identical_spectra_and_continues(env, tmp_path):
    config, state = env, tmp_path / "state.npz"
    messages = _messages(120.0)
    split = next(
        i for i, (_, msg) in enumerate(messages) if stamp_seconds(msg) - stamp_seconds(messages[0][1]) > 60
    )
    first, second = messages[:split], messages[split:]
    whole = OnlineValidator(load_config(config), diagnose=False)     # one pass over the flight, in process
    router = MessageRouter(load_config(config), whole)
    for topic, msg in messages:
        router.on_message(topic, msg, 0.0)
    router.flush()
    whole.finish()
    peer, child = Peer(), _start(config, state)
    try:
        peer.publish(first)
        saved = _checkpoint_after(peer, state, time.time())
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
        assert child.returncode == -signal.SIGKILL
        assert_same_tree(load_state(state), saved)          # the kill left the checkpoint whole

        restarted, matched = time.time(), dict(peer.matches)
        child = _start(config, state)
        peer.wait_new_subscriber(matched)
        peer.last.clear()
        peer.wait(lambda: "pitch" in peer.last, what="diagnostics of the restarted node")
        resumed = _checkpoint_after(peer, state, restarted)
        assert_same_tree(resumed, saved)  # identical spectra after the restart
        expected = OnlineValidator.from_state(load_config(config), saved, diagnose=False).results(
            diagnose=False
        )
        for name, ch in expected.channels.items():
            assert peer.last[name]["sweeps"] == str(ch.sweeps)
            assert peer.last[name]["epsilon"] == ("null" if ch.epsilon is None else repr(ch.epsilon))

        peer.publish(second)
        # the flight's last manoeuvre closes once the inputs have been silent for end_of_data_timeout (10 s
        # since the node took the last message, later than this side saw it under load): the end of the run,
        # as replay closes it at the end of the bag. Checkpoints until then hold the manoeuvre still open.
        deadline = time.monotonic() + 45.0
        while True:
            final = _checkpoint_after(peer, state, time.time())
            if _same_spectra(config, final, whole) or time.monotonic() > deadline:
                break
    finally:
        if child.poll() is None:
            child.kill()
        child.wait()
        err = child.stderr.read()
        child.stderr.close()
        peer.close()
    assert "Traceback" not in err
    a = OnlineValidator.from_state(load_config(config), final, diagnose=False)
    got, want = a.results(diagnose=False).channels, whole.results(diagnose=False).channels
    assert sum(ch.sweeps for ch in got.values()) >= 1
    for name in whole.config.channels:      # the same samples and manoeuvres as one pass over the flight
        assert (got[name].sweeps, got[name].bad_samples) == (want[name].sweeps, want[name].bad_samples), name
        assert [(m.kind, m.start_s, m.end_s) for m in got[name].manoeuvres] == \
            [(m.kind, m.start_s, m.end_s) for m in want[name].manoeuvres], name
        est_a, est_b = a.estimate(name), whole.estimate(name)
        assert (est_a is None) == (est_b is None)
        if est_a is not None:
            for key in ("gxx", "gyy", "gxy"):   # batches cut elsewhere (checkpoints): equal to rounding
                np.testing.assert_allclose(getattr(est_a, key), getattr(est_b, key), rtol=1e-9, atol=0)
