#!/usr/bin/env bash
# The test command of the README: every test, each part in its own environment.
#   scripts/test.sh [pytest args...]
#
# - core part: every test outside tests/ros, in .venv-core, a venv WITHOUT ROS
#   (CLM_SKIP_ROS=1 scripts/bootstrap.sh), PYTHONPATH unset, with the plugin
#   tests/core_only.py: it fails the run if the ROS layer is importable there,
#   if a ROS test is collected, or if a test imported a ROS module.
# - ROS part: tests/ros, in .venv (clm_core + ROS 2 Jazzy wheels + clm_ros),
#   CLM_REQUIRE_ROS=1, DDS discovery on loopback only.
#
# Path arguments choose the parts (`scripts/test.sh tests/solver` runs only the
# core part and builds only .venv-core, `scripts/test.sh tests/ros/test_launcher.py`
# only the ROS part); every other argument goes to both. Each test runs once.
# Both parts run; the exit status is the first failing part's (a part that
# selects no test counts as passed when the other ran tests).
# The ROS part runs its test files on CLM_ROS_WORKERS pytest-xdist workers (default 3, one file per worker at a
# time: --dist loadfile; 1: one process). Its tests wait on discovery and other processes far more than they
# compute, and each holds its own DDS domain (tests/ros/conftest.py), so files run side by side share nothing
# (3 workers on the 2-core machine: 240 s and 82 % of both cores, 2 workers: 297-308 s; docs/ros-nodes.md). Files are
# handed out in collection order (--no-loadscope-reorder), the longest first (tests/ros/conftest.LONGEST_FILES).
# Env: CLM_TEST_PARTS (default "core ros": the parts allowed to run), CLM_CORE_VENV
# (default .venv-core), CLM_VENV (default .venv), CLM_ROS_WORKERS (default 3).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
core_venv=${CLM_CORE_VENV:-$root/.venv-core}
ros_venv=${CLM_VENV:-$root/.venv}
ros_tests="$root/tests/ros"

# pytest options whose value is the next argument (so that value is not taken for a path)
takes_value=" -k -m -p -c -o -W -r -n --basetemp --maxfail --rootdir --deselect --ignore --ignore-glob --junitxml
 --junit-xml --durations --durations-min --tb --log-level --log-cli-level --log-file --confcutdir --override-ini
 --color --import-mode --capture --timeout --junit-prefix --cov-report "

opts=() core_paths=() ros_paths=() any_path=0 expect_value=0
for arg in "$@"; do
    if [ "$expect_value" = 1 ]; then opts+=("$arg"); expect_value=0; continue; fi
    case "$arg" in
        -*=*) opts+=("$arg"); continue ;;
        -*) opts+=("$arg"); case "$takes_value" in *" $arg "*) expect_value=1 ;; esac; continue ;;
    esac
    file=${arg%%::*}
    if [ ! -e "$file" ]; then opts+=("$arg"); continue; fi  # not a path: pass it on as is
    any_path=1
    real=$(cd "$(dirname "$file")" && pwd)/$(basename "$file")
    real=${real%/.}
    case "$real/" in
        "$ros_tests"/*) ros_paths+=("$arg") ;;
        *)
            case "$ros_tests/" in
                "$real"/*) core_paths+=("$arg" "--ignore=$ros_tests"); ros_paths+=("$ros_tests") ;;  # tests, .
                *) core_paths+=("$arg") ;;
            esac ;;
    esac
done
if [ "$any_path" = 0 ]; then
    core_paths=("--ignore=$ros_tests")  # testpaths (pyproject): tests
    ros_paths=("$ros_tests")
fi
case " ${CLM_TEST_PARTS:-core ros} " in *" core "*) ;; *) core_paths=() ;; esac
case " ${CLM_TEST_PARTS:-core ros} " in *" ros "*) ;; *) ros_paths=() ;; esac
# a path like `tests` gives --ignore once per occurrence and tests/ros to the ROS part once
if [ "${#ros_paths[@]}" -gt 0 ]; then
    mapfile -t ros_paths < <(printf '%s\n' "${ros_paths[@]}" | awk '!seen[$0]++')
fi

status=() names=()
run_part() {  # name, command...
    local name=$1; shift
    echo "test.sh: $name part: ${*}"
    local t0=$SECONDS rc=0
    "$@" || rc=$?
    echo "test.sh: $name part: exit $rc after $((SECONDS - t0)) s"
    names+=("$name"); status+=("$rc")
}

if [ "${#core_paths[@]}" -gt 0 ] && { [ "$any_path" = 0 ] || printf '%s\n' "${core_paths[@]}" | grep -qv '^--ignore='; }; then
    echo "test.sh: core venv $core_venv (no ROS)"
    CLM_SKIP_ROS=1 bash "$root/scripts/bootstrap.sh" "$core_venv"
    run_part core env -u PYTHONPATH -u CLM_REQUIRE_ROS \
        "$core_venv/bin/python" -m pytest -p tests.core_only "${opts[@]}" "${core_paths[@]}"
fi

if [ "${#ros_paths[@]}" -gt 0 ]; then
    echo "test.sh: ROS venv $ros_venv"
    CLM_SKIP_ROS=0 bash "$root/scripts/bootstrap.sh" "$ros_venv"
    "$ros_venv/bin/python" -c 'import rclpy, clm_msgs.msg, clm_ros' \
        || { echo "test.sh: the ROS environment is missing from $ros_venv (scripts/setup_ros.sh $ros_venv)" >&2; exit 1; }
    export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
    export CLM_REQUIRE_ROS=${CLM_REQUIRE_ROS:-1}
    workers=${CLM_ROS_WORKERS:-3}
    case "$workers" in ''|*[!0-9]*|0) echo "test.sh: CLM_ROS_WORKERS=$workers: must be a whole number >= 1" >&2; exit 2 ;; esac
    xdist=()
    [ "$workers" -gt 1 ] && xdist=(-n "$workers" --dist loadfile --no-loadscope-reorder)
    run_part ros "$ros_venv/bin/python" -m pytest "${xdist[@]}" "${opts[@]}" "${ros_paths[@]}"
fi

if [ "${#names[@]}" = 0 ]; then echo "test.sh: no part selected (CLM_TEST_PARTS=${CLM_TEST_PARTS:-})" >&2; exit 5; fi
# exit 5 (no test selected) passes when another part ran tests
rc=0 ran=0
for s in "${status[@]}"; do [ "$s" = 0 ] && ran=1; done
for i in "${!status[@]}"; do
    s=${status[$i]}
    if [ "$s" = 5 ] && [ "$ran" = 1 ]; then continue; fi
    if [ "$s" != 0 ]; then echo "test.sh: the ${names[$i]} part failed (exit $s)" >&2; [ "$rc" = 0 ] && rc=$s; fi
done
echo "test.sh: parts ${names[*]}: exit ${status[*]}"
exit "$rc"
