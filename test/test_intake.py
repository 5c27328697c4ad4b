"""How the node takes messages (gap_validation.ros.intake), without ROS: the reliability chosen from what the
publishers offer, the status note for a publisher that cannot be matched, and a QoS change that neither loses
nor repeats a message (fake subscriptions standing in for rclpy's)."""
from __future__ import annotations

import random

import pytest

from gap_validation.ros.intake import (
    BEST_EFFORT,
    RELIABLE,
    Intake,
    choose_reliability,
    message_key,
    publisher_note,
    take_all,
)


class _Handle:
    def __init__(self, queue):
        self.queue = queue

    def take_message(self, msg_type, raw):
        return self.queue.pop(0) if self.queue else None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


class FakeSubscription:
    """A subscription's queue: ``deliver`` puts a message in, ``take_message`` takes the oldest."""

    msg_type, raw = object, True

    def __init__(self, matched: int = 0):
        self.queue: list = []
        self.handle = _Handle(self.queue)
        self.matched = matched

    def deliver(self, seq: int) -> None:
        self.queue.append(
            (
                f"m{seq}".encode(),
                {
                    "source_timestamp": 1_000 + seq,
                    "publication_sequence_number": seq,
                    "received_timestamp": 2_000 + seq,
                },
            )
        )

    def get_publisher_count(self) -> int:
        return self.matched


def test_reliability_follows_the_publishers():
    assert choose_reliability("auto", []) == BEST_EFFORT              # none known yet: match any publisher
    assert choose_reliability("auto", [RELIABLE, RELIABLE]) == RELIABLE
    assert choose_reliability("auto", [RELIABLE, BEST_EFFORT]) == BEST_EFFORT
    assert choose_reliability("reliable", [BEST_EFFORT]) == RELIABLE   # fixed by the parameter
    assert choose_reliability("best_effort", [RELIABLE]) == BEST_EFFORT


def test_publisher_note_names_the_topic_the_offer_and_the_setting():
    note = publisher_note("/imu", "reliable", RELIABLE, "sensor_msgs/msg/Imu", "fields",
                          [("sensor_msgs/msg/Imu", BEST_EFFORT)])
    assert note == ("publisher on /imu offers BEST_EFFORT; set qos_reliability to auto or best_effort (the "
                    "subscription is RELIABLE)")
    assert publisher_note("/imu", "auto", BEST_EFFORT, "sensor_msgs/msg/Imu", "fields",
                          [("sensor_msgs/msg/Imu", RELIABLE), ("sensor_msgs/msg/Imu", BEST_EFFORT)]) is None
    typed = publisher_note("/imu", "auto", BEST_EFFORT, "sensor_msgs/msg/Imu", "config",
                           [("std_msgs/msg/Float64", RELIABLE)])
    assert typed.startswith(
        "publisher on /imu offers std_msgs/msg/Float64; the config says sensor_msgs/msg/Imu"
    )
    assert "\n" not in note + typed


def test_take_all_takes_what_waits_up_to_the_limit():
    sub = FakeSubscription()
    for seq in range(5):
        sub.deliver(seq)
    assert [data for data, _ in take_all(sub, 3)] == [b"m0", b"m1", b"m2"]
    assert [data for data, _ in take_all(sub, 10)] == [b"m3", b"m4"]
    assert take_all(sub, 10) == []


