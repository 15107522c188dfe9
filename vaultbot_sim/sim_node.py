"""The vaultbot_sim node: owns the world, the robot's joint state, TF and the device cables.

No physics runs here: the robot is kinematic (held pose + Hokuyo wrist sweep)
and the drivers render their sensors from what this node publishes.
TF is published directly (tf2_msgs/TFMessage), computed from the URDF, so no
robot_state_publisher or tf2_ros is needed.

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

import rosgraph
import rospy
from temoto_core.node import ok
from temoto_core import params
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

import numpy as np

from vaultbot_sim.devices import DeviceError, DeviceTable
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel, resolve_world
from vaultbot_sim.motion import HandWave, SimState, WristSweep
from vaultbot_sim.msg import DeviceState, DeviceStates
from vaultbot_sim.rosmsgs import tf_message
from vaultbot_sim.spec import HOLD_POSE, SWEEP_JOINT
from vaultbot_sim.srv import SetDeviceState, SetDeviceStateResponse, SetSweep, SetSweepResponse


def frame_prefix(value: object) -> str:
    """``~frame_prefix`` checked: '' or a legal name, ending in '/' (``vaultbot_2`` -> ``vaultbot_2/``)."""
    prefix = str(value or '').strip('/')
    if prefix and not rosgraph.names.is_legal_base_name(prefix.replace('/', '_')):
        raise ValueError('~frame_prefix %r: letters, digits, _ and / only, starting with a letter' % (value,))
    return prefix + '/' if prefix else ''


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
        self._publish_static()
        self._publish_devices()
        rospy.Service('~set_device_state', SetDeviceState, self._on_set_device)
        rospy.Service('~set_sweep', SetSweep, self._on_set_sweep)
        rospy.loginfo('vaultbot_sim: world %s, joint states at %.0f Hz', self.world_urdf, self.rate)

    def _frames(self, transforms: list) -> list:
        prefix = self.frame_prefix
        return [(prefix + parent, prefix + child, m) for parent, child, m in transforms] if prefix else transforms

    def _publish_static(self) -> None:
        fixed = [('world', self.robot.root, np.eye(4))]
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

    def step(self) -> None:
        now = rospy.Time.now()
        with self.lock:
            (names, pos, vel), (wnames, wpos, wvel) = self.state.step(now.to_sec())
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
