"""Flight logs that are not rosbag2: PX4 ULog (``.ulg``), ArduPilot DataFlash (``.bin``) and CSV.

* :mod:`~gap_validation.logs.base`: what every format gives (:class:`LogFile`, :class:`LogTopic`,
  :class:`WriteTopic`) and :func:`open_log`, which picks the format from the suffix;
* :mod:`~gap_validation.logs.ulog`: PX4 ULog, read and written;
* :mod:`~gap_validation.logs.dataflash`: ArduPilot DataFlash, read and written;
* :mod:`~gap_validation.logs.csvlog`: one CSV file per topic, read and written.

Replay (:mod:`gap_validation.bag.replay`) reads them through the same router as bags. This package imports
neither rclpy nor rosbags nor matplotlib.
"""
