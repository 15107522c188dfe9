#!/usr/bin/env python3
"""Robot benchmark: every stop of the base, measured from the simulation's ground truth.

The sim's motors publish the moment their commanded velocity becomes zero (``~base_state``,
``command_stale``, stamped at the trip) and the base's actual velocity at every step. The
figures are measured from there, never from a controller's or a manager's word:

1. the base controller SIGKILLed while the base drives at 0.5 m/s: kill -> commanded zero
   (the motors' own watchdog), and the braking time to rest;
2. the controller stalled (its cable pulled in stall mode: the process stays up, silent);
3. ``cmd_vel`` falls silent (the commander died): last ``cmd_vel`` -> commanded zero
   (the controller's 0.25 s timeout);
4. false stops: watchdog trips while the controller is alive, over a steady drive.

Each trial drives the other way than the last, so the base stays in the test world's free
space. ``--hogs N`` runs N busy loops beside it.

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
from temoto_core.wait import wait_for  # noqa: E402
from temoto_testing.sensor_manager import set_cable  # noqa: E402
from vaultbot_sim.base import CMD_VEL_TIMEOUT_S, HUSKY, MOTOR_TIMEOUT_S  # noqa: E402
from vaultbot_sim.msg import BaseState  # noqa: E402

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
        self._stop = threading.Event()
        threading.Thread(target=self._run, daemon=True, name='cmd_vel').start()

    def _run(self):
        while not self._stop.wait(0.05):
            if not self.silent:
                msg = Twist()
                msg.linear.x = self.speed
                self.pub.publish(msg)
                self.last_sent = time.time()

    def close(self):
        self._stop.set()


def drive(cmd, truth, direction):
    cmd.speed, cmd.silent = SPEED * direction, False
    wait_for(lambda: truth.last() is not None and truth.last().linear * direction >= SPEED * 0.9, HANG,
             'the base to drive')


def stopped(truth, t0):
    """(commanded zero at, at rest at): stamps from the truth after ``t0``."""
    zero = wait_for(lambda: next((s for s in truth.since(t0) if s.commanded_linear == 0.0), None), HANG,
                    'the commanded velocity to be zero')
    rest = wait_for(lambda: next((s for s in truth.since(zero.header.stamp.to_sec()) if s.linear == 0.0), None),
                    HANG, 'the base at rest')
    return zero.header.stamp.to_sec(), rest.header.stamp.to_sec()


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
            cmd.silent = True
            t0 = cmd.last_sent
        zero, rest = stopped(truth, t0)
        return zero - t0, rest - zero
    finally:
        cmd.silent = True
        controller.stop()
        if case == 'stall':
            set_cable('base', 'plugged')
        wait_for(lambda: truth.last().linear == 0.0, HANG, 'the base at rest between trials')


def false_stops(launcher, cmd, truth, seconds):
    """Watchdog trips while a live controller is commanded to drive, back and forth."""
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
    args = p.parse_args()
    master, launcher = loopback_master('bench_robot_')
    hogs = cpu_hogs(args.hogs)
    results = {}
    try:
        launcher.node('vaultbot_sim', 'vaultbot_sim', params=SIM)
        rospy.init_node('bench_robot', anonymous=True, disable_signals=True)
        truth, cmd = Truth(), Commander()
        wait_for(lambda: truth.last() is not None, HANG, 'the sim\'s base state')
        for case in ('kill', 'stall', 'cmd_vel'):
            print('bench_robot: %s x %d ...' % (case, args.trials), file=sys.stderr, flush=True)
            results[case] = [trial(launcher, cmd, truth, case, i) for i in range(args.trials)]
        print('bench_robot: false stops over %.0f s ...' % args.steady, file=sys.stderr, flush=True)
        trips, took = false_stops(launcher, cmd, truth, args.steady)
        results['false_stops'] = {'trips': trips, 'seconds': took}
        cmd.close()
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
        zeros = [z for z, _ in results[case]]
        rests = [r for _, r in results[case]]
        rows.append(('%s → commanded zero, p50 / p99 (n=%d)' % (what, len(zeros)),
                     '%s / %s (max %s)' % (ms(pct(zeros, 50)), ms(pct(zeros, 99)), ms(max(zeros))),
                     '≤ %s p99' % ms(goal)))
        rows.append(('… then at rest (braking from %.1f m/s), p50 / max' % SPEED,
                     '%s / %s' % (ms(pct(rests, 50)), ms(max(rests))),
                     '%s at %.0f m/s² (+ one 20 ms step)' % (ms(brake), HUSKY.decel)))
    fs = results['false_stops']
    rows.append(('false stops: motor watchdog trips with a live controller, %.0f s of driving' % fs['seconds'],
                 str(fs['trips']), '0'))
    print_table('Robot: the base\'s stops (motor watchdog %s; %d CPU hogs)' % (ms(MOTOR_TIMEOUT_S), args.hogs), rows)
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'robot.json'), 'w') as f:
        json.dump({'hogs': args.hogs, **results}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
