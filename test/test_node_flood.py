"""The node under a flood (a light version of ``benchmarks/bench_node_flood.py``) and its drop counter
(the counter itself, :class:`~gap_validation.ros.stamp_gaps.StampGaps`, in ``test_stamp_gaps.py``).

In-process, explicit rclpy Context: 10 kHz IMU for 6 s of message time, published as fast as the test can (so
the node's KEEP_LAST queue overflows), diagnostics every 0.5 s. Checked: memory bounded, /diagnostics on time,
and ``samples_dropped`` equal to the messages really missing (known from the published stamps).
"""
from __future__ import annotations

import importlib.util
import os
import random
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def bench():
    pytest.importorskip("rclpy")
    keys = ("ROS_PYTHON_CHECK_FIELDS", "ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")
    saved = {k: os.environ.get(k) for k in keys}
    os.environ.update({"ROS_PYTHON_CHECK_FIELDS": "1", "ROS_DOMAIN_ID": str(random.randint(0, 101)),
                       "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    spec = importlib.util.spec_from_file_location("bench_node_flood", ROOT / "benchmarks" / "bench_node_flood.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    yield module
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


def _check_flood(r) -> None:
    for topic, (missing, counted) in r.per_topic.items():
        assert counted == missing, topic          # every lost message is reported, none invented
    assert r.samples_dropped == r.truth_dropped   # ... and published in /diagnostics
    # on time: a message callback publishes when the timer is 1.5 periods late (the EventsExecutor queues the
    # timer behind the flood); 2 periods leaves room for the other jobs sharing the 2 cores
    expected = int(r.wall_s / r.diagnostics_period_s) - 1      # the flood lasts wall_s (2-7 s here)
    assert len(r.diagnostics_gaps_s) >= max(2, expected - 1) and r.worst_gap_ratio <= 2.0
    assert r.rss_mb[-1][1] - r.rss_at(1 / 3) < 25.0   # MB: no growth with the messages


@pytest.mark.slow
def test_realtime_10khz_flood_is_taken_with_bounded_memory_and_diagnostics_on_time(bench, tmp_path):
    """The issue's flood, 6 s of it in real time (the benchmark runs 60 s): the node keeps up."""
    r = bench.flood(6.0, 10_000.0, 100.0, realtime=True, diagnostic_period_s=0.5, workdir=tmp_path)
    assert r.received > 0.5 * r.published
    _check_flood(r)


@pytest.mark.slow
def test_flood_faster_than_the_node_counts_every_drop(bench, tmp_path):
    """Published as fast as possible (several times real time): the node drops most, and reports each drop.

    How many it takes depends on the machine (7-56 % seen on this one), so only that it takes some is pinned."""
    r = bench.flood(6.0, 10_000.0, 100.0, diagnostic_period_s=0.5, workdir=tmp_path)
    assert r.received > 0 and r.truth_dropped > 0
    _check_flood(r)


def test_message_callbacks_publish_diagnostics_when_the_timer_is_late(bench, tmp_path):
    """No executor runs the timer here (as when a flood queues it behind messages): the callbacks publish."""
    import time

    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Imu

    from gap_validation.ros.node import ValidatorNode

    context = Context()
    rclpy.init(context=context)
    try:
        node = ValidatorNode(context=context, parameter_overrides=[
            Parameter("config_file", value=str(bench.typed_config(tmp_path / "cfg.yaml"))),
            Parameter("diagnostic_period", value=0.1)])
        published = []
        real = node.publish_diagnostics
        node.publish_diagnostics = lambda: published.append(time.monotonic()) or real()
        msg, start, k = Imu(), time.monotonic(), 0
        while time.monotonic() - start < 1.0:
            bench._stamp(msg, k, 1000.0)
            node.on_message("/imu", msg)
            k += 1
        assert 4 <= len(published) <= 8   # every 1.5 periods (0.15 s) of the 1 s
        assert max(np.diff(published)) < 0.25
        node.close()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
