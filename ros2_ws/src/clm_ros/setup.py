"""ament_python package clm_ros (built by colcon, or pip-installed into a venv).

Where things go
---------------
colcon (``colcon build``, full ROS install): the node executables in
``install/clm_ros/lib/clm_ros/`` (setup.cfg, the ament convention that
``ros2 run clm_ros track_node`` relies on), the launch files in
``share/clm_ros/launch/`` and the parameter files in ``share/clm_ros/config/``
(``ros2 launch clm_ros demo.launch.py``).

pip (the project's venv: ``pip install -e ros2_ws/src/clm_ros``, run by
scripts/bootstrap.sh): pip installs wheels and ignores setup.cfg's script
directories, so the same console scripts land in the venv's ``bin/``
(``.venv/bin/track_node``, ``vehicle_node``, ``calibration_node``). A
non-editable ``pip install`` also copies the launch and config files to
``VENV/share/clm_ros/``; the editable install does not (use
``ros2_ws/src/clm_ros/config/demo.yaml`` from the source tree). In the venv
the documented way to start a node is ``python -m clm_ros.track_node
--ros-args ...`` (also ``clm_ros.vehicle_node``, ``clm_ros.calibration_node``),
which needs no script directory at all. tests/ros/test_packaging.py checks
both layouts.
"""

from glob import glob

from setuptools import find_packages, setup

package_name = "clm_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={package_name: ["fastdds_profile.xml", "fastdds_supervisor.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", sorted(glob("launch/*.launch.py"))),
        ("share/" + package_name + "/config", sorted(glob("config/*.yaml") + glob("config/*.json"))),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="CLM maintainers",
    maintainer_email="clm-maintainers@example.org",
    description="ROS 2 nodes of the CLM railway track-soil dynamics suite",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "track_node = clm_ros.track_node:main",
            "vehicle_node = clm_ros.vehicle_node:main",
            "calibration_node = clm_ros.calibration_node:main",
            "receiver_node = clm_ros.receiver_node:main",
        ],
        # sub-commands of the core's `clm` command (clm_core.cli loads this group; the core never imports clm_ros)
        "clm.commands": [
            "bags = clm_ros.commands.bags:register",
            "demo = clm_ros.commands.demo:register",
            "fleet = clm_ros.commands.fleet:register",
            "replay = clm_ros.commands.replay:register",
            "view = clm_ros.commands.view:register",
        ],
    },
)
