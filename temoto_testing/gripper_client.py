#!/usr/bin/env python3
"""A GripperCommand client that sends one goal and waits: the holder a test kills mid-stroke.
Usage: python -m temoto_testing.gripper_client ACTION GAP (the action's name, the gap wanted in metres)."""
import sys

import rospy
from control_msgs.msg import GripperCommand, GripperCommandAction, GripperCommandGoal

from temoto_core.action_client import TrackingActionClient


def main() -> None:
    action, gap = sys.argv[1], float(sys.argv[2])
    rospy.init_node('gripper_client', anonymous=True)
    client = TrackingActionClient(action, GripperCommandAction)
    client.wait_for_server(rospy.Duration(60))
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=gap)))
    rospy.spin()


if __name__ == '__main__':
    main()
