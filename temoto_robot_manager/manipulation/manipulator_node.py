"""The manipulator node: one arm's goals and servoing, for one described robot, over the arm's controller.

- ``<arm>/move_arm`` (``temoto_robot_manager/MoveArm`` action): a pose of the tool (any frame TF knows), a
  named pose of the description, or one position per joint. A goal is planned at once
  (``arm_planner.py``: IK through KDL, the way checked against the robot's own body, time-parameterised)
  and *rejected*, with its code and the field at fault, when it cannot be; nothing moves then. An
  accepted goal runs as a ``FollowJointTrajectory`` goal of the arm's controller, whose result it passes
  on (an abort says the controller's reason). A new goal preempts; a cancel holds the arm where it is;
- ``<arm>/servo_target`` (``geometry_msgs/PoseStamped``, a stream): the tool follows it (``servo.py``),
  sent to the controller's servo input as each target arrives (its latency is one step's computation),
  and at ``~servo_rate`` between targets. When the newest target is older than the arm's ``servo_timeout``
  (the description's; 0.1 s, MoveIt Servo's), or the arm's joint states are, the node sends one hold (zero
  velocities, no positions: the motors brake where the joints are) and falls silent; the controller's own
  deadman (0.1 s) would hold the arm too, one timeout later. A trajectory goal takes the arm from the stream.
  What slowed or halted the servo is said on ``<arm>/servo_status`` (``std_msgs/String``) when it changes. A hold is said twice: ``stopping: <why>``
  as it is sent, and ``holding: <why>`` once a joint state taken after it shows the arm at rest (every joint
  under ``REST_RAD_S``): a starved controller passes a hold on late, and a streamer that hands the arm on
  when it hears "holding" must not hand on an arm still braking (chaos, seed 17, step 2157);
- ``<arm>/servo_hold`` (``std_msgs/String``, the reason): hold the arm now and drop the stream's target,
  for a streamer that knows its own input is gone (a hand tracker's sample that did not come) sooner
  than the stream's timeout could tell.

A goal whose holder is gone (its client, or the Robot Manager that started this node: ``goal_holders.py``)
is cancelled at once, and the arm holds.

Private parameters: ``~description`` (a robot description file), ``~robot``, ``~arm`` (an arm of its
manipulation), ``~owner_topic`` (the Robot Manager's latched topic), ``~servo_rate`` (Hz, default 125, MoveIt Servo's),
``~halt_topic`` (default ``/temoto/halt``: the operator's "stop" aborts the goal and holds the arm; a goal
stamped before it that arrives after it is rejected).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import actionlib
import numpy as np
import rospy
import tf2_ros
from actionlib_msgs.msg import GoalStatus, GoalStatusArray
from control_msgs.msg import FollowJointTrajectoryAction, FollowJointTrajectoryGoal
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from temoto_core.action_client import TrackingActionClient
from temoto_core import clocks, params
from temoto_core.goal_holders import GoalHolders
from temoto_core.halt import HALT_TYPE, halt_topic, reason_of
from temoto_core.msg import MotionStatus
from temoto_core.node import ok, run_node, stop_requested
from temoto_core.rospy_internals import sender_of, wait_sent
from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics, KinematicsError
from temoto_robot_manager import command_gate
from temoto_robot_manager.manipulation.arm_planner import INVALID_GOAL, ArmPlanner, GoalRefused
from temoto_robot_manager.command_gate import CommandGate, Input
from temoto_robot_manager.description import described_robot
from temoto_robot_manager.guards import StopCode, StopReason
from temoto_robot_manager.msg import MoveArmAction, MoveArmFeedback, MoveArmResult
from temoto_robot_manager.navigation.obstacle_points import matrix_of_pose
from temoto_robot_manager.manipulation.self_collision import SelfCollision
from temoto_robot_manager.manipulation.world_clearance import WorldClearance
from temoto_robot_manager.manipulation.servo import WORLD_SLOW, Servo

STATE_TIMEOUT_S = 0.1        # joint states this old: where the arm is is not known, nothing is sent
REST_RAD_S = 0.01            # every joint slower than this: the arm is at rest (a braked UR5 reads about 1e-4)
LAST_WORDS_S = 1.0           # a stopped node's goal end, sent before rospy shuts down (node.py's grace: 2 s)
COLLISION_PERIOD_S = 0.04    # between two self-collision checks of the servo (25 Hz; MoveIt Servo checks at 50 Hz)


def arm_inputs(servo_timeout: float) -> Tuple[Input, Input]:
    """An arm's gate's inputs, highest first: a trajectory goal takes the arm from a servo stream (as MoveIt's
    trajectory execution and Servo: one at a time), and a stream is refused while a goal runs."""
    return Input('trajectory', 20), Input('servo', 10, servo_timeout)


@dataclass(frozen=True)
class ServoPoint:
    """One servo step for the controller's servo input, stamped with the target it was computed from."""
    positions: Sequence[float]
    velocities: Sequence[float]
    stamp: rospy.Time


