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
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

import numpy as np

from vaultbot_sim.base import MOTOR_TIMEOUT_S, BasePlant, Contact, wheel_speeds
from vaultbot_sim.devices import DeviceError, DeviceTable
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel, resolve_world
from vaultbot_sim.motion import HandWave, SimState, WristSweep
from vaultbot_sim.msg import BaseState, Contact as ContactMsg, DeviceState, DeviceStates
from vaultbot_sim.rosmsgs import tf_message
from vaultbot_sim.scene import Scene
from vaultbot_sim.spec import BASE_JOINTS, HOLD_POSE, SWEEP_JOINT, WHEEL_JOINTS
from vaultbot_sim.srv import SetDeviceState, SetDeviceStateResponse, SetSweep, SetSweepResponse


def frame_prefix(value: object) -> str:
    """``~frame_prefix`` checked: '' or a legal name, ending in '/' (``vaultbot_2`` -> ``vaultbot_2/``)."""
    prefix = str(value or '').strip('/')
    if prefix and not rosgraph.names.is_legal_base_name(prefix.replace('/', '_')):
        raise ValueError('~frame_prefix %r: letters, digits, _ and / only, starting with a letter' % (value,))
    return prefix + '/' if prefix else ''


# a touch lasts until the robot is this far from what it touched: a base held against a wall does not count a
# new contact at every creep of a step
CONTACT_MARGIN = 0.01


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
    try:
        x, y, yaw = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError('~origin %r: expected [x, y, yaw] in metres and radians' % (value,)) from None
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise ValueError('~origin %r: every value must be finite' % (value,))
    m = np.eye(4)
    m[0, 0], m[0, 1], m[1, 0], m[1, 1] = math.cos(yaw), -math.sin(yaw), math.sin(yaw), math.cos(yaw)
    m[0, 3], m[1, 3] = x, y
    return m


