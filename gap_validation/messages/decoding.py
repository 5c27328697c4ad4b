"""The decoding step, written once for replay and the node: serialized message in, samples or message out.

Replay (:mod:`gap_validation.bag.replay`, records of a bag) and the ROS 2 node
(:mod:`gap_validation.ros.node`, raw subscriptions) both hand each serialized message of a topic to its
:class:`TopicDecoder`:

1. the fast field decoder of :mod:`gap_validation.messages.cdr` reads the configured fields (when the topic's
   type and fields are covered);
2. the first :data:`VERIFY_MESSAGES` messages are also deserialised fully, with the front end's
   ``deserialize`` (the bag's typestore for replay, rclpy's ``deserialize_message`` for the node), and the
   fast values checked against what :class:`~gap_validation.messages.router.MessageRouter`'s field paths
   extract (:func:`fast_values_agree`); on the first difference the fast decoder is dropped for the topic;
3. a message the fast decoder cannot read (missing joint, short array, another encoding) is deserialised and
   routed as a message, so bad samples are counted the same way;
4. a message that does not deserialise at all is counted ``undecodable`` for every signal of the topic and
   reported with :class:`Undecodable`.

Then the front end routes the result: fast values with ``MessageRouter.on_values``, a message with
``MessageRouter.on_message``. Nothing here imports rclpy or rosbags.

Replay also has many records of a topic at once (:class:`~gap_validation.messages.cdr.Records`, e.g. a
decompressed mcap chunk): :meth:`TopicDecoder.decode_batch` reads their fields vectorised with the topic's
batch decoder (:func:`~gap_validation.messages.cdr.batch_decoder`) once the per-record decoder is trusted. The
batch decoder is checked in the same way on the first :data:`VERIFY_MESSAGES` records it reads (each also
deserialised fully and compared; on a difference it is dropped); whatever it does not read is for
:meth:`TopicDecoder.decode`, one record at a time, so what the two entries decide stays this module's.
"""
from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np

from gap_validation.core.errors import DataError
from gap_validation.core.fields import FieldError
from gap_validation.messages.cdr import Records, batch_decoder, fast_decoder
from gap_validation.messages.router import MessageRouter, Route, stamp_seconds

__all__ = ["TopicDecoder", "Undecodable", "VERIFY_MESSAGES", "UNDECODABLE", "fast_values_agree"]

#: Messages per topic decoded both ways (fast field decoder and full deserialisation) before replay and the
#: node trust the fast decoder.
VERIFY_MESSAGES = 8
#: Bad-sample reason of a message that does not deserialise.
UNDECODABLE = "undecodable"


class Undecodable(DataError):
    """A serialized message that does not deserialise (already counted ``undecodable``); ``error`` is why."""

    def __init__(self, topic: str, error: BaseException):
        super().__init__(f"topic {topic}: {error}")
        self.error = error


def fast_values_agree(
    routes: Sequence[Route], msg: Any, stamp: float | None, values: Sequence[float]
) -> bool:
    """Whether a fast decoder's ``(stamp, values)`` equal what ``routes`` extract from the fully decoded
    ``msg`` (NaN equals NaN); replay and the node stop using the fast decoder of a topic on the first
    difference.

    Parameters
    ----------
    routes : sequence of Route
        The topic's routes (:attr:`MessageRouter.routes`), one value each.
    msg : object
        The same message, fully deserialised.
    stamp : float or None
        The fast decoder's header stamp [s].
    values : sequence of float
        The fast decoder's raw values.
    """
    try:
        full = [route.path.extract(msg) for route in routes]
    except FieldError:
        return False
    return (len(full) == len(values) and stamp == stamp_seconds(msg)
            and all(a == b or (math.isnan(a) and math.isnan(b)) for a, b in zip(values, full)))


