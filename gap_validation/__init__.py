"""gap_validation: validate linear aircraft models against flight data in the nu-gap metric.

The house, by what each part depends on (docs/ARCHITECTURE.md):

* :mod:`gap_validation.core`: the math (numpy/scipy only): models and effects, metrics, margins, estimator,
  validator, diagnosis, simulation;
* :mod:`gap_validation.messages`: serialized messages to samples (fast CDR decoders, the one decoding step,
  the message router), no rclpy, no rosbags;
* :mod:`gap_validation.bag`: rosbag2 files through rosbags (reader, salvage, writer, replay of bags and logs);
* :mod:`gap_validation.logs`: PX4 ULog, ArduPilot DataFlash and CSV flight logs, read and written (no
  rosbags);
* :mod:`gap_validation.ros`: the ROS 2 node ``gap_validator`` (rclpy);
* :mod:`gap_validation.report`: figures (matplotlib), HTML report, terminal table;
* :mod:`gap_validation.cli`: ``gap-validate``;
* :mod:`gap_validation.history`, :mod:`gap_validation.cards`: validation history, test cards as YAML (configs
  are read and written by :mod:`gap_validation.core.config`, atomic writes are
  :mod:`gap_validation.core.atomic`).

Replay, node and library feed the same :class:`gap_validation.core.validator.OnlineValidator`.
"""

from gap_validation.core.exports import lazy_exports

__version__ = "0.1.0"

#: The library's front door: the core's main names (``import gap_validation as gv; gv.nugap(p1, p2)``),
#: imported when first used; everything else of the core is in :mod:`gap_validation.core`.
_PUBLIC = {
    "load_config": "gap_validation.core.config", "OnlineValidator": "gap_validation.core.validator",
    "nugap": "gap_validation.core.metrics", "epsilon": "gap_validation.core.metrics",
    "LinearModel": "gap_validation.core.models", "MimoModel": "gap_validation.core.models",
    "ValidationResult": "gap_validation.core.results", "simulate_flight": "gap_validation.core.simulation",
    "GapValidationError": "gap_validation.core.errors", "ConfigError": "gap_validation.core.errors",
    "DataError": "gap_validation.core.errors",
}
__all__ = ["__version__", *sorted(_PUBLIC)]
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
