"""ament_python package clm_ros (built by colcon, or pip-installed into a venv)."""

from setuptools import find_packages, setup

package_name = "clm_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="CLM maintainers",
    maintainer_email="clm-maintainers@example.org",
    description="ROS 2 nodes of the CLM railway track-soil dynamics suite",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "calibration_node = clm_ros.calibration_node:main",
        ],
    },
)
