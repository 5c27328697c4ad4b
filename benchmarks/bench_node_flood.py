#!/usr/bin/env python3
"""The ``gap_validator`` node under a flood: a 10 kHz IMU for 60 s of message time, in-process over DDS.

One process, one explicit rclpy ``Context``: the node (the Ultra Stick config, typed topics, raw
subscriptions, default parameters: KEEP_LAST 1000, queues drained every ``intake_period``) spins in an
executor thread while the main thread publishes (RELIABLE, from its own context: another DDS participant)
``sensor_msgs/Imu`` at ``--imu-rate-hz`` of message time (header stamps ``k / rate``) and
``sensor_msgs/JointState`` at ``--surface-rate-hz``, with a chirp on the surfaces and rates, as fast as it can
(or in real time with ``--realtime``). Printed:

* messages published, received by the node, and missing; the node's ``samples_dropped`` diagnostics value
  (inferred from header-stamp gaps) against the truth ``published - received``, counted between the first and
  the last message received (no gap reveals the head before the first one, lost while the queue filled before
  the first drain, nor the tail after the last): ratio 1 means every drop is reported;
* the largest interval between two ``/diagnostics`` publications of the node, from the flood's start to its
  end, over the diagnostics period (on time: <= 2; taken where the node publishes, so that a listener's own
  scheduling does not count);
* process RSS after the first third of the flood and at the end (bounded memory: growth ratio end/third
  near 1).

Usage::

    python benchmarks/bench_node_flood.py [--seconds 60] [--imu-rate-hz 10000] [--surface-rate-hz 100]
                                          [--realtime] [--executor events|single_threaded]
"""
from __future__ import annotations

import argparse
import math
import os
import random
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(0, 101)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402

from gap_validation.ros.node import ValidatorNode  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_node import typed_config  # noqa: E402  (the same typed config as the CPU benchmark)

T0_S = 1_700_000_000  # epoch of the first stamp [s]


def rss_mb() -> float:
    """Resident set size of this process [MB] (``VmRSS``)."""
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmRSS:")) / 1024


@dataclass
class FloodResult:
    """What a flood measured (times in seconds, memory in MB)."""

    published: int                  # IMU messages
    received: int
    tail: int                       # published after the last received one (no gap can show them)
    head: int                       # published before the first received one (idem)
    samples_dropped: int            # the node's diagnostics value (largest over channels: IMU + surfaces)
    truth_dropped: int              # missing between the first and last received messages, IMU + surfaces
    diagnostics_period_s: float
    diagnostics_gaps_s: list[float] = field(default_factory=list)
    rss_mb: list[tuple[float, float]] = field(default_factory=list)   # (fraction published, RSS)
    wall_s: float = 0.0
    per_topic: dict = field(default_factory=dict)                    # topic -> (missing, node's count)

    @property
    def missing(self) -> int:
        return self.published - self.received

    @property
    def worst_gap_ratio(self) -> float:
        return max(self.diagnostics_gaps_s, default=math.inf) / self.diagnostics_period_s

    def rss_at(self, fraction: float) -> float:
        return next(r for f, r in self.rss_mb if f >= fraction)


def _stamp(msg, k: int, rate_hz: float) -> None:
    """Stamp ``T0_S + k / rate_hz`` exactly (integer nanoseconds)."""
    ns = T0_S * 1_000_000_000 + round(k * 1e9 / rate_hz)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)


