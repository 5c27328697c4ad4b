"""``gap-validate replay BAG --config CFG --annotate OUT.mcap``: the flight and its verdict on one timeline.

The output is one MCAP file (the ``mcap`` package's writer: a single file Foxglove opens, where rosbags would
write a rosbag2 directory) holding every message of the bag, unchanged (ROS 2 CDR, the bag's own schemas),
plus what the node ``gap_validator`` would have published as the flight went on: ``/diagnostics`` every
``period_s`` of bag time, and the plottable topics ``/gap_validator/<channel>/frequency_response`` and
``.../verdict`` (docs/NODE_TOPICS.md) whenever they changed. They come from the same data path as replay
(:func:`replay`'s ``on_tick``: the router flushed at each tick, the cheap results,
:func:`~gap_validation.ros.status.channel_status`,
:func:`~gap_validation.core.plottable.frequency_response_table`), with the full diagnosis re-run when a
channel's sweep count changed (the node runs it after each new sweep). What a bag cannot show is left out: the
ages of the samples and STALE (the node's clock against the data's).
"""
from __future__ import annotations

import heapq
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from gap_validation.bag.reader import open_bag
from gap_validation.core.config import ValidationConfig
from gap_validation.core.errors import DataError
from gap_validation.core.plottable import table_dims, topic_token
from gap_validation.core.results import ValidationResult
from gap_validation.core.validator import OnlineValidator
from gap_validation.messages.router import MessageRouter
from gap_validation.ros.status import PlotChanges, channel_status

__all__ = ["Annotator", "write_annotated", "NODE_NAME", "TICK_S"]

#: The node's default name: the topics of the annotation are those of a node run with the defaults.
NODE_NAME = "gap_validator"
#: The node's default ``diagnostic_period`` [s].
TICK_S = 1.0
_LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}
_DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"
_TABLE = "std_msgs/msg/Float64MultiArray"
_STRING = "std_msgs/msg/String"


class Annotator:
    """What the node would publish at each tick of bag time, serialized (``replay(...,
    on_tick=annotator.tick)``).

    Parameters
    ----------
    config : ValidationConfig
        The replay's config (channels, grids, ``aircraft`` for the ``hardware_id``).
    node_name : str
        Name of the node the topics and status names are those of.
    diagnose : bool
        Re-run the full diagnosis when a channel's sweep count changed (its sentence in the statuses and
        verdicts).

    Attributes
    ----------
    messages : list of (int, str, str, bytes)
        ``(bag time [ns], topic, type, CDR)`` in time order.
    """

    def __init__(self, config: ValidationConfig, node_name: str = NODE_NAME, diagnose: bool = True):
        from rosbags.typesys import Stores, get_typestore

        self.config = config
        self.node_name = node_name
        self.diagnose = diagnose
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        aircraft = config.raw.get("aircraft") if isinstance(config.raw, dict) else None
        self.hardware_id = str(aircraft) if aircraft else f"/{node_name}"
        self.messages: list[tuple[int, str, str, bytes]] = []
        self._sweeps: dict[str, int] = {}
        self._top: dict[str, Any] = {}
        self._nonlinearity: dict[str, str | None] = {}
        self._changes = PlotChanges()

    # ------------------------------------------------------------------ one tick
    def tick(self, t_ns: int, validator: OnlineValidator, router: MessageRouter) -> None:
        """The node's diagnostics tick at bag time ``t_ns`` (the router flushed up to it)."""
        result = validator.results(diagnose=False)
        if self.diagnose:
            self._diagnose(result, validator)
        types = self.typestore.types
        statuses = []
        for name, ch in result.channels.items():
            channel = self.config.channels[name]
            extra = {} if channel.is_mimo else {"samples_input": router.samples(name, "input"),
                                                 "samples_output": router.samples(name, "output")}
            state = "off" if not self.diagnose else ("done" if name in self._top else "pending")
            statuses.append(channel_status(ch, candidate=self._top.get(name), diagnosis_state=state,
                                           extra_values=extra, nonlinearity=self._nonlinearity.get(name)))
        stamp = types["builtin_interfaces/msg/Time"](
            sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000)
        )
        header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="")
        status_type, kv = types["diagnostic_msgs/msg/DiagnosticStatus"], types["diagnostic_msgs/msg/KeyValue"]
        array = types[_DIAGNOSTICS](header=header, status=[
            status_type(level=_LEVELS[s.level], name=f"{self.node_name}: {s.channel}", message=s.message,
                        hardware_id=self.hardware_id, values=[kv(key=k, value=v) for k, v in s.values])
            for s in statuses])
        self._add(t_ns, "/diagnostics", _DIAGNOSTICS, array)
        for status in statuses:
            name = status.channel
            table, verdict = self._changes.changed(result.channels[name], self.config.channels[name], status)
            base = f"/{self.node_name}/{topic_token(name)}"
            if table is not None:
                self._add(t_ns, f"{base}/frequency_response", _TABLE, self._table(table))
            if verdict is not None:
                self._add(t_ns, f"{base}/verdict", _STRING, types[_STRING](data=verdict))

    def _diagnose(self, result: ValidationResult, validator: OnlineValidator) -> None:
        sweeps = {name: ch.sweeps for name, ch in result.channels.items()}
        if sweeps == self._sweeps:
            return
        self._sweeps = sweeps
        full = validator.results(diagnose=True)
        for name, ch in full.channels.items():
            if ch.epsilon is not None or (ch.mimo is not None and ch.nu_gap is not None):
                self._top[name] = ch.diagnosis[0] if ch.diagnosis else None
                self._nonlinearity[name] = ch.nonlinearity

    def _table(self, table: np.ndarray) -> Any:
        types = self.typestore.types
        dim = types["std_msgs/msg/MultiArrayDimension"]
        layout = types["std_msgs/msg/MultiArrayLayout"](
            dim=[dim(label=label, size=size, stride=stride) for label, size, stride in table_dims(table)],
            data_offset=0)
        return types[_TABLE](layout=layout, data=np.ascontiguousarray(table.ravel(), dtype=np.float64))

    def _add(self, t_ns: int, topic: str, msgtype: str, msg: Any) -> None:
        self.messages.append((int(t_ns), topic, msgtype, bytes(self.typestore.serialize_cdr(msg, msgtype))))


