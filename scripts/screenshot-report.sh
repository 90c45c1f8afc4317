#!/usr/bin/env bash
# Render an output folder's report (DIR/index.html, clm_core.outputs.report_index) in
# headless Chromium to a PNG, to look at the page as a reader would.
#   scripts/screenshot-report.sh DIR [OUT.png] [WIDTHxHEIGHT]
# Default OUT.png: DIR/index-screenshot.png (a name the report does not list as a
# figure of the run: it starts with "index-"); default size 1400x2400 px.
# Needs the Debian package `chromium` (or CHROMIUM=/path/to/chromium). No network:
# the page is read from a file:// URL, every background service is off, and the
# profile is a fresh temporary directory removed on exit.
set -euo pipefail
usage() { echo "usage: $0 DIR [OUT.png] [WIDTHxHEIGHT]  (DIR holds index.html)" >&2; exit 2; }
[ $# -ge 1 ] && [ $# -le 3 ] || usage
dir=$1
[ -f "$dir/index.html" ] || { echo "$0: no $dir/index.html (write it: python -m clm_core.outputs.report_index $dir)" >&2; exit 2; }
out=${2:-$dir/index-screenshot.png}
size=${3:-1400x2400}
[[ $size =~ ^([0-9]+)x([0-9]+)$ ]] || { echo "$0: size '$size': expected WIDTHxHEIGHT in px, e.g. 1400x2400" >&2; exit 2; }
w=${BASH_REMATCH[1]}; h=${BASH_REMATCH[2]}
browser=${CHROMIUM:-$(command -v chromium || command -v chromium-browser || true)}
[ -n "$browser" ] || { echo "$0: chromium not found (apt-get install chromium, or set CHROMIUM)" >&2; exit 3; }
page=$(cd "$dir" && pwd)/index.html
case $out in /*) ;; *) out=$(pwd)/$out ;; esac
profile=$(mktemp -d)
trap 'rm -rf "$profile"' EXIT
rm -f "$out"
# --virtual-time-budget: let the images load before the capture
timeout 120 "$browser" --headless --no-sandbox --disable-gpu --disable-quic --no-first-run \
  --disable-background-networking --disable-component-update --disable-sync --disable-dev-shm-usage \
  --hide-scrollbars --user-data-dir="$profile" --window-size="$w,$h" --virtual-time-budget=5000 \
  --screenshot="$out" "file://$page" >"$profile/chromium.log" 2>&1 || {
    echo "$0: chromium failed; its log:" >&2; cat "$profile/chromium.log" >&2; exit 1; }
[ -s "$out" ] || { echo "$0: no screenshot written; chromium's log:" >&2; cat "$profile/chromium.log" >&2; exit 1; }
echo "$out"
