"""Launch the ``gap_validator`` node (live model validation beside the flight stack).

Usage::

    ros2 launch gap_validation validator.launch.py config_file:=/path/cfg.yaml
    ros2 launch gap_validation validator.launch.py config_file:=/path/cfg.yaml use_sim_time:=true \
        state_file:=/var/tmp/gap_state.npz

With ``use_sim_time:=true`` and ``ros2 bag play --clock BAG`` the node gives the same numbers as
``gap-validate replay BAG``. Node parameters come from ``params_file`` (default: the installed
``config/validator.params.yaml``); the launch arguments below override it.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription


def generate_launch_description():
    share = get_package_share_directory("gap_validation")
    arguments = [
        DeclareLaunchArgument(
            "config_file",
            default_value=os.path.join(share, "config", "ultrastick25e.yaml"),
            description="validation config (YAML): channels, topics and models",
        ),
        DeclareLaunchArgument(
            "params_file",
            default_value=os.path.join(share, "config", "validator.params.yaml"),
            description="node parameters (QoS, periods, thresholds)",
        ),
        DeclareLaunchArgument(
            "use_sim_time", default_value="false", description="follow /clock (ros2 bag play --clock)"
        ),
        DeclareLaunchArgument(
            "state_file", default_value="", description="checkpoint of the gathered spectra ('' = off)"
        ),
        DeclareLaunchArgument(
            "results_dir",
            default_value="",
            description="where ~/save_results writes ('' = current directory)",
        ),
        DeclareLaunchArgument(
            "node_name",
            default_value="gap_validator",
            description="node name; the statuses are named '<node_name>: <channel>'",
        ),
        DeclareLaunchArgument("namespace", default_value="", description="node namespace (e.g. /uav1)"),
        DeclareLaunchArgument("log_level", default_value="info", description="ROS log level"),
    ]
    node = Node(
        package="gap_validation",
        executable="validator_node",
        name=LaunchConfiguration("node_name"),
        namespace=LaunchConfiguration("namespace"),
        output="screen",
        emulate_tty=True,
        parameters=[
            LaunchConfiguration("params_file"),
            {
                "config_file": LaunchConfiguration("config_file"),
                "use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool),
                "state_file": LaunchConfiguration("state_file"),
                "results_dir": LaunchConfiguration("results_dir"),
            },
        ],
        arguments=["--ros-args", "--log-level", LaunchConfiguration("log_level")],
    )
    return LaunchDescription(arguments + [node])
