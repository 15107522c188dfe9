"""The navigator node: move_base's interface over :class:`navigator.Navigator`, for one described robot.

On the wire, as move_base is, so RViz's "2D Nav Goal" tool and any move_base client work unchanged:
- ``move_base`` (``move_base_msgs/MoveBase`` action): a goal is checked at once and *rejected*,
  with the field at fault in the status text, when it is bad; a new goal preempts the current one;
  cancel stops the robot. Feedback is the base's pose; ``move_base/distance_remaining`` says how far
  is left;
- ``move_base_simple/goal`` (``PoseStamped``): passed to the action server as move_base does;
- ``~plan`` (``nav_msgs/Path``): the current plan, for RViz;
- ``~scene`` (``visualization_msgs/MarkerArray``, latched, 5 Hz): the footprint, and the stop zone on the
  current command (``scene_markers.py``), for the operator's scene;
- ``~halt_topic`` (default ``/temoto/halt``, ``std_msgs/String``): the operator's "stop": zero at once,
  and the goal ends ABORTED with the reason (``temoto_core/halt.py``); a goal stamped before the stop that
  arrives after it (it was on its way) is rejected;
- ``~motion_status`` (``temoto_core/MotionStatus``, latched): what the base gets now, typed (idle, moving, held,
  stopped), with the rule's code (``guards.StopCode``) and the text, when that changes;
- ``teleop/cmd_vel`` (``TwistStamped``): a stream of velocity commands (the hand in navigation mode), under
  the same guards as a goal: refused while a goal drives, when late, or while the Robot Manager that
  started the node is away (the stream then stopped at once), zero while the obstacle source is
  stale, through the collision monitor, zero once the stream is silent for 0.1 s (``teleop_drive.py``).
  ``teleop/status`` (latched ``String``) says what the stream gets, when that changes (``halted: <why>``
  after the operator's stop).

In: ``map`` (latched ``OccupancyGrid``), the odometry, and one obstacle source at a time (a
``LaserScan`` or a ``PointCloud2``, told by the message's own type), named by ``~obstacle_topic`` (a
navigator started by hand) or on the latched ``~obstacle_source_topic`` (default ``~obstacle_source``: the
Robot Manager names its source there, and names it again as it fails over and back). Out: ``cmd_vel``.

A goal whose holder is gone ends at once, the robot stopped (``goal_holders.py``): a
robot must not drive for nobody. Every arm must be inside the driving outline (``guards.ArmsInEnvelope``,
from the URDF on ``~robot_description``, default ``robot_description``, and the joint states): an arm out
holds the base at zero. The odometry is guarded too (``guards.py``): stale for 3 periods of the
description's ``odom_rate``, the base is commanded zero; stale for ``odom_patience``, or its publisher (the base
controller) dead, the goal ends ABORTED naming it, and a teleop stream is stopped, so a controller that is
respawned finds nothing to drive on.

One writer commands the base: its command gate (``command_gate.py``), with the goal's input above the teleop
stream's, and the guards (the obstacle source fresh, the odometry fresh, the arms inside the outline) that every
command passes. Three threads offer it commands or zeros, all under one lock: the control loop at ``~rate``, the
stream's callback, and the deadline watch, which wakes at the stream's deadman or the source's or the odometry's
staleness and zeroes the base at that moment rather than at the next tick. So a zero is never followed by a
command decided before it. The gate says the base's state on ``~motion_status``.

Private parameters: ``~description`` (a robot description file), ``~robot`` (its robot's name),
``~obstacle_topic`` (optional), ``~obstacle_source_topic``, ``~rate`` (Hz, default 20).
"""
from __future__ import annotations

import math
import threading
import time
from typing import Optional

import actionlib
import numpy as np
import rospy
import tf2_ros
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from move_base_msgs.msg import MoveBaseAction, MoveBaseActionGoal, MoveBaseFeedback, MoveBaseResult
from nav_msgs.msg import OccupancyGrid, Odometry, Path
from sensor_msgs.msg import JointState, LaserScan, PointCloud2
from std_msgs.msg import Float32, String
from visualization_msgs.msg import MarkerArray

