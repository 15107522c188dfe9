#!/usr/bin/env python3
"""A MoveArm client that sends one joint goal and waits: the holder a test or a benchmark kills mid-motion.
Usage: python -m temoto_testing.arm_client ARM Q1 .. Qn [SPEED_SCALE] (the joints in the description's order;
a seventh value for a six-joint arm is the speed scale)."""
import sys

import rospy

from temoto_robot_manager.msg import MoveArmAction, MoveArmGoal
from temoto_core.action_client import TrackingActionClient


def main() -> None:
    arm, values = sys.argv[1], [float(v) for v in sys.argv[2:]]
    joints, scale = (values[:6], values[6]) if len(values) == 7 else (values, 0.0)
    rospy.init_node('arm_client', anonymous=True)
    client = TrackingActionClient('/%s/move_arm' % arm, MoveArmAction)
    client.wait_for_server(rospy.Duration(60))
    client.send_goal(MoveArmGoal(joint_positions=joints, speed_scale=scale))
    rospy.spin()


if __name__ == '__main__':
    main()
