#!/usr/bin/env bash
# Create or update the project's virtual environment (.venv by default):
# clm_core with its dev tools, then the ROS 2 Jazzy wheels and the clm_msgs
# interfaces (scripts/setup_ros.sh). Idempotent and quick when nothing changed.
#
#   scripts/bootstrap.sh [VENV_DIR]        (env CLM_PYTHON picks the interpreter)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
venv=${1:-${CLM_VENV:-$root/.venv}}

pick_python() {
    if [ -n "${CLM_PYTHON:-}" ]; then echo "$CLM_PYTHON"; return; fi
    # ROS 2 Jazzy wheels exist for CPython 3.10-3.13
    for p in python3.11 python3.12 python3.10 python3.13 python3; do
        if command -v "$p" >/dev/null 2>&1 && "$p" -c 'import sys; sys.exit(not ((3,10) <= sys.version_info[:2] <= (3,13)))' 2>/dev/null; then
            echo "$p"; return
        fi
    done
    echo "bootstrap: no Python 3.10-3.13 found (set CLM_PYTHON)" >&2
    exit 1
}

if [ ! -x "$venv/bin/python" ]; then
    py=$(pick_python)
    echo "bootstrap: creating $venv with $($py --version 2>&1)"
    "$py" -m venv "$venv"
fi

stamp="$venv/.clm_core.stamp"
want=$(cat "$root/pyproject.toml" | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] || ! "$venv/bin/python" -c 'import clm_core' 2>/dev/null; then
    echo "bootstrap: installing clm_core and its dependencies"
    "$venv/bin/python" -m pip install -q --upgrade pip >/dev/null 2>&1 || true
    "$venv/bin/python" -m pip install -q -e "$root[dev]" 2>&1 | grep -v -E '^WARNING: Location .* is ignored' || true
    "$venv/bin/python" -c 'import clm_core, numpy, scipy, numba, matplotlib, rosbags' \
        || { echo "bootstrap: clm_core install failed" >&2; exit 1; }
    echo "$want" > "$stamp"
fi

if [ -f "$root/scripts/setup_ros.sh" ] && [ "${CLM_SKIP_ROS:-0}" != "1" ]; then
    bash "$root/scripts/setup_ros.sh" "$venv"
    # the ROS layer (nodes, bag tools, clm replay/record/play) as an editable package
    if ! "$venv/bin/python" -c 'import clm_ros.track_node' 2>/dev/null \
        || [ ! -f "$venv/.clm_ros.stamp" ] || [ "$(cat "$venv/.clm_ros.stamp")" != "$(sha256sum "$root/ros2_ws/src/clm_ros/setup.py" | cut -d' ' -f1)" ]; then
        echo "bootstrap: installing clm_ros"
        "$venv/bin/python" -m pip install -q -e "$root/ros2_ws/src/clm_ros" 2>&1 | grep -v -E '^WARNING: Location .* is ignored' || true
        "$venv/bin/python" -c 'import clm_ros.track_node' || { echo "bootstrap: clm_ros install failed" >&2; exit 1; }
        sha256sum "$root/ros2_ws/src/clm_ros/setup.py" | cut -d' ' -f1 > "$venv/.clm_ros.stamp"
    fi
fi
