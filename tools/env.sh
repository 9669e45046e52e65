# Source this to get the uav-flock environment: the venv, the sourced native ROS 2 (if any) and the
# built workspace. Used by ./uav-flock; also handy by hand: `source tools/env.sh`.
_uav_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# shellcheck disable=SC1091
source "$_uav_root/.venv/bin/activate"
if [ -z "${ROS_DISTRO:-}" ]; then
  # The pip path: the venv is the underlay the workspace was built against.
  export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  export CMAKE_PREFIX_PATH="$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
fi
# shellcheck disable=SC1091
source "$_uav_root/ros2_ws/install/setup.bash"
export UAV_FLOCK_ROOT="$_uav_root"
unset _uav_root
# One OpenBLAS kernel on every host. numpy's and scipy's OpenBLAS picks its kernels by CPU (SkylakeX on a host
# with AVX-512, Haswell on one with AVX2 only), and the two differ in the last bits of the Fiedler value
# (scipy.linalg.eigh) that metrics.csv records, so the same run recorded different bits on two machines (the
# trajectories were the same). Haswell's kernels need AVX2; a host without it keeps its own.
if [ -z "${OPENBLAS_CORETYPE:-}" ] && grep -qw avx2 /proc/cpuinfo 2>/dev/null; then
  export OPENBLAS_CORETYPE=Haswell
fi
