"""A chaos client's motion: navigation goals, servo streams and gripper goals, each held as a motion goal.

The client claims the robot's feature through the Robot Manager (a resource like any other: shared, released,
FAILED) and, while it holds it, moves the robot the way an operator's action would: a move_base goal to a
point of the lab, a servo stream along a short seeded path (or after the simulated hand tracker, through
the clutch that ``follow_hand`` uses), a gripper goal. Its failure policy is a motion action's: the FAILED
of the robot ends every motion on it (goals cancelled, the stream stopped), and a release cancels first.

Every motion is written to a journal, one JSON line per event, before the robot can act on it (a goal's
``sent`` before the goal goes out), with ``os.write`` on an append-only file: a SIGKILL loses nothing the
robot saw. The checker reads the journals and holds the simulation's ground truth against them: nothing
may move that no live client holds (``motion_checker.py``).
"""
from __future__ import annotations

import json
import math
import os
import threading
import time
from typing import Dict, Optional

import actionlib
import numpy as np
import PyKDL
import rospy
from actionlib_msgs.msg import GoalStatus
from control_msgs.msg import GripperCommandAction, GripperCommandGoal
from geometry_msgs.msg import PoseStamped
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from temoto_core.action_client import ACK_RESEND_S, redeliver
from temoto_core.msg import HandSample
from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics, KinematicsError
from temoto_robot_manager.msg import MoveArmAction, MoveArmGoal
from temoto_operator.dial import Dial
from temoto_operator.hand_follower import HOLD, TARGET, HandFollower
from temoto_robot_manager.navigation.obstacle_points import matrix_of_pose
from vaultbot_sim.srv import SetSweep

SERVER_WAIT_S = 30.0          # a part's action server appears within its start (its load has returned)
ANSWER_WAIT_S = 2.0           # the call waits this long for the acceptance or the refusal (ms, unless cut)
STREAM_PERIOD_S = 0.02        # the servo stream's 50 Hz
JOINTS_WAIT_S = 2.0           # where the arm is, from one joint_states message
SWEEP_ARM = 'right_arm'        # the Hokuyo's: it sweeps until held
HAND_PERIOD_S = 0.01          # the simulated hand tracker's 100 Hz (hands.yaml)
DELIVERY_S = 30.0             # a goal unacknowledged is sent again for this long (a cut link delays the answer)
HOLD_ANSWER_S = 1.0           # the manipulator says it holds once the arm rests, tens of ms (a cut link: never)
UR5_JOINTS = ('shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint', 'wrist_2_joint',
              'wrist_3_joint')
STATE_NAMES = {v: k for k, v in vars(GoalStatus).items() if k.isupper() and isinstance(v, int)}
DONE_STATES = (GoalStatus.PREEMPTED, GoalStatus.SUCCEEDED, GoalStatus.ABORTED, GoalStatus.REJECTED,
               GoalStatus.RECALLED, GoalStatus.LOST)


class Journal:
    """Append-only JSON lines, each written whole by one ``os.write`` (O_APPEND): a kill loses no line."""

    def __init__(self, path: str) -> None:
        self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        self._lock = threading.Lock()

    def write(self, **record) -> None:
        record.setdefault('t', time.time())
        with self._lock:
            os.write(self._fd, (json.dumps(record) + '\n').encode())


class HoldAnswer:
    """The manipulator's word that it holds an arm for a reason: ``holding: <reason>`` on its servo status."""

    def __init__(self, topic: str) -> None:
        self._said: set = set()
        self._cond = threading.Condition()
        self._sub = rospy.Subscriber(topic, String, self._on_status, queue_size=5)

    def _on_status(self, msg: String) -> None:
        with self._cond:
            self._said.add(msg.data)
            self._cond.notify_all()

    def wait(self, reason: str, timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: 'holding: ' + reason in self._said, timeout)

    def close(self) -> None:
        self._sub.unregister()


