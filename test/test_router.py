"""The message router (gap_validation.messages.router): from messages to batches of samples."""
import dataclasses
import math

import numpy as np
import pytest
from _messages import FakeValidator, T, imu, joints, make_config
from hypothesis import given, settings
from hypothesis import strategies as st

from gap_validation.core.config import SignalSpec, ValidationConfig
from gap_validation.core.fields import FieldError, FieldPath
from gap_validation.messages.router import MessageRouter, stamp_seconds


def test_router_batches_scales_and_uses_header_stamp():
    val = FakeValidator()
    router = MessageRouter(make_config(output_scale=math.pi / 180), val, batch=3)
    for k in range(7):
        router.on_message("/imu", imu(y=10.0 * k, sec=100, nanosec=k * 10_000_000), receive_time_s=999.0 + k)
        router.on_message(
            "/control_surfaces",
            joints(["elevator"], [0.01 * k], sec=100, nanosec=k * 10_000_000),
            receive_time_s=999.0 + k,
        )
        router.on_message("/other", imu(), receive_time_s=0.0)  # not configured: ignored
    assert len([b for b in val.batches if b[1] == "output"]) == 2  # two full batches of 3 pushed
    router.flush()
    t, y = val.samples("pitch", "output")
    np.testing.assert_allclose(t, 100.0 + 0.01 * np.arange(7), rtol=0, atol=1e-9)
    np.testing.assert_allclose(y, np.radians(10.0 * np.arange(7)))
    t, u = val.samples("pitch", "input")
    np.testing.assert_allclose(u, 0.01 * np.arange(7))
    assert router.samples("pitch", "output") == 7 and not val.bad


def test_router_pushes_all_streams_at_least_every_max_batch_s():
    """Input and output reach the validator interleaved in time (the estimator bounds their lag)."""
    val = FakeValidator()
    router = MessageRouter(make_config(), val, batch=10_000, max_batch_s=1.0)
    for k in range(40):
        t = 0.3 * k
        router.on_message("/imu", imu(sec=10 + int(t), nanosec=int(round((t % 1) * 1e9))), 0.0)
        router.on_message("/control_surfaces", joints(["elevator"], [0.0], sec=10 + int(t),
                                                      nanosec=int(round((t % 1) * 1e9))), 0.0)
    spans = [b[2][-1] - b[2][0] for b in val.batches]
    assert len(val.batches) >= 2 * 8 and max(spans) <= 1.0 + 0.3 + 1e-9  # + one sample period
    streams = [b[1] for b in val.batches]
    assert streams.count("input") == streams.count("output")


def test_router_receive_time_without_header_and_trigger_bool():
    val = FakeValidator()
    router = MessageRouter(make_config(input_field="data", trigger=True), val)
    router.routes["/control_surfaces"]  # Float64 surface topic
    for k in range(4):
        router.on_message(
            "/control_surfaces", T["std_msgs/msg/Float64"](data=0.5 * k), receive_time_s=5.0 + k
        )
        router.on_message("/sweep", T["std_msgs/msg/Bool"](data=k % 2 == 1), receive_time_s=5.0 + k)
    router.flush()
    t, u = val.samples("pitch", "input")
    np.testing.assert_allclose(t, [5.0, 6.0, 7.0, 8.0])
    np.testing.assert_allclose(u, [0.0, 0.5, 1.0, 1.5])
    t, trig = val.samples("pitch", "trigger")
    assert trig.dtype == bool and trig.tolist() == [False, True, False, True]


def test_router_counts_bad_samples_and_keeps_good_ones():
    val = FakeValidator()
    router = MessageRouter(make_config(), val)
    router.on_message("/control_surfaces", joints(["elevator"], [0.1], sec=1), 0.0)
    router.on_message("/control_surfaces", joints(["aileron"], [0.2], sec=2), 0.0)       # missing joint
    router.on_message("/control_surfaces", joints(["elevator"], [float("nan")], sec=3), 0.0)
    router.on_message("/control_surfaces", joints(["elevator"], [0.4], sec=3), 0.0)       # same time again
    router.on_message("/control_surfaces", joints(["elevator"], [0.5], sec=2), 0.0)       # back in time
    router.on_message("/control_surfaces", joints(["elevator"], [0.6], sec=4), 0.0)
    router.flush()
    t, u = val.samples("pitch", "input")
    assert t.tolist() == [1.0, 3.0, 4.0] and u.tolist() == [0.1, 0.4, 0.6]
    reasons = [r for _, _, r in val.bad]
    assert reasons == ["missing joint", "not finite", "time not increasing"]
    assert router.bad[("pitch", "input")]["missing joint"] == 1
    assert "elevator" in router.first_error[("pitch", "input")]


