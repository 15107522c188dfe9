"""The Husky base: the rules alone (vaultbot_sim/base.py), then the sim's motors and the base controller as
processes on a real roscore, judged by the sim's ground truth (``/vaultbot_sim/base_state``), never by the
controller's word."""
import math
import os
import signal
import threading
import time

import pytest
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from sensor_msgs.msg import JointState

from temoto_core.master_lookup import lookup_node, node_pid
from temoto_testing import wait_for, wait_receiving
from temoto_testing.sensor_manager import set_cable
from vaultbot_sim.base import (HUSKY, BasePlant, CommandShaper, Contact, WheelOdometry, body_velocity, ramp,
                               wheel_speeds)
from vaultbot_sim.msg import BaseState, Contact as ContactMsg
from vaultbot_sim.urdf_gen import TEST_WALL_X

HANG = 30.0
SIM_PARAMS = {'world': 'test_wall', 'sweep': False, 'hand_motion': False}


# ----------------------------------------------------------------------------------------------- the rules
def test_ramp_speeds_up_and_brakes_at_their_own_limits():
    assert ramp(0.0, 1.0, 1.0, 2.0, 0.1) == pytest.approx(0.1)
    assert ramp(1.0, 0.0, 1.0, 2.0, 0.1) == pytest.approx(0.8)       # braking: the larger limit
    assert ramp(0.5, -0.5, 1.0, 2.0, 0.1) == pytest.approx(0.3)      # reversing brakes first
    assert ramp(0.95, 1.0, 1.0, 2.0, 0.1) == 1.0                     # no overshoot


def test_the_shaper_clamps_ramps_and_commands_zero_at_once_when_cmd_vel_falls_silent():
    shaper = CommandShaper(timeout=0.25)
    shaper.request(5.0, -9.0, 0.0)
    assert shaper.target == (HUSKY.max_speed, -HUSKY.max_turn)
    shaper.step(0.0)
    assert shaper.step(0.1) == pytest.approx((0.1, -0.3))
    assert shaper.step(0.2) == pytest.approx((0.2, -0.6))
    assert shaper.step(0.26) == (0.0, 0.0), 'silent for more than its timeout: zero at once, not a ramp'
    with pytest.raises(ValueError, match='finite'):
        shaper.request(float('nan'), 0.0, 0.3)
    assert shaper.step(0.31) == (0.0, 0.0), 'a refused command changed nothing'


def test_the_shaper_passes_a_stop_on_at_once_and_ramps_any_other_slowing():
    shaper = CommandShaper(timeout=0.25)
    shaper.request(1.0, 0.0, 0.0)
    for t in (0.0, 0.5, 1.0):
        shaper.request(1.0, 0.0, t)
        shaper.step(t)
    assert shaper.output == pytest.approx((1.0, 0.0))
    shaper.request(0.5, 0.0, 1.0)
    assert shaper.step(1.1) == pytest.approx((0.8, 0.0)), 'slowing to a lower speed ramps at the braking limit'
    shaper.request(0.0, 0.0, 1.1)
    assert shaper.step(1.11) == (0.0, 0.0), 'a stop reaches the motors at once; they brake at their own limit'


def test_the_motors_follow_their_command_and_their_command_timeout_zeroes_a_stale_one():
    plant = BasePlant(motor_timeout=0.04)
    plant.command(*wheel_speeds(0.5, 0.0), now=0.0)
    plant.step(0.0)
    for i in range(1, 4):
        plant.command(*wheel_speeds(0.5, 0.0), now=i * 0.01)
        plant.step(i * 0.01)
    assert plant.velocity[0] == pytest.approx(0.03) and plant.commanded[0] == pytest.approx(0.5)
    assert not plant.drop_stale(0.0695)
    assert plant.drop_stale(0.0705) and plant.commanded == (0.0, 0.0) and plant.tripped_at == 0.0705
    plant.step(0.08)
    assert plant.velocity[0] == pytest.approx(0.0), 'braked at 2 m/s^2 from 0.03 m/s'


