"""The ROS 2 front end: the node ``gap_validator`` and what it needs besides rclpy.

* :mod:`~gap_validation.ros.node`: the node (parameters, subscriptions, timers, services; rclpy);
* :mod:`~gap_validation.ros.main`: the console script ``validator_node``;
* :mod:`~gap_validation.ros.parameters`: the node's parameters, their documentation and checks;
* :mod:`~gap_validation.ros.status`: one diagnostic task per channel and the status wording;
* :mod:`~gap_validation.ros.stamp_gaps`: messages missing from a topic's stamps;
* :mod:`~gap_validation.ros.message_types`: rclpy message classes of type names, fields checked on them;
* :mod:`~gap_validation.ros.diagnosis_worker`: full diagnoses in a background thread.

Only ``node`` and ``main`` import rclpy; nothing here imports rosbags (the decoding step is
:mod:`gap_validation.messages`).
"""
