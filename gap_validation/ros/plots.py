"""The node's plottable topics (docs/NODE_TOPICS.md): per channel, latched, republished only when they change.

* ``~/<channel>/frequency_response`` (``std_msgs/msg/Float64MultiArray``): the table of
  :func:`gap_validation.core.plottable.frequency_response_table`, row after row. ``layout.dim[0]`` names the rows
  (its label is the curve names joined by commas, its size their number), ``layout.dim[1]`` the frequencies
  (label ``frequency``, size the channel's grid). The grid is fixed for a config, so a plot layout's indices
  hold all flight long; frequencies without an estimate are NaN (plotters leave a gap).
* ``~/<channel>/verdict`` (``std_msgs/msg/String``): one JSON object, what the channel's ``/diagnostics`` status
  says (:func:`gap_validation.ros.status.verdict_mapping`): level, message, epsilon, nu-gap, margins,
  limited_by, the top diagnosis sentence, warnings.

Both use a reliable, transient-local QoS of depth 1: a plotter that starts late gets the latest at once.
"""
from __future__ import annotations

import json
from typing import Any

import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String

from gap_validation.core.plottable import CURVES, frequency_response_table, topic_token
from gap_validation.core.results import ValidationResult
from gap_validation.ros.status import ChannelStatus, verdict_mapping

__all__ = ["PlotTopics", "LATCHED", "topic_token", "table_message"]

#: Reliable, transient local, the latest only: a late subscriber gets the current curves at once.
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def table_message(table: np.ndarray) -> Float64MultiArray:
    """The ``Float64MultiArray`` of a curves table (rows :data:`CURVES`, columns the frequencies)."""
    rows, n = table.shape
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=",".join(CURVES), size=rows, stride=rows * n),
                      MultiArrayDimension(label="frequency", size=n, stride=n)]
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
        self._last: dict[str, tuple[np.ndarray | None, str | None]] = {}
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
            self._last.pop(name, None)

    def publish(self, result: ValidationResult, statuses: list[ChannelStatus]) -> None:
        """Publish each channel's table and verdict where they differ from the last published."""
        config = self.node.config.channels
        for status in statuses:
            name = status.channel
            channel, ch = config.get(name), result.channels.get(name)
            if channel is None or ch is None:
                continue
            table = frequency_response_table(ch, channel)
            verdict = json.dumps(verdict_mapping(status), sort_keys=True)
            last_table, last_verdict = self._last.get(name, (None, None))
            table_pub, verdict_pub = self._publishers(name)
            if table is not None and (last_table is None or not np.array_equal(table, last_table, equal_nan=True)):
                table_pub.publish(table_message(table))
                self.published += 1
                last_table = table
            if verdict != last_verdict:
                verdict_pub.publish(String(data=verdict))
                self.published += 1
            self._last[name] = (last_table, verdict)
