"""The gripper node: the gripper's command gate, between its clients and its controller.

Before it, a client's ``GripperCommand`` goal went straight to the controller, and every stop of the fingers (the
operator's halt, a client that died) was the controller's own: on a real gripper, a driver that knows nothing of
TeMoto, nothing would have stopped them. Here, as for the base and each arm, one gate (``command_gate.py``) is the
only writer of the gripper's commands, and the stops are the stack's:

- ``~action`` (``control_msgs/GripperCommandAction``, default ``gripper/command``): a goal is checked (its fields,
  its stamp against the operator's last stop, the Robot Manager's presence) and *rejected* naming what is wrong;
  an accepted one is the gate's ``goal`` input, sent on to the controller (the description's ``action``), whose
  result it passes on. A new goal preempts; a cancel stops the fingers where they are;
- the operator's stop (``~halt_topic``): the controller's goal is cancelled (the fingers stop, still pressing on
  what they hold), the goal ends ABORTED naming the reason, and a goal stamped before the stop that arrives after
  it is rejected;
- the goal's client gone (its process died, or it is out of reach: ``goal_holders.py``), or the Robot Manager
  that started this node: the controller's goal is cancelled, the goal ends ABORTED naming it;
- the controller gone (its action's status connection ends): the goal ends ABORTED, ``the gripper's controller
  is gone``; nothing resumes by itself when it comes back;
- ``gripper/motion_status`` (``temoto_core/MotionStatus``, latched): the gate's state and reason when they change.

Private parameters: ``~description``, ``~robot``, ``~owner_topic`` (the Robot Manager's latched topic),
``~halt_topic`` (default ``/temoto/halt``), ``~action``, ``~startup_timeout`` (s, default 30).
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Optional

import actionlib
import rospy
from actionlib_msgs.msg import GoalStatus, GoalStatusArray
from control_msgs.msg import GripperCommandAction, GripperCommandResult
from std_msgs.msg import String

from temoto_core import clocks, params
from temoto_core.action_client import TrackingActionClient
from temoto_core.goal_holders import GoalHolders
from temoto_core.halt import HALT_TYPE, halt_topic, reason_of
from temoto_core.msg import MotionStatus
from temoto_core.node import ok, run_node, stop_requested
from temoto_core.rospy_internals import wait_sent
from temoto_robot_manager import command_gate
from temoto_robot_manager.command_gate import CommandGate, Input
from temoto_robot_manager.description import described_robot
from temoto_robot_manager.guards import StopCode, StopReason

WATCH_PERIOD_S = 0.02        # between two looks at the goal's holders and the controller (50 Hz)
LAST_WORDS_S = 1.0           # a stopped node's goal end, sent before rospy shuts down (node.py's grace: 2 s)


@dataclass(frozen=True)
class Goal:
    """The gate's command: a client's goal, to be sent on to the controller."""
    goal: object
    handle: object


class GripperNode:
    def __init__(self) -> None:
        robot = described_robot(params.text('description', '', empty=False), params.text('robot', '', empty=False),
                                'gripper')
        self.gripper = robot.gripper
        self.lock = threading.Lock()
        self.clocks = clocks.for_this_node()
        self._halted_at = rospy.Time(0)           # the operator's last stop: a goal stamped before it is rejected
        self.active = None                        # the goal handle being run, and its id (read once, see below)
        self.active_id = ''
        self._sent = False                        # a goal of the controller runs for the active one
        self._controller_seen = False
        self.pub_motion = rospy.Publisher('gripper/motion_status', MotionStatus, queue_size=10, latch=True)
        self.gate = CommandGate('gripper', [Input('goal', 20)], [], self._write, None, self._report)
        self.controller = TrackingActionClient(self.gripper.action, GripperCommandAction)
        # the controller's status: its connection's end is how this node knows the controller is gone
        self._controller_status = rospy.Subscriber(self.gripper.action + '/status', GoalStatusArray,
                                                   lambda _m: None, queue_size=1)
        rospy.Subscriber(params.text('halt_topic', halt_topic('temoto')), HALT_TYPE, self._on_halt, queue_size=5,
                         tcp_nodelay=True)
        owner_topic = params.text('owner_topic', '')
        owner = rospy.Subscriber(owner_topic, String, lambda _m: None, queue_size=1) if owner_topic else None
        timeout = params.number('startup_timeout', 30.0, above=0)
        if not self.controller.wait_for_server(rospy.Duration(timeout)):
            raise ValueError('no gripper controller on %s' % rospy.resolve_name(self.gripper.action))
        action = params.text('action', 'gripper/command', empty=False)
        self.server = actionlib.ActionServer(action, GripperCommandAction, self._on_goal, self._on_cancel,
                                             auto_start=False)
        self.holders = GoalHolders('gripper', owner, self.server)
        if owner is not None and not self.holders.wait_for_owner(timeout):
            rospy.logwarn('gripper: the Robot Manager\'s topic %s never reached this node: its goals are taken as '
                          'no manager\'s', owner.resolved_name)
        self.server.start()
        rospy.loginfo('gripper: goals on %s, sent on to %s', rospy.resolve_name(action),
                      rospy.resolve_name(self.gripper.action))

    # -- goals -----------------------------------------------------------------------------------------------------
    def _on_goal(self, handle) -> None:
        now = time.monotonic()
        goal = handle.get_goal()
        goal_id = handle.get_goal_id().id
        stamp = self.clocks.goal_sent(handle.get_goal_id(), rospy.get_time())
        why = self._refusal(goal, stamp)
        if why is None:
            with self.lock:
                try:
                    self.gate.offer('goal', Goal(goal, handle), now, why='moving the fingers')
                except command_gate.Refused as err:          # the operator's stop came while it was checked
                    why = 'goal_id.stamp: %s' % err
                else:
                    previous, self.active, self.active_id = self.active, handle, goal_id
                    self.holders.new_goal()
        if why is not None:
            rospy.logwarn('gripper: goal %s rejected: %s', goal_id, why)
            handle.set_rejected(GripperCommandResult(), why)
            return
        if previous is not None:
            previous.set_canceled(GripperCommandResult(), 'preempted by goal %s' % goal_id)
        handle.set_accepted('moving the fingers to %.1f mm' % (1000 * goal.command.position))

    def _refusal(self, goal, stamp: float) -> Optional[str]:
        """Why a goal must not run, naming the field; None when it may."""
        halted = self._halted_at.to_sec()
        if stamp <= halted:                       # on its way when the operator said stop: overtaken by the stop
            return 'goal_id.stamp: sent %.0f ms before the operator\'s stop, which came first' % ((halted - stamp) * 1e3)
        away = self.holders.owner_away()
        if away is not None:
            return away
        position, effort = goal.command.position, goal.command.max_effort
        if not (math.isfinite(position) and position >= 0.0):
            return 'command.position %r must be a gap of 0 m or more' % position
        if not (math.isfinite(effort) and effort >= 0.0):
            return 'command.max_effort %r must be 0 (the gripper\'s own) or a positive force in N' % effort
        return None

    def _on_cancel(self, handle) -> None:
        goal_id = handle.get_goal_id().id
        with self.lock:
            if self.active is None or self.active_id != goal_id:
                return
            self.active = None
            self.gate.release('goal', StopReason(StopCode.ENDED, 'canceled: the fingers stop where they are'))
        handle.set_canceled(GripperCommandResult(), 'canceled: the fingers stop where they are')

    def _on_halt(self, msg) -> None:
        reason = reason_of(msg)
        with self.lock:
            self._halted_at = rospy.Time.now()
            halted, self.active = self.active, None
            self.gate.stop(StopReason(StopCode.HALTED, 'halted: %s' % reason), time.monotonic())
        if halted is not None:
            text = 'halted: %s; the fingers stop where they are' % reason
            halted.set_aborted(GripperCommandResult(), text)
        rospy.logwarn('gripper: halted (%s)', reason)

    def _done(self, handle, state: int, result) -> None:
        """The controller ended the goal it ran for ``handle``: its result and word passed on."""
        text = self.controller.get_goal_status_text() or 'status %d' % state
        with self.lock:
            if self.active is not handle:
                return                            # preempted, canceled, halted or orphaned already
            self.active = None
            self._sent = False                    # the controller ended it: nothing to cancel
            self.gate.release('goal', StopReason(StopCode.ENDED, text))
        result = result or GripperCommandResult()
        if state == GoalStatus.SUCCEEDED:
            handle.set_succeeded(result, text)
        else:
            handle.set_aborted(result, 'the gripper\'s controller ended the motion: %s' % text)

    def _feedback(self, handle, feedback) -> None:
        if self.active is handle:
            handle.publish_feedback(feedback)

    # -- the gate's writer and its word --------------------------------------------------------------------------
    def _write(self, command: Optional[Goal]) -> None:
        """The gate's writer (with the lock): nothing else commands the gripper. ``None`` is its zero: the
        controller's goal cancelled, and the fingers stop where they are."""
        if command is not None:
            handle = command.handle
            self.controller.send_goal(command.goal, done_cb=lambda state, result: self._done(handle, state, result),
                                      feedback_cb=lambda fb: self._feedback(handle, fb))
            self._sent = True
        elif self._sent:
            self.controller.cancel_goal()
            self._sent = False

    def _report(self, status: command_gate.Status) -> None:
        msg = MotionStatus(actuator='gripper', state=int(status.state),
                           reason=status.reason.value if status.reason else '', text=status.text)
        msg.header.stamp = rospy.Time.now()
        self.pub_motion.publish(msg)

    # -- the watch: holders and the controller ---------------------------------------------------------------------
    def spin(self) -> None:
        while not stop_requested() and ok():
            self._watch()
            time.sleep(WATCH_PERIOD_S)
        if stop_requested():
            self._stopped()
        ok()                                      # rospy is shut down here, on the main thread (temoto_core.node)

    def _watch(self) -> None:
        code = StopCode.HOLDER_GONE
        with self.lock:
            handle = self.active
            gone = self.holders.gone(self.active_id) if handle is not None else None
            if self._controller_status.get_num_connections() > 0:
                self._controller_seen = True
            elif self._controller_seen and handle is not None and gone is None:
                code, gone = StopCode.CONTROLLER_GONE, 'the gripper\'s controller is gone'
            if gone is None:
                return
            self.active = None
            self.gate.release('goal', StopReason(code, '%s: the fingers stop' % gone))
        rospy.logwarn('gripper: goal %s: %s: the fingers stop', handle.get_goal_id().id, gone)
        handle.set_aborted(GripperCommandResult(), '%s: the fingers stop where they are' % gone)

    def _stopped(self) -> None:
        """A stop signal (the ER Manager unloading this node): the goal under way ends ABORTED naming why."""
        with self.lock:
            handle, goal_id, self.active = self.active, self.active_id, None
            self.gate.stop(StopReason(StopCode.HOLDER_GONE, 'the gripper node was stopped'), time.monotonic())
        if handle is None:
            return
        why = self.holders.gone(goal_id) or 'the gripper node was stopped'
        handle.set_aborted(GripperCommandResult(), '%s: the fingers stop where they are' % why)
        if not wait_sent([self.server.status_pub, self.server.result_pub], LAST_WORDS_S):
            rospy.logwarn('gripper: the goal\'s end not sent within %.1f s of the stop', LAST_WORDS_S)


def main() -> None:
    run_node('gripper', GripperNode)
