"""The vaultbot_sim node: owns the world, the robot's joint state, TF, the base's motors and the device cables.

No dynamics run here: the robot is kinematic (held pose + Hokuyo wrist sweep, and a
base that follows its motors' command within the Husky's limits, ``base.py``), and the
drivers render their sensors from what this node publishes. The base collides with the
world in a private pybullet copy of it: a pose that touches an object is not entered,
and each new contact is published on ``~contacts``. ``~base_state`` is the base's
ground truth (pose, actual and commanded velocity), which tests and checks trust
rather than any controller's word.
TF is published directly (tf2_msgs/TFMessage), computed from the URDF, so no
robot_state_publisher or tf2_ros is needed. The base's odometry, ``odom -> base_link``,
is its controller's to publish (``base_controller.py``), as on a real Husky; this node
puts ``odom`` at the world's origin.

Names follow ROS's convention for several robots on one master: everything the
robot has (``joint_states``, ``robot_description``, this node's own topics and
services) is relative, so a robot started in namespace ``vaultbot_2`` has its
own; TF is the one shared tree on ``/tf`` and ``/tf_static``, and ``~frame_prefix``
(``vaultbot_2/``) keeps each robot's frames apart in it. A prefixed robot's
world hangs off the shared ``world`` frame at ``~origin`` ([x, y, yaw]), so
one RViz fixed in ``world`` shows every robot in its place.
"""
from __future__ import annotations

import math
import threading
import time

import rosgraph
import rospy
from temoto_core.node import ok
from temoto_core import params
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

import numpy as np

from vaultbot_sim.arm import ArmPlant, JointRange
from vaultbot_sim.base import MOTOR_TIMEOUT_S, BasePlant
from vaultbot_sim.body import Body, joint_names
from vaultbot_sim.devices import DeviceError, DeviceTable
from vaultbot_sim.gripper import STROKE, GripperPlant
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel, planar_matrix, resolve_world
from vaultbot_sim.motion import HandWave, SimState, WristSweep
from vaultbot_sim.msg import ArmState, BaseState, Contact as ContactMsg, DeviceState, DeviceStates, GripperState
from vaultbot_sim.rosmsgs import tf_message
from vaultbot_sim.scene import Scene
from vaultbot_sim.spec import ARM_JOINTS, GRIPPER_JOINTS, STOW_POSE, SWEEP_JOINT, WHEEL_JOINTS
from vaultbot_sim.world_map import world_map
from vaultbot_sim.srv import (ReleaseArm, ReleaseArmResponse, SetDeviceState, SetDeviceStateResponse, SetSweep,
                              SetSweepResponse)


def frame_prefix(value: object) -> str:
    """``~frame_prefix`` checked: '' or a legal name, ending in '/' (``vaultbot_2`` -> ``vaultbot_2/``)."""
    prefix = str(value or '').strip('/')
    if prefix and not rosgraph.names.is_legal_base_name(prefix.replace('/', '_')):
        raise ValueError('~frame_prefix %r: letters, digits, _ and / only, starting with a letter' % (value,))
    return prefix + '/' if prefix else ''


def planar_pose(value: object, name: str) -> tuple[float, float, float]:
    """A parameter [x, y, yaw] (metres, radians), checked."""
    try:
        x, y, yaw = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError('~%s %r: expected [x, y, yaw] in metres and radians' % (name, value)) from None
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise ValueError('~%s %r: every value must be finite' % (name, value))
    return x, y, yaw


def wheel_command(msg: JointState) -> tuple[float, float]:
    """(left, right) wheel speeds (rad/s) from a wheel command: each side's joints must be named, with finite
    velocities; the two wheels of a side are averaged (they are chained on a Husky)."""
    if len(msg.name) != len(msg.velocity):
        raise ValueError('%d names but %d velocities' % (len(msg.name), len(msg.velocity)))
    speeds = dict(zip(msg.name, msg.velocity))
    unknown = sorted(set(speeds) - set(WHEEL_JOINTS))
    if unknown:
        raise ValueError('unknown wheel joint(s) %s: use %s' % (', '.join(unknown), ', '.join(WHEEL_JOINTS)))
    sides = []
    for side in ('left', 'right'):
        given = [speeds[n] for n in WHEEL_JOINTS if side in n and n in speeds]
        if not given:
            raise ValueError('no %s wheel named' % side)
        if not all(math.isfinite(v) for v in given):
            raise ValueError('a %s wheel speed is not finite: %s' % (side, given))
        sides.append(sum(given) / len(given))
    return sides[0], sides[1]


