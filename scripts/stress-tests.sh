#!/usr/bin/env bash
# Flakiness measured, not hoped for: run the ROS tests N times on a clean clone and print failures per test.
#   scripts/stress-tests.sh N [pytest paths or args...]      (default paths: tests/ros)
#
# 1. clones the committed HEAD of this repository into a fresh temporary folder (no work-tree changes, no
#    caches, no venv: what a newcomer gets) and bootstraps it there (scripts/bootstrap.sh, 1-3 min);
# 2. runs the ROS part of the tests N times in a row in that clone (scripts/test.sh, CLM_TEST_PARTS=ros:
#    CLM_REQUIRE_ROS=1, DDS on loopback, one domain per test), each run with a JUnit report;
# 3. writes the per-test table to $CLM_STRESS_DIR/table.txt and prints it: every test with its passes, failures
#    (and errors), skips out of the runs and its mean and worst time, the slowest first; then the message of
#    each failure, each run's wall time, load and outcome, and the total; exit status 1 if any run failed.
# Env: CLM_STRESS_DIR (default: a new folder under ${TMPDIR:-/tmp}; kept at the end, its path printed),
# CLM_STRESS_NICE (default 10: the runs' nice level on a shared machine).
# Example (issue 21's target): scripts/stress-tests.sh 10
set -euo pipefail
if [ $# -lt 1 ] || ! [[ "$1" =~ ^[1-9][0-9]*$ ]]; then
    echo "usage: scripts/stress-tests.sh N [pytest paths or args...]   (N >= 1 runs of the ROS tests)" >&2
    exit 2
fi
runs=$1
shift
args=("$@")
[ ${#args[@]} -gt 0 ] || args=(tests/ros)
repo=$(cd "$(dirname "$0")/.." && git rev-parse --show-toplevel)
work=${CLM_STRESS_DIR:-$(mktemp -d "${TMPDIR:-/tmp}/clm-stress.XXXXXX")}
mkdir -p "$work"
clone=$work/clone
rm -rf "$clone"
git clone --quiet --no-hardlinks "$repo" "$clone"
git -C "$clone" checkout --quiet "$(git -C "$repo" rev-parse HEAD)"
echo "stress: $runs run(s) of ${args[*]} on a clean clone of $(git -C "$clone" rev-parse --short HEAD) in $clone"
cd "$clone"
if ! bash scripts/bootstrap.sh >"$work/bootstrap.log" 2>&1; then
    echo "stress: bootstrap failed; see $work/bootstrap.log" >&2
    tail -20 "$work/bootstrap.log" >&2
    exit 1
fi
failed_runs=0
: >"$work/runs.txt"
for i in $(seq 1 "$runs"); do
    t0=$(date +%s)
    set +e
    CLM_TEST_PARTS=ros nice -n "${CLM_STRESS_NICE:-10}" bash scripts/test.sh "${args[@]}" -q -p no:cacheprovider \
        --junitxml="$work/run$i.xml" >"$work/run$i.log" 2>&1
    rc=$?
    set -e
    t1=$(date +%s)
    [ "$rc" = 0 ] || failed_runs=$((failed_runs + 1))
    summary=$(tail -1 "$work/run$i.log")
    echo "run $i: exit $rc in $((t1 - t0)) s (load $(cut -d' ' -f1-3 /proc/loadavg)): $summary" | tee -a "$work/runs.txt"
done
.venv/bin/python - "$work" "$runs" <<'EOF'
"""The per-test table over the runs' JUnit reports: passes, failures, skips and times of every test."""
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

work, runs = Path(sys.argv[1]), int(sys.argv[2])
seen: dict[str, int] = defaultdict(int)
passed: dict[str, int] = defaultdict(int)
skipped: dict[str, int] = defaultdict(int)
times: dict[str, list[float]] = defaultdict(list)
bad: dict[str, list[str]] = defaultdict(list)
missing = []
for i in range(1, runs + 1):
    path = work / f"run{i}.xml"
    if not path.exists():
        missing.append(i)
        continue
    for case in ET.parse(path).getroot().iter("testcase"):
        name = f"{case.get('classname', '')}::{case.get('name', '')}"
        seen[name] += 1
        times[name].append(float(case.get("time") or 0.0))
        failed = False
        for kind in ("failure", "error"):
            el = case.find(kind)
            if el is not None:
                failed = True
                first = (el.get("message") or "").strip().splitlines()
                bad[name].append(f"run {i} {kind}: {first[0][:150] if first else ''}")
        if case.find("skipped") is not None:
            skipped[name] += 1
        elif not failed:
            passed[name] += 1
lines = [f"{'passed':>6} {'failed':>6} {'skipped':>7} {'runs':>4} {'mean s':>7} {'max s':>7}  test"]
for name in sorted(seen, key=lambda n: (-len(bad.get(n, [])), -max(times[n]))):
    t = times[name]
    lines.append(f"{passed[name]:>6} {len(bad.get(name, [])):>6} {skipped[name]:>7} {seen[name]:>4} {sum(t) / len(t):>7.1f} "
                 f"{max(t):>7.1f}  {name}")
total = sum(len(v) for v in bad.values())
lines.append(f"{sum(passed.values()):>6} {total:>6} {sum(skipped.values()):>7} {sum(seen.values()):>4} "
             f"{'':>7} {'':>7}  total: {len(seen)} test(s) x {runs} run(s)"
             + (f"; runs without a report (did not finish): {missing}" if missing else ""))
if bad:
    lines.append("")
    lines.append("failures:")
    for name in sorted(bad, key=lambda n: -len(bad[n])):
        lines.append(f"  {name}")
        lines.extend(f"    {what}" for what in bad[name])
text = "\n".join(lines) + "\n"
(work / "table.txt").write_text(text)
print(f"\nstress: per-test table ({work / 'table.txt'})")
print(text, end="")
EOF
echo "stress: $failed_runs of $runs run(s) failed; reports and logs in $work"
[ "$failed_runs" = 0 ]