from temoto_core import clocks, params
from temoto_core.goal_holders import GoalHolders
from temoto_core.halt import HALT_TYPE, halt_topic, reason_of
from temoto_core.msg import MotionStatus
from temoto_core.node import ok, run_node, stop_requested
from temoto_core.rospy_internals import connection_header, live_publisher_nodes, sender_of, wait_sent
from temoto_core.serialized import header_stamp
from temoto_core.wait import wait_for
from temoto_robot_manager import command_gate
from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics, KinematicsError
from temoto_robot_manager.command_gate import CommandGate
from temoto_robot_manager.navigation.costmap import Costmap, Footprint
from temoto_robot_manager.description import described_robot
from temoto_robot_manager.navigation.global_planner import NoPath
from temoto_robot_manager.guards import ArmsInEnvelope, OdometryFresh, PublisherAlive, SourceFresh, StopCode, StopReason
from temoto_robot_manager.navigation.navigator import BadGoal, Outcome, State, described, yaw_of
from temoto_robot_manager.navigation.obstacle_points import base_points, matrix_of
from temoto_robot_manager.navigation.scene_markers import base_scene
from temoto_robot_manager.navigation.teleop_drive import Refused, TeleopDrive, base_inputs

FEEDBACK_PERIOD_S = 0.2
LAST_WORDS_S = 1.0             # a stopped navigator's goal end, sent before rospy shuts down (node.py's grace: 2 s)
SCENE_PERIOD_S = 0.2           # the footprint and stop zone redrawn (5 Hz: a display, not a control loop)


