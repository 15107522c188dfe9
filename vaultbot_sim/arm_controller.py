"""A UR5's controller: a FollowJointTrajectory action, and a streaming input for servoing with a deadman.

As ros_control's joint_trajectory_controller does for a real UR5:
- ``<arm>/follow_joint_trajectory`` (``control_msgs/FollowJointTrajectoryAction``): a goal is checked
  against the arm before anything moves (``trajectory.Trajectory.check``: joints, ranges, pi rad/s,
  times) and refused with its result code and a text naming what is wrong; an accepted one is sampled
  at ``arm.COMMAND_RATE_HZ`` and streamed to the motors, with feedback (desired, actual, error). It
  ends SUCCESSFUL within the goal tolerance, or aborts when the arm strays beyond the path tolerance (a
  protective stop, a motor that does not follow) or misses the goal's time. A new goal preempts the one
  running; a cancel holds the arm where it is, and so does the end of the goal's client (its process died, or it
  is out of reach: ``temoto_core/goal_holders.py``): PREEMPTED, as if it had cancelled, naming it. A trajectory runs for somebody, or not
  at all (a manipulator SIGKILLed mid-trajectory once left the arm following it to its end);
- ``<arm>/servo_command`` (``trajectory_msgs/JointTrajectory``, one point: target positions and the
  velocities to pass them with, as MoveIt Servo publishes): forwarded and extrapolated at the command
  rate while it flows; silent for ``~servo_timeout`` (0.1 s, MoveIt Servo's), the arm holds. A point with
  no positions and every velocity zero is a hold: the motors brake where the joints are. (A hold sent as
  positions would pull the arm back to where its sender last saw it: an arm given back to its sweep was
  pulled back at the sweep's speed, seed 17, steps 1263 and 1509.) Refused while a trajectory runs: one
  arm obeys one master at a time (docs/robots.md);
- between motions it sends nothing: the motors hold where the last setpoint left them;
- switched off (SIGINT or SIGTERM: the ER Manager's unload) it holds the arm and gives it back to the sim
  (``~release_arm``), as controller_manager gives the hardware back when a controller stops: the Hokuyo's
  arm sweeps again if holding it had stopped the sweep. Killed or crashed, it gives nothing back, and the arm
  stays braked where it is;
- its cable is the sim's ``left_arm`` or ``right_arm`` device: crash exits 1, stall silences it.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Dict, Optional, Tuple

import actionlib
import rospy
from control_msgs.msg import (FollowJointTrajectoryAction, FollowJointTrajectoryFeedback,
                              FollowJointTrajectoryResult)
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from temoto_core import params
from temoto_core.goal_holders import GoalHolders
from temoto_core.node import init_node, ok, stop_requested
from vaultbot_sim.arm import COMMAND_RATE_HZ, SPEED, JointRange
from vaultbot_sim.cable_follower import CableFollower, fail
from vaultbot_sim.spec import ARM_JOINTS
from vaultbot_sim.srv import ReleaseArm
from vaultbot_sim.ticks import Ticks
from vaultbot_sim.trajectory import (GOAL_TOLERANCE_VIOLATED, OLD_HEADER_TIMESTAMP,
                                     PATH_TOLERANCE_VIOLATED, Refused, Trajectory)

ARMS = ('left_arm', 'right_arm')
UR5_RANGE = JointRange(-2 * math.pi, 2 * math.pi)
SERVO_TIMEOUT_S = 0.1
GOAL_TOLERANCE = 0.01        # rad, unless the goal says otherwise
PATH_TOLERANCE = 0.25        # rad between where a joint should be and where it is
GOAL_TIME_TOLERANCE = 0.5    # s after the trajectory's end to be within the goal tolerance
OLD_STAMP_S = 0.5            # a goal stamped further in the past than this is stale
RELEASE_WAIT_S = 1.0         # the give-back's bound: within the node's grace before rospy is shut down anyway


class ArmController:
    def __init__(self) -> None:
        self.arm = params.text('arm', 'left_arm', choices=ARMS)
        side = self.arm.split('_')[0]
        self.joints = ['%s_%s_joint' % (side, j) for j in ARM_JOINTS]
        self.ranges = {j: UR5_RANGE for j in self.joints}
        self.sim_ns = rospy.resolve_name(params.text('sim_ns', 'vaultbot_sim', empty=False)).rstrip('/')
        self.servo_timeout = params.number('servo_timeout', SERVO_TIMEOUT_S, above=0, maximum=1.0)
        self.rate = params.number('rate', COMMAND_RATE_HZ, above=0, maximum=1000)
        self.lock = threading.Lock()
        self.position: Dict[str, float] = {}
        self.servo: Optional[Tuple[float, Dict[str, Tuple[float, float]]]] = None    # (when, setpoint)
        self.running_goal = False
        self.switched_off = False          # set once, under self.lock: nothing is sent from then on
        self._positions = threading.Event()
        self.pub = rospy.Publisher('%s/joint_command' % self.arm, JointState, queue_size=10, tcp_nodelay=True)
        self.cable = CableFollower(self.arm, '%s: arm controller' % self.arm, self.sim_ns)
        rospy.Subscriber('joint_states', JointState, self._on_joint_states, queue_size=20, tcp_nodelay=True)
        timeout = params.number('startup_timeout', 10.0, above=0)
        if not self.cable.seen.wait(timeout) or not self._positions.wait(timeout):
            fail('%s: no device states or joint states after %.0f s (is vaultbot_sim running?)'
                      % (self.arm, timeout))
        rospy.Subscriber('%s/servo_command' % self.arm, JointTrajectory, self._on_servo, queue_size=10,
                         tcp_nodelay=True)
        self.server = actionlib.SimpleActionServer('%s/follow_joint_trajectory' % self.arm,
                                                   FollowJointTrajectoryAction, self._execute, auto_start=False)
        self.holders = GoalHolders('%s controller' % self.arm, None, self.server.action_server)
        self.server.start()

    # --- inputs ----------------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self.cable.running

    def _on_joint_states(self, msg: JointState) -> None:
        pos = dict(zip(msg.name, msg.position))
        if all(j in pos for j in self.joints):
            with self.lock:
                self.position = {j: pos[j] for j in self.joints}
            self._positions.set()

    def _on_servo(self, msg: JointTrajectory) -> None:
        try:
            if not msg.points:
                raise ValueError('no point')
            point = msg.points[0]
            names = list(msg.joint_names)
            if sorted(names) != sorted(self.joints):
                raise ValueError('joint_names must name each of %s once' % ', '.join(self.joints))
            if not point.positions:
                if len(point.velocities) != len(names) or any(v != 0.0 for v in point.velocities):
                    raise ValueError('a point without positions is a hold: it needs one velocity per joint, '
                                     'each zero (%d given)' % len(point.velocities))
                with self.lock:
                    if self.running_goal:
                        raise ValueError('a trajectory runs on this arm; cancel it first')
                    self.servo = None
                self.hold()
                return
            vel = list(point.velocities) or [0.0] * len(names)
            if len(point.positions) != len(names) or len(vel) != len(names):
                raise ValueError('%d positions and %d velocities for %d joints' % (len(point.positions), len(vel),
                                                                                len(names)))
            setpoint = {}
            for j, q, v in zip(names, point.positions, vel):
                if not (math.isfinite(q) and math.isfinite(v)):
                    raise ValueError('%s: position %r and velocity %r must be finite' % (j, q, v))
                r = self.ranges[j]
                if not r.lower <= q <= r.upper:
                    raise ValueError('%s at %.3f rad is beyond its range' % (j, q))
                setpoint[j] = (q, max(-SPEED, min(SPEED, v)))
            with self.lock:
                if self.running_goal:
                    raise ValueError('a trajectory runs on this arm; cancel it first')
                self.servo = (time.monotonic(), setpoint)
        except ValueError as e:
            rospy.logerr_throttle(1.0, '%s: servo command refused: %s' % (self.arm, e))
            return
        self.send(setpoint)               # at once: the command loop only fills the gaps between two

    # --- outputs ---------------------------------------------------------------------------------------
    def send(self, setpoint: Dict[str, Tuple[float, float]]) -> None:
        self._command(JointState(name=list(setpoint), position=[q for q, _ in setpoint.values()],
                                 velocity=[v for _, v in setpoint.values()]))

    def hold(self) -> None:
        """Stop where the arm is now: the motors brake to a hold (velocities only, all zero)."""
        self._command(JointState(name=list(self.joints), velocity=[0.0] * len(self.joints)))

    def _command(self, msg: JointState) -> None:
        if not self.running:
            return                        # stalled: silent
        with self.lock:                   # stamped and queued before a switch-off, or not at all
            if self.switched_off:
                return
            msg.header.stamp = rospy.Time.now()
            self.pub.publish(msg)

    def switch_off(self) -> None:
        """The last words of a clean stop: hold the arm, send nothing more, and give the arm back to the sim.
        A setpoint still on its way is stamped before the give-back, and the sim drops it (``ArmPlant.release``).
        Bounded by ``RELEASE_WAIT_S``: a sim that does not answer leaves the arm held, as a crash would."""
        self.hold()
        with self.lock:
            self.switched_off = True
            last = rospy.Time.now()
        if not self.running:
            return                        # stalled or unplugged: its words never reach the sim
        answer = []

        def call() -> None:
            try:
                answer.append(rospy.ServiceProxy('%s/release_arm' % self.sim_ns, ReleaseArm)(self.arm, last))
            except (rospy.ServiceException, rospy.ROSException, OSError) as err:
                answer.append(err)
        caller = threading.Thread(target=call, name='release', daemon=True)
        caller.start()
        caller.join(RELEASE_WAIT_S)
        if not answer:
            rospy.logwarn('%s: the sim did not answer the give-back within %.1f s: the arm stays held', self.arm,
                          RELEASE_WAIT_S)
        elif isinstance(answer[0], Exception) or not answer[0].success:
            rospy.logwarn('%s: the arm not given back: %s', self.arm, getattr(answer[0], 'message', answer[0]))
        else:
            rospy.loginfo('%s: switched off: %s', self.arm, answer[0].message)

    # --- the trajectory action ---------------------------------------------------------------------------
    def _execute(self, goal) -> None:
        result = FollowJointTrajectoryResult()
        with self.lock:
            start = dict(self.position)
            self.servo = None             # a trajectory takes the arm from the servo stream
            self.running_goal = True
        try:
            stamp = goal.trajectory.header.stamp.to_sec()
            if stamp and stamp < time.time() - OLD_STAMP_S:
                raise Refused(OLD_HEADER_TIMESTAMP, 'the trajectory is stamped %.1f s ago' % (time.time() - stamp))
            traj = Trajectory.check(self.joints, self.ranges, list(goal.trajectory.joint_names),
                                    [(p.time_from_start.to_sec(), p.positions, p.velocities)
                                     for p in goal.trajectory.points], start)
        except Refused as e:
            self._end(result, e.code, str(e), aborted=True)
            return
        goal_id = self.server.current_goal.get_goal_id().id
        self.holders.new_goal()
        goal_tol = self._tolerances(goal.goal_tolerance, GOAL_TOLERANCE)
        path_tol = self._tolerances(goal.path_tolerance, PATH_TOLERANCE)
        time_tol = goal.goal_time_tolerance.to_sec() or GOAL_TIME_TOLERANCE
        period = 1.0 / self.rate
        t0 = time.monotonic()
        target = traj.goal()
        for i in range(int((traj.duration + time_tol) / period) + 2):
            if not ok():
                return
            if self.server.is_preempt_requested():
                self.hold()
                self._end(result, 0, 'preempted: holding where it is', preempted=True)
                return
            gone = self.holders.gone(goal_id)
            if gone is not None:
                self.hold()
                # as if the client had cancelled it: nobody is left to want the motion (control_msgs has no code
                # for a client that is gone)
                self._end(result, 0, '%s: holding where it is' % gone, preempted=True)
                return
            t = time.monotonic() - t0
            want = traj.sample(t)
            self.send(want)
            with self.lock:
                here = dict(self.position)
            errors = {j: here[j] - want[j][0] for j in self.joints}
            self._feedback(want, here, errors)
            if t <= traj.duration:
                strayed = [j for j in self.joints if abs(errors[j]) > path_tol[j]]
                if strayed:
                    self.hold()
                    self._end(result, PATH_TOLERANCE_VIOLATED, '%s strayed %.3f rad from the path (tolerance %.3f)'
                              % (strayed[0], abs(errors[strayed[0]]), path_tol[strayed[0]]), aborted=True)
                    return
            elif all(abs(here[j] - target[j]) <= goal_tol[j] for j in self.joints):
                self._end(result, 0, 'reached the goal in %.2f s' % t)
                return
            time.sleep(max(0.0, t0 + (i + 1) * period - time.monotonic()))
        worst = max(self.joints, key=lambda j: abs(self.position[j] - target[j]))
        self.hold()
        self._end(result, GOAL_TOLERANCE_VIOLATED, '%s is %.3f rad from its goal %.1f s after the trajectory\'s '
                  'end' % (worst, abs(self.position[worst] - target[worst]), time_tol), aborted=True)

    def _tolerances(self, given, default: float) -> Dict[str, float]:
        out = {j: default for j in self.joints}
        for tol in given:
            if tol.name in out and tol.position > 0:
                out[tol.name] = tol.position
        return out

    def _feedback(self, want, here, errors) -> None:
        fb = FollowJointTrajectoryFeedback(joint_names=self.joints)
        fb.header.stamp = rospy.Time.now()
        fb.desired = JointTrajectoryPoint(positions=[want[j][0] for j in self.joints],
                                          velocities=[want[j][1] for j in self.joints])
        fb.actual = JointTrajectoryPoint(positions=[here[j] for j in self.joints])
        fb.error = JointTrajectoryPoint(positions=[errors[j] for j in self.joints])
        self.server.publish_feedback(fb)

    def _end(self, result, code: int, text: str, aborted: bool = False, preempted: bool = False) -> None:
        with self.lock:
            self.running_goal = False
        result.error_code, result.error_string = code, text
        (rospy.logwarn if aborted else rospy.loginfo)('%s: %s', self.arm, text)
        if preempted:
            self.server.set_preempted(result, text)
        elif aborted:
            self.server.set_aborted(result, text)
        else:
            self.server.set_succeeded(result, text)

    # --- the servo stream --------------------------------------------------------------------------------
    def spin(self) -> None:
        ticks = Ticks(1.0 / self.rate)
        rospy.loginfo('%s: trajectories on %s/follow_joint_trajectory, servoing on %s/servo_command (deadman %.2f s)',
                      self.arm, self.arm, self.arm, self.servo_timeout)
        while not stop_requested() and ok():
            now = time.monotonic()
            with self.lock:
                servo = self.servo
            if servo is not None:
                heard, setpoint = servo
                if now - heard > self.servo_timeout:         # the deadman: the stream fell silent
                    with self.lock:
                        self.servo = None
                    self.hold()
                    rospy.logwarn('%s: servo stream silent for %.2f s: holding' % (self.arm, now - heard))
                else:                                        # between two commands: where the last one leads
                    age = now - heard
                    self.send({j: (self.ranges[j].clamp(q + v * age), v) for j, (q, v) in setpoint.items()})
            with self.lock:
                # the deadman wakes the loop on time, not at its next tick
                deadline = None if self.servo is None else self.servo[0] + self.servo_timeout + 0.0002
            ticks.wait(deadline)
        if stop_requested():
            self.switch_off()
        ok()                              # rospy is shut down here, on the main thread (temoto_core.node)


def main() -> None:
    init_node('arm_controller')
    try:
        controller = ArmController()
    except ValueError as e:          # a bad parameter: say which
        rospy.logerr('arm_controller: %s', e)
        raise SystemExit(2)
    controller.spin()
