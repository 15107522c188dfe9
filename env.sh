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
# rospy's logging setup builds the list of places to look for python_logging.conf with a full
# rospack crawl of ROS_PACKAGE_PATH before it looks at the first one: ~15 ms (more under load) on every
# Python node start. Name the file it would find (ROS_HOME/config first, then Debian's /etc/ros) instead.
if [ -z "${ROS_PYTHON_LOG_CONFIG_FILE:-}" ]; then
    for _temoto_log_conf in "${ROS_HOME:-$HOME/.ros}/config/python_logging.conf" \
                            "${ROS_HOME:-$HOME/.ros}/config/python_logging.yaml" /etc/ros/python_logging.conf; do
        if [ -f "$_temoto_log_conf" ]; then export ROS_PYTHON_LOG_CONFIG_FILE="$_temoto_log_conf"; break; fi
    done
    unset _temoto_log_conf
fi
unset _temoto_root
