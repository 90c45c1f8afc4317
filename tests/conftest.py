"""Project-wide test configuration.

``CLM_REQUIRE_ROS=1`` (set by ``scripts/test.sh``, hence by CI) turns a missing
ROS 2 environment into an error instead of skipped ROS tests: a green run
then always includes the multi-process DDS tests.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CLM_ROS_SRC = ROOT / "ros2_ws" / "src" / "clm_ros"
if str(CLM_ROS_SRC) not in sys.path:
    sys.path.insert(0, str(CLM_ROS_SRC))


def pytest_configure(config: pytest.Config) -> None:
    if os.environ.get("CLM_REQUIRE_ROS") == "1":
        try:
            import clm_msgs.msg  # noqa: F401
            import rclpy  # noqa: F401
        except ImportError as exc:
            raise pytest.UsageError(
                f"CLM_REQUIRE_ROS=1 but the ROS environment is missing ({exc}); run scripts/setup_ros.sh VENV"
            ) from exc


@pytest.fixture(autouse=True)
def _check_every_figure() -> Iterator[None]:
    """Every figure a test renders (clm_core.io.plots) passes the checks of tests/io/figure_checks.py."""
    from clm_core.io import plots
    from tests.io.figure_checks import figure_problems, png_problems

    seen: list[tuple[Path, list[str]]] = []

    def observe(fig: object, path: Path) -> None:
        seen.append((path, figure_problems(fig)))  # type: ignore[arg-type]

    plots.figure_observers.append(observe)
    try:
        yield
    finally:
        plots.figure_observers.remove(observe)
    problems = [f"{path}: {p}" for path, found in seen for p in found]
    problems += [f"{path}: {p}" for path, _ in seen if path.exists() for p in png_problems(path)]
    if problems:
        pytest.fail("figures that break the report rules:\n" + "\n".join(problems), pytrace=False)
