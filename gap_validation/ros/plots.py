"""The node's plottable topics (docs/NODE_TOPICS.md): per channel, latched, republished only when they change.

* ``~/<channel>/frequency_response`` (``std_msgs/msg/Float64MultiArray``): the table of
  :func:`gap_validation.core.plottable.frequency_response_table`, row after row. ``layout.dim[0]`` names the
  rows (its label is the curve names joined by commas, its size their number), ``layout.dim[1]`` the
  frequencies (label ``frequency``, size the channel's grid). The grid is fixed for a config, so a plot
  layout's indices hold all flight long; frequencies without an estimate are NaN (plotters leave a gap).
* ``~/<channel>/verdict`` (``std_msgs/msg/String``): one JSON object, what the channel's ``/diagnostics``
  status says (:func:`gap_validation.ros.status.verdict_mapping`): level, message, epsilon, nu-gap, margins,
  limited_by, the top diagnosis sentence, warnings.

Both use a reliable, transient-local QoS of depth 1: a plotter that starts late gets the latest at once.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String

from gap_validation.core.plottable import table_dims, topic_token
from gap_validation.core.results import ValidationResult
from gap_validation.ros.status import ChannelStatus, PlotChanges

__all__ = ["PlotTopics", "LATCHED", "topic_token", "table_message"]

#: Reliable, transient local, the latest only: a late subscriber gets the current curves at once.
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def table_message(table: np.ndarray) -> Float64MultiArray:
    """The ``Float64MultiArray`` of a curves table (rows the curves, columns the frequencies)."""
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                      for label, size, stride in table_dims(table)]
    msg.layout.data_offset = 0
    msg.data = table.ravel().tolist()
    return msg


class PlotTopics:
    """The plottable topics of a node's channels (publishers made when a channel first has a status).

    Parameters
    ----------
    node : rclpy.node.Node
        The validator node (its ``config`` holds the channels).
    """

    def __init__(self, node: Any):
        self.node = node
        self._pubs: dict[str, tuple[Any, Any]] = {}
        self._changes = PlotChanges()
        self.published = 0           # messages published (tests, benchmarks)

    def _publishers(self, channel: str) -> tuple[Any, Any]:
        pubs = self._pubs.get(channel)
        if pubs is None:
            token = topic_token(channel)
            pubs = (self.node.create_publisher(Float64MultiArray, f"~/{token}/frequency_response", LATCHED),
                    self.node.create_publisher(String, f"~/{token}/verdict", LATCHED))
            self._pubs[channel] = pubs
        return pubs

    def sync(self, channels) -> None:
        """Drop the publishers of channels no longer in the config (after a reload)."""
        for name in [n for n in self._pubs if n not in channels]:
            for pub in self._pubs.pop(name):
                self.node.destroy_publisher(pub)
            self._changes.forget(name)

    def publish(self, result: ValidationResult, statuses: list[ChannelStatus]) -> None:
        """Publish each channel's table and verdict where they differ from the last published."""
        config = self.node.config.channels
        for status in statuses:
            channel, ch = config.get(status.channel), result.channels.get(status.channel)
            if channel is None or ch is None:
                continue
            table, verdict = self._changes.changed(ch, channel, status)
            table_pub, verdict_pub = self._publishers(status.channel)
            if table is not None:
                table_pub.publish(table_message(table))
                self.published += 1
            if verdict is not None:
                verdict_pub.publish(String(data=verdict))
                self.published += 1
