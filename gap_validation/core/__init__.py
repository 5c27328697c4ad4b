"""ROS-free core of gap_validation: models, effects, metrics, margins, estimator, validator, diagnosis.

Imports numpy and scipy only (never rclpy, rosbags or matplotlib; yaml only when a config file is read or
written), so it is usable as a plain library and testable without ROS. ``__all__`` is its public face, each
name imported when first used.
"""

from gap_validation.core.exports import lazy_exports

#: The package's public face: name -> the module defining it (imported when the name is first used).
_PUBLIC = {
    "LinearModel": "models",
    "MimoModel": "models",
    "nugap": "metrics",
    "epsilon": "metrics",
    "nugap_frequency_data": "metrics",
    "epsilon_frequency_data": "metrics",
    "chordal_distance": "metrics",
    "epsilon_per_frequency": "metrics",
    "winding_condition": "metrics",
    "margins_from_epsilon": "margins",
    "OnlineValidator": "validator",
    "ValidationResult": "results",
    "ChannelResult": "results",
    "Band": "results",
    "Candidate": "results",
    "ValidationConfig": "config",
    "ChannelConfig": "config",
    "parse_config": "config",
    "load_config": "config",
    "dump_config": "config",
    "FrequencyResponseEstimator": "estimator",
    "SpectralEstimate": "estimator",
    "analyse_channel": "diagnosis",
    "fit_effects": "fitting",
    "simulate_flight": "simulation",
    "FlightOptions": "flight_options",
    "truth_models": "simulation",
    "FrequencyData": "frd",
    "GapValidationError": "errors",
    "ConfigError": "errors",
    "DataError": "errors",
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
