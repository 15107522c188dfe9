#!/usr/bin/env python3
"""A move_base client that sends one goal and waits: the holder a test or a benchmark kills mid-drive.
Usage: python -m temoto_testing.goal_client X Y YAW [--raw] (world frame). ``--raw``: the goal is published on
the action's goal topic, with this node's name in its id, and the status is never subscribed to: a client
that died before its status connection was made, as the navigator sees it."""
import math
import sys
import time

import rospy
from actionlib_msgs.msg import GoalStatusArray
from move_base_msgs.msg import MoveBaseAction, MoveBaseActionGoal, MoveBaseGoal
from temoto_core.action_client import TrackingActionClient


def _say(line: str) -> None:
    """One whole line in one write: print() writes the text and its newline apart, and two threads' lines
    interleaved (a status line took the goal's end as its last word, in a CI run)."""
    sys.stdout.write(line + '\n')
    sys.stdout.flush()


def main() -> None:
    x, y, yaw = (float(v) for v in sys.argv[1:4])
    rospy.init_node('goal_client', anonymous=True)
    goal = MoveBaseGoal()
    goal.target_pose.header.frame_id = 'world'
    goal.target_pose.pose.position.x, goal.target_pose.pose.position.y = x, y
    goal.target_pose.pose.orientation.z, goal.target_pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    if '--raw' in sys.argv[4:]:
        pub = rospy.Publisher('/move_base/goal', MoveBaseActionGoal, queue_size=1, latch=True)
        msg = MoveBaseActionGoal(goal=goal)
        msg.header.stamp = msg.goal_id.stamp = rospy.Time.now()
        msg.goal_id.id = '%s-1-%.3f' % (rospy.get_name(), msg.goal_id.stamp.to_sec())
        pub.publish(msg)
        _say('goal sent raw: %s' % msg.goal_id.id)
        rospy.spin()
        return
    client = TrackingActionClient('/move_base', MoveBaseAction)
    client.wait_for_server(rospy.Duration(60))
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
