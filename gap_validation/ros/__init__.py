"""The ROS 2 front end: the node ``gap_validator`` and what it needs besides rclpy.

* :mod:`~gap_validation.ros.node`: the node (parameters, timers, services, diagnostics, model update; rclpy);
* :mod:`~gap_validation.ros.topics`: the node's subscriptions (types and QoS following the graph) and the
  taking of their messages through the decoding step into the router (rclpy);
* :mod:`~gap_validation.ros.excitation`: the test card (``~/plan``) and, with ``excitation_enabled``, its
  injection (``~/excite``, ``~/abort``, the offsets' publishers and timer; rclpy);
* :mod:`~gap_validation.ros.injection`: where each channel's offset goes, and the samples (no rclpy);
* :mod:`~gap_validation.ros.jobs`: the node's files: resume from a checkpoint, checkpoints and
  ``~/save_results`` written off the executor and answered when done (rclpy);
* :mod:`~gap_validation.ros.collaborators`: what the node lends those three components (parameters, log-once,
  clock, flush, the executor's wait set), so none of them reads the node's private names;
* :mod:`~gap_validation.ros.intake`: queues drained in one wake-up, QoS matched to the publishers;
* :mod:`~gap_validation.ros.background`: the slow writes on snapshots, in a thread or a child process;
* :mod:`~gap_validation.ros.main`: the console script ``validator_node``;
* :mod:`~gap_validation.ros.parameters`: the node's parameters, their documentation and checks;
* :mod:`~gap_validation.ros.status`: one diagnostic task per channel and the status wording;
* :mod:`~gap_validation.ros.plots`: the plottable topics, ``~/<channel>/frequency_response`` and
  ``~/<channel>/verdict`` (rclpy; docs/NODE_TOPICS.md);
* :mod:`~gap_validation.ros.stamp_gaps`: messages missing from a topic's stamps;
* :mod:`~gap_validation.ros.message_types`: rclpy message classes of type names, fields checked on them;
* :mod:`~gap_validation.ros.diagnosis_worker`: full diagnoses in a background thread.

Only ``node``, ``topics``, ``jobs``, ``excitation``, ``plots`` and ``main`` import rclpy; nothing here imports
rosbags (the decoding step is :mod:`gap_validation.messages`).
"""

from gap_validation.core.exports import lazy_exports

#: The package's public face: name -> the module defining it (imported when the name is first used).
_PUBLIC = {
    "ValidatorNode": "node",
    "NODE_NAME": "node",
    "PARAMETERS": "parameters",
    "check_parameters": "parameters",
    "ChannelStatus": "status",
    "channel_status": "status",
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