@dataclass(frozen=True)
class Trajectory:
    """A trajectory goal for the controller's action, and the goal handle it runs for."""
    goal: FollowJointTrajectoryGoal
    handle: object
    duration: float


class ManipulatorNode:
    def __init__(self) -> None:
        robot = described_robot(params.text('description', '', empty=False), params.text('robot', '', empty=False),
                                'manipulation')
        name = params.text('arm', '', empty=False)
        if name not in robot.manipulation:
            raise ValueError('robot %s has no arm %r (its arms: %s)' % (robot.name, name,
                                                                       ', '.join(robot.manipulation)))
        self.arm = robot.manipulation[name]
        urdf = rospy.get_param(params.text('robot_description', 'robot_description'))
        try:
            self.kin = ArmKinematics(urdf, self.arm.base_frame, self.arm.tool_frame, self.arm.joints)
        except KinematicsError as err:
            raise ValueError('arm %s: %s' % (name, err)) from None
        reference = dict(zip(self.arm.joints, self.arm.named_poses.get('stow', [0.0] * self.kin.n)))
        self.body = SelfCollision(urdf, self.arm.joints, reference)
        # the map's obstacles, once the map comes; seen from as far as the servo slows down before them
        self.world = WorldClearance(self.arm.world_margin, reach=self.arm.world_margin + WORLD_SLOW)
        self.map_frame = ''
        self.planner = ArmPlanner(self.kin, self.arm.named_poses, self._touches, self._world_touch)
        self.servo_rate = params.number('servo_rate', 125.0, above=0, maximum=500)
        self.servo_timeout = self.arm.servo_timeout       # a target this old is not followed (the description's)
        self.servo = Servo(self.kin, 1.0 / self.servo_rate, self._body_distance, self._world_free)
        self.lock = threading.Lock()
        self.wake = threading.Condition(self.lock)     # a new servo target: step at once, not at the next tick
        self._new_target = False
        self._hold_now = ''                      # a streamer's hold, for the loop to send: the reason
        self._halted_at = rospy.Time(0)          # the operator's last stop: a target stamped before it is dropped
        self._said = None
        self.clocks = clocks.for_this_node()     # a station's stamps on this host's clock
        self._checked_at = 0.0                         # the servo's last self-collision check
        self._moved_by: Optional[str] = None           # what the last command sent moves: 'servo', 'trajectory'
        self._controller_seen = False                  # connected to the controller's status once
        self.q: Optional[List[float]] = None
        self.q_at = 0.0
        self._still_at = 0.0                     # the latest joint state that showed the arm at rest
        # the loop's own: a hold it sent and has not yet seen take effect (its reason), and when
        self._stopping = ''
        self._stop_sent_at = 0.0
        self.target: Optional[np.ndarray] = None
        self.target_at = 0.0
        self.target_stamp = rospy.Time(0)        # the target's own stamp: its servo commands carry it
        self.active = None                       # the goal handle being run
        # its id, read once as it comes: a handle's accessors take the action server's lock, which the server
        # holds while it calls _on_goal (that then takes self.lock); asked under self.lock they would deadlock
        self.active_id = ''
        self.tf = tf2_ros.Buffer(cache_time=rospy.Duration(10.0))
        self._tf_listener = tf2_ros.TransformListener(self.tf)
        self.controller = TrackingActionClient(self.arm.action, FollowJointTrajectoryAction)
        self.pub_servo = rospy.Publisher(self.arm.servo_topic, JointTrajectory, queue_size=5, tcp_nodelay=True)
        self.pub_status = rospy.Publisher('%s/servo_status' % name, String, queue_size=5, latch=True)
        self.pub_motion = rospy.Publisher('%s/motion_status' % name, MotionStatus, queue_size=10, latch=True)
        # the only writer of the arm's commands (the controller's servo input and its trajectory action)
        self.gate = CommandGate(name, arm_inputs(self.servo_timeout), [], self._write, None, self._report)
        rospy.Subscriber('joint_states', JointState, self._on_joint_states, queue_size=20, tcp_nodelay=True)
        rospy.Subscriber('map', OccupancyGrid, self._on_map, queue_size=1)
        rospy.Subscriber('%s/servo_hold' % name, String, self._on_servo_hold, queue_size=5, tcp_nodelay=True)
        rospy.Subscriber('%s/servo_target' % name, PoseStamped, self._on_servo_target, queue_size=5,
                         tcp_nodelay=True)
        rospy.Subscriber(params.text('halt_topic', halt_topic('temoto')), HALT_TYPE, self._on_halt, queue_size=5,
                         tcp_nodelay=True)
        owner_topic = params.text('owner_topic', '')
        self._owner = rospy.Subscriber(owner_topic, String, lambda _m: None, queue_size=1) if owner_topic else None
        # the controller's status: its connection's end is how this node knows the controller is gone
        self._controller_status = rospy.Subscriber(self.arm.action + '/status', GoalStatusArray, lambda _m: None,
                                                   queue_size=1)
        if not self.controller.wait_for_server(rospy.Duration(params.number('startup_timeout', 30.0, above=0))):
            raise ValueError('no trajectory controller on %s' % rospy.resolve_name(self.arm.action))
        self.server = actionlib.ActionServer('%s/move_arm' % name, MoveArmAction, self._on_goal, self._on_cancel,
                                             auto_start=False)
        self.holders = GoalHolders('manipulator', self._owner, self.server)
        if not self.holders.wait_for_owner(params.number('startup_timeout', 30.0, above=0)):
            rospy.logwarn('manipulator: the Robot Manager\'s topic %s never reached this node: its goals are taken '
                          'as no manager\'s', self._owner.resolved_name)
        self.server.start()
        rospy.loginfo('manipulator: %s of %s, goals on %s, servo targets on %s', name, robot.name,
                      rospy.resolve_name('%s/move_arm' % name), rospy.resolve_name('%s/servo_target' % name))

    # -- inputs ------------------------------------------------------------------------------------------------
    def _on_joint_states(self, msg: JointState) -> None:
        pos = dict(zip(msg.name, msg.position))
        if all(j in pos for j in self.arm.joints):
            q, at = [pos[j] for j in self.arm.joints], time.monotonic()
            vel = dict(zip(msg.name, msg.velocity))
            with self.lock:
                if all(j in vel for j in self.arm.joints):
                    still = all(abs(vel[j]) < REST_RAD_S for j in self.arm.joints)
                else:                             # a driver that sends no velocities: the positions' change
                    dt = at - self.q_at
                    still = self.q is not None and dt > 0 and \
                        max(abs(a - b) for a, b in zip(q, self.q)) < REST_RAD_S * dt
                self.q, self.q_at = q, at
                if still:
                    self._still_at = at

    def _in_base(self, pose: PoseStamped) -> np.ndarray:
        """The pose as a matrix in the arm's base frame; raises GoalRefused naming the frame."""
        frame = pose.header.frame_id.strip() or self.arm.base_frame
        try:
            t = self.tf.lookup_transform(self.arm.base_frame, frame, rospy.Time(0), rospy.Duration(0.2))
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as err:
            raise GoalRefused(INVALID_GOAL, 'pose.header.frame_id %r: no transform to %s (%s)'
                              % (frame, self.arm.base_frame, err)) from None
        return matrix_of_pose(t.transform.translation, t.transform.rotation) @ matrix_of_pose(
            pose.pose.position, pose.pose.orientation)

    def _on_servo_target(self, msg: PoseStamped) -> None:
        age = 0.0
        if not msg.header.stamp.is_zero():
            wall = rospy.get_time()
            stamp = self.clocks.observe(sender_of(msg), msg.header.stamp.to_sec(), wall)
            # the stream's timeout counts from when the target was sent: over a link that was cut, TCP keeps a
            # stream's targets and delivers them seconds late, once the link is back; they are not followed
            age = max(0.0, wall - stamp)
            why = None
            if age > self.servo_timeout:
                why = 'refusing servo targets sent %.0f ms ago (more than the stream\'s %.0f ms)' % (
                    1e3 * age, 1e3 * self.servo_timeout)
            elif stamp <= self._halted_at.to_sec():
                why = 'refusing servo targets sent before the operator\'s stop'   # overtaken by it
            if why is not None:
                rospy.logwarn_throttle(1.0, 'manipulator: %s', why)
                with self.lock:
                    self.pub_status.publish(String(why))
                    self._said = why
                return
        try:
            target = self._in_base(msg)
        except (GoalRefused, ValueError) as err:
            rospy.logerr_throttle(1.0, 'manipulator: servo target refused: %s' % err)
            return
        with self.lock:
            self.target, self.target_at = target, time.monotonic() - age
            self.target_stamp = msg.header.stamp if not msg.header.stamp.is_zero() else rospy.Time.now()
            self._new_target = True
            self.wake.notify()

    def _on_servo_hold(self, msg: String) -> None:
        """Sent from the loop's thread, after any step it is computing: nothing can follow the hold."""
        with self.lock:
            self.target = None
            self._hold_now = msg.data.strip() or 'told to hold'
            self._new_target = True
            self.wake.notify()

    def _on_halt(self, msg) -> None:
        """The operator's "stop" (``temoto_core/halt.py``): the goal ends ABORTED and the controller holds the
        arm; a servo stream is held as by ``servo_hold`` (from the loop's thread)."""
        reason = reason_of(msg)
        self._halted_at = rospy.Time.now()
        with self.lock:
            halted, self.active = self.active, None
            self.target = None
            why = 'halted: %s' % reason
            streaming = self.gate.owner == 'servo'
            self.gate.stop(StopReason(StopCode.HALTED, why), time.monotonic())   # now: the loop says the rest
            if streaming:
                self._stopping, self._stop_sent_at = why, time.monotonic()
            self._hold_now = why
            self._new_target = True
            self.wake.notify()
        if halted is not None:
            text = 'halted: %s; the arm holds' % reason
            halted.set_aborted(self._result(MoveArmResult.PREEMPTED, text), text)
        rospy.logwarn('manipulator: halted (%s)', reason)

    def _touches(self, q) -> Optional[str]:
        near = self.body.nearest(dict(zip(self.arm.joints, q)), 0.0)
        return '%s touches %s' % (near.link, near.other) if near else None

    def _on_map(self, msg: OccupancyGrid) -> None:
        info = msg.info
        self.world.set_map((info.origin.position.x, info.origin.position.y), info.resolution, info.width,
                           info.height, msg.data)
        self.map_frame = msg.header.frame_id
        rospy.loginfo('manipulator: the map (%dx%d in %s) keeps %s off the world', info.width, info.height,
                      msg.header.frame_id, self.arm.name)

    def _world_touch(self, q) -> Optional[str]:
        """Why the arm at ``q`` would touch the map's obstacles, or None (no map: nothing to check against)."""
        base = self._base_in_map()
        return None if base is None else self.world.touch(self.kin.skeleton(q), base)

    def _world_free(self, q) -> Optional[Tuple[float, str]]:
        """How far the arm at ``q`` is beyond its margin from the map's obstacles, and where, when near them."""
        base = self._base_in_map()
        return None if base is None else self.world.free(self.kin.skeleton(q), base)

    def _base_in_map(self) -> Optional[np.ndarray]:
        """The arm's base in the map's frame, or None: no map yet (nothing to check against), or no transform."""
        if not self.world.known:
            return None
        try:
            t = self.tf.lookup_transform(self.map_frame, self.arm.base_frame, rospy.Time(0)).transform
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as err:
            rospy.logwarn_throttle(5.0, 'manipulator: no transform from %s to the map\'s %s: the world is not '
                                   'checked: %s', self.arm.base_frame, self.map_frame, err)
            return None
        return matrix_of_pose(t.translation, t.rotation)

    def _body_distance(self, q, margin: float) -> Optional[float]:
        near = self.body.nearest(dict(zip(self.arm.joints, q)), margin)
        return near.distance if near else None

    # -- goals -------------------------------------------------------------------------------------------------
    def _on_goal(self, handle) -> None:
        now = time.monotonic()
        goal = handle.get_goal()
        with self.lock:
            q = list(self.q) if self.q is not None and time.monotonic() - self.q_at < 1.0 else None
        stamp = self.clocks.goal_sent(handle.get_goal_id(), rospy.get_time())
        try:
            halted = self._halted_at.to_sec()
            if stamp <= halted:                   # on its way when the operator said stop: overtaken by the stop
                raise GoalRefused(INVALID_GOAL, 'goal_id.stamp: sent %.0f ms before the operator\'s stop, which '
                                  'came first' % ((halted - stamp) * 1e3))
            away = self.holders.owner_away()
            if away is not None:
                raise GoalRefused(MoveArmResult.MANAGER_AWAY, away)
            if q is None:
                raise GoalRefused(INVALID_GOAL, 'where the arm is is not known: no joint states of %s'
                                  % ', '.join(self.arm.joints))
            pose = self._in_base(goal.pose) if goal.pose.header.frame_id.strip() else None
            points = self.planner.plan(q, pose, goal.named_pose.strip(), list(goal.joint_positions),
                                       goal.speed_scale)
        except GoalRefused as err:
            rospy.logwarn('manipulator: goal %s refused: %s', handle.get_goal_id().id, err)
            handle.set_rejected(MoveArmResult(error_code=err.code, error_string=str(err), joint_positions=q or []),
                                str(err))
            return
        trajectory = FollowJointTrajectoryGoal()
        trajectory.trajectory.joint_names = list(self.arm.joints)
        for t, positions, velocities in points:
            point = JointTrajectoryPoint(positions=positions, velocities=velocities)
            point.time_from_start = rospy.Duration.from_sec(t)
            trajectory.trajectory.points.append(point)
        goal_id = handle.get_goal_id().id
        with self.lock:
            try:
                # sent to the controller by the gate: a trajectory takes the arm from the servo stream
                self.gate.offer('trajectory', Trajectory(trajectory, handle, points[-1][0]), now,
                                why='moving to the goal')
            except command_gate.Refused as err:            # the operator's stop came while it was planned
                refused = str(err)
            else:
                refused = None
                previous, self.active, self.active_id = self.active, handle, goal_id
                self.holders.new_goal()
                self.target = None
        if refused is not None:
            rospy.logwarn('manipulator: goal %s refused: %s', goal_id, refused)
            handle.set_rejected(self._result(INVALID_GOAL, 'goal_id.stamp: ' + refused), refused)
            return
        if previous is not None:
            previous.set_canceled(self._result(MoveArmResult.PREEMPTED), 'preempted by goal %s'
                                  % handle.get_goal_id().id)
        handle.set_accepted('moving %s: %.1f s' % (self.arm.name, points[-1][0]))
        rospy.loginfo('manipulator: goal %s: %d points over %.2f s sent to the controller%s', handle.get_goal_id().id,
                      len(points), points[-1][0], ' (preempting %s)' % previous.get_goal_id().id if previous else '')

    def _on_cancel(self, handle) -> None:
        goal_id = handle.get_goal_id().id        # a new handle object for the same goal
        with self.lock:
            if self.active is None or self.active_id != goal_id:
                return
            self.active = None
            # the controller holds the arm where it is
            self.gate.release('trajectory', StopReason(StopCode.ENDED, 'canceled: the arm holds where it is'))
        handle.set_canceled(self._result(MoveArmResult.PREEMPTED), 'canceled: the arm holds where it is')

    def _done(self, handle, state: int, result) -> None:
        rospy.loginfo('manipulator: goal %s: the controller ended it (status %d)', handle.get_goal_id().id, state)
        if state == GoalStatus.SUCCEEDED:
            text = 'there'
        else:
            why = (result.error_string if result is not None else '') or self.controller.get_goal_status_text() \
                or 'status %d' % state
            text = 'the arm\'s controller ended the motion: %s' % why
        with self.lock:
            if self.active is not handle:
                return                           # preempted, canceled or orphaned already
            self.active = None
            self._moved_by = None                # the controller ended it: nothing to cancel
            self.gate.release('trajectory', StopReason(StopCode.ENDED, text))
        if state == GoalStatus.SUCCEEDED:
            handle.set_succeeded(self._result(MoveArmResult.SUCCESS), text)
            return
        handle.set_aborted(self._result(MoveArmResult.CONTROLLER_FAILED, text), text)

    def _feedback(self, handle, fb, duration: float) -> None:
        if self.active is not handle:
            return
        t = fb.desired.time_from_start.to_sec() if fb.desired.time_from_start else 0.0
        handle.publish_feedback(MoveArmFeedback(fraction=min(1.0, t / duration) if duration > 0 else 1.0,
                                                joint_positions=list(fb.actual.positions)))

    def _result(self, code: int, text: str = '') -> MoveArmResult:
        with self.lock:
            q = list(self.q) if self.q is not None else []
        return MoveArmResult(error_code=code, error_string=text, joint_positions=q)

    # -- the loop: holders, the controller, and the servo stream ---------------------------------------------
    def spin(self) -> None:
        period = 1.0 / self.servo_rate
        next_at = time.monotonic()
        while not stop_requested() and ok():
            with self.wake:
                wake_at = next_at
                if self.gate.owner == 'servo':    # the stream's silence is acted on at its moment, not a tick later
                    wake_at = min(wake_at, self.target_at + self.servo_timeout + 0.0005)
                delay = wake_at - time.monotonic()
                if delay > 0 and not self._new_target:
                    self.wake.wait(delay)
                self._new_target = False
            now = time.monotonic()
            if now >= next_at:
                next_at = max(next_at + period, now)
                self._watch_goal()
            self._servo(now)
        if stop_requested():
            self._stopped()
        ok()                                      # rospy is shut down here, on the main thread (temoto_core.node)

    def _stopped(self) -> None:
        """A stop signal (the ER Manager unloading this node, most often because the manager that started it
        died): a goal under way ends ABORTED naming why, and the arm holds, before rospy shuts down; unsaid, the
        goal's client would hear nothing (as a navigator's did: CI at dda811a)."""
        with self.lock:
            handle, goal_id, self.active = self.active, self.active_id, None
            streaming = self.gate.owner == 'servo'
            self.gate.stop(StopReason(StopCode.HOLDER_GONE, 'the manipulator was stopped'), time.monotonic())
            if streaming:
                self._say('stopping: the manipulator was stopped')
        if handle is None:
            return
        why = self.holders.gone(goal_id) or 'the manipulator was stopped'
        rospy.logwarn('manipulator: goal %s: %s: the arm holds', goal_id, why)
        handle.set_aborted(self._result(MoveArmResult.PREEMPTED, why), '%s: the arm holds' % why)
        if not wait_sent([self.server.status_pub, self.server.result_pub], LAST_WORDS_S):
            rospy.logwarn('manipulator: the goal\'s end not sent within %.1f s of the stop', LAST_WORDS_S)

    def _servo(self, now: float) -> None:
        """One servo step towards the latest target, if it is fresh, the arm's state is, and no goal runs."""
        with self.lock:
            told, self._hold_now = self._hold_now, ''     # a goal running owns the arm: a hold is moot
            if self.active is not None:
                self._stopping = ''
                return
            lapsed = self.gate.enforce(now)               # the gate's own deadman, behind the target's below
            if lapsed is not None:
                self._stopping, self._stop_sent_at = lapsed.text, time.monotonic()
                self._say('stopping: %s' % lapsed.text)
            streaming = self.gate.owner == 'servo'
            target = self.target if now - self.target_at <= self.servo_timeout else None
            stamp = self.target_stamp
            q = list(self.q) if self.q is not None and now - self.q_at <= STATE_TIMEOUT_S else None
            stopped = self._stopping and self._still_at > self._stop_sent_at
            if told:
                if streaming:
                    self._hold(StopReason(StopCode.ENDED, told))
                elif self._stopping and not stopped:      # a hold on its way: said, once it took, for this reason
                    self._stopping = told
                    self._say('stopping: %s' % told)
                else:                                     # an arm the stream does not move is left alone
                    self._stopping = ''
                    self._say('holding: %s' % told)
                return
            away = self.holders.owner_away() if target is not None else None
            if target is None or q is None or away is not None:
                if streaming:
                    # the stream fell silent, the arm's state did, or the manager went: hold now, not one more
                    # deadman later (a hold needs no state: the motors brake where the joints are)
                    if target is None:
                        self._hold(StopReason(StopCode.DEADMAN, 'no target for %.1f s' % self.servo_timeout))
                    elif away is not None:
                        self._hold(StopReason(StopCode.HOLDER_GONE, away))
                    else:
                        self._hold(StopReason(StopCode.STATE_STALE, 'no joint states for %.1f s' % STATE_TIMEOUT_S))
                elif stopped:
                    self._say('holding: %s' % self._stopping)
                    self._stopping = ''
                return
        check = now - self._checked_at >= COLLISION_PERIOD_S
        if check:
            self._checked_at = now
        step = self.servo.step(q, target, check)          # outside the lock: the IK takes its time
        with self.lock:
            try:
                self.gate.offer('servo', ServoPoint(step.positions, step.velocities, stamp), now,
                                why=step.why or 'following the servo target')
            except command_gate.Refused:
                # a stop, a hold or a trajectory came while the step was computed, or a stream stopped goes on
                # (it must pause first): not sent. The hold it got is said once the arm rests
                if self._stopping and self._still_at > self._stop_sent_at:
                    self._say('holding: %s' % self._stopping)
                    self._stopping = ''
                return
            self._stopping = ''
            self._say(step.why)

    def _write(self, command) -> None:
        """The gate's writer: nothing else commands the arm. ``None`` is the gate's zero: a hold of what moves it
        (a trajectory cancelled: the controller holds; a servo stream: zero velocities, no positions, the motors
        brake where the joints are). A hold at the positions last seen would pull the arm back to them: seen up to
        ``STATE_TIMEOUT_S`` ago, of an arm still moving, or already given back to the sim's sweep (seed 17, steps
        1263 and 1509). An arm nothing here moves is left alone (its own sweep goes on)."""
        if isinstance(command, Trajectory):
            handle, duration = command.handle, command.duration
            self.controller.send_goal(command.goal, done_cb=lambda state, result: self._done(handle, state, result),
                                      feedback_cb=lambda fb: self._feedback(handle, fb, duration))
            self._moved_by = 'trajectory'
            return
        if isinstance(command, ServoPoint):
            self._publish(command.positions, command.velocities, command.stamp)
            self._moved_by = 'servo'
            return
        if self._moved_by == 'trajectory':
            self.controller.cancel_goal()
        elif self._moved_by == 'servo':
            self._publish([], [0.0] * len(self.arm.joints), rospy.Time.now())
        self._moved_by = None

    def _publish(self, positions, velocities, stamp: rospy.Time) -> None:
        """A servo command; ``stamp``: its target's (a step's), or now (a hold). A command's age from its target is
        then read end to end, by the controller or by a benchmark, and a step between targets is told from the step
        made from a new one."""
        point = JointTrajectoryPoint(positions=list(positions), velocities=list(velocities))
        msg = JointTrajectory(joint_names=list(self.arm.joints), points=[point])
        msg.header.stamp = stamp
        self.pub_servo.publish(msg)

    def _hold(self, reason: StopReason) -> None:
        """The stream's hold, through the gate (with the lock). "holding" is said by the loop once the arm is seen
        at rest after it."""
        self.gate.release('servo', reason)
        self._stopping, self._stop_sent_at = reason.text, time.monotonic()
        self._say('stopping: %s' % reason.text)

    def _report(self, status: command_gate.Status) -> None:
        """``<arm>/motion_status``: the gate says when the arm's state or its reason changes."""
        msg = MotionStatus(actuator=self.arm.name, state=int(status.state),
                           reason=status.reason.value if status.reason else '', text=status.text)
        msg.header.stamp = rospy.Time.now()
        self.pub_motion.publish(msg)

    def _watch_goal(self) -> None:
        """End the running goal at once when its holder or its controller is gone; the arm holds."""
        code = MoveArmResult.PREEMPTED
        with self.lock:
            handle = self.active
            gone = self.holders.gone(self.active_id) if handle is not None else None
            if gone is None and handle is not None:
                if self._controller_status.get_num_connections() > 0:
                    self._controller_seen = True
                elif self._controller_seen:
                    code, gone = MoveArmResult.CONTROLLER_FAILED, 'the arm\'s controller is gone'
            if gone is not None:
                self.active = None
                self.gate.release('trajectory', StopReason(
                    StopCode.CONTROLLER_GONE if code == MoveArmResult.CONTROLLER_FAILED else StopCode.HOLDER_GONE,
                    '%s: the arm holds' % gone))
        if gone is None:
            return
        rospy.logwarn('manipulator: goal %s: %s: the arm holds', handle.get_goal_id().id, gone)
        handle.set_aborted(self._result(code, gone), '%s: the arm holds' % gone)

    def _say(self, why: str) -> None:
        if why != self._said:
            self._said = why
            self.pub_status.publish(String(why or 'following'))


def main() -> None:
    run_node('manipulator', ManipulatorNode)
