#!/usr/bin/env python3
"""Robot benchmark: every stop of the base, measured from the simulation's ground truth.

The sim's motors publish the moment their commanded velocity becomes zero (``~base_state``,
``command_stale``, stamped at the trip) and the base's actual velocity at every step. The
figures are measured from there, never from a controller's or a manager's word:

1. the base controller SIGKILLed while the base drives at 0.5 m/s: kill -> commanded zero
   (the motors' own command timeout), and the braking time to rest;
2. the controller stalled (its cable pulled in stall mode: the process stays up, silent);
3. ``cmd_vel`` falls silent (the commander died): last ``cmd_vel`` -> commanded zero
   (the controller's 0.25 s timeout);
4. false stops: command timeout trips while the controller is alive, over a steady drive;
5. the left arm's controller SIGKILLed, or stalled, during a trajectory: -> the motors'
   setpoint dropped (commanded joint speed zero), then at rest;
6. the servo stream falls silent: last servo message -> the arm told to hold (the deadman),
   then at rest; and a servo message -> its setpoint sent to the motors (the controller's
   latency), p95.

Each base trial drives the other way than the last, so the base stays in the test world's
free space; each arm trial turns the shoulder the other way. ``--hogs N`` runs N busy loops
beside it.

Prints a markdown table and writes bench/results/robot.json.
Usage: python bench/bench_robot.py [--trials N] [--steady S] [--hogs N]
"""
import argparse
import json
import os
import signal
import sys
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import rospy  # noqa: E402
from geometry_msgs.msg import Twist  # noqa: E402

from common import cpu_hogs, loopback_master, pct, print_table, stop_hogs  # noqa: E402
from temoto_core.action_client import TrackingActionClient
from temoto_core.wait import wait_for  # noqa: E402
from temoto_testing.sensor_manager import set_cable  # noqa: E402
from vaultbot_sim.base import CMD_VEL_TIMEOUT_S, HUSKY, MOTOR_TIMEOUT_S  # noqa: E402
from vaultbot_sim.msg import ArmState, BaseState  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint  # noqa: E402
import actionlib  # noqa: E402
from control_msgs.msg import FollowJointTrajectoryAction, FollowJointTrajectoryGoal  # noqa: E402
from vaultbot_sim.spec import ARM_JOINTS, STOW_POSE  # noqa: E402

HANG = 20.0
SPEED = 0.5
SIM = {'world': 'test_wall', 'sweep': False, 'hand_motion': False}


class Truth:
    """The sim's base states, as they arrive."""

    def __init__(self):
        self.lock = threading.Lock()
        self.states = []
        self.sub = rospy.Subscriber('/vaultbot_sim/base_state', BaseState, self._on, queue_size=500,
                                    tcp_nodelay=True)

    def _on(self, msg):
        with self.lock:
            self.states.append(msg)

    def since(self, t):
        with self.lock:
            return [s for s in self.states if s.header.stamp.to_sec() >= t]

    def last(self):
        with self.lock:
            return self.states[-1] if self.states else None


class Commander:
    """cmd_vel at 20 Hz on a thread; ``speed`` may change, ``silent`` stops it."""

    def __init__(self):
        self.pub = rospy.Publisher('/cmd_vel', Twist, queue_size=10, tcp_nodelay=True)
        self.speed = 0.0
        self.silent = True
        self.last_sent = 0.0
        self.quiet = threading.Event()     # set by the thread once it has seen ``silent``: nothing more goes out
        self._stop = threading.Event()
        threading.Thread(target=self._run, daemon=True, name='cmd_vel').start()

    def _run(self):
        while not self._stop.wait(0.05):
            if not self.silent:
                msg = Twist()
                msg.linear.x = self.speed
                self.pub.publish(msg)
                self.last_sent = time.time()
            else:
                self.quiet.set()

    def fall_silent(self) -> float:
        """Stop sending; the wall time of the last message, once the thread can send no more."""
        self.quiet.clear()
        self.silent = True
        wait_for(self.quiet.is_set, HANG, 'the commander to fall silent')
        return self.last_sent

    def close(self):
        self._stop.set()