def test_a_touching_pose_is_not_entered_and_the_base_stops_where_it_touched():
    plant = BasePlant()
    plant.velocity = (1.0, 0.0)
    plant.command(*wheel_speeds(1.0, 0.0), now=0.0)
    plant.step(0.0)
    wall = Contact('chassis_link', 'wall', 0.0, 0.0)
    contact = plant.step(0.02, touching=lambda pose: wall if pose[0] > 0.01 else None)
    assert contact is wall and plant.at_rest
    assert 0.01 - 0.02 / 64 <= plant.pose[0] <= 0.01, 'stopped at the last free 64th of the step'
    assert plant.wheels[0] * 0.165 == pytest.approx(plant.pose[0]), 'the wheels turned as far as it went'


def test_wheel_odometry_integrates_what_the_wheels_turned():
    left, right = wheel_speeds(0.5, 0.4)
    assert body_velocity(left, right) == pytest.approx((0.5, 0.4))
    plant, odom = BasePlant(), WheelOdometry()
    odom.update(*plant.wheels, 0.0)
    for i in range(1, 201):
        plant.command(left, right, i * 0.02)
        plant.step(i * 0.02)
        odom.update(*plant.wheels, i * 0.02)
    assert odom.pose == pytest.approx(plant.pose, abs=1e-4)     # the midpoint rule against the exact arc
    assert odom.velocity == pytest.approx(plant.velocity, abs=1e-6)