def _run_change(rng, intake: Intake, old: FakeSubscription, new: FakeSubscription, settle) -> list:
    """Messages arriving (to the subscriptions matched so far) while ``intake`` changes from ``old`` to
    ``new``, drained at random moments; ``settle()`` is called after a while. Returns every message taken."""
    taken, seq, now = [], [0], 0.0

    def arrive(subs, n):
        for _ in range(n):
            for sub in subs:
                sub.deliver(seq[0])
            seq[0] += 1

    arrive([old], rng.randint(0, 30))
    taken += intake.drain(1000)
    settle()
    arrive([old], rng.randint(0, 20))                # the new one has not matched the publisher yet
    while intake.changing:
        if rng.random() < 0.3:
            new.matched = 1
        arrive([old, new] if new.matched else [old], rng.randint(0, 20))
        if rng.random() < 0.5 and new.matched:        # a message already in one queue, not yet in the other
            new.deliver(seq[0])
            taken += intake.drain(1000)
            old.deliver(seq[0])
            seq[0] += 1
        now += 1.0
        retire = intake.retire_due(now)
        taken += intake.drain(1000)
        if retire:
            assert intake.retired() == [old]
            old.queue.clear()                         # destroyed: what it still held is gone (taken via new)
        assert now < 1000
    arrive([new], rng.randint(0, 20))
    taken += intake.drain(1000)
    # each once, in order
    assert [info["publication_sequence_number"] for _, info in taken] == list(range(seq[0]))
    return taken


@pytest.mark.parametrize("seed", range(20))
def test_a_reliability_change_neither_loses_nor_repeats_a_message(seed):
    """The old subscription is drained with the new one until the new one has matched; a message both deliver
    is taken once; none is lost, whatever the interleaving of arrivals and drains."""
    old, new = FakeSubscription(matched=1), FakeSubscription(matched=0)
    intake = Intake("/imu", "sensor_msgs/msg/Imu", "fields", {BEST_EFFORT: old}, BEST_EFFORT)
    _run_change(random.Random(seed), intake, old, new,
                lambda: intake.settle(RELIABLE, publishers=1, deadline=100.0, subscription=new))
    assert (
        intake.current is new and intake.subscriptions == {RELIABLE: new} and intake.reliability == RELIABLE
    )


@pytest.mark.parametrize("seed", range(10))
def test_before_the_publishers_are_known_both_subscriptions_are_drained_once(seed):
    """Unknown publishers: a best-effort and a reliable subscription from the start; the reliable one (here
    the late matcher) is kept once the publishers are known reliable; every message once."""
    best, reliable = FakeSubscription(matched=1), FakeSubscription(matched=0)
    intake = Intake("/imu", "sensor_msgs/msg/Imu", "fields", {RELIABLE: reliable, BEST_EFFORT: best}, None)
    assert intake.changing and intake.current is None and not intake.retire_due(0.0)
    _run_change(random.Random(seed), intake, best, reliable,
                lambda: intake.settle(RELIABLE, publishers=1, deadline=100.0))
    assert intake.subscriptions == {RELIABLE: reliable}


def test_a_change_ends_at_its_deadline_when_a_publisher_never_matches():
    old, new = FakeSubscription(matched=1), FakeSubscription(matched=0)
    intake = Intake("/imu", "sensor_msgs/msg/Imu", "fields", {BEST_EFFORT: old}, BEST_EFFORT)
    intake.settle(RELIABLE, publishers=2, deadline=5.0, subscription=new)
    assert not intake.retire_due(4.9) and intake.retire_due(5.0)
    with pytest.raises(RuntimeError):
        intake.settle(RELIABLE, publishers=1, deadline=9.0, subscription=FakeSubscription())
    assert message_key({"source_timestamp": None, "publication_sequence_number": None}) is None


@pytest.mark.parametrize("seed", range(10))
def test_messages_one_subscription_dropped_come_in_publication_order(seed):
    """Both subscriptions drained (publishers not known yet): the best-effort one drops messages under load
    that the reliable one delivers. Taken once each and in the order they were published: the reliable queue's
    fill-ins after the best-effort queue's later messages would be a time jump back (a new segment: a
    manoeuvre cut in two, seen on a node under load)."""
    rng = random.Random(seed)
    best, reliable = FakeSubscription(matched=1), FakeSubscription(matched=0)
    intake = Intake("/imu", "sensor_msgs/msg/Imu", "fields", {RELIABLE: reliable, BEST_EFFORT: best}, None)
    taken, seq = [], 0
    for round_ in range(30):
        # the publishers are known reliable: both drained until the reliable one matched
        if round_ == 10:
            intake.settle(RELIABLE, publishers=1, deadline=100.0)
        if round_ == 20:
            reliable.matched = 1
        for _ in range(rng.randint(1, 60)):
            reliable.deliver(seq)
            if rng.random() > 0.3:                    # best effort: three in ten lost
                best.deliver(seq)
            seq += 1
        retire = intake.retire_due(float(round_))
        taken += intake.drain(1000)
        if retire:
            intake.retired()
            best.queue.clear()
    assert [info["publication_sequence_number"] for _, info in taken] == list(range(seq))


