"""From serialized messages to samples, with no rclpy and no rosbags import.

* :mod:`~gap_validation.messages.cdr`: fast CDR field decoders (only the configured fields; of one record, or
  of many at once);
* :mod:`~gap_validation.messages.decoding`: the one decoding step replay and the node share (decode, verify
  the first messages against full deserialisation, fall back, count ``undecodable``);
* :mod:`~gap_validation.messages.router`: the :class:`~gap_validation.messages.router.MessageRouter` from
  messages (bag or live) to :class:`~gap_validation.core.validator.OnlineValidator`.

Depends on :mod:`gap_validation.core` only; :mod:`gap_validation.bag` and :mod:`gap_validation.ros` build on
it.
"""

from gap_validation.core.exports import lazy_exports

#: The package's public face: name -> the module defining it (imported when the name is first used).
_PUBLIC = {
    "MessageRouter": "router", "Route": "router", "TopicDecoder": "decoding", "fast_decoder": "cdr",
    "batch_decoder": "cdr"
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
