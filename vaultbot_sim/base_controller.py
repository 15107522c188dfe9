"""The Husky's base controller: ``cmd_vel`` in, wheel commands out, odometry from the wheel encoders.

As a real base driver does (husky_base with diff_drive_controller):
- ``cmd_vel`` (``geometry_msgs/Twist``) is clamped to the top speeds and reached within the
  acceleration limits (``base.CommandShaper``); a command with a NaN or an infinity is refused,
  logged, and changes nothing;
- no ``cmd_vel`` for ``~cmd_vel_timeout`` (0.25 s): it commands zero at once, and the motors brake
  at their limit. A dead commander never leaves the robot moving;
- it streams the wheel speeds to the motors (``wheel_command``) at ``base.COMMAND_RATE_HZ`` while
  they are not zero, and a zero once a second at rest. The motors have a command timeout of their own
  (``base.MOTOR_TIMEOUT_S``), so a controller that dies or stalls leaves the base braking;
- it publishes ``odom`` (``nav_msgs/Odometry``) and ``/tf`` ``odom -> base_link`` from the wheels'
  joint states, at their rate (50 Hz);
- its cable is the sim's ``base`` device: ``temoto sim unplug base --mode crash`` makes it exit 1,
  ``--mode stall`` makes it stop every output while its process stays up.
"""
from __future__ import annotations

import threading
import time

import rospy
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

from temoto_core import params
from temoto_core.node import init_node, ok
from vaultbot_sim.base import (CMD_VEL_TIMEOUT_S, COMMAND_RATE_HZ, CommandShaper, WheelOdometry, wheel_speeds)
from vaultbot_sim.cable_follower import CableFollower, fail
from vaultbot_sim.kinematics import planar_matrix, quat_from_matrix
from vaultbot_sim.rosmsgs import tf_message
from vaultbot_sim.spec import BASE_JOINTS, WHEEL_JOINTS
from vaultbot_sim.ticks import Ticks

IDLE_PERIOD_S = 1.0     # at rest, one zero command a second


class BaseController:
    def __init__(self) -> None:
        self.sim_ns = rospy.resolve_name(params.text('sim_ns', 'vaultbot_sim', empty=False)).rstrip('/')
        self.shaper = CommandShaper(timeout=params.number('cmd_vel_timeout', CMD_VEL_TIMEOUT_S, above=0,
                                                          maximum=10.0))
        self.rate = params.number('rate', COMMAND_RATE_HZ, above=0, maximum=1000)
        startup_timeout = params.number('startup_timeout', 10.0, above=0)
        self.lock = threading.Lock()
        self.odometry: WheelOdometry | None = None
        self.pub_wheels = rospy.Publisher('wheel_command', JointState, queue_size=10, tcp_nodelay=True)
        self.pub_odom = rospy.Publisher('odom', Odometry, queue_size=10, tcp_nodelay=True)
        self.pub_tf = rospy.Publisher('/tf', TFMessage, queue_size=10, tcp_nodelay=True)
        self.cable = CableFollower('base', 'base: motor controller', self.sim_ns)
        if not self.cable.seen.wait(startup_timeout):
            fail('base: nothing on %s/device_states after %.0f s (is vaultbot_sim running?)'
                      % (self.sim_ns, startup_timeout))
        prefix = str(rospy.get_param(self.sim_ns + '/frame_prefix', ''))
        self.odom_frame, self.base_frame = prefix + 'odom', prefix + 'base_link'
        rospy.Subscriber('joint_states', JointState, self._on_joint_states, queue_size=20, tcp_nodelay=True)
        rospy.Subscriber('cmd_vel', Twist, self._on_cmd_vel, queue_size=10, tcp_nodelay=True)
        rospy.on_shutdown(self._stop_motors)

    @property
    def running(self) -> bool:
        return self.cable.running

    def _on_cmd_vel(self, msg: Twist) -> None:
        try:
            with self.lock:
                self.shaper.request(msg.linear.x, msg.angular.z, time.monotonic())
        except ValueError as e:
            rospy.logerr_throttle(1.0, 'base: %s; refused' % e)

    def _on_joint_states(self, msg: JointState) -> None:
        if not self.running:
            return
        pos = dict(zip(msg.name, msg.position))
        try:
            left = (pos['front_left_wheel_joint'] + pos['rear_left_wheel_joint']) / 2
            right = (pos['front_right_wheel_joint'] + pos['rear_right_wheel_joint']) / 2
        except KeyError:
            return                               # not a state with the wheels (another publisher's)
        t = msg.header.stamp.to_sec()
        with self.lock:
            if self.odometry is None:
                self.odometry = WheelOdometry(tuple(pos.get(n, 0.0) for n in BASE_JOINTS))
            x, y, yaw = self.odometry.update(left, right, t)
            linear, angular = self.odometry.velocity
        odom = Odometry()
        odom.header.stamp, odom.header.frame_id, odom.child_frame_id = msg.header.stamp, self.odom_frame, \
            self.base_frame
        odom.pose.pose.position.x, odom.pose.pose.position.y = x, y
        q = odom.pose.pose.orientation
        q.x, q.y, q.z, q.w = quat_from_matrix(planar_matrix(0.0, 0.0, yaw))
        odom.twist.twist.linear.x, odom.twist.twist.angular.z = linear, angular
        self.pub_odom.publish(odom)
        self.pub_tf.publish(tf_message([(self.odom_frame, self.base_frame, planar_matrix(x, y, yaw))],
                                       msg.header.stamp))

    def _wheel_command(self, linear: float, angular: float) -> JointState:
        left, right = wheel_speeds(linear, angular)
        cmd = JointState(name=list(WHEEL_JOINTS), velocity=[left if 'left' in n else right for n in WHEEL_JOINTS])
        cmd.header.stamp = rospy.Time.now()
        return cmd

    def _stop_motors(self) -> None:
        """A clean stop tells the motors zero at once, rather than leaving it to their command timeout."""
        if self.running:
            self.pub_wheels.publish(self._wheel_command(0.0, 0.0))

    def spin(self) -> None:
        ticks = Ticks(1.0 / self.rate)
        rospy.loginfo('base: commanding the wheels at %.0f Hz; cmd_vel timeout %.2f s', self.rate,
                      self.shaper.timeout)
        idle_since = None                   # when the command last became zero
        while ok():
            if self.running:
                now = time.monotonic()
                with self.lock:
                    linear, angular = self.shaper.step(now)
                # at rest, a zero now and then: the motors hold zero by themselves, and a robot that stands
                # most of the time should not cost 100 messages a second
                if (linear, angular) != (0.0, 0.0):
                    idle_since = None
                    self.pub_wheels.publish(self._wheel_command(linear, angular))
                elif idle_since is None or now - idle_since >= IDLE_PERIOD_S:
                    idle_since = now
                    self.pub_wheels.publish(self._wheel_command(0.0, 0.0))
            ticks.wait()


def main() -> None:
    init_node('base_controller')
    try:
        controller = BaseController()
    except ValueError as e:          # a bad parameter: say which
        rospy.logerr('base_controller: %s', e)
        raise SystemExit(2)
    controller.spin()