@pytest.mark.parametrize("seed", range(10))
def test_messages_the_reliable_queue_delivers_late_do_not_come_after_later_ones(seed):
    """Both subscriptions drained (publishers not known yet, then a reliable publisher known): the best-effort
    queue loses a message, the reliable queue holds back every later one until the lost one is resent (it
    delivers in order), so for a while the best-effort queue is ahead. Its later messages wait until the
    reliable queue passes them (or :attr:`Intake.HOLD_S`): taken once each and in publication order (seen on a
    restarted node under load: one time jump back per topic, a manoeuvre cut in two)."""
    rng = random.Random(seed)
    best, reliable = FakeSubscription(matched=1), FakeSubscription(matched=1)
    intake = Intake("/imu", "sensor_msgs/msg/Imu", "fields", {RELIABLE: reliable, BEST_EFFORT: best}, None)
    taken, seq, lagging, now = [], 0, [], 0.0
    for round_ in range(40):
        if round_ == 10:
            intake.settle(RELIABLE, publishers=1, deadline=100.0)
        for _ in range(rng.randint(1, 60)):
            # lost on the wire: the reliable queue waits for the resend
            if rng.random() > 0.9 or lagging:
                lagging.append(seq)
            else:
                reliable.deliver(seq)
            if rng.random() > 0.2 and not (lagging and lagging[0] == seq):
                best.deliver(seq)
            seq += 1
        if lagging and rng.random() < 0.5:             # resent: the reliable queue delivers the lot, in order
            for s in lagging:
                reliable.deliver(s)
            lagging.clear()
        now += 0.05
        retire = intake.retire_due(now) if round_ >= 15 else False
        taken += intake.drain(1000, now=now)
        if retire:
            intake.retired()
            best.queue.clear()
    for s in lagging:
        reliable.deliver(s)
    for _ in range(Intake.LINGER + 1):
        now += 0.05
        taken += intake.drain(1000, now=now)
    got = [info["publication_sequence_number"] for _, info in taken]
    assert got == list(range(seq))
    assert not intake.changing


def test_a_best_effort_publisher_is_not_held_back_by_a_reliable_queue_nothing_reaches():
    """A best-effort publisher only (the reliable subscription matched none): its messages are not held."""
    best, reliable = FakeSubscription(matched=1), FakeSubscription(matched=0)
    intake = Intake("/imu", "sensor_msgs/msg/Imu", "fields", {RELIABLE: reliable, BEST_EFFORT: best}, None)
    for seq in range(5):
        best.deliver(seq)
    assert [info["publication_sequence_number"] for _, info in intake.drain(1000, now=0.0)] == list(range(5))


def test_a_message_held_for_the_reliable_queue_goes_after_hold_s():
    """The reliable queue never delivers a message the best-effort one has (its publisher left): released
    after
    :attr:`Intake.HOLD_S`, not kept for ever."""
    best, reliable = FakeSubscription(matched=1), FakeSubscription(matched=1)
    intake = Intake("/imu", "sensor_msgs/msg/Imu", "fields", {RELIABLE: reliable, BEST_EFFORT: best}, None)
    reliable.deliver(0)
    best.deliver(0)
    best.deliver(1)
    assert [i["publication_sequence_number"] for _, i in intake.drain(1000, now=0.0)] == [0]
    assert intake.drain(1000, now=Intake.HOLD_S / 2) == []
    assert [i["publication_sequence_number"] for _, i in intake.drain(1000, now=Intake.HOLD_S)] == [1]