class TopicDecoder:
    """The decoding step of one topic (see the module docstring).

    Parameters
    ----------
    router : MessageRouter
        Whose routes say which fields to read, and which counts ``undecodable`` messages.
    topic : str
        The topic.
    msgtype : str
        Its message type (``sensor_msgs/msg/Imu`` ...).
    deserialize : callable
        ``deserialize(raw) -> message``, the full deserialisation of the front end.
    fast : bool
        Use the fast field decoder where one covers the type and fields.
    errors : tuple of exception types
        What ``deserialize`` raises for a message that does not decode (others propagate).
    on_disagree : callable, optional
        ``on_disagree(topic)`` when the fast decoder disagrees with full deserialisation (it is dropped).
    """

    __slots__ = (
        "router",
        "topic",
        "routes",
        "decoder",
        "verify_left",
        "deserialize",
        "errors",
        "on_disagree",
        "batch",
        "batch_verify_left",
    )

    def __init__(self, router: MessageRouter, topic: str, msgtype: str, deserialize: Callable[[Any], Any], *,
                 fast: bool = True, errors: tuple[type[BaseException], ...] = (Exception,),
                 on_disagree: Callable[[str], None] | None = None):
        self.router = router
        self.topic = topic
        self.routes = router.routes.get(topic, ())
        #: The fast field decoder (None: every message is deserialised).
        self.decoder = fast_decoder(msgtype, [r.path for r in self.routes]) if fast else None
        self.verify_left = VERIFY_MESSAGES
        #: The batch decoder (None: records are decoded one by one), verified on its first records too.
        self.batch = batch_decoder(msgtype, [r.path for r in self.routes]) if fast else None
        self.batch_verify_left = VERIFY_MESSAGES
        self.deserialize = deserialize
        self.errors = errors
        self.on_disagree = on_disagree

    def decode(self, raw: Any) -> tuple[float | None, Sequence[float] | None, Any]:
        """Decode one serialized message.

        Parameters
        ----------
        raw : bytes-like
            The serialized (CDR) message.

        Returns
        -------
        stamp_s, values, message
            ``(stamp or None, raw values, None)`` from the trusted fast decoder, else ``(None, None,
            message)`` fully deserialised (verified against the fast values while :attr:`verify_left` > 0).

        Raises
        ------
        Undecodable
            When ``deserialize`` fails with one of :attr:`errors` (counted ``undecodable`` by the router).
        """
        stamp, values = None, None
        if self.decoder is not None:
            try:
                stamp, values = self.decoder(raw)
            except Exception:  # noqa: BLE001 - FastDecodeError, struct.error: decode this one fully
                stamp, values = None, None
            if values is not None and self.verify_left <= 0:
                return stamp, values, None
        try:
            msg = self.deserialize(raw)
        except self.errors as err:
            self.router.count_bad_message(self.topic, UNDECODABLE)
            raise Undecodable(self.topic, err) from None
        if values is not None:
            self.verify_left -= 1
            if not fast_values_agree(self.routes, msg, stamp, values):
                self.decoder = None
                if self.on_disagree is not None:
                    self.on_disagree(self.topic)
        return None, None, msg

    def decode_batch(self, records: Records) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Read the fields of many records of the topic at once.

        Parameters
        ----------
        records : Records
            Serialized (CDR) messages of this topic, in arrival order.

        Returns
        -------
        stamp_s, values, fast : numpy.ndarray
            Per record: the header stamp [s] (NaN: none, use the receive time), a row of raw values (one per
            route), and whether it was read. A record not read must go through :meth:`decode` (all of them
            until the per-record decoder is trusted, or when the batch decoder was dropped).
        """
        n = len(records)
        if self.batch is None or self.decoder is None or self.verify_left > 0:
            return np.full(n, np.nan), np.empty((n, len(self.routes))), np.zeros(n, dtype=bool)
        stamps, values, fast = self.batch(records)
        if self.batch_verify_left > 0:
            for i in np.flatnonzero(fast)[:self.batch_verify_left]:
                try:
                    msg = self.deserialize(records.raw(int(i)))
                except self.errors:             # not a check: left to decode(), record by record
                    fast[i] = False
                    continue
                self.batch_verify_left -= 1
                stamp = None if math.isnan(stamps[i]) else float(stamps[i])
                if not fast_values_agree(self.routes, msg, stamp, values[i].tolist()):
                    self.batch = None
                    if self.on_disagree is not None:
                        self.on_disagree(self.topic)
                    fast[:] = False
                    break
        return stamps, values, fast
