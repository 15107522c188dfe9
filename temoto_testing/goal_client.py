#!/usr/bin/env python3
"""A move_base client that sends one goal and waits: the holder a test or a benchmark kills mid-drive.
Usage: python -m temoto_testing.goal_client X Y YAW (world frame)."""
import math
import sys
import time

import rospy
from actionlib_msgs.msg import GoalStatusArray
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
from temoto_core.action_client import TrackingActionClient


def _say(line: str) -> None:
    """One whole line in one write: print() writes the text and its newline apart, and two threads' lines
    interleaved (a status line took the goal's end as its last word, in a CI run)."""
    sys.stdout.write(line + '\n')
    sys.stdout.flush()


def main() -> None:
    x, y, yaw = (float(v) for v in sys.argv[1:4])
    rospy.init_node('goal_client', anonymous=True)
    client = TrackingActionClient('/move_base', MoveBaseAction)
    client.wait_for_server(rospy.Duration(60))
    goal = MoveBaseGoal()
    goal.target_pose.header.frame_id = 'world'
    goal.target_pose.pose.position.x, goal.target_pose.pose.position.y = x, y
    goal.target_pose.pose.orientation.z, goal.target_pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    # the status as it reaches this node, a line a second: a test sees the connection carry on after a cut link
    heard = {'said': 0.0}

    def on_status(_msg) -> None:
        now = time.time()
        if now - heard['said'] >= 1.0:
            heard['said'] = now
            _say('status heard at %.3f' % now)
    rospy.Subscriber('/move_base/status', GoalStatusArray, on_status, queue_size=1)
    client.send_goal(goal, done_cb=lambda state, result: _say(
        'goal ended %s: %s' % (state, client.get_goal_status_text())))
    rospy.spin()


if __name__ == '__main__':
    main()
