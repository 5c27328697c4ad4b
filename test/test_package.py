"""Packaging as rosdep and ``ros2 launch`` see it: package.xml declares everything the package imports, and
the launch file parses and declares the arguments it uses (loaded with ``launch`` where it is installed)."""
from __future__ import annotations

import ast
import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "launch" / "validator.launch.py"

#: Python top-level module -> its rosdep key (ROS packages are their own keys).
ROSDEP = {"numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml",
          "matplotlib": "python3-matplotlib", "pytest": "python3-pytest", "hypothesis": "python3-hypothesis",
          "mpmath": "python3-mpmath", "xdist": "python3-pytest-xdist"}
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "launch", "launch_ros", "ament_index_python", "diagnostic_msgs",
                "sensor_msgs", "std_msgs", "std_srvs", "geometry_msgs", "rosgraph_msgs"}
#: No rosdep key (or none for the extra used): installed with pip, as the README says.
PIP_ONLY = {"rosbags": "pip install rosbags", "distributed": "dask[distributed]",
            "cloudpickle": "dask[distributed]", "jsbsim": "pip install jsbsim",
            "mcap": "pip install mcap", "pyulog": "pip install pyulog", "pymavlink": "pip install pymavlink"}
NO_LAUNCH = ("ROS 2's launch / launch_ros packages are not installed (no `ros2 launch` here); "
             "test_launch_file_parses_and_declares_every_argument_it_uses checks the file without them")
#: Message packages the node imports by name (``message_types.message_class``) for the default topic types.
BY_NAME = {"sensor_msgs", "std_msgs"}


def _imports(paths) -> set[str]:
    found = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module.split(".")[0])
    local = (
        {p.stem for p in (ROOT / "test").glob("*.py")}
        | {p.stem for p in (ROOT / "benchmarks").glob("*.py")}
        # the suite's own modules, and the benchmarks it runs a case of
        | {"gap_validation"}
    )
    return {m for m in found if m not in sys.stdlib_module_names and m not in local and not m.startswith("_")}


def _declared(*tags: str) -> set[str]:
    root = ET.parse(ROOT / "package.xml").getroot()
    return {e.text.strip() for tag in tags for e in root.iter(tag)}


def _key(module: str) -> str:
    if module in ROSDEP:
        return ROSDEP[module]
    assert module in ROS_PACKAGES or module in PIP_ONLY, (
        f"import of {module}: add its rosdep key to test_package.py (ROSDEP / ROS_PACKAGES) and to "
        "package.xml"
    )
    return module


def test_package_xml_declares_everything_the_package_imports():
    runtime = _imports([*(ROOT / "gap_validation").rglob("*.py"), LAUNCH]) | BY_NAME
    declared = _declared("exec_depend", "depend")
    missing = sorted(_key(m) for m in runtime if m not in PIP_ONLY and _key(m) not in declared)
    assert not missing, f"package.xml lacks <exec_depend> for {missing}"
    tests = _imports(ROOT.glob("test/*.py"))
    declared_tests = declared | _declared("test_depend")
    missing = sorted(_key(m) for m in tests if m not in PIP_ONLY and _key(m) not in declared_tests)
    assert not missing, f"package.xml lacks <test_depend> for {missing}"
    readme = (ROOT / "README.md").read_text()
    for module, command in PIP_ONLY.items():
        assert module in runtime | tests, f"{module} is no longer imported: drop it from PIP_ONLY"
        assert command in readme, f"README must say how {module} is installed ({command})"


def _launch_tree():
    tree = ast.parse(LAUNCH.read_text(), str(LAUNCH))
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]
    declared = {c.args[0].value for c in calls if c.func.id == "DeclareLaunchArgument"}
    used = {c.args[0].value for c in calls if c.func.id == "LaunchConfiguration"}
    nodes = [c for c in calls if c.func.id == "Node"]
    return tree, declared, used, nodes


def test_launch_file_parses_and_declares_every_argument_it_uses():
    from gap_validation.ros.parameters import PARAMETERS

    tree, declared, used, nodes = _launch_tree()
    assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description" for n in tree.body)
    assert used <= declared, f"LaunchConfiguration without DeclareLaunchArgument: {sorted(used - declared)}"
    assert {"config_file", "params_file", "use_sim_time", "node_name", "namespace"} <= declared
    (node,) = nodes
    keywords = {k.arg: k.value for k in node.keywords}
    assert ast.literal_eval(keywords["package"]) == "gap_validation"
    assert ast.literal_eval(keywords["executable"]) == "validator_node"
    overrides = [d for d in ast.walk(keywords["parameters"]) if isinstance(d, ast.Dict)]
    names = {k.value for d in overrides for k in d.keys}
    assert names <= set(PARAMETERS) | {"use_sim_time"}, (
        f"not node parameters: {sorted(names - set(PARAMETERS))}"
    )


def test_launch_file_loads_with_launch(tmp_path, monkeypatch):
    """Where ``launch`` is installed (a ROS 2 install; not pip's ROS here), the description is built for
    real."""
    launch = pytest.importorskip("launch", reason=NO_LAUNCH)
    # the repository's launch/ folder, seen as a namespace package
    if not hasattr(launch, "LaunchDescription"):
        pytest.skip(NO_LAUNCH)
    pytest.importorskip("launch_ros", reason=NO_LAUNCH)
    index = tmp_path / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    (index / "gap_validation").write_text("")
    monkeypatch.setenv(
        "AMENT_PREFIX_PATH", f"{tmp_path}{os.pathsep}{os.environ.get('AMENT_PREFIX_PATH', '')}"
    )
    from launch.launch_description_sources import get_launch_description_from_python_launch_file

    description = get_launch_description_from_python_launch_file(str(LAUNCH))
    names = {argument.name for argument in description.get_launch_arguments()}
    assert names == _launch_tree()[1]


def test_run_tests_runs_what_its_arguments_say():
    """``scripts/run-tests test/test_x.py`` runs that file only (it used to append the whole test folder)."""
    import subprocess

    proc = subprocess.run(
        [
            "bash",
            str(ROOT / "scripts" / "run-tests"),
            "--collect-only",
            "-q",
            "--noconftest",
            "test/test_layouts.py",
        ],
        cwd=ROOT,
        env=dict(os.environ),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    ids = [line for line in proc.stdout.splitlines() if "::" in line]
    assert ids and all(line.startswith("test/test_layouts.py::") for line in ids), proc.stdout[-2000:]