def origin_matrix(value: object) -> np.ndarray:
    """``~origin`` [x, y, yaw] (metres, radians) as a homogeneous transform."""
    return planar_matrix(*planar_pose(value, 'origin'))


class SimNode:
    def __init__(self):
        world = params.text('world', 'lab', empty=False)
        self.world_urdf = resolve_world(world)
        self.robot_urdf = params.text('robot_urdf', ROBOT_URDF, empty=False)
        self.rate = params.number('rate', 50.0, above=0, maximum=1000)
        sweep = WristSweep(STOW_POSE[SWEEP_JOINT], amplitude=params.number('sweep_amplitude', math.pi / 2, minimum=0),
                           speed=params.number('sweep_speed', math.pi / 2, above=0),
                           enabled=params.flag('sweep', True))
        hand = HandWave(amplitude=params.number('hand_amplitude', 0.3, minimum=0),
                        period=params.number('hand_period', 8.0, above=0),
                        enabled=params.flag('hand_motion', True))
        self.state = SimState(sweep, hand)
        self._sweep_yielded = False             # holding the Hokuyo's arm stopped the sweep: its give-back resumes it
        # 0: the motors keep their last command for ever, as on a robot whose drivers have no command timeout;
        # every stop must then come from the stack (docs/robots.md, "No stop left to the motors")
        motor_timeout = params.number('motor_timeout', MOTOR_TIMEOUT_S, minimum=0, maximum=1.0) or math.inf
        base = BasePlant(motor_timeout=motor_timeout,
                         pose=planar_pose(rospy.get_param('~base_pose', [0.0, 0.0, 0.0]), 'base_pose'))
        self.robot = TreeModel(self.robot_urdf)
        self.world = TreeModel(self.world_urdf)
        self.devices = DeviceTable()
        self.lock = threading.Lock()
        self.frame_prefix = frame_prefix(params.text('frame_prefix', ''))
        self.origin = origin_matrix(rospy.get_param('~origin', [0.0, 0.0, 0.0]))

        # the drivers stamp their data with the prefix; set before the URDFs, which they wait for
        rospy.set_param('~frame_prefix', self.frame_prefix)
        with open(self.robot_urdf) as f:
            rospy.set_param('robot_description', f.read())
        rospy.set_param('~robot_urdf', self.robot_urdf)
        rospy.set_param('~world_urdf', self.world_urdf)

        self.pub_js = rospy.Publisher('joint_states', JointState, queue_size=10)
        self.pub_world_js = rospy.Publisher('~world_joint_states', JointState, queue_size=10)
        self.pub_tf = rospy.Publisher('/tf', TFMessage, queue_size=10)
        self.pub_tf_static = rospy.Publisher('/tf_static', TFMessage, queue_size=1, latch=True)
        self.pub_devices = rospy.Publisher('~device_states', DeviceStates, queue_size=1, latch=True)
        self.pub_base = rospy.Publisher('~base_state', BaseState, queue_size=50, tcp_nodelay=True)
        self.pub_contacts = rospy.Publisher('~contacts', ContactMsg, queue_size=50, tcp_nodelay=True)
        self.pub_arms = rospy.Publisher('~arm_states', ArmState, queue_size=50, tcp_nodelay=True)
        self.pub_gripper = rospy.Publisher('~gripper_state', GripperState, queue_size=50, tcp_nodelay=True)
        # the collision world: the robot and the world in a private pybullet copy, posed, never stepped
        ranges = {j.name: JointRange(j.lower, j.upper) for j in self.robot.joints}
        arms = {arm: ArmPlant(joints, STOW_POSE, ranges, motor_timeout)
                for arm, joints in joint_names(('left', 'right'), ARM_JOINTS).items()}
        gripper = GripperPlant(params.number('gripper_gap', STROKE, minimum=0, maximum=STROKE), motor_timeout)
        self.body = Body(Scene(self.robot_urdf, self.world_urdf), base, arms, gripper)
        self._publish_static()
        self.pub_map = rospy.Publisher('map', OccupancyGrid, queue_size=1, latch=True)
        self._publish_map()
        self._publish_devices()
        rospy.Service('~set_device_state', SetDeviceState, self._on_set_device)
        rospy.Service('~set_sweep', SetSweep, self._on_set_sweep)
        rospy.Service('~release_arm', ReleaseArm, self._on_release_arm)
        rospy.Subscriber('wheel_command', JointState, self._on_wheel_command, queue_size=10, tcp_nodelay=True)
        for arm in self.body.arms:
            rospy.Subscriber('%s/joint_command' % arm, JointState, self._on_arm_command, arm, queue_size=10,
                             tcp_nodelay=True)
        rospy.Subscriber('gripper/joint_command', JointState, self._on_gripper_command, queue_size=10,
                         tcp_nodelay=True)
        threading.Thread(target=self._watch_motors, name='motor command timeout', daemon=True).start()
        rospy.loginfo('vaultbot_sim: world %s, joint states at %.0f Hz', self.world_urdf, self.rate)

    def _frames(self, transforms: list) -> list:
        prefix = self.frame_prefix
        return [(prefix + parent, prefix + child, m) for parent, child, m in transforms] if prefix else transforms

    def _publish_map(self) -> None:
        """The lab's map, latched on ``map`` as a map server serves a saved one (``world_map.py``)."""
        grid = world_map(self.world)
        msg = OccupancyGrid()
        msg.header.stamp, msg.header.frame_id = rospy.Time.now(), self.frame_prefix + 'world'
        msg.info.map_load_time = msg.header.stamp
        msg.info.resolution = grid.resolution
        msg.info.width, msg.info.height = grid.size
        msg.info.origin.position.x, msg.info.origin.position.y = grid.origin
        msg.info.origin.orientation.w = 1.0
        msg.data = grid.cells.ravel().tolist()
        self.pub_map.publish(msg)

    def _publish_static(self) -> None:
        fixed = [('world', 'odom', np.eye(4))]
        fixed = self._frames(fixed + self.robot.fixed_transforms() + self.world.fixed_transforms())
        if self.frame_prefix:
            fixed.append(('world', self.frame_prefix + 'world', self.origin))
        self.pub_tf_static.publish(tf_message(fixed, rospy.Time.now()))

    def _device_msgs(self) -> list[DeviceState]:
        return [DeviceState(name=c.name, plugged=c.plugged, mode=c.mode) for c in self.devices.all()]

    def _publish_devices(self) -> None:
        msg = DeviceStates(devices=self._device_msgs())
        msg.header.stamp = rospy.Time.now()
        self.pub_devices.publish(msg)

    def _on_set_device(self, req) -> SetDeviceStateResponse:
        with self.lock:
            try:
                c = self.devices.set(req.device, req.state, req.mode)
            except DeviceError as e:
                rospy.logwarn('set_device_state: %s', e)
                return SetDeviceStateResponse(success=False, message=str(e), devices=self._device_msgs())
            self._publish_devices()
            text = f'{c.name} {"plugged" if c.plugged else "unplugged (" + c.mode + ")"}'
            rospy.loginfo('vaultbot_sim: %s', text)
            return SetDeviceStateResponse(success=True, message=text, devices=self._device_msgs())

    def _on_set_sweep(self, req) -> SetSweepResponse:
        with self.lock:
            try:
                self.state.sweep.set(bool(req.enabled), float(req.speed))
            except ValueError as e:
                return SetSweepResponse(success=False, message=str(e))
            self._sweep_yielded = False           # the operator's word: a give-back resumes only what yielded
            if req.enabled and self.body.arms['right_arm'].held:
                # whoever held the Hokuyo's arm gave it back: the sweep goes on from where the wrist is
                self._give_back('right_arm', rospy.get_time())
            text = f'sweep {"on" if req.enabled else "off"} at {self.state.sweep.speed:.3f} rad/s'
            rospy.loginfo('vaultbot_sim: %s', text)
            return SetSweepResponse(success=True, message=text)

    def _on_release_arm(self, req) -> ReleaseArmResponse:
        """The arm's controller was switched off (a clean stop: ``arm_controller.py``'s last words), as
        controller_manager gives the hardware back when a controller stops: nobody holds the arm, the sim's
        own pose keeps it where it is, and the Hokuyo's sweep goes on if holding the arm had stopped it. A
        controller that crashes or is killed says nothing, and its arm stays braked, as a UR's does."""
        arm = req.arm
        if arm not in self.body.arms:
            return ReleaseArmResponse(success=False, message='no arm %r: give one of %s'
                                      % (arm, ', '.join(sorted(self.body.arms))))
        with self.lock:
            if not self.body.arms[arm].held:
                return ReleaseArmResponse(success=True, message='%s: nobody held it' % arm)
            self._give_back(arm, max(req.sent.to_sec(), rospy.get_time()))
            if arm == 'right_arm' and self._sweep_yielded:
                self.state.sweep.set(True)
                self._sweep_yielded = False
                text = '%s given back: the sweep goes on' % arm
            else:
                text = '%s given back: it stays where it is' % arm
        rospy.loginfo('vaultbot_sim: %s', text)
        return ReleaseArmResponse(success=True, message=text)

    def _give_back(self, arm: str, sent: float) -> None:
        """Nobody holds ``arm`` from here (self.lock held): the sim's own pose takes it where it is (the sweep,
        the Hokuyo's wrist), and a setpoint stamped before ``sent`` takes nothing (``ArmPlant.release``)."""
        plant = self.body.arms[arm]
        with self.body.lock:
            if SWEEP_JOINT in plant.joints:
                self.state.sweep.position = plant.position[SWEEP_JOINT]
            self.state.hold.update({j: plant.position[j] for j in plant.joints if j != SWEEP_JOINT})
            plant.release(sent)

    # --- the motors -----------------------------------------------------------------------------------
    def _on_wheel_command(self, msg: JointState) -> None:
        try:
            left, right = wheel_command(msg)
        except ValueError as e:
            rospy.logerr_throttle(1.0, 'vaultbot_sim: wheel command refused: %s' % e)
            return
        if self.body.command_base(left, right, time.monotonic()):
            self._publish_base(rospy.Time.now())      # the stop's moment, not the next step's

    def _on_arm_command(self, msg: JointState, arm: str) -> None:
        """A setpoint per joint (positions and velocities), or a stop: velocities only, all zero (brake to a
        hold where the joints are; a hold sent as positions would pull the arm back to where it was seen). A stop
        takes no arm that nobody holds: only a setpoint takes the Hokuyo's from its sweep."""
        if not msg.position and msg.velocity and all(v == 0.0 for v in msg.velocity):
            if self.body.stop_arm(arm, time.monotonic()):
                self._publish_arm(arm, rospy.Time.now())
            return
        try:
            if len(msg.name) != len(msg.position) or len(msg.name) != len(msg.velocity):
                raise ValueError('%d names, %d positions and %d velocities' % (len(msg.name), len(msg.position),
                                                                               len(msg.velocity)))
            if self.body.command_arm(arm, {n: (q, v) for n, q, v in zip(msg.name, msg.position, msg.velocity)},
                                     time.monotonic(), msg.header.stamp.to_sec()):
                self._publish_arm(arm, rospy.Time.now())      # the hold's moment, not the next step's
        except ValueError as e:
            rospy.logerr_throttle(1.0, 'vaultbot_sim: %s command refused: %s' % (arm, e))

    def _on_gripper_command(self, msg: JointState) -> None:
        """A setpoint for the fingers, as for an arm's joints: each finger's joint (half the gap) and the speed
        to move it with; or a stop (velocities only, all zero)."""
        if not msg.position and msg.velocity and all(v == 0.0 for v in msg.velocity):
            self.body.stop_gripper(time.monotonic())
            self._publish_gripper(rospy.Time.now())
            return
        try:
            if len(msg.name) != len(msg.position) or len(msg.name) != len(msg.velocity) or not msg.name:
                raise ValueError('%d names, %d positions and %d velocities' % (len(msg.name), len(msg.position),
                                                                               len(msg.velocity)))
            unknown = sorted(set(msg.name) - set(GRIPPER_JOINTS))
            if unknown:
                raise ValueError('not joints of the gripper: %s (use %s)' % (', '.join(unknown),
                                                                           ', '.join(GRIPPER_JOINTS)))
            if len(set(msg.position)) != 1 or len(set(msg.velocity)) != 1:
                raise ValueError('the fingers move together: one position and one velocity for both')
            self.body.command_gripper(2 * msg.position[0], 2 * abs(msg.velocity[0]), time.monotonic())
        except ValueError as e:
            rospy.logerr_throttle(1.0, 'vaultbot_sim: gripper command refused: %s' % e)

    def _watch_motors(self) -> None:
        """The motors' own command timeout, on its own thread: a stale command is dropped within the timeout, whatever
        the sim's step rate, and the moment is published at once (the ground truth of the stop)."""
        while ok():
            for part in self.body.drop_stale(time.monotonic()):
                stamp = rospy.Time.now()
                if part == 'base':
                    self._publish_base(stamp)
                elif part == 'gripper':
                    self._publish_gripper(stamp)
                else:
                    self._publish_arm(part, stamp)
            self.body.wait_for_deadline(time.monotonic())

    def _publish_base(self, stamp: rospy.Time) -> None:
        with self.body.lock:
            plant = self.body.base
            msg = BaseState(x=plant.pose[0], y=plant.pose[1], yaw=plant.pose[2], linear=plant.velocity[0],
                            angular=plant.velocity[1], commanded_linear=plant.commanded[0],
                            commanded_angular=plant.commanded[1], command_stale=plant.tripped_at is not None,
                            contacts=self.body.contacts)
        msg.header.stamp = stamp
        self.pub_base.publish(msg)

    def _publish_arm(self, arm: str, stamp: rospy.Time) -> None:
        commanded, speed = self.body.arm_speeds(arm)
        plant = self.body.arms[arm]
        msg = ArmState(arm=arm, held=plant.held, command_stale=plant.tripped_at is not None,
                       commanded_speed=commanded, speed=speed)
        msg.header.stamp = stamp
        self.pub_arms.publish(msg)

    def _publish_gripper(self, stamp: rospy.Time) -> None:
        with self.body.lock:
            plant = self.body.gripper
            msg = GripperState(gap=plant.gap, speed=plant.velocity, has_setpoint=plant.setpoint is not None,
                               setpoint_gap=plant.setpoint[0] if plant.setpoint else 0.0,
                               command_stale=plant.tripped_at is not None, blocked=plant.blocked_at is not None)
        msg.header.stamp = stamp
        self.pub_gripper.publish(msg)

    def _step_body(self, hold: dict, stamp: rospy.Time):
        with self.lock:
            right = self.body.arms['right_arm']
            if right.held and self.state.sweep.enabled:
                self.state.sweep.set(False)           # someone holds the Hokuyo's arm: the sweep yields
                self._sweep_yielded = True
                rospy.loginfo('vaultbot_sim: the right arm is held: the sweep stops')
        step = self.body.step(time.monotonic(), hold)
        for contact, speed in step.contacts:
            msg = ContactMsg(robot_link=contact.robot_link, object_link=contact.object_link, x=contact.x,
                             y=contact.y, speed=speed)
            msg.header.stamp = stamp
            self.pub_contacts.publish(msg)
            rospy.logwarn('vaultbot_sim: contact: %s touched %s at (%.2f, %.2f), %.2f m/s', contact.robot_link,
                          contact.object_link, contact.x, contact.y, speed)
        self._publish_base(stamp)
        for arm in self.body.arms:
            self._publish_arm(arm, stamp)
        self._publish_gripper(stamp)
        return step

    def step(self) -> None:
        now = rospy.Time.now()
        with self.lock:
            (names, pos, vel), (wnames, wpos, wvel) = self.state.step(now.to_sec())
        body = self._step_body(dict(zip(names, pos)), now)
        keep = [i for i, n in enumerate(names) if n not in body.names]
        names = [names[i] for i in keep] + body.names
        pos = [pos[i] for i in keep] + body.positions
        vel = [vel[i] for i in keep] + body.velocities
        js = JointState(name=names, position=pos, velocity=vel)
        js.header.stamp = now
        self.pub_js.publish(js)
        wjs = JointState(name=wnames, position=wpos, velocity=wvel)
        wjs.header.stamp = now
        self.pub_world_js.publish(wjs)
        moving = self.robot.moving_transforms(dict(zip(names, pos)))
        moving += self.world.moving_transforms(dict(zip(wnames, wpos)))
        self.pub_tf.publish(tf_message(self._frames(moving), now))

    def spin(self) -> None:
        rate = rospy.Rate(self.rate)
        while ok():
            self.step()
            try:
                rate.sleep()
            except rospy.ROSInterruptException:
                break
