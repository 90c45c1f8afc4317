#!/usr/bin/env bash
# The test command of the README: set up the environment, then run every test.
#   scripts/test.sh [pytest args...]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bash "$root/scripts/bootstrap.sh"
cd "$root"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export CLM_REQUIRE_ROS=${CLM_REQUIRE_ROS:-1}
exec "$root/.venv/bin/python" -m pytest "$@"
