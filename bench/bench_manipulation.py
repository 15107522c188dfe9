#!/usr/bin/env python3
"""Manipulation benchmark: the manipulator and the gripper, measured from the simulation's ground truth.

The sim, the left arm's controller, its manipulator (``temoto_robot_manager manipulator``, as the Robot
Manager starts it) and the gripper's controller run as processes on a loopback master. Measured:

1. a bad arm goal: sent -> REJECTED at the client (nothing moves), p99;
2. a pose goal 0.3 rad away: sent -> accepted (IK, the way's self-collision check, the time
   parameterisation), p50 and p95;
3. servo latency: a target published -> the servo command made from it received here (one step's
   computation and two hops on loopback), p50 and p95. The manipulator stamps each command with its target's
   stamp, so a step at its own 125 Hz tick toward the previous target is not taken for this one's; and the
   servo commands per second while a 20 Hz stream is followed (the loop's rate);
4. the servo stream falls silent: last target, and the one due next that did not come -> the arm
   commanded to hold (``arm_states``), p99;
5. an arm goal's client SIGKILLed mid-motion: kill -> the arm commanded to hold, p50 and max;
6. the gripper's controller SIGKILLed mid-stroke: kill -> the motor's setpoint dropped (``gripper_state``),
   p99;
7. in process: one check of the arm against the world (its skeleton through KDL, then the lab's map), as the
   servo makes it every 40 ms and a goal's way every 0.05 rad, p50 and p95.

Prints a markdown table and writes bench/results/manipulation.json.
Usage: python bench/bench_manipulation.py [--trials N]
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

import numpy as np  # noqa: E402
import rospy  # noqa: E402
from actionlib_msgs.msg import GoalStatus  # noqa: E402
from control_msgs.msg import GripperCommand, GripperCommandAction, GripperCommandGoal  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from trajectory_msgs.msg import JointTrajectory  # noqa: E402

from common import loopback_master, pct, print_table  # noqa: E402
from temoto_core.action_client import TrackingActionClient  # noqa: E402
from temoto_core.wait import wait_for  # noqa: E402
from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics  # noqa: E402
from temoto_robot_manager.manipulation.world_clearance import WorldClearance  # noqa: E402
from temoto_robot_manager.msg import MoveArmAction, MoveArmGoal  # noqa: E402
from temoto_testing.motion import ARM_CLIENT  # noqa: E402
from vaultbot_sim.gripper import STROKE  # noqa: E402
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel, quat_from_matrix  # noqa: E402
from vaultbot_sim.msg import ArmState, GripperState  # noqa: E402
from vaultbot_sim.spec import ARM_JOINTS, STOW_POSE  # noqa: E402
from vaultbot_sim.kinematics import WORLDS  # noqa: E402
from vaultbot_sim.world_map import world_map  # noqa: E402

HANG = 30.0
VAULTBOT = os.path.join(ROOT, 'temoto_robot_manager', 'config', 'vaultbot.yaml')
LEFT = ['left_%s_joint' % j for j in ARM_JOINTS]
STOW = [STOW_POSE[j] for j in LEFT]


class Log:
    """Messages of a topic with their local arrival times."""

    def __init__(self, topic, kind):
        self.lock = threading.Lock()
        self.items = []
        self.sub = rospy.Subscriber(topic, kind, self._cb, queue_size=200, tcp_nodelay=True)

    def _cb(self, msg):
        with self.lock:
            self.items.append((time.monotonic(), msg))

    def since(self, t):
        with self.lock:
            return [(at, m) for at, m in self.items if at >= t]

    def last(self):
        with self.lock:
            return self.items[-1][1] if self.items else None


def joints_now(joints):
    msg = joints.last()
    pos = dict(zip(msg.name, msg.position))
    return [pos[j] for j in LEFT]


def pose_msg(m, frame='base_link'):
    msg = PoseStamped()
    msg.header.frame_id, msg.header.stamp = frame, rospy.Time.now()
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = m[:3, 3]
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = quat_from_matrix(m)
    return msg


def arm_held_after(states, t0):
    """Local time of the first left-arm state after ``t0`` whose commanded speed is zero."""
    hit = wait_for(lambda: next((at for at, m in states.since(t0) if m.arm == 'left_arm' and m.commanded_speed == 0.0),
                                None), HANG, 'the arm commanded to hold')
    return hit


def home(client):
    client.send_goal(MoveArmGoal(named_pose='stow', speed_scale=1.0))
    client.wait_for_result(rospy.Duration(HANG))


def world_check_times(n: int = 2000):
    """Seconds each of ``n`` world checks takes: the left arm's skeleton at a pose near its hold, against the lab's
    map, the base at the lab's origin."""
    with open(ROBOT_URDF) as f:
        kin = ArmKinematics(f.read(), 'base_link', 'left_tool0', LEFT)
    grid = world_map(TreeModel(WORLDS['lab']))
    world = WorldClearance(0.05)
    world.set_map(grid.origin, grid.resolution, grid.size[0], grid.size[1], grid.cells.ravel())
    rng = np.random.default_rng(3)
    times = []
    for _ in range(n):
        q = np.array(STOW) + rng.uniform(-0.5, 0.5, 6)
        t = time.perf_counter()
        world.touch(kin.skeleton(q), np.eye(4))
        times.append(time.perf_counter() - t)
    return times


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--trials', type=int, default=20)
    args = p.parse_args()
    world_times = world_check_times()
    master, launcher = loopback_master('bench_manipulation')
    out = {}
    try:
        rospy.init_node('bench_manipulation', anonymous=True, disable_signals=True)
        launcher.node('vaultbot_sim', 'vaultbot_sim', params={'world': 'lab', 'sweep': False, 'hand_motion': False})
        launcher.node('vaultbot_sim', 'arm_controller', name='left_arm_controller', params={'arm': 'left_arm'})
        launcher.node('temoto_robot_manager', 'manipulator', name='left_arm_manipulator',
                      params={'description': VAULTBOT, 'robot': 'vaultbot', 'arm': 'left_arm'})
        gripper = launcher.node('vaultbot_sim', 'gripper_controller')
        joints = Log('/joint_states', JointState)
        states = Log('/vaultbot_sim/arm_states', ArmState)
        fingers = Log('/vaultbot_sim/gripper_state', GripperState)
        commands = Log('/left_arm/servo_command', JointTrajectory)
        client = TrackingActionClient('/left_arm/move_arm', MoveArmAction)
        assert client.wait_for_server(rospy.Duration(HANG))
        wait_for(lambda: joints.last() and states.last() and fingers.last(), HANG, 'the sim\'s states')
        model = TreeModel(ROBOT_URDF)

        # 1. bad goals, rejected
        rejected = []
        for i in range(args.trials * 4):
            t = time.monotonic()
            client.send_goal(MoveArmGoal(joint_positions=[0.0] * 5))
            client.wait_for_result(rospy.Duration(HANG))
            assert client.get_state() == GoalStatus.REJECTED
            rejected.append(time.monotonic() - t)
        # 2. pose goals 0.3 rad away, accepted
        accepted = []
        rng = np.random.default_rng(5)
        for i in range(args.trials):
            q = np.array(STOW) + rng.uniform(-0.3, 0.3, 6)
            cfg = dict(STOW_POSE, **dict(zip(LEFT, q)))
            accepted_at = []
            t = time.monotonic()
            client.send_goal(MoveArmGoal(pose=pose_msg(model.link_pose('left_tool0', cfg)), speed_scale=1.0),
                             active_cb=lambda: accepted_at.append(time.monotonic()))
            client.wait_for_result(rospy.Duration(HANG))
            if client.get_state() == GoalStatus.SUCCEEDED and accepted_at:
                accepted.append(accepted_at[0] - t)
            home(client)
        # 3. servo latency, and 4. the stream's silence
        pub = rospy.Publisher('/left_arm/servo_target', PoseStamped, queue_size=5, tcp_nodelay=True)
        wait_for(lambda: pub.get_num_connections() > 0, HANG, 'the manipulator subscribed')
        latency, silent_hold, missing_hold, rates = [], [], [], []
        start = model.link_pose('left_tool0', STOW_POSE)
        for trial in range(max(3, args.trials // 4)):
            sign = 1 if trial % 2 == 0 else -1
            began = time.monotonic()
            for k in range(40):                   # 2 s at 20 Hz, 2 cm along y
                target = start.copy()
                target[1, 3] += sign * 0.0005 * k
                msg = pose_msg(target)
                t = time.monotonic()
                pub.publish(msg)
                got = wait_for(lambda: next((at for at, m in commands.since(t) if m.header.stamp == msg.header.stamp),
                                            None), HANG, 'the servo command made from the target')
                latency.append(got - t)
                last = t
                if k < 39:
                    time.sleep(max(0.0, t + 0.05 - time.monotonic()))     # the stream's own pace: 20 Hz
            rates.append(len(commands.since(began)) / (last - began))
            # the first hold after the last target, from the moment that target was sent, and from the moment
            # the next one was due (it did not come)
            held = arm_held_after(states, last + 0.05)
            silent_hold.append(held - last)
            missing_hold.append(held - (last + 0.05))
            home(client)
        pub.unregister()
        # 5. an arm goal's client killed mid-motion
        orphaned = []
        for trial in range(max(3, args.trials // 2)):
            far = list(STOW)
            far[0] += 1.2 if trial % 2 == 0 else -1.2
            child = launcher.command(ARM_CLIENT + ['left_arm'] + [str(v) for v in far] + ['0.3'], 'arm_client')
            wait_for(lambda: next((m for _, m in states.since(time.monotonic() - 0.1) if m.arm == 'left_arm'
                                   and m.speed > 0.3), None), HANG, 'the arm moving')
            t = time.monotonic()
            os.kill(child.pid, signal.SIGKILL)
            orphaned.append(arm_held_after(states, t) - t)
            child.stop()
            home(client)
        # 6. the gripper's controller killed mid-stroke (it is started again for each trial)
        dropped = []
        grip = TrackingActionClient('/gripper/gripper_command', GripperCommandAction)
        for trial in range(max(3, args.trials // 2)):
            assert grip.wait_for_server(rospy.Duration(HANG))
            gap = fingers.last().gap
            grip.send_goal(GripperCommandGoal(command=GripperCommand(position=0.0 if gap > STROKE / 2 else STROKE)))
            wait_for(lambda: abs(fingers.last().speed) > 0.05, HANG, 'the fingers moving')
            t = time.monotonic()
            os.kill(gripper.pid, signal.SIGKILL)
            hit = wait_for(lambda: next((at for at, m in fingers.since(t) if m.command_stale), None), HANG,
                           'the motor to drop the setpoint')
            dropped.append(hit - t)
            gripper.stop()
            gripper = launcher.node('vaultbot_sim', 'gripper_controller')
            grip = TrackingActionClient('/gripper/gripper_command', GripperCommandAction)
        ms = lambda xs, q: 1000 * pct(xs, q)      # noqa: E731
        out = {
            'rejected_ms': {'p50': ms(rejected, 50), 'p99': ms(rejected, 99), 'n': len(rejected)},
            'accepted_ms': {'p50': ms(accepted, 50), 'p95': ms(accepted, 95), 'n': len(accepted)},
            'servo_latency_ms': {'p50': ms(latency, 50), 'p95': ms(latency, 95), 'n': len(latency)},
            'servo_silence_hold_ms': {'p50': ms(silent_hold, 50), 'p99': ms(silent_hold, 99), 'n': len(silent_hold)},
            'servo_missing_hold_ms': {'p50': ms(missing_hold, 50), 'p99': ms(missing_hold, 99)},
            'servo_commands_per_s': {'min': min(rates), 'p50': pct(rates, 50)},
            'client_killed_hold_ms': {'p50': ms(orphaned, 50), 'max': 1000 * max(orphaned), 'n': len(orphaned)},
            'gripper_killed_stop_ms': {'p50': ms(dropped, 50), 'p99': ms(dropped, 99), 'n': len(dropped)},
            'world_check_ms': {'p50': ms(world_times, 50), 'p95': ms(world_times, 95), 'n': len(world_times)},
        }
        print_table('Manipulation (ground truth from the sim)', [
            ('bad arm goal -> REJECTED, p99 (n=%d)' % len(rejected), '%.1f ms' % out['rejected_ms']['p99'], '<= 20 ms'),
            ('pose goal 0.3 rad away -> accepted, p50 / p95 (n=%d)' % len(accepted),
             '%.0f / %.0f ms' % (out['accepted_ms']['p50'], out['accepted_ms']['p95']), '<= 250 ms p95'),
            ('servo target -> the servo command made from it, p50 / p95 (n=%d)' % len(latency),
             '%.1f / %.1f ms' % (out['servo_latency_ms']['p50'], out['servo_latency_ms']['p95']), '<= 15 ms p95'),
            ('servo commands per second while following a 20 Hz stream, min (n=%d)' % len(rates),
             '%.0f' % out['servo_commands_per_s']['min'], '>= 125 (MoveIt Servo)'),
            ('servo stream silent -> arm told to hold, from the last target / from the one that did not come, '
             'p99 (n=%d)' % len(silent_hold),
             '%.0f / %.0f ms' % (out['servo_silence_hold_ms']['p99'], out['servo_missing_hold_ms']['p99']),
             '<= 100 ms of silence (MoveIt Servo 0.1 s)'),
            ('arm goal client SIGKILLed -> arm told to hold, p50 / max (n=%d)' % len(orphaned),
             '%.0f / %.0f ms' % (out['client_killed_hold_ms']['p50'], out['client_killed_hold_ms']['max']),
             '<= 300 ms'),
            ('gripper controller SIGKILLed -> fingers stopped, p50 / p99 (n=%d)' % len(dropped),
             '%.0f / %.0f ms' % (out['gripper_killed_stop_ms']['p50'], out['gripper_killed_stop_ms']['p99']),
             '<= 50 ms'),
            ('one world check of the arm (skeleton + the lab\'s map), in process, p50 / p95 (n=%d)' % len(world_times),
             '%.2f / %.2f ms' % (out['world_check_ms']['p50'], out['world_check_ms']['p95']),
             '<= 1 ms p95 (a servo step\'s budget at 125 Hz: 8 ms)'),
        ])
    finally:
        launcher.stop_all()
        master.stop()
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'manipulation.json'), 'w') as f:
        json.dump(out, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
