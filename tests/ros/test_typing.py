"""mypy strict (as configured in pyproject.toml) over the ROS layer: clm_ros and its launch files.

The configuration ([tool.mypy]) is the one CI's bare ``mypy`` uses; this test
runs it on the ROS paths only, so that the ROS tests alone catch a typing
regression there (clm_core is checked by the same configuration).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mypy")

REPO_ROOT = Path(__file__).resolve().parents[2]
CLM_ROS_SRC = REPO_ROOT / "ros2_ws" / "src" / "clm_ros"


def test_mypy_strict_clean_over_clm_ros() -> None:
    paths = [str(CLM_ROS_SRC / "clm_ros"), str(CLM_ROS_SRC / "launch")]
    proc = subprocess.run([sys.executable, "-m", "mypy", *paths], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"mypy over clm_ros failed (exit {proc.returncode}):\n{proc.stdout}\n{proc.stderr}"
    assert "Success" in proc.stdout, proc.stdout
