"""Console script ``validator_node``: parse, start the node, spin, shut down.

Run::

    ros2 run gap_validation validator_node --ros-args -p config_file:=/path/cfg.yaml
    validator_node --ros-args -p config_file:=/path/cfg.yaml        # pip install, no colcon
    python -m gap_validation.ros.main --ros-args -p config_file:=/path/cfg.yaml

Exit status 2 on a bad config or parameter (one line on stderr), 0 after Ctrl-C or shutdown.
"""
from __future__ import annotations

from gap_validation.blas import single_threaded_blas

single_threaded_blas()  # before numpy loads (gap_validation/blas.py: measured 2x faster under load)

import argparse
import gc
import sys

from gap_validation.core.errors import GapValidationError, one_line
from gap_validation.ros.node import ValidatorNode
from gap_validation.ros.parameters import PARAMETERS

try:  # rclpy is only needed to run the node
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    _ROS_IMPORT_ERROR: ImportError | None = None
except ImportError as _err:  # pragma: no cover - exercised only without ROS 2
    rclpy = None
    _ROS_IMPORT_ERROR = _err

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    lines = "\n".join(f"  {name:<18} {p.default!r:<12} {p.description}" for name, p in PARAMETERS.items())
    return argparse.ArgumentParser(
        prog="validator_node", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="ROS 2 node gap_validator: live nu-gap validation of linear aircraft models.",
        epilog="usage: validator_node --ros-args -p config_file:=/path/cfg.yaml [-p name:=value ...]\n"
               f"parameters:\n{lines}")


def _executor(node: ValidatorNode) -> "rclpy.executors.Executor":
    """The executor the ``executor`` parameter asks for (EventsExecutor when rclpy has it)."""
    if node.get_parameter("use_sim_time").value:
        # rclpy Jazzy's EventsExecutor fires ROS-time timers wrongly when /clock drives them
        return SingleThreadedExecutor()
    if node.get_parameter("executor").value == "events":
        try:
            from rclpy.experimental import EventsExecutor

            return EventsExecutor()
        except ImportError:  # pragma: no cover - older rclpy
            node.get_logger().info("rclpy has no EventsExecutor: using the SingleThreadedExecutor")
    return SingleThreadedExecutor()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``validator_node``; returns the exit status (2: bad config or parameters)."""
    if rclpy is None:  # pragma: no cover
        print(f"validator_node: error: rclpy is not available ({_ROS_IMPORT_ERROR}); source a ROS 2 setup",
              file=sys.stderr)
        return 2
    from rclpy.utilities import remove_ros_args

    argv = list(sys.argv[1:] if args is None else args)
    extra = remove_ros_args(["validator_node", *argv])[1:]
    try:
        _parser().parse_args(extra)
    except SystemExit as exit_:
        return int(exit_.code or 0)
    rclpy.init(args=["validator_node", *argv])
    try:
        node = ValidatorNode()
    except GapValidationError as err:
        print(f"validator_node: error: {one_line(err)}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = _executor(node)
    executor.add_node(node)
    # what start-up built (modules, config, models, restored spectra) lives as long as the node: out of the
    # cyclic garbage collector's full collections, which hold the interpreter lock for as long as they take
    gc.freeze()
    try:
        while rclpy.ok():  # spin_once loop: EventsExecutor.spin() of Jazzy neither runs timers nor stops
            executor.spin_once(timeout_sec=0.5)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