class SimNode:
    def __init__(self):
        world = params.text('world', 'lab', empty=False)
        self.world_urdf = resolve_world(world)
        self.robot_urdf = params.text('robot_urdf', ROBOT_URDF, empty=False)
        self.rate = params.number('rate', 50.0, above=0, maximum=1000)
        sweep = WristSweep(HOLD_POSE[SWEEP_JOINT], amplitude=params.number('sweep_amplitude', math.pi / 2, minimum=0),
                           speed=params.number('sweep_speed', math.pi / 2, above=0),
                           enabled=params.flag('sweep', True))
        hand = HandWave(amplitude=params.number('hand_amplitude', 0.3, minimum=0),
                        period=params.number('hand_period', 8.0, above=0),
                        enabled=params.flag('hand_motion', True))
        self.state = SimState(sweep, hand)
        self.plant = BasePlant(motor_timeout=params.number('motor_timeout', MOTOR_TIMEOUT_S, above=0, maximum=1.0),
                               pose=planar_pose(rospy.get_param('~base_pose', [0.0, 0.0, 0.0]), 'base_pose'))
        self.contacts = 0
        self.touching: set = set()          # (robot link, world link) pairs within CONTACT_MARGIN now
        self.touching_next: set = set()
        self._motors = threading.Condition()
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
        # the collision world: the robot and the world in a private pybullet copy, posed, never stepped
        self.collider = Scene(self.robot_urdf, self.world_urdf)
        self._publish_static()
        self._publish_devices()
        rospy.Service('~set_device_state', SetDeviceState, self._on_set_device)
        rospy.Service('~set_sweep', SetSweep, self._on_set_sweep)
        rospy.Subscriber('wheel_command', JointState, self._on_wheel_command, queue_size=10, tcp_nodelay=True)
        threading.Thread(target=self._watch_motors, name='motor watchdog', daemon=True).start()
        rospy.loginfo('vaultbot_sim: world %s, joint states at %.0f Hz', self.world_urdf, self.rate)

    def _frames(self, transforms: list) -> list:
        prefix = self.frame_prefix
        return [(prefix + parent, prefix + child, m) for parent, child, m in transforms] if prefix else transforms

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
            text = f'sweep {"on" if req.enabled else "off"} at {self.state.sweep.speed:.3f} rad/s'
            rospy.loginfo('vaultbot_sim: %s', text)
            return SetSweepResponse(success=True, message=text)

    # --- the base's motors and body -------------------------------------------------------
    def _on_wheel_command(self, msg: JointState) -> None:
        try:
            left, right = wheel_command(msg)
            with self._motors:
                self.plant.command(left, right, time.monotonic())
                self._motors.notify()
        except ValueError as e:
            rospy.logerr_throttle(1.0, 'vaultbot_sim: wheel command refused: %s' % e)

    def _watch_motors(self) -> None:
        """The motors' own watchdog, on its own thread: a stale command is replaced by zero within the timeout,
        whatever the sim's step rate, and the moment is published at once (the ground truth of the stop)."""
        while ok():
            with self._motors:
                now = time.monotonic()
                if self.plant.watchdog(now):
                    self._publish_base(rospy.Time.now())
                last = self.plant.command_at
                wait = 0.5 if last is None or self.plant.commanded == (0.0, 0.0) else \
                    max(0.0, last + self.plant.motor_timeout - now) + 0.0005
                self._motors.wait(wait)

    def _touching(self, robot_cfg: dict):
        """The collision check of a candidate pose: the first new contact, or None when the pose is free."""
        def check(pose):
            cfg = dict(robot_cfg, **dict(zip(BASE_JOINTS, pose)))
            self.collider.set_robot(cfg)
            near = self.collider.contacts(margin=CONTACT_MARGIN)
            self.touching_next = {(a, b) for a, b, _ in near}
            overlap = [(a, b) for a, b, d in near if d <= 0.0]
            return Contact(overlap[0][0], overlap[0][1], pose[0], pose[1]) if overlap else None
        return check

    def _publish_base(self, stamp: rospy.Time) -> None:
        plant = self.plant
        msg = BaseState(x=plant.pose[0], y=plant.pose[1], yaw=plant.pose[2], linear=plant.velocity[0],
                        angular=plant.velocity[1], commanded_linear=plant.commanded[0],
                        commanded_angular=plant.commanded[1], command_stale=plant.tripped_at is not None,
                        contacts=self.contacts)
        msg.header.stamp = stamp
        self.pub_base.publish(msg)

    def _step_base(self, robot_cfg: dict, stamp: rospy.Time) -> tuple[list, list, list]:
        with self._motors:
            speed = abs(self.plant.velocity[0])
            self.touching_next = self.touching          # unchanged unless the base tries to move
            contact = self.plant.step(time.monotonic(), self._touching(robot_cfg))
            began = contact is not None and not self.touching
            self.touching = self.touching_next
            if began:                                   # one event per touch, however long it is pushed
                self.contacts += 1
                msg = ContactMsg(robot_link=contact.robot_link, object_link=contact.object_link, x=contact.x,
                                 y=contact.y, speed=speed)
                msg.header.stamp = stamp
                self.pub_contacts.publish(msg)
                rospy.logwarn('vaultbot_sim: contact: %s touched %s at (%.2f, %.2f), %.2f m/s', contact.robot_link,
                              contact.object_link, contact.x, contact.y, speed)
            self._publish_base(stamp)
            return self._base_joints()

    def _base_joints(self) -> tuple[list, list, list]:
        """The base's virtual joints and the wheels: names, positions, velocities (lock held)."""
        plant = self.plant
        (x, y, yaw), (v, w) = plant.pose, plant.velocity
        left, right = plant.wheels
        wheel_v = wheel_speeds(v, w)
        names = list(BASE_JOINTS) + list(WHEEL_JOINTS)
        pos = [x, y, yaw] + [left if 'left' in n else right for n in WHEEL_JOINTS]
        vel = [v * math.cos(yaw), v * math.sin(yaw), w] + [wheel_v[0] if 'left' in n else wheel_v[1]
                                                            for n in WHEEL_JOINTS]
        return names, pos, vel

    def step(self) -> None:
        now = rospy.Time.now()
        with self.lock:
            (names, pos, vel), (wnames, wpos, wvel) = self.state.step(now.to_sec())
        cfg = dict(zip(names, pos))
        bnames, bpos, bvel = self._step_base(cfg, now)
        keep = [i for i, n in enumerate(names) if n not in WHEEL_JOINTS]
        names = [names[i] for i in keep] + bnames
        pos = [pos[i] for i in keep] + bpos
        vel = [vel[i] for i in keep] + bvel
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
