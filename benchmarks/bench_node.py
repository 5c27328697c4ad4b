#!/usr/bin/env python3
"""CPU the ``gap_validator`` node spends per second of flight: its own work (goal: at most 5 % of one core)
and, with ``--live``, its whole process over DDS (goal: at most 8 % of one core).

A simulated sweep flight (the Ultra Stick config, servo lag and delay hidden in the truth) with the IMU at
1 kHz and the surfaces (JointState, three joints) at 100 Hz feeds the three channels. Its messages are built
and serialized ahead of each simulated second (not timed); then, in flight-time order, what the node's intake
timer does with each ``intake_period`` (50 ms) of messages (``ValidatorNode.take_messages``: the decoding step
with fast field decoding, stamp-gap accounting, the router) runs on every slice, and the node's timers run
when due: ``publish_diagnostics`` every ``diagnostic_period`` (1 s), the checkpoint every
``checkpoint_period`` (5 s, to a temporary state file: the snapshot in the executor, the write in the
background thread, both counted), and the full diagnosis whenever the node starts one (it runs in the node's
worker thread; the benchmark waits for it inside the timed region, so its CPU counts in full).
``time.process_time`` (all threads of the process) around these calls, divided by the flight duration, is the
figure; the ratio to the 5 % goal is printed (below 1 meets it). Not counted: DDS transport and rclpy's
executor (see ``--live``). An extra line gives the cost of ``raw_decoding:=false`` (rclpy deserialisation,
then the router) on the same messages, deserialisation included.

``--live S`` additionally runs the real console script (``python -m gap_validation.ros.main``, default
parameters) for S seconds of wall time while a child process publishes Imu at 1 kHz and JointState at 100 Hz
(a chirp) over DDS, and reports the CPU of the node's whole process (``/proc/<pid>/stat``, its child processes
included): DDS's threads, rclpy's executor and the node -- once per executor, with the ratio to the 8 % goal.
``--live-only`` skips the in-process part.

Usage::

    python benchmarks/bench_node.py [--minutes M] [--imu-rate-hz 1000] [--surface-rate-hz 100] [--live S]
                                    [--live-only] [--qos reliable|best_effort]
"""
from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(0, 101)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
import yaml  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402

from gap_validation.cli.arguments import hidden_effects  # noqa: E402
from gap_validation.core.config import load_config  # noqa: E402
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402
from gap_validation.ros.message_types import message_class  # noqa: E402
from gap_validation.ros.node import ValidatorNode  # noqa: E402

GOAL_FRACTION = 0.05
#: Goal of the whole process over DDS (issue 16): at most 8 % of one core at 1 kHz IMU + 100 Hz surfaces.
LIVE_GOAL_FRACTION = 0.08
CONFIG = ROOT / "config" / "ultrastick25e.yaml"


def typed_config(path: Path) -> Path:
    """The Ultra Stick config with message types (the node subscribes at once, no graph discovery)."""
    data = yaml.safe_load(CONFIG.read_text())
    for channel in data["channels"].values():
        channel["input"]["type"] = "sensor_msgs/msg/JointState"
        channel["output"]["type"] = "sensor_msgs/msg/Imu"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def simulate(minutes: float, imu_rate_hz: float, surface_rate_hz: float):
    config = load_config(CONFIG)
    sweep_s = max(20.0, (minutes * 60.0 - 3 * 8.0) / 3.0)  # one sweep per axis fills the flight
    options = FlightOptions(sweeps_per_channel=1, sweep_duration_s=sweep_s, quiet_s=3.0,
                            imu_rate_hz=imu_rate_hz, surface_rate_hz=surface_rate_hz)
    hidden = [f"{ch}:{e}" for ch in config.channels
              for e in ("first_order_lag:bandwidth_rad_s=37.7", "time_delay:seconds=0.05")]
    return simulate_flight(config, hidden_effects(hidden, config), options, seed=3)


