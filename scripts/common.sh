# Shared by the scripts in this folder: paths and the ROS environment.
# shellcheck shell=bash
SLS_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# The catkin workspace lives outside the repository (SLS_WS overrides): a
# workspace inside it would link back to it (rospack then warns "File system
# loop detected") and its builds would hold second copies of the executables
# (rosrun would ask which one to run). One per clone: the folder name ends in
# a hash of the clone's path, so two clones never build each other's source.
sls_default_ws() {
  local hash
  hash="$(printf '%s' "$SLS_ROOT" | sha1sum | cut -c1-8)"
  printf '%s/structured_light_stabilizer/ws-%s-%s' "${XDG_CACHE_HOME:-$HOME/.cache}" "$(basename "$SLS_ROOT")" "$hash"
}
SLS_WS="${SLS_WS:-$(sls_default_ws)}"
case "$SLS_WS/" in
  "$SLS_ROOT"/*)
    echo "SLS_WS=$SLS_WS is inside the repository: rospack would loop through it; choose a folder outside it" >&2
    exit 1
    ;;
esac
# Debian's ROS needs Debian's python3 (a pyenv shim earlier on PATH breaks
# catkin and pluginlib's cmake: "No module named catkin_pkg"), docs/building.md.
export PATH="/usr/bin:/bin:$PATH"
export ROS_HOME="${ROS_HOME:-$SLS_WS/ros_home}"
export ROS_LOG_DIR="${ROS_LOG_DIR:-$ROS_HOME/log}"
export PYTHONDONTWRITEBYTECODE=1

sls_source_ws() {
  # setup.bash reads unset variables; do not let 'set -u' kill the caller.
  set +u
  # shellcheck disable=SC1091
  source "$SLS_WS/devel/setup.bash"
  set -u
}