def drive(cmd, truth, direction):
    cmd.speed, cmd.silent = SPEED * direction, False
    wait_for(lambda: truth.last() is not None and truth.last().linear * direction >= SPEED * 0.9, HANG,
             'the base to drive')


def stop_moments(states, t0, commanded, actual, what):
    """(commanded zero at, at rest at): stamps of the first states after ``t0`` whose ``commanded`` field, then
    whose ``actual`` field, is zero; ``states`` is a Truth or an ArmTruth, ``what`` names the part."""
    zero = wait_for(lambda: next((s for s in states.since(t0) if getattr(s, commanded) == 0.0), None), HANG,
                    '%s to be told zero' % what)
    rest = wait_for(lambda: next((s for s in states.since(zero.header.stamp.to_sec()) if getattr(s, actual) == 0.0),
                                 None), HANG, '%s at rest' % what)
    return zero.header.stamp.to_sec(), rest.header.stamp.to_sec()


def stopped(truth, t0):
    return stop_moments(truth, t0, 'commanded_linear', 'linear', 'the base')


def trial(launcher, cmd, truth, case, index):
    controller = launcher.node('vaultbot_sim', 'base_controller', name='base_controller')
    try:
        wait_for(lambda: cmd.pub.get_num_connections() > 0, HANG, 'the controller on cmd_vel')
        drive(cmd, truth, 1 if index % 2 == 0 else -1)
        t0 = time.time()
        if case == 'kill':
            os.kill(controller.pid, signal.SIGKILL)
        elif case == 'stall':
            set_cable('base', 'unplugged', 'stall')
        else:                           # the commander dies: cmd_vel stops
            t0 = cmd.fall_silent()
        zero, rest = stopped(truth, t0)
        return zero - t0, rest - zero
    finally:
        cmd.silent = True
        controller.stop()
        if case == 'stall':
            set_cable('base', 'plugged')
        wait_for(lambda: truth.last().linear == 0.0, HANG, 'the base at rest between trials')


LEFT = ['left_%s_joint' % j for j in ARM_JOINTS]
TERMINAL = {actionlib.GoalStatus.REJECTED, actionlib.GoalStatus.ABORTED, actionlib.GoalStatus.SUCCEEDED,
            actionlib.GoalStatus.PREEMPTED, actionlib.GoalStatus.RECALLED, actionlib.GoalStatus.LOST}


