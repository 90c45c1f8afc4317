"""What every test needs: the report rules applied to every figure a test renders.

Nothing here knows about ROS: core tests run in a venv without it
(``scripts/test.sh``, guarded by :mod:`tests.core_only`), the ROS tests'
own configuration is tests/ros/conftest.py.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def _check_every_figure() -> Iterator[None]:
    """Every figure a test renders (clm_core.outputs.plots) passes the checks of tests/outputs/figure_checks.py."""
    from clm_core.outputs import plots
    from tests.outputs.figure_checks import figure_problems, png_problems

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
