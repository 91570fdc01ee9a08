# Shared by the scripts in this folder: paths and the ROS environment.
# shellcheck shell=bash
SLS_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
SLS_WS="${SLS_WS:-$SLS_ROOT/.ws}"
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