def test_router_structural_error_names_topic():
    router = MessageRouter(make_config(output_field="angular_velocity.w"), FakeValidator())
    with pytest.raises(FieldError) as err:
        router.on_message("/imu", imu(), 0.0)
    assert "/imu" in str(err.value) and "angular_velocity.w" in str(err.value) and err.value.structural


def test_on_values_matches_on_message_with_time_offset():
    val_a, val_b = FakeValidator(), FakeValidator()
    a, b = MessageRouter(make_config(), val_a), MessageRouter(make_config(), val_b)
    a.time_offset_s = b.time_offset_s = 50.0
    for k in range(5):
        msg = joints(["elevator"], [0.1 * k], sec=k + 1)
        a.on_message("/control_surfaces", msg, 0.0)
        b.on_values(
            "/control_surfaces", stamp_seconds(msg), [FieldPath.parse("position[elevator]").extract(msg)]
        )
    a.flush()
    b.flush()
    for stream in ("input",):
        ta, va = val_a.samples("pitch", stream)
        tb, vb = val_b.samples("pitch", stream)
        np.testing.assert_array_equal(ta, tb)
        np.testing.assert_array_equal(va, vb)
        assert ta[0] == 51.0
    assert a.latest_time_s() == 55.0


def test_router_pushes_trigger_topics_first():
    """A sweep edge must reach the estimator before the samples of the same instant."""
    val = FakeValidator()
    router = MessageRouter(make_config(trigger=True), val, batch=10_000, max_batch_s=1.0)
    for k in range(12):
        t = 0.25 * k
        stamp = dict(sec=10 + int(t), nanosec=int(round((t % 1) * 1e9)))
        router.on_message("/imu", imu(**stamp), 0.0)
        router.on_message("/control_surfaces", joints(["elevator"], [0.0], **stamp), 0.0)
        router.on_message("/sweep", T["std_msgs/msg/Bool"](data=True), receive_time_s=10.0 + t)
    router.flush()
    streams = [b[1] for b in val.batches]
    pushes = [streams[i:i + 3] for i in range(0, len(streams), 3)]
    assert len(pushes) >= 3 and all(p[0] == "trigger" for p in pushes)


def test_router_passes_a_jump_back_in_time_on_as_a_new_segment():
    """A looped bag: stamps start over. The router passes them on (the estimator opens a new time base) and
    counts the jump; steps back within the jump threshold are still dropped."""
    val = FakeValidator()
    router = MessageRouter(make_config(), val)
    for sec in (10, 11, 12, 13, 1, 2, 3):                 # back by 12 s: a new lap
        router.on_message("/control_surfaces", joints(["elevator"], [0.1 * sec], sec=sec), 0.0)
    router.on_message("/control_surfaces", joints(["elevator"], [0.0], sec=3), 0.0)  # duplicate stamp
    router.flush()
    t, _ = val.samples("pitch", "input")
    assert t.tolist() == [10.0, 11.0, 12.0, 13.0, 1.0, 2.0, 3.0]
    assert [r for _, _, r in val.bad] == ["time jumped back (new segment)", "time not increasing"]


def test_router_jump_threshold_follows_the_channel_max_gap():
    config = make_config()
    ch = config.channels["pitch"]
    config = ValidationConfig(channels={"pitch": dataclasses.replace(ch, estimator={"max_gap_s": 5.0})})
    val = FakeValidator()
    router = MessageRouter(config, val)
    for sec in (10, 11, 12, 8, 9, 13):                    # 4 s back < max_gap_s: reordered, dropped
        router.on_message("/control_surfaces", joints(["elevator"], [0.0], sec=sec), 0.0)
    router.flush()
    assert val.samples("pitch", "input")[0].tolist() == [10.0, 11.0, 12.0, 13.0]


@pytest.mark.parametrize("clip, pinned", [(None, False), (0.7, True)])
def test_router_detects_a_surface_pinned_at_its_extremes(clip, pinned):
    val = FakeValidator()
    router = MessageRouter(make_config(), val)
    t = np.arange(0.0, 60.0, 0.02)
    f_hz = 0.2 * (10.0 ** (t / 60.0))                      # 0.2-2 Hz log sweep
    u = 0.1 * np.sin(2 * np.pi * np.cumsum(f_hz) * 0.02) + np.random.default_rng(0).normal(0, 1e-4, t.size)
    if clip:
        u = np.clip(u, -clip * 0.1, clip * 0.1)
    for tk, uk in zip(t, u):
        router.on_message("/control_surfaces", joints(["elevator"], [uk], sec=100 + int(tk),
                                                       nanosec=int(round((tk % 1) * 1e9))), 0.0)
    router.flush()
    found = router.saturation("pitch")
    assert bool(found) == pinned
    if pinned:
        assert {side for side, _, _ in found} == {"maximum", "minimum"}
        assert all(abs(abs(value) - 0.07) < 1e-3 and n > 100 for _, value, n in found)


