#!/usr/bin/env bash
# The main job of the README: set up the environment, then run the end-to-end
# demo on shipped defaults: the vehicle simulator node and the track-soil node
# as separate processes over DDS (loopback), recorded to a bag and plotted in
# results/demo/, the free-field vibration at receivers 8, 16 and 32 m from
# the track (two-step method on the demo's sleeper soil forces: PPV, KB_F,max,
# one-third-octave levels; the receiver filters are cached on disk, so a
# second run reads them back) and the rail-deflection spectra in
# results/demo/, then the frequency-domain report of every preset in
# results/report/.
#   CLM_DEMO_RECEIVERS=8,16,32 (default; empty: no receivers)
#   scripts/demo.sh [clm demo options, e.g. --duration 5]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bash "$root/scripts/bootstrap.sh"
cd "$root"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# --overwrite: results/ is regenerated on every run (the commands refuse an existing output without it)
"$root/.venv/bin/clm" demo --out results/demo --overwrite "$@"
receivers=${CLM_DEMO_RECEIVERS-8,16,32}
if [ -n "$receivers" ]; then
  "$root/.venv/bin/python" -m clm_core.outputs.demo_receivers results/demo --receivers "$receivers"
fi
"$root/.venv/bin/clm" report --out results/report --overwrite
"$root/.venv/bin/python" -m clm_core.outputs.report_index results "clm demo and report" >/dev/null
echo "demo: results in $root/results/ (index.html; demo/: bag, plots, receivers, summary.json; report/: receptances)"