class ArmTruth:
    """The sim's left arm states, and the left controller's setpoints (for its latency)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.states, self.setpoints = [], []
        rospy.Subscriber('/vaultbot_sim/arm_states', ArmState, self._on_state, queue_size=500, tcp_nodelay=True)
        rospy.Subscriber('/left_arm/joint_command', JointState, self._on_setpoint, queue_size=500, tcp_nodelay=True)
        rospy.Subscriber('/joint_states', JointState, self._on_joints, queue_size=5, tcp_nodelay=True)
        self.pan = STOW_POSE[LEFT[0]]

    def _on_joints(self, msg):
        if LEFT[0] in msg.name:
            self.pan = msg.position[msg.name.index(LEFT[0])]

    def _on_state(self, msg):
        if msg.arm == 'left_arm':
            with self.lock:
                self.states.append(msg)

    def _on_setpoint(self, msg):
        with self.lock:
            self.setpoints.append((time.time(), msg))

    def since(self, t):
        with self.lock:
            return [s for s in self.states if s.header.stamp.to_sec() >= t]

    def last(self):
        with self.lock:
            return self.states[-1] if self.states else None


def arm_stopped(arm, t0):
    return stop_moments(arm, t0, 'commanded_speed', 'speed', 'the arm')


def arm_trial(launcher, arm, case, index, servo_pub):
    controller = launcher.node('vaultbot_sim', 'arm_controller', name='left_arm_controller',
                               params={'arm': 'left_arm'})
    direction = 1 if index % 2 == 0 else -1
    latencies = []
    try:
        start = STOW_POSE[LEFT[0]]
        if case == 'servo':
            wait_for(lambda: servo_pub.get_num_connections() > 0, HANG, 'the controller on servo_command')
            t1 = time.monotonic()
            sent = []
            for k in range(int(1.0 * 125)):          # one second at 125 Hz, as MoveIt Servo streams
                q = [start + direction * 0.5 * (time.monotonic() - t1)] + [STOW_POSE[j] for j in LEFT[1:]]
                stamp = time.time()
                servo_pub.publish(JointTrajectory(joint_names=LEFT, points=[JointTrajectoryPoint(
                    positions=q, velocities=[direction * 0.5] + [0.0] * 5)]))
                sent.append((stamp, q[0]))
                time.sleep(max(0.0, t1 + (k + 1) / 125.0 - time.monotonic()))
            t0 = sent[-1][0]
            with arm.lock:
                got = {round(m.position[0], 9): t for t, m in arm.setpoints if m.position}
            latencies = [got[round(q, 9)] - t for t, q in sent if round(q, 9) in got]
        else:
            client = TrackingActionClient('/left_arm/follow_joint_trajectory', FollowJointTrajectoryAction)
            if not client.wait_for_server(rospy.Duration(HANG)):
                raise RuntimeError('the left arm\'s action server did not come up')
            goal = FollowJointTrajectoryGoal()
            goal.trajectory.joint_names = LEFT
            # 1.5 rad from where the shoulder is, back toward the stowed pose: every trial moves as far
            here = arm.pan
            point = JointTrajectoryPoint(positions=[here + (-1.5 if here > start else 1.5)] +
                                         [STOW_POSE[j] for j in LEFT[1:]])
            point.time_from_start = rospy.Duration(3.0)
            goal.trajectory.points = [point]
            client.send_goal(goal)
            wait_for(lambda: (arm.last() is not None and arm.last().speed > 0.3) or
                     client.get_state() in TERMINAL, HANG, 'the arm to move')
            if client.get_state() in TERMINAL:
                raise RuntimeError('the trajectory ended before the arm moved: %s' % client.get_goal_status_text())
            t0 = time.time()
            if case == 'kill':
                os.kill(controller.pid, signal.SIGKILL)
            else:
                set_cable('left_arm', 'unplugged', 'stall')
        zero, rest = arm_stopped(arm, t0)
        return zero - t0, rest - zero, latencies
    finally:
        controller.stop()
        if case == 'stall':
            set_cable('left_arm', 'plugged')
        # back to the start for the next trial: the sim is restarted by nobody, so the arm is sent home
        wait_for(lambda: arm.last().speed == 0.0, HANG, 'the arm at rest between trials')


def false_stops(launcher, cmd, truth, seconds):
    """Command timeout trips while a live controller is commanded to drive, back and forth."""
    controller = launcher.node('vaultbot_sim', 'base_controller', name='base_controller')
    try:
        wait_for(lambda: cmd.pub.get_num_connections() > 0, HANG, 'the controller on cmd_vel')
        t0 = time.time()
        direction = 1
        while time.time() - t0 < seconds:
            drive(cmd, truth, direction)
            t1 = time.time()
            wait_for(lambda: time.time() - t1 > 1.0, 2.0, 'a second of driving')
            direction = -direction
        cmd.silent = True
        trips = sum(1 for a, b in zip(truth.since(t0), truth.since(t0)[1:]) if b.command_stale and not a.command_stale)
        return trips, time.time() - t0
    finally:
        cmd.silent = True
        controller.stop()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--trials', type=int, default=30)
    p.add_argument('--steady', type=float, default=30.0, help='seconds of driving for the false-stop count')
    p.add_argument('--hogs', type=int, default=0)
    p.add_argument('--only', choices=('base', 'arms'), help='one part\'s cases')
    args = p.parse_args()
    master, launcher = loopback_master('bench_robot_')
    hogs = cpu_hogs(args.hogs)
    results = {}
    try:
        launcher.node('vaultbot_sim', 'vaultbot_sim', params=SIM)
        rospy.init_node('bench_robot', anonymous=True, disable_signals=True)
        truth, cmd = Truth(), Commander()
        wait_for(lambda: truth.last() is not None, HANG, 'the sim\'s base state')
        for case in ('kill', 'stall', 'cmd_vel') if args.only != 'arms' else ():
            print('bench_robot: %s x %d ...' % (case, args.trials), file=sys.stderr, flush=True)
            results[case] = [trial(launcher, cmd, truth, case, i) for i in range(args.trials)]
        if args.only != 'arms':
            print('bench_robot: false stops over %.0f s ...' % args.steady, file=sys.stderr, flush=True)
            trips, took = false_stops(launcher, cmd, truth, args.steady)
            results['false_stops'] = {'trips': trips, 'seconds': took}
        cmd.close()
        arm = ArmTruth()
        servo_pub = rospy.Publisher('/left_arm/servo_command', JointTrajectory, queue_size=10, tcp_nodelay=True)
        for case in ('kill', 'stall', 'servo') if args.only != 'base' else ():
            print('bench_robot: arm %s x %d ...' % (case, args.trials), file=sys.stderr, flush=True)
            results['arm_' + case] = [arm_trial(launcher, arm, case, i, servo_pub) for i in range(args.trials)]
    finally:
        stop_hogs(hogs)
        launcher.stop_all()
        master.stop()
    ms = lambda v: '%.0f ms' % (v * 1e3)  # noqa: E731
    rows = []
    brake = HUSKY.braking_time(SPEED, 0.0)
    for case, what, goal in (('kill', 'the base controller SIGKILLed while driving', 50e-3),
                             ('stall', 'the base controller stalled (alive, silent)', 50e-3),
                             ('cmd_vel', 'cmd_vel silent (the commander died)', CMD_VEL_TIMEOUT_S + 20e-3)):
        if case not in results:
            continue
        zeros = [z for z, _ in results[case]]
        rests = [r for _, r in results[case]]
        rows.append(('%s → commanded zero, p50 / p99 (n=%d)' % (what, len(zeros)),
                     '%s / %s (max %s)' % (ms(pct(zeros, 50)), ms(pct(zeros, 99)), ms(max(zeros))),
                     '≤ %s p99' % ms(goal)))
        rows.append(('… then at rest (braking from %.1f m/s), p50 / max' % SPEED,
                     '%s / %s' % (ms(pct(rests, 50)), ms(max(rests))),
                     '%s at %.0f m/s² (+ one 20 ms step)' % (ms(brake), HUSKY.decel)))
    for case, what, goal in (('arm_kill', 'the left arm\'s controller SIGKILLed during a trajectory', 50e-3),
                             ('arm_stall', 'the left arm\'s controller stalled during a trajectory', 50e-3),
                             ('arm_servo', 'the servo stream silent (125 Hz before)', 100e-3)):
        if case not in results:
            continue
        zeros = [z for z, _, _ in results[case]]
        rests = [r for _, r, _ in results[case]]
        rows.append(('%s → told to hold, p50 / p99 (n=%d)' % (what, len(zeros)),
                     '%s / %s (max %s)' % (ms(pct(zeros, 50)), ms(pct(zeros, 99)), ms(max(zeros))),
                     '≤ %s p99' % ms(goal)))
        rows.append(('… then at rest, p50 / max', '%s / %s' % (ms(pct(rests, 50)), ms(max(rests))),
                     'braking at 8 rad/s²'))
    missed = [z - 1.0 / 125 for z, _, _ in results.get('arm_servo', [])]
    if missed:
        rows.append(('… the same, from the message that did not come (8 ms after the last), p50 / p99',
                     '%s / %s' % (ms(pct(missed, 50)), ms(pct(missed, 99))), '≤ 100 ms p99'))
    lat = [x for _, _, trial_lat in results.get('arm_servo', []) for x in trial_lat]
    if lat:
        rows.append(('servo message → its setpoint to the motors, p50 / p95 (n=%d)' % len(lat),
                     '%.1f / %.1f ms' % (pct(lat, 50) * 1e3, pct(lat, 95) * 1e3), '≤ 10 ms p95'))
    fs = results.get('false_stops')
    if fs:
        rows.append(('false stops: motor command timeout trips with a live controller, %.0f s of driving'
                     % fs['seconds'],
                     str(fs['trips']), '0'))
    print_table('Robot: the base\'s and the arms\' stops (motor command timeout %s; %d CPU hogs)'
                % (ms(MOTOR_TIMEOUT_S), args.hogs), rows)
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'robot%s.json' % ('_' + args.only if args.only else '')),
              'w') as f:
        json.dump({'hogs': args.hogs, **results}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