# ----------------------------------------------------------------------------------------------- processes
class CmdVel:
    """A commander: publishes one Twist at 20 Hz on a thread, until told otherwise or ``stop()``."""

    def __init__(self, rospy, topic='/cmd_vel'):
        self.pub = rospy.Publisher(topic, Twist, queue_size=10, tcp_nodelay=True)
        self.linear = self.angular = 0.0
        self.last_sent = 0.0           # wall time of the last message
        self._stop = threading.Event()
        self._thread = None
        self._rospy = rospy

    def send(self, linear: float, angular: float = 0.0) -> None:
        self.linear, self.angular = linear, angular
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, daemon=True, name='cmd_vel')
            self._thread.start()

    def _run(self):
        for _ in range(int(HANG * 20)):        # bounded: at most HANG seconds of commands
            if self._stop.is_set():
                return
            msg = Twist()
            msg.linear.x, msg.angular.z = self.linear, self.angular
            self.pub.publish(msg)
            self.last_sent = time.time()
            self._stop.wait(0.05)

    def stop(self) -> float:
        """Stop commanding; the wall time of the last message sent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(HANG)
        return self.last_sent

    def close(self):
        self.stop()
        self.pub.unregister()


@pytest.fixture
def base(procs, rospy_client, collect):
    """The sim in the test world, its base controller, a commander, and the ground truth."""
    truth = collect('/vaultbot_sim/base_state', BaseState)
    contacts = collect('/vaultbot_sim/contacts', ContactMsg)
    odom = collect('/odom', Odometry)
    sim = procs.node('vaultbot_sim', 'vaultbot_sim', params=SIM_PARAMS)
    controller = procs.node('vaultbot_sim', 'base_controller')
    cmd = CmdVel(rospy_client)
    wait_receiving([truth.sub, contacts.sub, odom.sub], HANG, 'the sim\'s and the controller\'s topics')
    wait_for(lambda: cmd.pub.get_num_connections() > 0, HANG, 'the controller to subscribe to cmd_vel')
    wait_for(lambda: truth.last() is not None, HANG, 'the base\'s first ground truth')
    yield dict(truth=truth, contacts=contacts, odom=odom, sim=sim, controller=controller, cmd=cmd)
    cmd.close()


def latest(log):
    msg = log.last()
    assert msg is not None
    return msg


def stamps(log, after=0.0):
    with log.lock:
        return [m for m in log.msgs if m.header.stamp.to_sec() > after]


def test_cmd_vel_drives_the_base_within_its_limits_and_odometry_follows_the_truth(base):
    truth, odom, cmd = base['truth'], base['odom'], base['cmd']
    start = time.time()
    cmd.send(3.0)                 # three times the Husky's top speed: clamped
    wait_for(lambda: latest(truth).x > 1.0, HANG, 'the base to drive a metre')
    states = stamps(truth, start)
    assert max(s.linear for s in states) <= HUSKY.max_speed + 1e-9
    assert max(s.commanded_linear for s in states) <= HUSKY.max_speed + 1e-9
    for a, b in zip(states, states[1:]):
        dt = b.header.stamp.to_sec() - a.header.stamp.to_sec()
        if dt > 0.005 and b.linear > a.linear:
            assert (b.linear - a.linear) / dt <= HUSKY.accel * 1.5, 'accelerated beyond the limit'
    last_cmd = cmd.stop()
    zeroed = wait_for(lambda: next((s for s in stamps(truth, last_cmd) if s.commanded_linear == 0.0), None),
                      HANG, 'the commanded velocity to be zero once cmd_vel stopped')
    waited = zeroed.header.stamp.to_sec() - last_cmd
    assert 0.2 <= waited <= 5.0, 'zero %.3f s after the last cmd_vel: the timeout is 0.25 s' % waited
    rest = wait_for(lambda: next((s for s in stamps(truth, zeroed.header.stamp.to_sec()) if s.linear == 0.0), None),
                    HANG, 'the base at rest')
    assert rest.x < TEST_WALL_X - 0.6 and not base['contacts'].msgs
    # odometry from the wheel encoders says where the truth says, at the same stamp
    by_stamp = {m.header.stamp.to_nsec(): m for m in stamps(truth, start)}
    pairs = [(o, by_stamp[o.header.stamp.to_nsec()]) for o in stamps(odom, start)
             if o.header.stamp.to_nsec() in by_stamp]
    assert len(pairs) > 20, 'odometry at the joint states\' rate, stamped as the truth'
    for o, t in pairs:
        assert math.hypot(o.pose.pose.position.x - t.x, o.pose.pose.position.y - t.y) < 0.01
    assert base['controller'].alive() and base['sim'].alive()


def drive_until_moving(base, speed=0.5):
    base['cmd'].send(speed)
    return wait_for(lambda: latest(base['truth']).linear >= speed * 0.9, HANG, 'the base to drive')


def test_a_killed_controller_leaves_the_motors_braking(base):
    truth = base['truth']
    drive_until_moving(base)
    killed = time.time()
    os.kill(base['controller'].pid, signal.SIGKILL)       # the commander goes on sending cmd_vel
    tripped = wait_for(lambda: next((s for s in stamps(truth, killed) if s.command_stale), None), HANG,
                       'the motors\' command timeout to trip')
    assert tripped.commanded_linear == 0.0 and tripped.header.stamp.to_sec() - killed < 1.0
    wait_for(lambda: latest(truth).linear == 0.0, HANG, 'the base at rest')
    wait_for(lambda: not base['controller'].alive(), HANG, 'the controller to be gone')


def test_a_stalled_controller_stays_up_and_the_motors_stop(base):
    truth = base['truth']
    drive_until_moving(base)
    stalled = time.time()
    set_cable('base', 'unplugged', 'stall')
    try:
        wait_for(lambda: any(s.command_stale for s in stamps(truth, stalled)), HANG, 'the motors\' command timeout')
        wait_for(lambda: latest(truth).linear == 0.0, HANG, 'the base at rest')
        assert base['controller'].alive(), 'a stall keeps the process up'
        before, since = latest(truth).x, time.time()
        wait_for(lambda: latest(truth).header.stamp.to_sec() > since + 1.0, HANG, 'a second of truth')
        assert latest(truth).x == before and latest(truth).commanded_linear == 0.0, 'a stalled controller moved it'
    finally:
        set_cable('base', 'plugged')


def test_a_crashed_controller_exits_1_and_the_motors_stop(base):
    truth = base['truth']
    drive_until_moving(base)
    set_cable('base', 'unplugged', 'crash')
    try:
        wait_for(lambda: not base['controller'].alive(), HANG, 'the controller to exit')
        assert base['controller'].returncode == 1
        assert 'motor controller disconnected' in base['controller'].log()
        wait_for(lambda: latest(truth).linear == 0.0 and latest(truth).commanded_linear == 0.0, HANG,
                 'the base at rest')
    finally:
        set_cable('base', 'plugged')


def test_driving_into_the_wall_is_one_contact_and_the_base_stops_short_of_it(base):
    truth, contacts = base['truth'], base['contacts']
    base['cmd'].send(1.0)
    touch = wait_for(contacts.last, HANG, 'a contact with the wall')
    assert touch.object_link == 'wall' and touch.speed > 0.0
    wait_for(lambda: latest(truth).contacts == 1 and latest(truth).linear == 0.0, HANG, 'the base stopped on it')
    pushed = time.time()
    wait_for(lambda: latest(truth).header.stamp.to_sec() > pushed + 1.0, HANG, 'a second of pushing')
    assert len(contacts.msgs) == 1 and latest(truth).contacts == 1, 'one touch counts once, however long'
    assert latest(truth).x < TEST_WALL_X - 0.3, 'the base went through the wall'
    at_wall = latest(truth).x
    base['cmd'].send(-0.3)
    wait_for(lambda: latest(truth).x < at_wall - 0.1, HANG, 'the base to back away')


def test_bad_commands_are_refused_by_name_and_move_nothing(base, rospy_client):
    truth = base['truth']
    base['cmd'].send(float('nan'))
    wheels = rospy_client.Publisher('/wheel_command', JointState, queue_size=10)
    try:
        wait_for(lambda: wheels.get_num_connections() > 0, HANG, 'the sim to subscribe to wheel_command')
        wheels.publish(JointState(name=['front_left_wheel_joint', 'tail_wheel_joint'], velocity=[5.0, 5.0]))
        wait_for(lambda: 'refused' in base['controller'].log() and 'refused' in base['sim'].log(), HANG,
                 'both refusals in the logs')
    finally:
        wheels.unregister()
    assert 'finite' in base['controller'].log() and 'tail_wheel_joint' in base['sim'].log()
    since = time.time()
    wait_for(lambda: latest(truth).header.stamp.to_sec() > since + 0.5, HANG, 'half a second of truth')
    assert all(s.linear == 0.0 and s.commanded_linear == 0.0 and s.x == 0.0 for s in stamps(truth, 0.0))


def _controller_pid():
    uri = lookup_node(os.environ['ROS_MASTER_URI'], '/base_controller')
    return node_pid(uri) if uri else None


def test_base_launch_starts_a_killed_controller_again_and_it_drives(procs, rospy_client, collect):
    """The chaos history (5) kills the base controller: as the robot's own launch it must come back, or the
    base could never drive again until the robot lost power."""
    truth = collect('/vaultbot_sim/base_state', BaseState)
    procs.node('vaultbot_sim', 'vaultbot_sim', params=SIM_PARAMS)
    procs.launch('vaultbot_sim', 'base.launch')
    first = wait_for(_controller_pid, HANG, 'the base controller to register')
    os.kill(first, signal.SIGKILL)
    second = wait_for(lambda: (_controller_pid() or first) != first and _controller_pid(), HANG,
                      'the base controller to be started again')
    assert second != first
    cmd = CmdVel(rospy_client)
    try:
        wait_for(lambda: cmd.pub.get_num_connections() > 0, HANG, 'the new controller to subscribe to cmd_vel')
        cmd.send(0.3)
        wait_for(lambda: truth.last() is not None and truth.last().linear >= 0.25, HANG, 'the base to drive')
    finally:
        cmd.close()
