"""follow_hand: an arm's tool follows the operator's hand through a clutch, scaled by a dial.

What it holds: the robot's manipulation (Robot Manager) and a hand source (the station's Sensor Manager,
type ``hand``). What it runs: ``HandFollower`` (``temoto_operator/hand_follower.py``), fed from the
hand source's subscriber thread, so a sample becomes a servo target with no queue between them:

- a grab after an open hand engages; the tool then follows the hand's motion relative to the grab, times
  the dial's scale, on ``<arm>/servo_target`` (the hand's axes are taken as the arm base frame's);
- a hand that goes (no sample for 2 of its periods, out of view, a sample not finite, its source FAILED)
  holds the arm at once on ``<arm>/servo_hold``, from a loop that waits for exactly the follower's
  deadline; the clutch then needs an open hand and a new grab;
- a failed source is released and the best hand source that works is started in its place (the Sensor
  Manager's ranking); when none works, the action ends FAILED, the arm held. The failover runs beside the
  loop (a candidate may take its whole first-data allowance), so a stop meanwhile ends the action at once;
- the robot's manipulation failing (a controller crashed) ends it FAILED, the arm held.

In navigation mode (``mode`` base: "drive with my hand", "follow my hand with the base") it holds the
robot's navigation instead, and the same clutch drives the base (``temoto_operator/hand_drive.py``): the
hand's motion since the grab becomes a ``TwistStamped`` on the navigator's ``teleop/cmd_vel``, and a lost
hand a zero there. The navigator keeps its guards on the stream (``teleop_drive.py``) and says what it does on
``teleop/status``; a hold or a refusal is passed to the operator as feedback.

The dial: ``/<ns>/dial`` (``std_msgs/Float32``, a scale from 0.01 to 10, stepped onto the 1-2-5 series) and
``/<ns>/dial/step`` (``std_msgs/Int8``, clicks finer (-) or coarser (+)); the scale now is latched on
``/<ns>/dial/scale``. A scale out of range is refused, naming the range, and the scale stays.
"""
from __future__ import annotations

import threading
import time

import numpy as np
import rospy
import tf2_ros
from control_msgs.msg import GripperCommandActionFeedback, GripperCommandActionResult
from geometry_msgs.msg import PoseStamped, TwistStamped
from std_msgs.msg import Float32, Int8, String
from visualization_msgs.msg import MarkerArray

from temoto_action_engine.action_base import ActionError
from temoto_action_engine.robot_action import RobotAction
from temoto_action_engine.scene import SceneDisplay
from temoto_core.errors import TemotoError
from temoto_core.halt import HALT_TYPE, halt_topic, reason_of
from temoto_core.msg import HandSample
from temoto_operator import dial
from temoto_operator.dial import Dial
from temoto_operator.hand_drive import GAIN_NAVIGATION, velocity_of
from temoto_operator.hand_follower import HOLD, TARGET, HandFollower
from temoto_robot_manager.navigation.obstacle_points import matrix_of
from temoto_robot_manager.navigation.scene_markers import gripper_text, hand_scene

HAND_TYPE = 'hand'
HAND_TOPIC_KEY = 'hand_data'
SAMPLE_PERIOD_S = 0.01          # a Leap Motion's 100 Hz (hands.yaml declares the same rate)
TOOL_WAIT_S = 0.2               # the tool's pose from TF at a grab
BASE_WORDS = ('base', 'drive', 'driving', 'navigation')   # the ``mode`` that drives the base, not an arm
SCENE_PERIOD_S = 0.1            # the hand and its target redrawn (10 Hz: a display, not the servo loop)
FAILOVER_POLL_S = 0.05          # how soon a stop is seen while another hand source is being started


