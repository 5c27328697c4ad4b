"""The one decoding step (gap_validation.messages.decoding) that replay and the node share."""
import numpy as np
import pytest
from _messages import TS, FakeValidator, imu, joints, make_config

from gap_validation.core.errors import DataError
from gap_validation.messages.cdr import Records
from gap_validation.messages.decoding import VERIFY_MESSAGES, TopicDecoder, Undecodable, fast_values_agree
from gap_validation.messages.router import MessageRouter

IMU = "sensor_msgs/msg/Imu"
JOINT_STATE = "sensor_msgs/msg/JointState"


def _decoder(deserialize=None, msgtype=IMU, topic="/imu", **kwargs):
    router = MessageRouter(make_config(), FakeValidator())
    full = deserialize or (lambda raw: TS.deserialize_cdr(raw, msgtype))
    return router, TopicDecoder(router, topic, msgtype, full, **kwargs)


def _raw(msg, msgtype=IMU):
    return TS.serialize_cdr(msg, msgtype)


def test_first_messages_are_verified_then_the_fast_decoder_is_trusted():
    calls = []
    router, step = _decoder(lambda raw: calls.append(1) or TS.deserialize_cdr(raw, IMU))
    assert step.decoder is not None
    outs = [step.decode(_raw(imu(y=0.1 * k, sec=k))) for k in range(VERIFY_MESSAGES + 3)]
    assert len(calls) == VERIFY_MESSAGES                   # deserialised only while verifying
    assert all(out[2] is not None for out in outs[:VERIFY_MESSAGES])
    stamp, values, msg = outs[-1]
    assert msg is None and values == [pytest.approx(0.1 * (VERIFY_MESSAGES + 2))]
    assert stamp == pytest.approx(VERIFY_MESSAGES + 2.5)


def test_a_disagreeing_fast_decoder_is_dropped():
    seen = []
    lie = {"n": 0}

    def deserialize(raw):
        msg = TS.deserialize_cdr(raw, IMU)
        lie["n"] += 1
        msg.angular_velocity.y += 1.0                      # full deserialisation says otherwise
        return msg

    _, step = _decoder(deserialize, on_disagree=seen.append)
    step.decode(_raw(imu(y=0.5)))
    assert step.decoder is None and seen == ["/imu"]
    for _ in range(VERIFY_MESSAGES + 2):                  # from now on every message is deserialised
        assert step.decode(_raw(imu(y=0.5)))[2] is not None


def test_a_message_the_fast_decoder_cannot_read_is_deserialised():
    router = MessageRouter(make_config(), FakeValidator())
    step = TopicDecoder(router, "/control_surfaces", JOINT_STATE,
                        lambda raw: TS.deserialize_cdr(raw, JOINT_STATE))
    step.verify_left = 0
    stamp, values, msg = step.decode(_raw(joints(["elevator"], [0.25]), JOINT_STATE))
    assert msg is None and values == [0.25]
    _, values, msg = step.decode(_raw(joints(["aileron"], [0.25]), JOINT_STATE))  # no elevator: full decode
    assert values is None and msg is not None and list(msg.name) == ["aileron"]
    assert step.decoder is not None                        # a missing joint is the message's fault


def test_an_undecodable_message_is_counted_and_reported():
    router, step = _decoder()                              # default: any exception means undecodable
    step.decoder = None
    with pytest.raises(Undecodable) as err:
        step.decode(b"\x00\x01\x00\x00")
    assert "topic /imu" in str(err.value) and err.value.error is not None
    assert router.bad == {("pitch", "output"): {"undecodable": 1}}


def test_errors_outside_the_declared_ones_propagate():
    def broken(raw):
        raise RuntimeError("bug")

    _, step = _decoder(broken, errors=(DataError,))
    step.decoder = None
    with pytest.raises(RuntimeError):
        step.decode(_raw(imu()))


def test_values_agree_treats_nan_as_equal_and_checks_the_stamp():
    router = MessageRouter(make_config(), FakeValidator())
    routes = router.routes["/imu"]
    msg = imu(y=float("nan"), sec=3, nanosec=0)
    assert fast_values_agree(routes, msg, 3.0, [float("nan")])
    assert not fast_values_agree(routes, msg, 4.0, [float("nan")])
    assert not fast_values_agree(routes, imu(y=1.0, sec=3, nanosec=0), 3.0, [np.nextafter(1.0, 2.0)])


def _records(n, start=0):
    return Records.from_raws([_raw(imu(y=0.01 * k, sec=k + 1)) for k in range(start, start + n)])


def test_batches_are_read_once_the_record_decoder_is_trusted_and_checked_too():
    calls = []
    _, step = _decoder(lambda raw: calls.append(1) or TS.deserialize_cdr(raw, IMU))
    stamps, values, fast = step.decode_batch(_records(5))
    # not trusted yet: every record goes through decode()
    assert not fast.any() and calls == []
    for k in range(VERIFY_MESSAGES):
        step.decode(_raw(imu(y=0.01 * k, sec=k + 1)))
    stamps, values, fast = step.decode_batch(_records(20, start=VERIFY_MESSAGES))
    assert fast.all() and len(calls) == 2 * VERIFY_MESSAGES       # the batch decoder's first records checked
    assert values[:, 0].tolist() == [0.01 * k for k in range(VERIFY_MESSAGES, VERIFY_MESSAGES + 20)]
    assert stamps.tolist() == [k + 1.5 for k in range(VERIFY_MESSAGES, VERIFY_MESSAGES + 20)]
    step.decode_batch(_records(20))
    assert len(calls) == 2 * VERIFY_MESSAGES                      # then trusted


def test_a_disagreeing_batch_decoder_is_dropped_and_records_go_one_by_one():
    seen, count = [], {"n": 0}

    def deserialize(raw):
        msg = TS.deserialize_cdr(raw, IMU)
        count["n"] += 1
        # the record decoder passed; the batch decoder will not
        if count["n"] > VERIFY_MESSAGES:
            msg.angular_velocity.y += 1.0
        return msg

    _, step = _decoder(deserialize, on_disagree=seen.append)
    for k in range(VERIFY_MESSAGES):
        step.decode(_raw(imu(sec=k + 1)))
    _, _, fast = step.decode_batch(_records(10))
    assert not fast.any() and step.batch is None and seen == ["/imu"]
    assert step.decoder is not None                       # records are still read one by one (decode)
    assert not step.decode_batch(_records(10))[2].any()


def test_replay_and_node_use_this_step():
    """One decoding step: both front ends build TopicDecoder (the node in its topics component), neither
    decodes fields on its own."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "gap_validation"
    for front_end in ("bag/replay.py", "ros/topics.py"):
        text = (root / front_end).read_text()
        assert "TopicDecoder(" in text and "fast_decoder" not in text and "verify_left" not in text
    for module in ("node", "jobs"):
        text = (root / "ros" / f"{module}.py").read_text()
        assert "fast_decoder" not in text and "verify_left" not in text
