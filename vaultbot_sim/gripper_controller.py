"""The gripper's controller: a ``GripperCommand`` action, as ros_control's gripper_action_controller serves one.

- ``gripper/gripper_command`` (``control_msgs/GripperCommandAction``): ``command.position`` is the gap
  wanted between the pads (m, 0 to the stroke), ``command.max_effort`` the force allowed (N; 0: the
  gripper's own). A goal is checked before anything moves and refused with a text naming what is wrong.
  An accepted one is streamed to the motor at ``~rate`` with feedback, and ends:
  - SUCCEEDED, ``reached_goal``: within ``GOAL_TOLERANCE`` of the gap wanted, the fingers at rest;
  - SUCCEEDED, ``stalled``: the fingers stopped short of it for ``STALL_TIME_S`` (an object between the
    pads: a grasp). The controller reads its stall from the fingers' joint states, as a real one reads
    its encoders, not from the simulation's word;
  - ABORTED: neither within the stroke's time plus a second.
  A new goal preempts the one running; a cancel stops the fingers where they are, and so does the end of
  the goal's client (its process died, or it is out of reach), as the arms' manipulators do: ABORTED,
  naming it. Nothing moves for a holder that is gone (chaos, history 5: a client killed mid-stroke, and
  the fingers went on for 0.56 s).
- ``~halt_topic`` (``std_msgs/String``, the reason; none unless given: the Robot Manager gives its namespace's
  ``/<ns>/halt``): the operator's "stop". The fingers stop where they are at once, and the goal ends ABORTED
  naming the reason; a goal stamped before the last stop is refused when it arrives after it (it was on its
  way when the operator said stop);
- between goals it sends nothing: the motor holds the fingers where the last setpoint left them (its
  command timeout, ``gripper.py``, stops them if the controller dies mid-motion);
- its cable is the sim's ``gripper`` device: crash exits 1, stall silences it, action included.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Optional

import actionlib
import rospy
from control_msgs.msg import GripperCommandAction, GripperCommandFeedback, GripperCommandResult
from sensor_msgs.msg import JointState

from temoto_core import clocks, params
from temoto_core.goal_holders import GoalHolders
from temoto_core.halt import HALT_TYPE, reason_of
from temoto_core.node import init_node, ok, spin
from vaultbot_sim.cable_follower import CableFollower, fail
from vaultbot_sim.gripper import SPEED, STROKE
from vaultbot_sim.spec import GRIPPER_JOINTS
from vaultbot_sim.ticks import Ticks

RATE_HZ = 50.0
GOAL_TOLERANCE = 0.0005     # m of the gap, with the fingers at rest: stopped while moving, they stop short of it
STALL_TIME_S = 0.2          # s without the gap moving STALL_MOTION: stalled
STALL_MOTION = 0.0005       # m
DEFAULT_EFFORT = 100.0      # N, when the goal gives 0 (a 2F-85 closes with 20 to 235 N)
MAX_EFFORT = 235.0          # N


class Refused(ValueError):
    """A goal that must not run; the message names the field."""


def check_goal(position: float, max_effort: float) -> float:
    """The effort the goal runs with; raises Refused naming what is wrong."""
    if not math.isfinite(position):
        raise Refused('command.position %r is not a number of metres' % position)
    if not 0.0 <= position <= STROKE:
        raise Refused('command.position %.4f m is beyond the stroke [0, %.3f] m' % (position, STROKE))
    if not math.isfinite(max_effort) or max_effort < 0.0:
        raise Refused('command.max_effort %r must be 0 (the gripper\'s own) or a positive force in N' % max_effort)
    if max_effort > MAX_EFFORT:
        raise Refused('command.max_effort %.0f N is above the gripper\'s %.0f N' % (max_effort, MAX_EFFORT))
    return max_effort or DEFAULT_EFFORT


class GripperController:
    def __init__(self) -> None:
        self.sim_ns = rospy.resolve_name(params.text('sim_ns', 'vaultbot_sim', empty=False)).rstrip('/')
        self.rate = params.number('rate', RATE_HZ, above=0, maximum=1000)
        self.speed = params.number('speed', SPEED, above=0, maximum=SPEED)
        action = params.text('action', 'gripper/gripper_command', empty=False)
        self.lock = threading.Lock()
        self.gap: Optional[float] = None
        self.moving = 0.0                         # m/s of the gap now, from the finger joints' velocities
        self._gap_seen = threading.Event()
        self._halt: Optional[str] = None          # the operator's stop, for the goal running: its reason
        self._halted_at = rospy.Time(0)           # the last stop: a goal stamped before it is refused
        self.clocks = clocks.for_this_node()      # a station's stamps on this host's clock
        self.pub = rospy.Publisher('gripper/joint_command', JointState, queue_size=10, tcp_nodelay=True)
        self.cable = CableFollower('gripper', 'gripper: controller', self.sim_ns)
        rospy.Subscriber('joint_states', JointState, self._on_joint_states, queue_size=20, tcp_nodelay=True)
        timeout = params.number('startup_timeout', 10.0, above=0)
        if not self.cable.seen.wait(timeout) or not self._gap_seen.wait(timeout):
            fail('gripper: no device states or finger joint states after %.0f s (is vaultbot_sim running?)' % timeout)
        self.server = actionlib.SimpleActionServer(action, GripperCommandAction, self._execute, auto_start=False)
        self.holders = GoalHolders('gripper controller', None, self.server.action_server)
        halt = params.text('halt_topic', '')
        if halt:
            rospy.Subscriber(halt, HALT_TYPE, self._on_halt, queue_size=5, tcp_nodelay=True)
        self.server.start()
        rospy.loginfo('gripper: GripperCommand on %s, gap %.1f mm', rospy.resolve_name(action), 1000 * self.gap)

    @property
    def running(self) -> bool:
        return self.cable.running

    def _on_joint_states(self, msg: JointState) -> None:
        if GRIPPER_JOINTS[0] in msg.name:
            i = msg.name.index(GRIPPER_JOINTS[0])
            with self.lock:
                self.gap = 2 * msg.position[i]
                self.moving = 2 * msg.velocity[i] if len(msg.velocity) > i else 0.0
            self._gap_seen.set()

    def _on_halt(self, msg) -> None:
        """The operator's stop: the fingers stop now, not at the goal's next period; the goal ends there."""
        reason = reason_of(msg)
        active = self.server.is_active()          # asked outside self.lock: it takes the server's lock
        with self.lock:
            self._halted_at = rospy.Time.now()
            if active:
                self._halt = reason
        self.stop()
        rospy.logwarn('gripper: halted (%s)', reason)

    def _gap(self) -> float:
        with self.lock:
            return self.gap

    # --- outputs ---------------------------------------------------------------------------------------
    def send(self, gap: float) -> None:
        if not self.running:
            return
        half = self.speed / 2
        msg = JointState(name=list(GRIPPER_JOINTS), position=[gap / 2] * 2, velocity=[half] * 2)
        with self.lock:                           # never a setpoint after the operator's stop, for its goal
            if self._halt is not None:
                return
            msg.header.stamp = rospy.Time.now()
            self.pub.publish(msg)

    def stop(self) -> None:
        """The fingers stop where they are, still pressing on what they hold (velocities only, all zero)."""
        if not self.running:
            return
        msg = JointState(name=list(GRIPPER_JOINTS), velocity=[0.0, 0.0])
        msg.header.stamp = rospy.Time.now()
        self.pub.publish(msg)

    # --- the action --------------------------------------------------------------------------------------
    def _execute(self, goal) -> None:
        target, effort_limit = goal.command.position, goal.command.max_effort
        stamp = self.clocks.goal_sent(self.server.current_goal.get_goal_id(), rospy.get_time())
        with self.lock:
            self._halt = None
            halted_at = self._halted_at.to_sec()
        try:
            if stamp <= halted_at:
                raise Refused('the goal was sent %.0f ms before the operator\'s stop, which came first: not run'
                              % ((halted_at - stamp) * 1e3))
            effort = check_goal(target, effort_limit)
        except Refused as e:
            self._end(self._result(False, False, 0.0), str(e), aborted=True)
            return
        period = 1.0 / self.rate
        budget = STROKE / self.speed + 1.0
        # the goal's client, watched through its subscription to the status (``goal_holders.py``)
        goal_id = self.server.current_goal.get_goal_id().id
        self.holders.new_goal()
        ticks = Ticks(period)
        t0 = time.monotonic()
        still_since, still_gap = t0, self._gap()
        for _ in range(int(budget / period) + 2):
            if not ok():
                return
            while not self.running and ok():      # stalled: silent for the rest of its life, results included
                time.sleep(0.05)
            if self.server.is_preempt_requested():
                self.stop()
                self._end(self._result(False, False, 0.0), 'preempted: stopped at %.1f mm' % (1000 * self._gap()),
                          preempted=True)
                return
            with self.lock:
                halt, self._halt = self._halt, None
            if halt is not None:
                self.stop()
                self._end(self._result(False, False, 0.0), 'halted: %s; stopped at %.1f mm' % (halt, 1000 * self._gap()),
                          aborted=True)
                return
            gone = self.holders.gone(goal_id)
            if gone is not None:
                self.stop()
                self._end(self._result(False, False, 0.0), '%s: stopped at %.1f mm' % (gone, 1000 * self._gap()),
                          aborted=True)
                return
            self.send(target)
            gap, now = self._gap(), time.monotonic()
            with self.lock:
                at_rest = self.moving == 0.0
            if abs(gap - target) <= GOAL_TOLERANCE and at_rest:
                self.stop()
                self._end(self._result(True, False, 0.0), 'reached %.1f mm in %.2f s' % (1000 * gap, now - t0))
                return
            if abs(gap - still_gap) > STALL_MOTION:
                still_since, still_gap = now, gap
            elif now - still_since >= STALL_TIME_S:
                self.stop()
                self._end(self._result(False, True, effort), 'stalled at %.1f mm, %.1f mm short of %.1f mm: an '
                          'object between the pads' % (1000 * gap, 1000 * abs(gap - target), 1000 * target))
                return
            self.server.publish_feedback(GripperCommandFeedback(position=gap, effort=0.0, stalled=False,
                                                                reached_goal=False))
            ticks.wait()
        self.stop()
        self._end(self._result(False, False, 0.0), 'at %.1f mm, not %.1f mm, after %.1f s' % (
            1000 * self._gap(), 1000 * target, budget), aborted=True)

    def _result(self, reached: bool, stalled: bool, effort: float) -> GripperCommandResult:
        return GripperCommandResult(position=self._gap(), effort=effort, stalled=stalled, reached_goal=reached)

    def _end(self, result: GripperCommandResult, text: str, aborted: bool = False, preempted: bool = False) -> None:
        (rospy.logwarn if aborted else rospy.loginfo)('gripper: %s', text)
        if preempted:
            self.server.set_preempted(result, text)
        elif aborted:
            self.server.set_aborted(result, text)
        else:
            self.server.set_succeeded(result, text)

def main() -> None:
    init_node('gripper_controller')
    try:
        GripperController()
    except ValueError as e:          # a bad parameter: say which
        rospy.logerr('gripper_controller: %s', e)
        raise SystemExit(2)
    spin()
