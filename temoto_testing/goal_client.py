#!/usr/bin/env python3
"""A move_base client that sends one goal and waits: the holder a test or a benchmark kills mid-drive.
Usage: python -m temoto_testing.goal_client X Y YAW (world frame)."""
import math
import sys

import rospy
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
from temoto_core.action_client import TrackingActionClient


def main() -> None:
    x, y, yaw = (float(v) for v in sys.argv[1:4])
    rospy.init_node('goal_client', anonymous=True)
    client = TrackingActionClient('/move_base', MoveBaseAction)
    client.wait_for_server(rospy.Duration(60))
    goal = MoveBaseGoal()
    goal.target_pose.header.frame_id = 'world'
    goal.target_pose.pose.position.x, goal.target_pose.pose.position.y = x, y
    goal.target_pose.pose.orientation.z, goal.target_pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    client.send_goal(goal)
    rospy.spin()


if __name__ == '__main__':
    main()