def _stamp(msg, t: float) -> None:
    sec = int(t)
    msg.header.stamp.sec = sec
    msg.header.stamp.nanosec = min(int(round((t - sec) * 1e9)), 999_999_999)


class Messages:
    """Merged, time-ordered rclpy messages of the flight, built one slice of flight time at a time."""

    def __init__(self, flight):
        imu = flight.topics["/imu"]
        surfaces = flight.topics["/control_surfaces"]
        self.imu, self.surfaces = imu, surfaces
        self.joints = list(surfaces.joint_names)
        self.keys = {"angular_velocity.x": "x", "angular_velocity.y": "y", "angular_velocity.z": "z"}
        times = np.concatenate([imu.receive_s, surfaces.receive_s])
        kind = np.concatenate([np.zeros(len(imu), int), np.ones(len(surfaces), int)])
        index = np.concatenate([np.arange(len(imu)), np.arange(len(surfaces))])
        order = np.argsort(times, kind="stable")
        self.times, self.kind, self.index = times[order], kind[order], index[order]

    def __len__(self) -> int:
        return int(self.times.size)

    def build(self, k: int):
        i = int(self.index[k])
        if self.kind[k] == 0:
            msg = Imu()
            _stamp(msg, float(self.imu.stamp_s[i]))
            for field, values in self.imu.values.items():
                setattr(msg.angular_velocity, self.keys[field], float(values[i]))
            return "/imu", msg
        position = np.zeros(len(self.joints))
        for field, values in self.surfaces.values.items():
            position[self.joints.index(field[field.index("[") + 1:-1])] = values[i]
        msg = JointState(name=self.joints, position=position.tolist())
        _stamp(msg, float(self.surfaces.stamp_s[i]))
        return "/control_surfaces", msg


def run(minutes: float, imu_rate_hz: float, surface_rate_hz: float) -> dict:
    flight = simulate(minutes, imu_rate_hz, surface_rate_hz)
    messages = Messages(flight)
    context = Context()
    rclpy.init(context=context)
    tmp = Path(tempfile.mkdtemp(prefix="bench_node_"))
    config = str(typed_config(tmp / "cfg.yaml"))
    node = ValidatorNode(context=context, parameter_overrides=[
        Parameter("config_file", value=config), Parameter("state_file", value=str(tmp / "state.npz"))])
    other = ValidatorNode(context=context, cli_args=["--ros-args", "-r", "__node:=gap_validator_messages"],
                          parameter_overrides=[Parameter("config_file", value=config),
                                               Parameter("raw_decoding", value=False)])
    assert node.topics.raw and not other.topics.raw
    classes = {topic: message_class(node.topics.intakes[topic].type_name) for topic in node.topics.raw}
    slice_period = node.get_parameter("intake_period").value
    message_path_s = 0.0
    diag_period = node.get_parameter("diagnostic_period").value
    ckpt_period = node.get_parameter("checkpoint_period").value
    cpu = {"messages": 0.0, "diagnostics": 0.0, "checkpoints": 0.0, "diagnosis": 0.0}
    counts = {"messages": 0, "diagnostics": 0, "checkpoints": 0, "diagnosis": 0}
    t0 = float(messages.times[0])
    next_diag, next_ckpt = t0 + diag_period, t0 + ckpt_period
    slice_s, k, n = 1.0, 0, len(messages)
    try:
        while k < n:
            end = float(messages.times[k]) + slice_s
            batch = []
            while k < n and messages.times[k] < end:
                topic, msg = messages.build(k)
                batch.append((topic, serialize_message(msg)))
                k += 1
            drains = _drains(batch, messages.times[k - len(batch):k], slice_period)
            start = time.process_time()
            for drained in drains:          # what the intake timer hands over per wake-up
                for topic, items in drained.items():
                    node.take_messages(topic, items)
            cpu["messages"] += time.process_time() - start
            counts["messages"] += len(batch)
            start = time.process_time()
            for drained in drains:
                for topic, items in drained.items():
                    other.take_messages(topic, [(deserialize_message(data, classes[topic]), info)
                                                for data, info in items])
            message_path_s += time.process_time() - start
            now = end
            while next_diag <= now:
                start = time.process_time()
                node.publish_diagnostics()
                cpu["diagnostics"] += time.process_time() - start
                counts["diagnostics"] += 1
                if node.diagnosis_worker.job is not None:
                    start = time.process_time()
                    node.wait_for_diagnosis(timeout_s=600.0)
                    cpu["diagnosis"] += time.process_time() - start
                    counts["diagnosis"] += 1
                next_diag += diag_period
            while next_ckpt <= now:
                start = time.process_time()
                # the checkpoint timer: snapshot here, write in the thread
                node.jobs.checkpoint_in_background()
                node.jobs.background.wait(60.0)
                node.jobs.harvest()
                cpu["checkpoints"] += time.process_time() - start
                counts["checkpoints"] += 1
                next_ckpt += ckpt_period
        result = node.validator.results(diagnose=False)
    finally:
        for each in (node, other):
            each.close()
            each.destroy_node()
        rclpy.shutdown(context=context)
    duration_s = float(messages.times[-1] - messages.times[0])
    return {"duration_s": duration_s, "messages": n, "cpu": cpu, "counts": counts, "result": result,
            "message_path_us": message_path_s / n * 1e6, "rate_msgs_s": n / duration_s}