def _palm(msg: HandSample) -> np.ndarray:
    p, q = msg.palm.position, msg.palm.orientation
    x, y, z, w = q.x, q.y, q.z, q.w
    n = x * x + y * y + z * z + w * w
    m = np.eye(4)
    if not np.isfinite(n) or n < 1e-9:
        m[:3, :3] = np.nan
    else:
        s = 2.0 / n
        m[:3, :3] = [[1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
                     [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
                     [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)]]
    m[:3, 3] = (p.x, p.y, p.z)
    return m


def _identity() -> np.ndarray:
    """The clutch's "tool" in navigation mode: its target is then the scaled hand motion itself."""
    return np.eye(4)


def _twist(linear: float, angular: float) -> TwistStamped:
    msg = TwistStamped()
    msg.header.stamp = rospy.Time.now()
    msg.twist.linear.x, msg.twist.angular.z = linear, angular
    return msg


def _pose(frame: str, m: np.ndarray) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id, msg.header.stamp = frame, rospy.Time.now()
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in m[:3, 3])
    r = m[:3, :3]
    w = np.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
    x = np.copysign(np.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0, r[2, 1] - r[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0, r[0, 2] - r[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0, r[1, 0] - r[0, 1])
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = float(x), float(y), float(z), float(w)
    return msg


class FollowHand(RobotAction):
    lock = None                  # set once on_start has what a hold needs
    hand = None
    arm = ''
    driving = False
    _drawn_at = 0.0
    _target_drawn = None
    _gripper = None                 # its last state, when this arm carries the robot's gripper
    _subs: list = []
    _hand_sub = None

    def on_start(self):
        self.driving = (self.input('mode') or '').strip().lower() in BASE_WORDS
        if self.driving:
            info = self.claim_robot('navigation')
            self.part = 'base'
        else:
            info = self.claim_robot('manipulation')
            self._choose_arm(info)
            self.part = self.arm
        self.dial = Dial()
        scale = self.input('scale')
        if scale not in (None, ''):
            try:
                self.dial.set(dial.scale_of(scale))
            except ValueError as err:
                raise ActionError('scale %s: %s' % (scale, err)) from None
        self.lock = threading.Lock()
        self.halted = False
        ns = self.context.namespace
        if self.driving:
            self.follower = HandFollower(self.dial, SAMPLE_PERIOD_S, gain=GAIN_NAVIGATION)
            self.pub_twist = rospy.Publisher(self.robot_topic('teleop/cmd_vel'), TwistStamped, queue_size=5,
                                             tcp_nodelay=True)
            self._subs = [rospy.Subscriber(self.robot_topic('teleop/status'), String, self._on_drive_status,
                                           queue_size=5)]
        else:
            self.follower = HandFollower(self.dial, SAMPLE_PERIOD_S)
            self.tf = tf2_ros.Buffer(cache_time=rospy.Duration(5.0))
            self._tf_listener = tf2_ros.TransformListener(self.tf)
            self.pub_target = rospy.Publisher(self.robot_topic('%s/servo_target' % self.arm), PoseStamped,
                                              queue_size=5, tcp_nodelay=True)
            self.pub_hold = rospy.Publisher(self.robot_topic('%s/servo_hold' % self.arm), String, queue_size=5,
                                            tcp_nodelay=True)
            self._subs = []
        self.pub_scale = rospy.Publisher(dial.topic(ns, dial.SCALE), Float32, queue_size=1, latch=True)
        self.pub_scale.publish(Float32(self.dial.scale))
        self._subs += [rospy.Subscriber(dial.topic(ns, dial.SET), Float32, self._on_dial, queue_size=5),
                       rospy.Subscriber(dial.topic(ns, dial.STEP), Int8, self._on_dial_step, queue_size=5),
                       rospy.Subscriber(halt_topic(ns), HALT_TYPE, self._on_halt, queue_size=5, tcp_nodelay=True)]
        if self.driving:
            self.show_scene(SceneDisplay('the footprint and its stop zone', 'marker array',
                                         self.navigator_topic('scene')))
        else:
            scene_topic = '/%s/follow_hand/%s/scene' % (ns, self.arm)
            self.pub_scene = rospy.Publisher(scene_topic, MarkerArray, queue_size=1, latch=True)
            gripper = info.get('gripper') or {}
            if gripper.get('arm') == self.arm and gripper.get('action'):
                # the gripper's state as its controller's action says it, whoever commands it ("close the gripper")
                self._gripper = {'gap': None, 'stalled': False, 'reached': False}
                action = self.robot_topic(gripper['action'])
                self._subs += [rospy.Subscriber(action + '/feedback', GripperCommandActionFeedback,
                                                lambda m: self._on_gripper(m.feedback), queue_size=5),
                               rospy.Subscriber(action + '/result', GripperCommandActionResult,
                                                lambda m: self._on_gripper(m.result), queue_size=5)]
            self.show_scene(SceneDisplay('the hand and its target', 'marker array', scene_topic))
        self._start_hand()
        self.event('following', part=self.part, arm=self.arm, scale=self.dial.scale, hand=self.hand.sensor_name)
        self.feedback('the %s follows your hand at %gx: open your hand, then grab' % (self.part, self.dial.scale))

    def _choose_arm(self, info: dict) -> None:
        arms = info.get('arm_frames') or {}
        said = (self.input('arm') or '').strip().lower()
        default = (info.get('gripper') or {}).get('arm') or next(iter(sorted(arms)), '')
        self.arm = next((a for a in arms if said and a.startswith(said)), None) if said else default
        if self.arm not in arms:
            raise ActionError('%s has no %s arm (its arms: %s)' % (info['name'], said, ', '.join(sorted(arms))))
        self.base_frame, self.tool_frame = arms[self.arm]['base_frame'], arms[self.arm]['tool_frame']

    # -- the hand source ----------------------------------------------------------------------------------------
    def _start_hand(self) -> None:
        self._use_hand(self._new_hand())

    def _new_hand(self, sensors=None):
        """The best hand source that works, from ``sensors`` (the station's Sensor Manager interface by default)."""
        try:
            return (sensors or self.station_sensor_manager).start_sensor(HAND_TYPE, [HAND_TOPIC_KEY],
                                                                         on_status=self.post)
        except TemotoError as err:
            raise ActionError('no hand source works: %s' % err) from None

    def _use_hand(self, hand) -> None:
        sub = rospy.Subscriber(hand.topic(HAND_TOPIC_KEY), HandSample, self._on_sample, queue_size=5,
                               tcp_nodelay=True)
        with self.lock:
            self.hand, self._hand_sub = hand, sub

    def _hand_failed(self, event) -> None:
        failed = self.hand
        self._hold('the hand source %s failed: %s' % (failed.sensor_name, event.message))
        with self.lock:
            sub, self._hand_sub = self._hand_sub, None
        if sub is not None:
            sub.unregister()     # a failed source may still publish (stalled, then back): it engages nothing
        self.event('hand_failed', hand=failed.sensor_name, message=event.message, origin=event.origin)
        # the failover takes as long as the Sensor Manager's tries (seconds, when a candidate is unplugged too): it
        # runs beside this loop, so the operator's stop ends the action at once. What it brings after the action
        # ended is released: by the registrar's shutdown, or refused by a registrar already shut down.
        found = {}
        done = threading.Event()
        # taken here, once: after the action ends its interfaces are released, and asking for one again from the
        # failover's thread would make a new registrar that nothing shuts down
        sensors = self.station_sensor_manager

        def fail_over():
            try:
                try:
                    sensors.stop_sensor(failed.resource_id)
                except TemotoError as err:   # its owner may be gone with it; what it held is released in cascade
                    self.log_warn('releasing the failed hand source: %s' % err)
                found['hand'] = self._new_hand(sensors)
            except ActionError as err:
                found['error'] = err
            finally:
                done.set()
        threading.Thread(target=fail_over, daemon=True, name='hand-failover').start()
        while not done.wait(FAILOVER_POLL_S):
            if not self.action_ok():
                return
        if not self.action_ok():
            return
        if 'error' in found:
            self.fail('lost the hand (%s), and no other hand source works: %s' % (event.origin, found['error']))
            return
        self._use_hand(found['hand'])
        self.event('following', part=self.part, arm=self.arm, scale=self.dial.scale, hand=self.hand.sensor_name)
        self.feedback('the hand source failed (%s); now %s: open your hand, then grab again'
                      % (event.origin, self.hand.sensor_name))

    # -- samples, from the subscriber's thread ------------------------------------------------------------------
    def _on_sample(self, msg: HandSample) -> None:
        if not self.action_ok():
            return
        with self.lock:
            if self.halted:
                return
            try:
                command = self.follower.sample(time.monotonic(), _palm(msg), float(msg.grab_strength), msg.tracked,
                                               _identity if self.driving else self._tool_now)
            except ActionError as err:         # no tool pose at the grab: nothing engages
                command = self.follower.lost(str(err))
                self.log_warn(str(err))
            self._send(command)
            if not self.driving:
                self._draw(_palm(msg), command)

    def _on_halt(self, msg) -> None:
        """The operator's "stop": no target after it, whatever the hand does; the action ends."""
        with self.lock:
            self.halted = True
            self._send(self.follower.lost('halted: %s' % reason_of(msg)))
        self.event('halted', reason=reason_of(msg))
        self.request_stop()

    def _tool_now(self) -> np.ndarray:
        try:
            t = self.tf.lookup_transform(self.base_frame, self.tool_frame, rospy.Time(0), rospy.Duration(TOOL_WAIT_S))
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as err:
            raise ActionError('where the %s is is not known: %s' % (self.tool_frame, err)) from None
        return matrix_of(t.transform)

    def _send(self, command) -> None:
        """Publish a follower's command; called with self.lock held, so a hold is never overtaken."""
        if command is None:
            return
        if self.driving:
            linear, angular = (velocity_of(command.pose[:3, 3], self.dial.scale * GAIN_NAVIGATION)
                               if command.kind == TARGET else (0.0, 0.0))
            self.pub_twist.publish(_twist(linear, angular))
        elif command.kind == TARGET:
            self.pub_target.publish(_pose(self.base_frame, command.pose))
        elif command.kind == HOLD:
            self.pub_hold.publish(String(command.why))

    def _draw(self, palm: np.ndarray, command) -> None:
        """The hand and its target in the scene, at most every ``SCENE_PERIOD_S`` (after the servo target went:
        drawing never delays it), and at once when the clutch lets go."""
        now = time.monotonic()
        let_go = command is not None and command.kind == HOLD
        if not let_go and now - self._drawn_at < SCENE_PERIOD_S:
            return
        self._drawn_at = now
        if command is not None and command.kind == TARGET:
            self._target_drawn = command.pose[:3, 3]
        hand = self.follower.clutch.hand_point(palm)
        target = self._target_drawn if hand is not None else None
        said = gripper_text(self._gripper['gap'], self._gripper['stalled'], self._gripper['reached']) \
            if self._gripper is not None else ''
        self.pub_scene.publish(hand_scene(self.base_frame, rospy.Time.now(), hand, target, gripper=said,
                                          tool=self._target_drawn))

    def _on_gripper(self, state) -> None:
        self._gripper = {'gap': float(state.position), 'stalled': bool(state.stalled),
                         'reached': bool(state.reached_goal)}

    def _on_drive_status(self, msg: String) -> None:
        """The navigator's word on the stream, when it changes: a hold or a refusal is said to the operator."""
        if msg.data != 'driving':
            self.feedback('the base: %s' % msg.data)

    def _hold(self, why: str) -> None:
        with self.lock:
            self._send(self.follower.lost(why))

    # -- the dial -----------------------------------------------------------------------------------------------
    def _on_dial(self, msg: Float32) -> None:
        self._turn(lambda: self.dial.set(float(msg.data)))

    def _on_dial_step(self, msg: Int8) -> None:
        self._turn(lambda: self.dial.step(int(msg.data)))

    def _turn(self, change) -> None:
        with self.lock:
            try:
                scale = change()
            except ValueError as err:
                self.feedback('dial refused: %s' % err)
                return
        self.pub_scale.publish(Float32(scale))
        self.feedback('scale %gx' % scale)

    # -- the loop: the hand's deadline and the resources' statuses ------------------------------------------------
    def execute(self):
        while self.action_ok():
            with self.lock:
                deadline = self.follower.deadline()
            timeout = 0.5 if deadline is None else max(0.0, deadline - time.monotonic())
            item = self.next_item(timeout)
            if not self.action_ok():
                break
            if item is None:
                with self.lock:
                    self._send(self.follower.check(time.monotonic()))
                continue
            if self.hand is not None and item.resource_id == self.hand.resource_id and item.failed:
                self._hand_failed(item)
                continue
            why = self.robot_event(item)
            if why is not None:
                self._hold(why)
                self.fail(why)

    def on_stop(self):
        if self.lock is not None:
            self._hold('follow_hand stopped')
        for sub in self._subs + ([self._hand_sub] if self._hand_sub is not None else []):
            sub.unregister()
