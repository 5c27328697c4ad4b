"""rosbag2 files, through ``rosbags`` (the only part of the package that imports it).

* :mod:`~gap_validation.bag.reader`: open a bag (``Bag``, ``open_bag``, ``TopicInfo``), stream its records;
* :mod:`~gap_validation.bag.batches`: its records in batches (an mcap chunk at a time, sqlite3 rows many at a
  time);
* :mod:`~gap_validation.bag.salvage`: what a damaged ``.mcap`` / ``.db3`` still holds;
* :mod:`~gap_validation.bag.writer`: a simulated flight as a bag (``write_flight``);
* :mod:`~gap_validation.bag.replay`: recorded flights through the one data path into the validator.
"""

from gap_validation.core.exports import lazy_exports

#: The package's public face: name -> the module defining it (imported when the name is first used).
_PUBLIC = {
    "open_bag": "reader", "Bag": "reader", "TopicInfo": "reader", "ReplayOutcome": "replay",
    "BagReport": "replay", "is_log_source": "replay", "Damage": "salvage", "write_flight": "writer"
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