def _drains(batch: list, times, period_s: float) -> list[dict]:
    """The batch cut into intake periods: per period, topic -> [(serialized, info)] in arrival order."""
    groups: dict[int, dict] = {}
    t0 = float(times[0]) if len(times) else 0.0
    for (topic, data), t in zip(batch, times):
        groups.setdefault(int((float(t) - t0) // period_s), {}).setdefault(topic, []).append((data, {}))
    return [groups[i] for i in sorted(groups)]


_PUBLISHER = r"""
import math, sys, time
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, JointState
duration_s, imu_hz, surface_hz = (float(a) for a in sys.argv[1:4])
reliability = ReliabilityPolicy.RELIABLE if sys.argv[4] == "reliable" else ReliabilityPolicy.BEST_EFFORT
rclpy.init()
node = rclpy.create_node("bench_flight_stack")
qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=reliability)
imu_pub = node.create_publisher(Imu, "/imu", qos)
joint_pub = node.create_publisher(JointState, "/control_surfaces", qos)
while imu_pub.get_subscription_count() == 0 or joint_pub.get_subscription_count() == 0:
    time.sleep(0.05)
every = max(1, round(imu_hz / surface_hz))
t0, k = time.time(), 0
while time.time() - t0 < duration_s:
    while k / imu_hz <= time.time() - t0:
        tr = k / imu_hz
        t = t0 + tr
        u = 0.05 * math.sin(2 * math.pi * (0.2 * tr + 0.025 * tr * tr))
        imu = Imu()
        imu.header.stamp.sec, imu.header.stamp.nanosec = int(t), int((t - int(t)) * 1e9)
        imu.angular_velocity.x, imu.angular_velocity.y, imu.angular_velocity.z = 3 * u, -2 * u, u
        imu_pub.publish(imu)
        if k % every == 0:
            joints = JointState(name=["aileron", "elevator", "rudder"], position=[u, u, u])
            joints.header = imu.header
            joint_pub.publish(joints)
        k += 1
    time.sleep(0.002)
node.destroy_node()
rclpy.shutdown()
"""


def _cpu_s(pid: int) -> float:
    """CPU time [s] of process ``pid`` and its live child processes (user + system, all threads)."""
    def own(p: int) -> float:
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            return 0.0
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    children = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            children += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return own(pid) + sum(_cpu_s(c) for c in children)


def live(seconds: float, imu_rate_hz: float, surface_rate_hz: float, executor: str,
         qos: str = "reliable") -> float:
    """CPU fraction of one core of the console-script process (and its children) while a flight stack
    publishes."""
    import signal
    import subprocess

    tmp = Path(tempfile.mkdtemp(prefix="bench_node_live_"))
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(0, 101)))
    node = subprocess.Popen([sys.executable, "-m", "gap_validation.ros.main", "--ros-args", "-p",
                             f"config_file:={typed_config(tmp / 'cfg.yaml')}", "-p",
                             f"state_file:={tmp / 'state.npz'}", "-p", f"executor:={executor}",
                             "-p", f"results_dir:={tmp}"],
                            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(3.0)  # imports and start-up are not part of the steady state
        publisher = subprocess.Popen([sys.executable, "-c", _PUBLISHER, str(seconds + 4.0), str(imu_rate_hz),
                                      str(surface_rate_hz), qos], env=env)
        time.sleep(3.0)  # discovery and matching
        cpu0, wall0 = _cpu_s(node.pid), time.monotonic()
        time.sleep(seconds)
        cpu1, wall1 = _cpu_s(node.pid), time.monotonic()
        publisher.wait(timeout=60)
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=30)
        except subprocess.TimeoutExpired:
            node.kill()
    return (cpu1 - cpu0) / (wall1 - wall0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=4.0, help="flight length (default 4)")
    parser.add_argument("--imu-rate-hz", type=float, default=1000.0)
    parser.add_argument("--surface-rate-hz", type=float, default=100.0)
    parser.add_argument("--live", type=float, default=0.0, metavar="S",
                        help="also measure the console script's process over DDS for S seconds")
    parser.add_argument("--live-only", action="store_true", help="skip the in-process measurement")
    parser.add_argument("--qos", choices=("reliable", "best_effort"), default="reliable",
                        help="reliability the live flight stack publishes with (the node follows it)")
    parser.add_argument("--executors", default="events,single_threaded",
                        help="executors of the live runs, comma-separated")
    args = parser.parse_args(argv)
    if not args.live_only:
        _in_process(args)
    for executor in args.executors.split(",") if args.live > 0 else ():
        fraction = live(args.live, args.imu_rate_hz, args.surface_rate_hz, executor, args.qos)
        print(f"live console script over DDS ({executor} executor, {args.qos} publisher): whole process "
              f"{fraction * 100:.1f} % of one core (DDS threads, rclpy executor and the node; goal <= "
              f"{LIVE_GOAL_FRACTION * 100:.0f} %: ratio {fraction / LIVE_GOAL_FRACTION:.2f})", flush=True)
    return 0