# ------------------------------------------------------------------------------------------------ the file
def _bag_records(bag) -> Iterator[tuple[int, int, str, str, bytes]]:
    for topic, msgtype, t_ns, raw in bag.records(None):
        yield int(t_ns), 0, topic, msgtype, bytes(raw)


def write_annotated(bag_path: str | Path, out: str | Path, annotator: Annotator) -> int:
    """Write the bag's messages and the annotator's, merged in time order, as one MCAP file.

    Parameters
    ----------
    bag_path : path
        The replayed bag (rosbag2 directory, ``.mcap`` or ``.db3``).
    out : path
        The MCAP file to write (replaced atomically: written beside it, then renamed).
    annotator : Annotator
        After the replay.

    Returns
    -------
    int
        Messages written.

    Raises
    ------
    DataError
        One line naming the file when the output cannot be written or a topic's type has no definition.
    """
    from mcap.writer import Writer

    out = Path(out)
    tmp = out.with_name(f".{out.name}.tmp")
    schemas: dict[str, int] = {}
    channels: dict[tuple[str, str], int] = {}
    written = 0
    try:
        with open_bag(bag_path) as bag, open(tmp, "wb") as stream:
            writer = Writer(stream)
            writer.start(profile="ros2", library="gap_validation")

            def channel(topic: str, msgtype: str) -> int:
                key = (topic, msgtype)
                if key not in channels:
                    if msgtype not in schemas:
                        store = (
                            annotator.typestore if msgtype in annotator.typestore.fielddefs else bag.typestore
                        )
                        if store is bag.typestore:
                            bag.ensure_type(msgtype)
                        text = store.generate_msgdef(msgtype)[0]
                        schemas[msgtype] = writer.register_schema(name=msgtype, encoding="ros2msg",
                                                                  data=text.encode())
                    channels[key] = writer.register_channel(topic=topic, message_encoding="cdr",
                                                            schema_id=schemas[msgtype])
                return channels[key]

            ours = ((t, 1, topic, msgtype, data) for t, topic, msgtype, data in annotator.messages)
            for t_ns, _, topic, msgtype, data in heapq.merge(
                _bag_records(bag), ours, key=lambda r: (r[0], r[1])
            ):
                writer.add_message(channel_id=channel(topic, msgtype), log_time=t_ns, data=data,
                                   publish_time=t_ns, sequence=written)
                written += 1
            writer.finish()
        tmp.replace(out)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise DataError(f"--annotate {out}: cannot write ({err.strerror or err})") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return written