class Motion:
    """One motion goal of this client: a goal handle's, or a stream's."""

    def __init__(self, mid: str, part: str, kind: str, robot: int) -> None:
        self.id, self.part, self.kind, self.robot = mid, part, kind, robot
        self.handle = None                       # actionlib goal handle (goals)
        self.stop = threading.Event()            # a stream's end, asked
        self.accepted = threading.Event()
        self.answered = threading.Event()        # accepted or refused
        self.ended = False


def _quaternion(m: np.ndarray) -> tuple:
    r = PyKDL.Rotation(*(float(v) for v in m[:3, :3].reshape(-1)))
    return r.GetQuaternion()


def _pose(frame: str, m: np.ndarray) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id, msg.header.stamp = frame, rospy.Time.now()
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in m[:3, 3])
    o.x, o.y, o.z, o.w = _quaternion(m)
    return msg


class MotionClient:
    """The motions of one client, on the robot's features it holds (``robot_of(feature)``)."""

    def __init__(self, journal: Journal, node: str) -> None:
        self.journal = journal
        self.node = node
        self.lock = threading.RLock()            # held while a goal is sent, so that its callbacks find it
        self.motions: Dict[str, Motion] = {}     # not ended
        self._count = 0
        self._clients: Dict[str, actionlib.ActionClient] = {}
        self._kinematics: Dict[str, ArmKinematics] = {}
        self._publishers: Dict[str, rospy.Publisher] = {}

    # -- goals ---------------------------------------------------------------------------------------------
    def navigate(self, robot: int, info: dict, x: float, y: float, yaw: float, frame: str) -> dict:
        goal = MoveBaseGoal()
        pose = goal.target_pose
        pose.header.frame_id, pose.header.stamp = frame, rospy.Time.now()
        pose.pose.position.x, pose.pose.position.y = x, y
        pose.pose.orientation.z, pose.pose.orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
        return self._goal(robot, 'base', 'goal', self._topic(info, 'move_base'), MoveBaseAction, goal,
                          '%s (%.2f, %.2f, %.2f)' % (frame, x, y, yaw))

    def grip(self, robot: int, info: dict, gap: float, effort: float) -> dict:
        goal = GripperCommandGoal()
        goal.command.position, goal.command.max_effort = gap, effort
        return self._goal(robot, 'gripper', 'grip', self._topic(info, info['gripper']['action']),
                          GripperCommandAction, goal, 'gap %.3f m, %.0f N' % (gap, effort))

    def arm_goal(self, robot: int, info: dict, arm: str, offsets, speed: float) -> dict:
        """A trajectory goal of ``arm`` (its manipulator's ``move_arm``): from where its joints are, by ``offsets``
        (rad, one per joint), at ``speed`` of each joint's limit."""
        joints = ['%s_%s' % (arm.split('_')[0], j) for j in UR5_JOINTS]
        try:
            msg = rospy.wait_for_message(self._topic(info, 'joint_states'), JointState, JOINTS_WAIT_S)
        except rospy.ROSException as err:
            return {'ok': False, 'error': 'where the %s is is not known: %s' % (arm, err)}
        here = dict(zip(msg.name, msg.position))
        goal = MoveArmGoal(joint_positions=[here[j] + d for j, d in zip(joints, offsets)], speed_scale=speed)
        return self._goal(robot, arm, 'arm_goal', self._topic(info, '%s/move_arm' % arm), MoveArmAction, goal,
                          'joints by %s at %.1f' % (list(offsets), speed))

    def _goal(self, robot: int, part: str, kind: str, topic: str, spec, goal, what: str) -> dict:
        client = self._client(topic, spec)
        if not client.wait_for_server(rospy.Duration(SERVER_WAIT_S)):
            return {'ok': False, 'error': 'no action server on %s after %.0f s' % (topic, SERVER_WAIT_S)}
        motion = self._new(part, kind, robot)
        with self.lock:
            self.journal.write(id=motion.id, ev='sent', part=part, kind=kind, what=what, robot=robot)
            motion.handle = client.send_goal(goal, transition_cb=lambda gh, m=motion: self._transition(m, gh))
        threading.Thread(target=self._deliver, args=(motion,), name='deliver-%s' % motion.id, daemon=True).start()
        motion.answered.wait(ANSWER_WAIT_S)
        with self.lock:
            state = STATE_NAMES.get(motion.handle.get_goal_status(), '?')
            text = motion.handle.get_goal_status_text()
        return {'ok': True, 'id': motion.id, 'accepted': motion.accepted.is_set(), 'state': state, 'text': text[:200]}

    @staticmethod
    def _deliver(motion: Motion) -> None:
        """The goal sent again while its server has not acknowledged it (``action_client.redeliver``): sent as its
        server restarted, it went to the dead incarnation (seed 17, step 7407: never answered)."""
        for _ in range(int(DELIVERY_S / ACK_RESEND_S)):
            if motion.answered.wait(ACK_RESEND_S) or motion.ended or not redeliver(motion.handle):
                return

    def _transition(self, motion: Motion, gh) -> None:
        with self.lock:
            if motion.ended:
                return
            status = gh.get_goal_status()
            if status in (GoalStatus.ACTIVE, GoalStatus.PREEMPTING) and not motion.accepted.is_set():
                motion.accepted.set()
                motion.answered.set()
                self.journal.write(id=motion.id, ev='accepted')
            if gh.get_comm_state() == actionlib.CommState.DONE or status in DONE_STATES:
                text = gh.get_goal_status_text()
                if not motion.accepted.is_set() and status not in (GoalStatus.REJECTED, GoalStatus.RECALLED):
                    # it ran (it succeeded, was aborted or preempted), though its ACTIVE never reached this
                    # client: the status is published at 5 Hz, and a goal preempted at once is not in any
                    motion.accepted.set()
                    self.journal.write(id=motion.id, ev='accepted')
                if not motion.accepted.is_set():
                    self.journal.write(id=motion.id, ev='refused', state=STATE_NAMES.get(status, '?'), reason=text)
                    motion.answered.set()
                    self._end(motion, None)
                else:
                    self._end(motion, 'result', STATE_NAMES.get(status, '?'), text)

    def cancel(self, pick: int) -> dict:
        """Cancel one of this client's motions (a goal's cancel; a stream ended)."""
        with self.lock:
            live = sorted(self.motions)
            if not live:
                return {'ok': True, 'cancelled': ''}
            motion = self.motions[live[pick % len(live)]]
            self._let_go(motion, 'cancelled', 'cancelled by its client')
        return {'ok': True, 'cancelled': motion.id}

    # -- servo ---------------------------------------------------------------------------------------------
    def servo_path(self, robot: int, info: dict, arm: str, offset: tuple, seconds: float) -> dict:
        """Stream servo targets for ``seconds``: the tool from where it is to ``offset`` (m, the arm's base
        frame) and back, at 50 Hz; the stream then stops, and tells the arm to hold."""
        frames = info['arm_frames'][arm]
        try:
            start = self._tool(info, arm)
        except (KinematicsError, rospy.ROSException) as err:
            return {'ok': False, 'error': 'where the %s is is not known: %s' % (arm, err)}
        target = self._publisher(self._topic(info, '%s/servo_target' % arm), PoseStamped)
        hold = self._publisher(self._topic(info, '%s/servo_hold' % arm), String)
        answer = HoldAnswer(self._topic(info, '%s/servo_status' % arm)) if arm == SWEEP_ARM else None
        motion = self._new(arm, 'servo', robot)
        self.journal.write(id=motion.id, ev='sent', part=arm, kind='servo', robot=robot,
                           what='path %s for %.1f s' % (offset, seconds))
        self.journal.write(id=motion.id, ev='accepted')
        motion.accepted.set()

        def stream() -> None:
            t0 = time.monotonic()
            while not motion.stop.is_set():
                s = (time.monotonic() - t0) / seconds
                if s >= 1.0:
                    break
                m = start.copy()
                m[:3, 3] += np.array(offset) * (1.0 - abs(2.0 * s - 1.0))
                target.publish(_pose(frames['base_frame'], m))
                motion.stop.wait(STREAM_PERIOD_S)
            with self.lock:
                self._end(motion, 'stream_done')
            hold.publish(String('%s ended' % motion.id))
            self._give_back(info, arm, '%s ended' % motion.id, answer)
        threading.Thread(target=stream, name='servo-%s' % motion.id, daemon=True).start()
        return {'ok': True, 'id': motion.id}

    def servo_hand(self, robot: int, info: dict, arm: str, hand_topic: str, scale: float, seconds: float) -> dict:
        """Follow the hand source on ``hand_topic`` for ``seconds`` through the clutch and the dial, as
        ``follow_hand`` does: a stale hand (2 of its periods) holds the arm at once."""
        frames = info['arm_frames'][arm]
        try:
            self._kinematics_of(info, arm)
        except (KinematicsError, rospy.ROSException) as err:
            return {'ok': False, 'error': 'no kinematics for the %s: %s' % (arm, err)}
        dial = Dial()
        dial.set(scale)
        follower = HandFollower(dial, HAND_PERIOD_S)
        target = self._publisher(self._topic(info, '%s/servo_target' % arm), PoseStamped)
        hold = self._publisher(self._topic(info, '%s/servo_hold' % arm), String)
        answer = HoldAnswer(self._topic(info, '%s/servo_status' % arm)) if arm == SWEEP_ARM else None
        motion = self._new(arm, 'servo', robot)
        self.journal.write(id=motion.id, ev='sent', part=arm, kind='servo', robot=robot,
                           what='hand %s at %gx for %.1f s' % (hand_topic, scale, seconds))
        self.journal.write(id=motion.id, ev='accepted')
        motion.accepted.set()
        follow = threading.Lock()
        wake = threading.Event()

        def send(command) -> None:
            if command is None or motion.stop.is_set():
                return
            if command.kind == TARGET:
                target.publish(_pose(frames['base_frame'], command.pose))
            elif command.kind == HOLD:
                hold.publish(String(command.why))

        def on_sample(msg: HandSample) -> None:
            p, o = msg.palm.position, msg.palm.orientation
            palm = matrix_of_pose(p, o)
            with follow:
                try:
                    send(follower.sample(time.monotonic(), palm, float(msg.grab_strength), msg.tracked,
                                         lambda: self._tool(info, arm)))
                except (KinematicsError, rospy.ROSException) as err:
                    send(follower.lost(str(err)))
            wake.set()

        sub = rospy.Subscriber(hand_topic, HandSample, on_sample, queue_size=5, tcp_nodelay=True)

        def watch() -> None:
            end = time.monotonic() + seconds
            while not motion.stop.is_set() and time.monotonic() < end:
                with follow:
                    deadline = follower.deadline()
                wait = end - time.monotonic() if deadline is None else deadline - time.monotonic()
                wake.clear()
                if wait > 0:
                    wake.wait(min(wait, 0.1))
                    continue
                with follow:
                    send(follower.check(time.monotonic()))
            sub.unregister()
            with self.lock:
                self._end(motion, 'stream_done')
            with follow:                  # a sample being followed is sent before the hold, not after it
                hold.publish(String('%s ended' % motion.id))
            self._give_back(info, arm, '%s ended' % motion.id, answer)
        threading.Thread(target=watch, name='hand-%s' % motion.id, daemon=True).start()
        return {'ok': True, 'id': motion.id}

    def _give_back(self, info: dict, arm: str, reason: str, answer: Optional[HoldAnswer]) -> None:
        """After a stream's end and its hold (``reason``): the Hokuyo's arm given back to its sweep once the
        manipulator says it holds, as an operator would (held, it stops the sweep for good, and with it the
        stitched cloud, an obstacle source). Given back while the manipulator still followed the stream, the
        arm was taken again by the stream's last steps or its hold (seed 17, steps 1263 and 1509)."""
        if answer is None:
            return
        try:
            if not answer.wait(reason, HOLD_ANSWER_S):
                rospy.logwarn('chaos client: the %s\'s manipulator did not say it holds within %.1f s', arm,
                              HOLD_ANSWER_S)
        finally:
            answer.close()
        with self.lock:
            if any(m.part == arm for m in self.motions.values()):
                return
        try:
            rospy.ServiceProxy(self._topic(info, 'vaultbot_sim/set_sweep'), SetSweep)(True, 0.0)
        except (rospy.ServiceException, rospy.ROSException, OSError) as err:
            rospy.logwarn('chaos client: the %s not given back to its sweep: %s', arm, err)

    # -- the robot's end, and this client's --------------------------------------------------------------------
    def robot_failed(self, robot: int, message: str) -> None:
        """A motion action's policy: the FAILED of the robot ends every motion on it."""
        with self.lock:
            for motion in [m for m in self.motions.values() if m.robot == robot]:
                self._let_go(motion, 'robot_failed', message or 'FAILED')

    def releasing(self, robot: int) -> None:
        """Before the robot is released: every motion on it is let go."""
        with self.lock:
            for motion in [m for m in self.motions.values() if m.robot == robot]:
                self._let_go(motion, 'released', 'its robot was released')

    def live(self) -> list:
        with self.lock:
            return sorted(self.motions)

    def _let_go(self, motion: Motion, cause: str, reason: str) -> None:
        motion.stop.set()
        if motion.handle is not None:
            motion.handle.cancel()
        self._end(motion, cause, {'cancelled': 'CANCELLED', 'released': 'RELEASED'}.get(cause, 'FAILED'), reason)

    def _end(self, motion: Motion, cause: Optional[str], state: str = '', reason: str = '') -> None:
        """Called with the lock held. ``cause`` None: refused (journaled already)."""
        if motion.ended:
            return
        motion.ended = True
        motion.stop.set()
        self.motions.pop(motion.id, None)
        if cause is not None:
            self.journal.write(id=motion.id, ev='ended', cause=cause, state=state, reason=reason)

    # -- plumbing ----------------------------------------------------------------------------------------------
    def _new(self, part: str, kind: str, robot: int) -> Motion:
        with self.lock:
            self._count += 1
            motion = Motion('%s#%d' % (self.node, self._count), part, kind, robot)
            self.motions[motion.id] = motion
        return motion

    @staticmethod
    def _topic(info: dict, name: str) -> str:
        return (info.get('ros_namespace') or '/').rstrip('/') + '/' + name.lstrip('/')

    def _client(self, topic: str, spec) -> actionlib.ActionClient:
        if topic not in self._clients:
            self._clients[topic] = actionlib.ActionClient(topic, spec)
        return self._clients[topic]

    def _publisher(self, topic: str, msg_type) -> rospy.Publisher:
        if topic not in self._publishers:
            self._publishers[topic] = rospy.Publisher(topic, msg_type, queue_size=5, tcp_nodelay=True)
        return self._publishers[topic]

    def _kinematics_of(self, info: dict, arm: str) -> ArmKinematics:
        if arm not in self._kinematics:
            frames = info['arm_frames'][arm]
            urdf = rospy.get_param(self._topic(info, 'robot_description'))
            side = arm.split('_')[0]
            self._kinematics[arm] = ArmKinematics(urdf, frames['base_frame'], frames['tool_frame'],
                                                  ['%s_%s' % (side, j) for j in UR5_JOINTS])
        return self._kinematics[arm]

    def _tool(self, info: dict, arm: str) -> np.ndarray:
        """Where the arm's tool is now (its base frame), from one joint_states message."""
        kin = self._kinematics_of(info, arm)
        msg = rospy.wait_for_message(self._topic(info, 'joint_states'), JointState, JOINTS_WAIT_S)
        pos = dict(zip(msg.name, msg.position))
        return kin.fk([pos[j] for j in kin.joints])
