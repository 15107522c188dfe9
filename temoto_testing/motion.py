"""Waiting on the robot's motion as the sim's ground truth tells it (``vaultbot_sim/base_state``), for tests and
benchmarks across processes."""
import sys
from typing import List

from actionlib_msgs.msg import GoalStatus

from temoto_core.wait import wait_for

GOAL_CLIENT = [sys.executable, '-m', 'temoto_testing.goal_client']     # + X Y YAW: one goal, then waits
ARM_CLIENT = [sys.executable, '-m', 'temoto_testing.arm_client']       # + ARM Q1..Q6 [SCALE]: one goal, then waits
GRIPPER_CLIENT = [sys.executable, '-m', 'temoto_testing.gripper_client']   # + ACTION GAP: one goal, then waits


def commanded_zero_after(states: List, t0: float, timeout: float):
    """The first of the latest base states stamped after ``t0`` whose commanded velocity is zero."""
    return wait_for(lambda: next((s for s in states[-20:] if s.header.stamp.to_sec() > t0
                                  and s.commanded_linear == 0.0 and s.commanded_angular == 0.0), None), timeout,
                    'the base commanded to zero')


def aborted_goal(status_arrays: List, timeout: float):
    """The first aborted goal among the latest ``move_base/status`` messages."""
    return wait_for(lambda: next((st for m in status_arrays[-3:] for st in m.status_list
                                  if st.status == GoalStatus.ABORTED), None), timeout, 'a goal aborted')
