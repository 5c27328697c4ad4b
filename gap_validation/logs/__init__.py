"""Flight logs that are not rosbag2: PX4 ULog (``.ulg``), ArduPilot DataFlash (``.bin``) and CSV.

* :mod:`~gap_validation.logs.base`: what every format gives (:class:`LogFile`, :class:`LogTopic`,
  :class:`WriteTopic`);
* :mod:`~gap_validation.logs.formats`: :func:`~gap_validation.logs.formats.open_log`, which picks the format
  from the suffix;
* :mod:`~gap_validation.logs.ulog`: PX4 ULog, read and written;
* :mod:`~gap_validation.logs.dataflash`: ArduPilot DataFlash, read and written;
* :mod:`~gap_validation.logs.csvlog`: one CSV file per topic, read and written;
* :mod:`~gap_validation.logs.checks`: the logging checks (a topic logged too slowly for the band, irregular
  stamps), each with the fix in the autopilot's words;
* :mod:`~gap_validation.logs.merge`: the blocks of a log's topics merged in time order as they come (replay
  holds a block or two, not the flight);
* :mod:`~gap_validation.logs.flight`: a simulated flight written as an autopilot's log, with the config that
  reads it (``gap-validate simulate --format``).

Replay (:mod:`gap_validation.bag.replay`) streams them block by block (:meth:`LogFile.blocks
<gap_validation.logs.base.LogFile.blocks>`) through the same router as bags. This package imports
neither rclpy nor rosbags nor matplotlib.
"""

from gap_validation.core.exports import lazy_exports

#: The package's public face: name -> the module defining it (imported when the name is first used).
_PUBLIC = {
    "open_log": "formats", "LogFile": "base", "LogTopic": "base", "LogSeries": "base", "WriteTopic": "base",
    "is_log": "base", "write_ulog": "ulog", "write_dataflash": "dataflash", "write_csv": "csvlog",
    "check_stamps": "checks", "write_flight_log": "flight"
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
