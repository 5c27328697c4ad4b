"""ament_python package gap_validation (also installable with plain pip)."""
from glob import glob

from setuptools import find_packages, setup

package_name = "gap_validation"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(include=["gap_validation", "gap_validation.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
    ],
    python_requires=">=3.10",
    install_requires=["numpy", "scipy", "PyYAML", "rosbags>=0.10", "matplotlib", "dask[distributed]",
                      # gap-validate linearize / simulate --jsbsim: JSBSim's nonlinear 6-DOF model; the wheel
                      # ships the aircraft (c172x, J3Cub, pa28 ...). Imported only by gap_validation.jsbsim,
                      # lazily.
                      "jsbsim>=1.2",
                      # gap-validate replay --annotate: one MCAP file Foxglove opens (rosbags writes a rosbag2
                      # directory); imported only by gap_validation.cli.annotate, lazily.
                      "mcap>=1.1",
                      # gap-validate replay FLIGHT.ulg / FLIGHT.bin: PX4's and ArduPilot's own log readers
                      # (gap_validation.logs; also the references its readers and writers are checked
                      # against).
                      "pyulog>=1.0", "pymavlink>=2.4"],
    extras_require={"test": ["pytest", "hypothesis", "pytest-xdist", "mpmath", "ruff==0.17.6"]},
    zip_safe=True,
    maintainer="gap_validation developers",
    maintainer_email="dev@gap-validation.invalid",
    description="Validate linear aircraft models against flight data in the nu-gap metric",
    license="MIT",
    entry_points={
        "console_scripts": [
            "gap-validate = gap_validation.cli.main:main",
            "validator_node = gap_validation.ros.main:main",
        ],
    },
)
