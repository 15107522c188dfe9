# Source this file to get a shell where Debian's ROS tools (rostopic, rosservice,
# rosmsg, rosrun, roslaunch) and the venv see the project's packages and types:
#   source env.sh
# It does not start a master; ROS_MASTER_URI keeps whatever value it has.
_temoto_root="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)"
export TEMOTO_ROOT="$_temoto_root"
export ROS_PACKAGE_PATH="$_temoto_root:$_temoto_root/build/ros_shims${ROS_PACKAGE_PATH:+:$ROS_PACKAGE_PATH}"
export PYTHONPATH="$_temoto_root${PYTHONPATH:+:$PYTHONPATH}"
export PATH="$_temoto_root/.venv/bin${PATH:+:$PATH}"
export ROS_HOSTNAME="${ROS_HOSTNAME:-127.0.0.1}"
export ROS_MASTER_URI="${ROS_MASTER_URI:-http://127.0.0.1:11311}"
unset _temoto_root