def _in_process(args) -> None:
    out = run(args.minutes, args.imu_rate_hz, args.surface_rate_hz)
    total = sum(out["cpu"].values())
    fraction = total / out["duration_s"]
    print(f"flight: {out['duration_s']:.0f} s, {out['messages']} messages ({out['rate_msgs_s']:.0f}/s: IMU "
          f"{args.imu_rate_hz:g} Hz, surfaces {args.surface_rate_hz:g} Hz, 3 channels)")
    for key, seconds in out["cpu"].items():
        n = out["counts"][key]
        each = f"{seconds / n * 1e6:.1f} us each" if key == "messages" and n else \
            (f"{seconds / n * 1e3:.1f} ms each" if n else "")
        print(f"  {key:<12} {seconds:8.3f} s CPU  ({n} calls, {each})")
    print(f"node CPU per second of flight: {fraction * 100:.2f} % of one core "
          f"(goal <= {GOAL_FRACTION * 100:.0f} %: ratio {fraction / GOAL_FRACTION:.2f})")
    print(
        f"  raw_decoding:=false instead: {out['message_path_us']:.1f} us per message (rclpy deserialisation "
        f"included) = {out['message_path_us'] * out['rate_msgs_s'] / 1e4:.2f} % of one core for the messages"
    )
    eps = ", ".join(f"{name} {ch.epsilon:.2f} ({ch.sweeps} sweeps)" if ch.epsilon is not None else f"{name} -"
                    for name, ch in out["result"].channels.items())
    print(f"  sanity: epsilon {eps}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