def test_structural_error_skips_only_that_signal():
    """A field the message type lacks breaks that signal alone: raised once, the topic's others go on."""
    config = make_config()
    ch = config.channels["pitch"]
    roll = dataclasses.replace(ch, name="roll", output=SignalSpec("/imu", "angular_velocity.w"))
    val = FakeValidator()
    router = MessageRouter(ValidationConfig(channels={"pitch": ch, "roll": roll}), val)
    with pytest.raises(FieldError, match="angular_velocity has: x, y, z"):
        router.on_message("/imu", imu(y=1.0, sec=1), 0.0)
    for sec in (2, 3):
        router.on_message("/imu", imu(y=float(sec), sec=sec), 0.0)       # no more errors
    router.flush()
    assert val.samples("pitch", "output")[1].tolist() == [1.0, 2.0, 3.0]
    assert val.samples("roll", "output")[0].size == 0 and not val.bad
    assert "angular_velocity.w" in router.broken[("roll", "output")]


# ------------------------------------------------------------------------------------------ runs of messages
#: Steps between message times: exact binary fractions (spans reached exactly), reordering, a jump back, NaN.
_STEP = st.sampled_from([0.125, 0.125, 0.25, 0.0, 0.375, -0.125, -40.0, float("nan")]) | st.floats(0.0, 0.3)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["/imu", "/control_surfaces", "/sweep"]), _STEP,
                          st.floats(-1.0, 1.0) | st.just(float("nan"))), min_size=1, max_size=120),
       st.lists(st.integers(0, 120), max_size=6), st.lists(st.integers(0, 120), max_size=4),
       st.integers(1, 40), st.sampled_from([0.25, 0.5, 1.0, 1.5]), st.sampled_from([0.0, 60.0, -12.5]))
def test_runs_of_values_reach_the_validator_as_message_by_message(
    messages, cuts, singles, batch, span, offset
):
    """``on_values_batch`` pushes the same batches at the same messages as ``on_values`` one by one (full
    batches, time spans, time jumping back, NaN times and values, runs mixed with single messages)."""
    times, t = [], 50.0
    for _, step, _ in messages:
        t = t + step if math.isfinite(step) else t
        times.append(t if math.isfinite(step) else float("nan"))
    one, many = FakeValidator(), FakeValidator()
    routers = [
        MessageRouter(make_config(trigger=True), v, batch=batch, max_batch_s=span) for v in (one, many)
    ]
    for router in routers:
        router.time_offset_s = offset
    for (topic, _, value), t in zip(messages, times):
        routers[0].on_values(topic, t, [value])
    topics = ["/imu", "/control_surfaces", "/sweep"]
    bounds = sorted({0, len(messages), *(c for c in cuts if c < len(messages))})
    singles = set(singles)
    for start, stop in zip(bounds, bounds[1:]):
        run = list(range(start, stop))
        while run:
            if run[0] in singles:              # a single message between runs (a record decoded on its own)
                i = run.pop(0)
                routers[1].on_values(messages[i][0], times[i], [messages[i][2]])
                continue
            part = run[:next((j for j, i in enumerate(run) if i in singles), len(run))]
            run = run[len(part):]
            which = np.array([topics.index(messages[i][0]) for i in part])
            values = [np.array([[messages[i][2]] for i in part if messages[i][0] == topic]).reshape(-1, 1)
                      for topic in topics]
            routers[1].on_values_batch(topics, which, np.array([times[i] for i in part]), values)
    for router in routers:
        router.flush()
    assert len(one.batches) == len(many.batches)
    for a, b in zip(one.batches, many.batches):
        assert a[:2] == b[:2] and np.array_equal(a[2], b[2], equal_nan=True)
        assert np.array_equal(a[3], b[3], equal_nan=True)
    assert sorted(one.bad) == sorted(many.bad) and routers[0].messages == routers[1].messages


# span reached exactly
@pytest.mark.parametrize("times", [50 + 0.125 * np.arange(30),
                                   np.r_[50 + 0.125 * np.arange(9), 8 + 0.125 * np.arange(9)],  # a jump back
                                   np.r_[50.0, 50.0, 50.0, 49.9, 50.25, 50.5]])                 # reordered
def test_runs_push_where_message_by_message_pushes(times):
    batches = []
    for split in (False, True):
        val = FakeValidator()
        router = MessageRouter(make_config(), val, batch=7, max_batch_s=0.25)
        topics = np.arange(times.size) % 3 == 0                  # every third message a surface position
        if split:
            names = ["/imu", "/control_surfaces"]
            router.on_values_batch(names, topics.astype(int), times,
                                   [np.ones((int((~topics).sum()), 1)), np.ones((int(topics.sum()), 1))])
        else:
            for t, surface in zip(times, topics):
                router.on_values("/control_surfaces" if surface else "/imu", t, [1.0])
        router.flush()
        batches.append([(c, s, t.tolist()) for c, s, t, _ in val.batches])
    assert batches[0] == batches[1]
