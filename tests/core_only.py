"""pytest plugin of the core run (``scripts/test.sh``: ``-p tests.core_only``): the core tests need no ROS.

The core tests run in a venv without ROS (``.venv-core``). This plugin turns
that into a checked fact:

- at start, the ROS layer must not be importable (``clm_ros``, ``rclpy``,
  ``clm_msgs``): otherwise the run would not prove anything;
- no test under tests/ros may be collected (they belong to the ROS run);
- at the end, no ROS module may have been imported by any test (a test that
  needs ROS belongs under tests/ros).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

#: Top-level packages of the ROS layer; none may be importable in the core venv.
ROS_PACKAGES = ("clm_ros", "rclpy", "clm_msgs", "rosidl_runtime_py", "rcl_interfaces", "launch_ros")
ROS_TESTS = Path(__file__).resolve().parent / "ros"


def _importable(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def pytest_configure(config: pytest.Config) -> None:
    found = [name for name in ROS_PACKAGES if _importable(name)]
    if found:
        raise pytest.UsageError(
            f"the core run (-p tests.core_only) needs a venv without ROS, but {', '.join(found)} can be imported "
            f"from {sys.executable}; build one with CLM_SKIP_ROS=1 bash scripts/bootstrap.sh .venv-core"
        )


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    ros = sorted({str(Path(str(item.path)).relative_to(ROS_TESTS.parent.parent)) for item in items
                  if ROS_TESTS in Path(str(item.path)).resolve().parents})
    if ros:
        raise pytest.UsageError(f"the core run collected ROS tests ({', '.join(ros)}): run them in the ROS venv")


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    loaded = sorted(m for m in sys.modules if m.split(".")[0] in ROS_PACKAGES)
    if loaded:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        msg = f"core run: ROS modules were imported by a core test: {', '.join(loaded)} (move it to tests/ros)"
        if reporter is not None:
            reporter.write_line(msg, red=True)
        else:
            print(msg, file=sys.stderr)