class NavigatorNode:
    def __init__(self) -> None:
        robot = described_robot(params.text('description', '', empty=False), params.text('robot', '', empty=False),
                                'navigation')
        nav = robot.navigation
        self.robot = robot
        self.odom_frame, self.base_frame = nav.odom_frame, nav.base_frame
        self.map_frame: Optional[str] = None
        self.lock = threading.Lock()
        self.wake = threading.Condition(self.lock)
        footprint = Footprint.of(nav.footprint, nav.protrusions)
        self.arms = self._arms_guard(robot, footprint)
        self.nav = described(nav, OdometryFresh(nav.odom_rate, nav.odom_patience), [self.arms])
        self.tf = tf2_ros.Buffer(cache_time=rospy.Duration(10.0))
        self._tf_listener = tf2_ros.TransformListener(self.tf)
        self.rate = params.number('rate', 20.0, above=0, maximum=200)
        self.pub_cmd = rospy.Publisher(nav.cmd_vel_topic, Twist, queue_size=5, tcp_nodelay=True)
        self.pub_plan = rospy.Publisher('~plan', Path, queue_size=1, latch=True)
        self.pub_scene = rospy.Publisher('~scene', MarkerArray, queue_size=1, latch=True)
        self.pub_status = rospy.Publisher('~motion_status', MotionStatus, queue_size=10, latch=True)
        self.commanded = (0.0, 0.0)
        self.source_topic = ''
        # the only writer of cmd_vel: every command and every zero goes through it, under self.lock
        guards = [SourceFresh(self.nav.freshness, lambda: self.source_topic)] + self.nav.guards
        self.gate = CommandGate('base', base_inputs(nav.teleop_timeout), guards, send=self._send, zero=(0.0, 0.0),
                                report=self._report)
        self._scene_at = 0.0
        self.pub_left = rospy.Publisher('move_base/distance_remaining', Float32, queue_size=5)
        self.pub_goal = rospy.Publisher('move_base/goal', MoveBaseActionGoal, queue_size=5)
        self.teleop = TeleopDrive(self.nav, nav.teleop_max_age)
        self.pub_teleop_status = rospy.Publisher('teleop/status', String, queue_size=5, latch=True)
        self._teleop_said = None
        self.active = None                      # the goal handle being driven
        # the operator's last stop (this host's wall clock): a goal stamped before it is refused. Not the teleop
        # stream's own horizon, which a lost base controller moves too
        self._halted_at = -math.inf
        self.clocks = clocks.for_this_node()     # a station's stamps on this host's clock
        # its id, read once as it comes: a handle's accessors take the action server's lock, which the server
        # holds while it calls _on_goal (that then takes self.lock); asked under self.lock they would deadlock
        self.active_id = ''
        self._source_sub = None
        self._frames = threading.Condition()    # the latest frame of the source, for the frames thread
        self._frame = None
        threading.Thread(target=self._make_obstacles, name='obstacle frames', daemon=True).start()
        self._feedback_at = 0.0
        self.server = actionlib.ActionServer('move_base', MoveBaseAction, self._on_goal, self._on_cancel,
                                             auto_start=False)
        rospy.Subscriber('map', OccupancyGrid, self._on_map, queue_size=1)
        self._odom_sub = rospy.Subscriber(nav.odom_topic, Odometry, self._on_odom, queue_size=5, tcp_nodelay=True)
        self.odom_publisher = PublisherAlive(lambda: live_publisher_nodes(self._odom_sub), 'the odometry\'s publisher')
        rospy.Subscriber('move_base_simple/goal', PoseStamped, self._on_simple_goal, queue_size=5)
        rospy.Subscriber('joint_states', JointState, self._on_joint_states, queue_size=5, tcp_nodelay=True)
        rospy.Subscriber(params.text('halt_topic', halt_topic('temoto')), HALT_TYPE, self._on_halt, queue_size=5,
                         tcp_nodelay=True)
        rospy.Subscriber('teleop/cmd_vel', TwistStamped, self._on_teleop, queue_size=5, tcp_nodelay=True)
        # the Robot Manager's latched topic: its connection is also how the navigator knows the manager lives
        self._owner = rospy.Subscriber(params.text('obstacle_source_topic', '~obstacle_source'), String,
                                       lambda msg: self.use_source(msg.data), queue_size=5)
        initial = params.text('obstacle_topic', '')
        if initial:
            self.use_source(initial)
        # move_base's server appears once a goal can be checked (the map) and planned (the pose); a client that
        # waits for the server then never sees a refusal that only says "not yet"
        try:
            wait_for(lambda: self.nav.costmap is not None and self.nav.pose is not None,
                     params.number('startup_timeout', 30.0, above=0), 'the map and the odometry')
        except TimeoutError:
            rospy.logwarn('navigator: no %s after %.0f s; serving goals anyway (each is refused until both come)',
                          'map' if self.nav.costmap is None else 'odometry', params.number('startup_timeout', 30.0))
        self.holders = GoalHolders('navigator', self._owner, self.server,
                                   fire_and_forget='move_base_simple-')
        # started by a Robot Manager (it names the topic): its connection is seen before any goal is served
        managed = rospy.has_param('~obstacle_source_topic')
        if managed and not self.holders.wait_for_owner(params.number('startup_timeout', 30.0, above=0)):
            rospy.logwarn('navigator: the Robot Manager\'s topic %s never reached this node: its goals are taken as '
                          'no manager\'s', self._owner.resolved_name)
        self.server.start()
        threading.Thread(target=self._watch_deadlines, name='deadline watch', daemon=True).start()
        rospy.loginfo('navigator: %s, footprint %s m, %s -> %s', robot.name, list(nav.footprint),
                      rospy.resolve_name('move_base'), rospy.resolve_name(nav.cmd_vel_topic))

    @staticmethod
    def _arms_guard(robot, footprint: Footprint) -> ArmsInEnvelope:
        """The guard that keeps every arm of ``robot`` inside the driving outline, from the URDF's chains."""
        arms = {}
        if robot.manipulation:
            name = params.text('robot_description', 'robot_description', empty=False)
            if not rospy.has_param(name):
                raise ValueError('no URDF on the parameter %s: the arms cannot be kept inside the outline'
                                 % rospy.resolve_name(name))
            urdf = rospy.get_param(name)
            base = robot.navigation.base_frame.rsplit('/', 1)[-1]      # a URDF's link: no TF frame prefix
            for arm in robot.manipulation.values():
                try:
                    arms[arm.name] = (arm.joints, ArmKinematics(urdf, base, arm.tool_frame.rsplit('/', 1)[-1],
                                                                arm.joints).skeleton)
                except KinematicsError as err:
                    raise ValueError('arm %s: %s' % (arm.name, err)) from None
        return ArmsInEnvelope(footprint, arms, robot.navigation.arm_inset)

    # -- inputs ------------------------------------------------------------------------------------------------
    def _on_joint_states(self, msg: JointState) -> None:
        now = time.monotonic()
        positions = dict(zip(msg.name, msg.position))
        with self.lock:
            self.arms.update(positions, now)

    def use_source(self, topic: str) -> None:
        """Take obstacles from ``topic`` from now on; until its first frame the robot does not drive."""
        topic = topic.strip()
        if not topic or topic == self.source_topic:
            return
        if self._source_sub is not None:
            self._source_sub.unregister()
        with self.lock:
            self.nav.freshness.reset()
            self.source_topic = topic
        self._source_sub = rospy.Subscriber(topic, rospy.AnyMsg, self._on_obstacles, topic, queue_size=1,
                                            tcp_nodelay=True, buff_size=2 ** 24)
        rospy.loginfo('navigator: obstacles from %s', rospy.resolve_name(topic))

    def _on_map(self, msg: OccupancyGrid) -> None:
        info = msg.info
        costmap = Costmap.from_grid((info.origin.position.x, info.origin.position.y), info.resolution,
                                    info.width, info.height, msg.data, self.nav.footprint)
        with self.lock:
            self.map_frame = msg.header.frame_id
            self.nav.set_map(costmap)
        rospy.loginfo('navigator: map %dx%d at %.2f m in %s', info.width, info.height, info.resolution,
                      msg.header.frame_id)

    def _map_from(self, frame: str) -> np.ndarray:
        """The transform from ``frame`` to the map's frame, now; raises LookupError naming the frame."""
        try:
            return matrix_of(self.tf.lookup_transform(self.map_frame, frame, rospy.Time(0)).transform)
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as err:
            raise LookupError('no transform from %r to the map\'s frame %r: %s' % (frame, self.map_frame, err))

    def _on_odom(self, msg: Odometry) -> None:
        now = time.monotonic()
        if self.map_frame is None:
            return
        try:
            m = self._map_from(msg.header.frame_id or self.odom_frame)
        except LookupError as err:
            rospy.logwarn_throttle(5.0, 'navigator: %s', err)
            return
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        x, y = (m @ np.array([p.x, p.y, 0.0, 1.0]))[:2]
        yaw = yaw_of(q.x, q.y, q.z, q.w) + math.atan2(m[1, 0], m[0, 0])
        with self.lock:
            self.nav.set_pose((float(x), float(y), math.atan2(math.sin(yaw), math.cos(yaw))), now)

    def _on_obstacles(self, raw: rospy.AnyMsg, topic: str) -> None:
        """A frame of the source: its arrival counted at once, its obstacles made on the frames thread. The
        receive thread must stay free to see every frame come: made here, a slow frame hid the ones after it
        (queue_size 1), and the period was learnt from the frames used, not the ones sent."""
        now = time.monotonic()
        if topic != self.source_topic:
            return                                  # a frame from the source just left
        with self.wake:
            self.nav.freshness.arrived(now, header_stamp(getattr(raw, '_buff', None)))
        with self._frames:
            self._frame = (raw, topic, now)
            self._frames.notify()

    def _make_obstacles(self) -> None:
        """The frames thread: the latest frame that arrived becomes the obstacles (older ones are dropped)."""
        while not rospy.is_shutdown():
            with self._frames:
                while self._frame is None and not rospy.is_shutdown():
                    self._frames.wait(0.5)
                frame, self._frame = self._frame, None
            if frame is not None:
                try:
                    self._use_frame(*frame)
                except Exception as err:        # one bad frame must not end the thread that makes obstacles
                    rospy.logerr_throttle(5.0, 'navigator: a frame of %s could not be used: %s', frame[1], err)

    def _use_frame(self, raw: rospy.AnyMsg, topic: str, now: float) -> None:
        if topic != self.source_topic:
            return
        kind = connection_header(raw).get('type', '')
        msg = {'sensor_msgs/LaserScan': LaserScan, 'sensor_msgs/PointCloud2': PointCloud2}.get(kind)
        if msg is None:
            rospy.logerr_throttle(5.0, 'navigator: %s carries %s, not a LaserScan or a PointCloud2: no obstacles '
                                  'from it' % (topic, kind))
            return
        frame = msg().deserialize(raw._buff)
        try:
            sensor = matrix_of(self.tf.lookup_transform(self.base_frame, frame.header.frame_id,
                                                        rospy.Time(0)).transform)
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as err:
            rospy.logwarn_throttle(5.0, 'navigator: %s: no transform to %s: %s', topic, self.base_frame, err)
            return
        points = base_points(frame, sensor, self.nav.footprint)
        with self.wake:
            if topic != self.source_topic:
                return                              # the source changed while this frame was made
            if isinstance(frame, LaserScan) and frame.scan_time > 0:
                self.nav.freshness.pace.declared = frame.scan_time
            self.nav.set_obstacles(points, now)
            self.wake.notify_all()

    # -- goals -------------------------------------------------------------------------------------------------
    def _on_simple_goal(self, msg: PoseStamped) -> None:
        """As move_base does: a simple goal becomes an action goal, so it has a status like any other."""
        goal = MoveBaseActionGoal()
        goal.header.stamp = rospy.Time.now()
        goal.goal_id.stamp = goal.header.stamp
        goal.goal_id.id = 'move_base_simple-%d' % time.monotonic_ns()
        goal.goal.target_pose = msg
        self.pub_goal.publish(goal)

    def _checked(self, target: PoseStamped):
        if self.map_frame is None:
            raise BadGoal('target_pose', 'no map has come yet')
        frame = target.header.frame_id.strip()
        if not frame:
            raise BadGoal('target_pose.header.frame_id', 'empty: name the goal\'s frame (%s or %s)'
                          % (self.map_frame, self.odom_frame))
        p, q = target.pose.position, target.pose.orientation
        for name, v in (('position.x', p.x), ('position.y', p.y), ('position.z', p.z)):
            if not math.isfinite(v):
                raise BadGoal('target_pose.pose.' + name, 'must be a finite number, not %r' % v)
        try:
            m = self._map_from(frame)
        except LookupError:
            raise BadGoal('target_pose.header.frame_id', 'unknown frame %r: no transform from it to %r'
                          % (frame, self.map_frame)) from None
        x, y = (m @ np.array([p.x, p.y, 0.0, 1.0]))[:2]
        rot = math.atan2(m[1, 0], m[0, 0])
        quat = (q.x, q.y, q.z, q.w)
        checked = self.nav.check(float(x), float(y), quat)
        return checked[0], checked[1], checked[2] + rot

    def _on_goal(self, handle) -> None:
        target = handle.get_goal().target_pose
        now = time.monotonic()
        away = self.holders.owner_away()
        if away is not None:
            rospy.logwarn('navigator: goal %s refused: %s', handle.get_goal_id().id, away)
            handle.set_rejected(MoveBaseResult(), away)
            return
        goal_id = handle.get_goal_id().id
        stamp = self.clocks.goal_sent(handle.get_goal_id(), rospy.get_time())
        try:
            with self.lock:
                halted = self._halted_at
                if stamp <= halted:               # on its way when the operator said stop: overtaken by the stop
                    raise BadGoal('goal_id.stamp', 'sent %.0f ms before the operator\'s stop, which came first'
                                  % ((halted - stamp) * 1e3))
                goal = self._checked(target)
                self.nav.start(goal, now)
                try:
                    # the goal has the base from now: a stream is refused, and stopped if it drove
                    self.gate.offer('goal', (0.0, 0.0), now, moving=False, why='driving to the goal')
                except command_gate.Refused as err:        # the operator's stop came while it was checked
                    self.nav.cancel()
                    raise BadGoal('goal_id', str(err)) from None
                previous, self.active, self.active_id = self.active, handle, goal_id
                self.holders.new_goal()
                path = self.nav.path
        except (BadGoal, NoPath) as err:
            rospy.logwarn('navigator: goal %s refused: %s', handle.get_goal_id().id, err)
            handle.set_rejected(MoveBaseResult(), str(err))
            return
        if previous is not None:
            previous.set_canceled(MoveBaseResult(), 'preempted by goal %s' % handle.get_goal_id().id)
        handle.set_accepted('driving to (%.2f, %.2f, %.0f deg) in %s' % (goal[0], goal[1], math.degrees(goal[2]),
                                                                       self.map_frame))
        self._publish_plan(path)
        rospy.loginfo('navigator: goal %s: to (%.2f, %.2f, %.0f deg), %d plan points', handle.get_goal_id().id,
                      goal[0], goal[1], math.degrees(goal[2]), len(path))

    def _on_cancel(self, handle) -> None:
        goal_id = handle.get_goal_id().id        # a new handle object for the same goal
        with self.lock:
            if self.active is None or self.active_id != goal_id:
                return
            self.nav.cancel()
            self.gate.release('goal', StopReason(StopCode.ENDED, 'canceled: the robot stops'))
            self.active = None
        handle.set_canceled(MoveBaseResult(), 'canceled: the robot stops')
        rospy.loginfo('navigator: goal %s canceled', handle.get_goal_id().id)

    def _on_halt(self, msg) -> None:
        """The operator's "stop" (``temoto_core/halt.py``): zero now, whoever drives; the goal ends ABORTED."""
        reason = reason_of(msg)
        with self.lock:
            self.gate.stop(StopReason(StopCode.HALTED, 'halted: %s' % reason), time.monotonic())
            self._halted_at = rospy.get_time()
            self.teleop.halt(self._halted_at)
            self._say_teleop('halted: %s' % reason)
            halted, self.active = self.active, None
            if halted is not None:
                self.nav.cancel()
        if halted is not None:
            halted.set_aborted(MoveBaseResult(), 'halted: %s' % reason)
            self._publish_plan(None)
        rospy.logwarn('navigator: halted (%s)%s', reason, ': goal %s aborted' % halted.get_goal_id().id
                      if halted is not None else '')

    def _on_teleop(self, msg: TwistStamped) -> None:
        """A command of the teleop stream: decided and sent at once, under the lock the loop and the
        staleness watch hold, so a zero decided by either is never overtaken by a command decided before it."""
        now, wall = time.monotonic(), rospy.get_time()
        stamp = self.clocks.observe(sender_of(msg), msg.header.stamp.to_sec(), wall)
        holders = getattr(self, 'holders', None)        # None until the action server starts
        away = holders.owner_away() if holders is not None else 'the navigator is still starting'
        with self.wake:
            started = self.gate.owner != 'teleop'
            try:
                if away is not None:              # as a goal is: nothing moves for a node nobody manages
                    self.gate.release('teleop', StopReason(StopCode.HOLDER_GONE, away))
                    raise Refused(away)
                decision = self.teleop.command(stamp, wall, msg.twist.linear.x, msg.twist.angular.z)
                status = self.gate.offer('teleop', (decision.linear, decision.angular), now, decision.moving,
                                         decision.held, decision.why or 'a teleop stream drives it')
            except (Refused, command_gate.Refused) as err:
                self._say_teleop('refused: %s' % err)
                self.gate.refused(StopReason(StopCode.REFUSED, 'a teleop command refused: %s' % err))
                return
            if started:
                self.wake.notify_all()         # the deadline watch now has a stream to guard
            self._say_teleop('held: %s' % status.text if status.state is command_gate.State.HELD
                             else decision.why or 'driving')

    def _report(self, status: command_gate.Status) -> None:
        """``~motion_status``: the gate says when the base's state or its reason changes (with the gate's lock)."""
        msg = MotionStatus(actuator='base', state=int(status.state), reason=status.reason.value if status.reason
                           else '', text=status.text)
        msg.header.stamp = rospy.Time.now()
        self.pub_status.publish(msg)

    def _say_teleop(self, text: str) -> None:
        """``teleop/status`` when what the stream gets changes (not at 100 Hz); called with the lock held."""
        if text != self._teleop_said:
            self._teleop_said = text
            self.pub_teleop_status.publish(String(text))
            if text.startswith('refused'):
                rospy.logwarn_throttle(2.0, 'navigator: teleop command %s', text)

    def _publish_plan(self, path: Optional[np.ndarray]) -> None:
        msg = Path()
        msg.header.stamp, msg.header.frame_id = rospy.Time.now(), self.map_frame or ''
        for x, y in (path if path is not None else []):
            pose = PoseStamped(header=msg.header)
            pose.pose.position.x, pose.pose.position.y, pose.pose.orientation.w = x, y, 1.0
            msg.poses.append(pose)
        self.pub_plan.publish(msg)

    # -- commanding the base -----------------------------------------------------------------------------------
    def _send(self, command) -> None:
        """The gate's writer: nothing else publishes ``cmd_vel``."""
        cmd = Twist()
        cmd.linear.x, cmd.angular.z = command
        self.pub_cmd.publish(cmd)
        self.commanded = command

    def _publish_scene(self, now: float) -> None:
        """The footprint and the stop zone on the last command, for the operator's scene, at ``SCENE_PERIOD_S``."""
        if now - self._scene_at < SCENE_PERIOD_S:
            return
        self._scene_at = now
        linear, angular = self.commanded
        self.pub_scene.publish(base_scene(self.nav.footprint, self.base_frame, linear, angular, rospy.Time.now(),
                                          self.nav.monitor.settings))

    def _watch_deadlines(self) -> None:
        """Zero at a deadline, not at the next tick: the teleop stream's deadman (``TELEOP_TIMEOUT_S``), and the
        obstacle source's or the odometry's staleness (3 periods + 20 ms), by the gate's own rules."""
        acted = -math.inf                            # the last deadline acted on: deadlines only move on
        with self.wake:
            while ok():
                deadlines = [self.gate.deadline()]
                if self.gate.owner is not None:
                    deadlines.append(self.nav.stop_deadline())
                due = [d for d in deadlines if d is not None and d > acted]
                now = time.monotonic()
                if not due:
                    self.wake.wait(0.5)
                    continue
                if now < min(due):
                    self.wake.wait(min(due) - now)
                    continue
                acted = now
                owner = self.gate.owner
                stopped = self.gate.enforce(now)
                if stopped is None:
                    continue
                if stopped.code is StopCode.DEADMAN:
                    self._say_teleop('stopped: %s' % stopped.text)
                    continue
                if owner == 'teleop':
                    self._say_teleop('held: %s' % stopped.text)
                rospy.logwarn('navigator: %s: stopped', stopped)

    def spin(self) -> None:
        period = 1.0 / self.rate
        next_at = time.monotonic()
        while not stop_requested() and ok():
            now = time.monotonic()
            self._watch_controller()
            gone = None
            with self.lock:
                if self.active is not None:
                    gone = self.holders.gone(self.active_id)
                    if gone is not None:
                        self.nav.cancel()
                        self.gate.release('goal', StopReason(StopCode.HOLDER_GONE, gone))
                        orphan, self.active = self.active, None
            if gone is not None:
                rospy.logwarn('navigator: goal %s: %s: the robot stops', orphan.get_goal_id().id, gone)
                orphan.set_aborted(MoveBaseResult(), '%s: the robot stopped' % gone)
                self._publish_plan(None)
            with self.lock:
                handle, was = self.active, self.nav.state
                tick = self.nav.tick(now)
                if handle is not None and tick.ending is not None:
                    self.gate.release('goal', StopReason(tick.ending.code, tick.ending.text))
                elif handle is not None:
                    self.gate.offer('goal', (tick.linear, tick.angular), now, tick.linear != 0.0 or tick.angular != 0.0,
                                    self._held(tick), 'driving to the goal')
                if tick.ending is not None:
                    self.active = None
                replanned = handle is not None and tick.ending is None and tick.state is State.DRIVING
                path = self.nav.path
                pose = self.nav.pose
            if handle is not None and tick.ending is None and tick.state is not was:
                rospy.loginfo('navigator: goal %s: %s', handle.get_goal_id().id, tick.state.value)
            if tick.ending is not None:
                self._end(handle, tick)
            elif handle is not None and now - self._feedback_at >= FEEDBACK_PERIOD_S:
                self._feedback_at = now
                self._feedback(handle, pose, tick.remaining)
                if replanned:
                    self._publish_plan(path)
            self._publish_scene(now)
            next_at += period
            delay = next_at - time.monotonic()
            if delay < 0:
                next_at = time.monotonic()
            else:
                time.sleep(delay)
        if stop_requested():
            self._stopped()
        ok()                                      # rospy is shut down here, on the main thread (temoto_core.node)

    def _watch_controller(self) -> None:
        """The odometry's publisher (the base controller) dead: the goal ends ABORTED naming it and a teleop stream
        stops, at once, before a respawned controller could take the old commands up again."""
        lost = self.odom_publisher.poll()
        if lost is None:
            return
        with self.lock:
            handle, self.active = self.active, None
            tick = self.nav.abort(lost) if handle is not None else None
            if self.gate.owner == 'teleop':
                self.teleop.halt(rospy.get_time())
                self._say_teleop('stopped: %s' % lost)
            # said in the goal's words when a goal ends by it
            self.gate.stop(StopReason(lost.code, tick.ending.text if tick is not None else lost.text, lost.final),
                           time.monotonic())
        rospy.logerr('navigator: %s%s', lost, ': goal %s aborted' % handle.get_goal_id().id if handle else '')
        if handle is not None:
            self._end(handle, tick)

    def _stopped(self) -> None:
        """A stop signal (the ER Manager unloading this navigator, most often because the manager that started it
        died): the base stops, and a goal under way ends ABORTED naming why, before rospy shuts down. Unsaid,
        the goal's client heard nothing: a navigator stopped before its loop had seen its manager's death left
        the goal unended (CI at dda811a)."""
        with self.lock:
            handle, goal_id, self.active = self.active, self.active_id, None
            if handle is not None:
                self.nav.cancel()
            self.gate.stop(StopReason(StopCode.HOLDER_GONE, 'the navigator was stopped'), time.monotonic())
        if handle is None or handle.get_goal_status().status not in (GoalStatus.ACTIVE, GoalStatus.PREEMPTING):
            return
        why = self.holders.gone(goal_id) or 'the navigator was stopped'
        rospy.logwarn('navigator: goal %s: %s: the robot stops', goal_id, why)
        handle.set_aborted(MoveBaseResult(), '%s: the robot stopped' % why)
        if not wait_sent([self.server.status_pub, self.server.result_pub], LAST_WORDS_S):
            rospy.logwarn('navigator: the goal\'s end not sent within %.1f s of the stop', LAST_WORDS_S)

    def _feedback(self, handle, pose, remaining: float) -> None:
        fb = MoveBaseFeedback()
        fb.base_position.header.stamp, fb.base_position.header.frame_id = rospy.Time.now(), self.map_frame
        if pose is not None:
            fb.base_position.pose.position.x, fb.base_position.pose.position.y = pose[0], pose[1]
            fb.base_position.pose.orientation.z = math.sin(pose[2] / 2)
            fb.base_position.pose.orientation.w = math.cos(pose[2] / 2)
        handle.publish_feedback(fb)
        self.pub_left.publish(Float32(remaining))

    def _held(self, tick) -> Optional[StopReason]:
        """The goal's own reason for a zero, as the gate says it (a guard that trips is the gate's own)."""
        if tick.state is State.WAITING:
            return StopReason(StopCode.OBSTACLES_STALE, 'no fresh obstacle source from %s: the goal waits'
                              % self.source_topic)
        if tick.state is State.BLOCKED:
            return StopReason(StopCode.BLOCKED, 'stopped by an obstacle: the goal waits')
        if tick.state is State.HELD:
            return self.nav.held_by
        return None

    def _end(self, handle, tick) -> None:
        text = tick.ending.text
        if handle is None or handle.get_goal_status().status not in (GoalStatus.ACTIVE, GoalStatus.PREEMPTING):
            return
        if tick.ending.outcome is Outcome.SUCCEEDED:
            handle.set_succeeded(MoveBaseResult(), text)
            rospy.loginfo('navigator: goal %s: %s', handle.get_goal_id().id, text)
        else:
            handle.set_aborted(MoveBaseResult(), text)
            rospy.logwarn('navigator: goal %s aborted: %s', handle.get_goal_id().id, text)
        self._publish_plan(None)


def main() -> None:
    run_node('navigator', NavigatorNode)
