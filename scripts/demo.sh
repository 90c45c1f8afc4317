#!/usr/bin/env bash
# The main job of the README: set up the environment, then run the end-to-end
# demo on shipped defaults, leaving its outputs in results/.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bash "$root/scripts/bootstrap.sh"
cd "$root"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
exec "$root/.venv/bin/python" -m clm_core.demo "$@"