def flood(seconds: float = 60.0, imu_rate_hz: float = 10_000.0, surface_rate_hz: float = 100.0, *,
          realtime: bool = False, executor: str = "events", diagnostic_period_s: float = 1.0,
          workdir: Path | None = None, qos_depth: int | None = None) -> FloodResult:
    """Publish ``seconds`` of message time at the given rates into a fresh node; see the module docstring."""
    tmp = tempfile.TemporaryDirectory() if workdir is None else None
    workdir = Path(tmp.name) if tmp is not None else workdir
    context, pub_context = Context(), Context()
    rclpy.init(context=context)
    rclpy.init(context=pub_context)
    spinner, thread, stop = None, None, threading.Event()
    try:
        node = ValidatorNode(context=context, parameter_overrides=[
            Parameter("config_file", value=str(typed_config(workdir / "ultrastick25e.yaml"))),
            Parameter("diagnostic_period", value=diagnostic_period_s)]
            + ([Parameter("qos_depth", value=qos_depth)] if qos_depth else []))
        published_at, dropped = [], [0]
        publish = node.publish_diagnostics

        def recorded():   # where the node publishes: a listener's own scheduling does not count
            array = publish()
            if array is not None:
                for status in array.status:
                    values = {kv.key: kv.value for kv in status.values}
                    dropped[0] = max(dropped[0], int(values.get("samples_dropped", "0")))
                published_at.append(time.monotonic())
            return array

        node.publish_diagnostics = recorded
        if executor == "events":
            from rclpy.experimental import EventsExecutor
            spinner = EventsExecutor(context=context)
        else:
            spinner = SingleThreadedExecutor(context=context)
        spinner.add_node(node)

        def spin() -> None:
            while not stop.is_set() and context.ok():
                spinner.spin_once(timeout_sec=0.05)

        thread = threading.Thread(target=spin, daemon=True)
        thread.start()
        publisher = rclpy.create_node("flood_publisher", context=pub_context)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        imu_pub = publisher.create_publisher(Imu, "/imu", qos)
        surf_pub = publisher.create_publisher(JointState, "/control_surfaces", qos)
        deadline = time.monotonic() + 20.0
        while (imu_pub.get_subscription_count() < 1 or surf_pub.get_subscription_count() < 1
               or any(i.changing or i.reliability != "reliable" for i in node.topics.intakes.values())) \
                and time.monotonic() < deadline:
            time.sleep(0.05)   # matched, and the node has followed the publishers to RELIABLE
        n_imu = int(round(seconds * imu_rate_hz))
        every = max(1, int(round(imu_rate_hz / surface_rate_hz)))
        imu, joints = Imu(), JointState(name=["aileron", "elevator", "rudder"], position=[0.0, 0.0, 0.0])
        rss, started = [], time.monotonic()
        for k in range(n_imu):
            t = k / imu_rate_hz
            if realtime:
                ahead = started + t - time.monotonic()
                if ahead > 0.002:
                    time.sleep(ahead)
            u = 0.05 * math.sin(2 * math.pi * (0.2 + 0.05 * t) * t)   # a slow chirp (sweeps for the node)
            if k % every == 0:
                _stamp(joints, k, imu_rate_hz)
                joints.position = [u, u, u]
                surf_pub.publish(joints)
            _stamp(imu, k, imu_rate_hz)
            imu.angular_velocity.x = imu.angular_velocity.y = imu.angular_velocity.z = -3.0 * u
            imu_pub.publish(imu)
            if k % max(1, n_imu // 30) == 0:
                rss.append(((k + 1) / n_imu, rss_mb()))
        flood_end = time.monotonic()
        # let the queues drain: until the node has taken nothing new for two intake periods and a diagnostics
        # period has passed since the flood ended
        settled, last, stable_at = time.monotonic(), -1, None
        while time.monotonic() - settled < 30.0:
            now = node.router.messages.get("/imu", 0)
            if now != last:
                last, stable_at = now, time.monotonic()
            elif time.monotonic() - stable_at > max(0.2, 2 * node.get_parameter("intake_period").value) \
                    and time.monotonic() > flood_end + diagnostic_period_s:
                break
            time.sleep(0.02)
        rss.append((1.0, rss_mb()))
        stop.set()
        thread.join(timeout=10.0)
        node.publish_diagnostics()          # with the node stopped: the value read is its final count
        received = node.router.messages.get("/imu", 0)
        truth, tail, head, per_topic = 0, 0, 0, {}
        for topic, count, rate in (("/imu", n_imu, imu_rate_hz), ("/control_surfaces", -(-n_imu // every),
                                                                   imu_rate_hz / every)):
            gaps_seen = node.topics.gaps.get(topic)
            if gaps_seen is None or gaps_seen.first_s is None:
                per_topic[topic] = (0, node.samples_dropped(topic))
                continue
            first_index = int(round((gaps_seen.first_s - T0_S) * rate))
            last_index = int(round((gaps_seen.last_s - T0_S) * rate))
            missing = last_index - first_index + 1 - node.router.messages.get(topic, 0)
            truth += missing
            per_topic[topic] = (missing, node.samples_dropped(topic))
            if topic == "/imu":
                head, tail = first_index, count - 1 - last_index
        # on time from the flood's start to its end (a stall at either end counts)
        during = [a for a in published_at if started <= a <= flood_end]
        gaps = list(np.diff([started, *during, flood_end]))
        result = FloodResult(
            published=n_imu,
            received=received,
            tail=tail,
            head=head,
            samples_dropped=dropped[0],
            truth_dropped=truth,
            diagnostics_period_s=diagnostic_period_s,
            diagnostics_gaps_s=gaps,
            rss_mb=rss,
            wall_s=flood_end - started,
            per_topic=per_topic,
        )
        node.close()
        return result
    finally:
        stop.set()
        if thread is not None:
            thread.join(timeout=10.0)
        if spinner is not None:
            spinner.shutdown()
        rclpy.shutdown(context=context)
        rclpy.shutdown(context=pub_context)
        if tmp is not None:
            tmp.cleanup()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="message time of the flood [s]")
    parser.add_argument("--imu-rate-hz", type=float, default=10_000.0)
    parser.add_argument("--surface-rate-hz", type=float, default=100.0)
    parser.add_argument(
        "--realtime", action="store_true", help="publish in real time (default: as fast as possible)"
    )
    parser.add_argument("--executor", choices=("events", "single_threaded"), default="events")
    parser.add_argument(
        "--qos-depth", type=int, default=None, help="the node's qos_depth (default: its default)"
    )
    args = parser.parse_args()
    r = flood(
        args.seconds,
        args.imu_rate_hz,
        args.surface_rate_hz,
        realtime=args.realtime,
        executor=args.executor,
        qos_depth=args.qos_depth,
    )
    print(
        f"flood: {r.published} IMU messages ({args.seconds:g} s at {args.imu_rate_hz:g} Hz) in "
        f"{r.wall_s:.1f} s "
        f"wall ({r.published / r.wall_s:,.0f} msgs/s published), executor {args.executor}"
    )
    print(
        f"received by the node {r.received}, missing {r.missing} (head before the first received: {r.head}, "
        "tail "
        f"after the last: {r.tail})"
    )
    truth = r.truth_dropped
    ratio = r.samples_dropped / truth if truth else (1.0 if r.samples_dropped == 0 else math.inf)
    print(
        f"samples_dropped reported {r.samples_dropped} vs IMU + surface messages missing between the first "
        "and "
        f"last received {truth}: ratio {ratio:.3f} (1: every drop reported)"
    )
    for topic, (missing, counted) in r.per_topic.items():
        print(
            f"  {topic}: missing between its first and last received messages {missing}, the node's count "
            f"{counted}"
        )
    print(f"/diagnostics during the flood: {len(r.diagnostics_gaps_s) - 1} messages, worst interval "
          f"{max(r.diagnostics_gaps_s):.2f} s = {r.worst_gap_ratio:.2f} x the period (on time: <= 2)")
    third, end = r.rss_at(1 / 3), r.rss_mb[-1][1]
    print(f"RSS after a third {third:.1f} MB, at the end {end:.1f} MB: growth ratio {end / third:.3f} "
          f"(+{end - third:.1f} MB; bounded: about 1)")


if __name__ == "__main__":
    main()
