#!/usr/bin/env python3
"""Safety benchmark (issue 51): every stop the stack owes, with the motors' command timeout off, from the ground truth.

The simulated motors keep their last command for ever (``motor_timeout: 0``), as on a robot whose drivers have
none: a stop measured here is the stack's own, and each row names the part that made it. Every figure is read from
the simulation's ground truth (``vaultbot_sim/base_state``, ``arm_states``, ``gripper_state``), never from a
node's word. Processes: the sim in the lab, the base controller, the SICK, the navigator, the left arm's
controller and manipulator, the gripper's controller, each as the Robot Manager starts them.

1. halt: "stop" on the halt topic (as the action engine publishes it the moment it grounds the word) while the
   base drives, while the left arm runs a trajectory, while the gripper closes -> each commanded zero;
2. a holder SIGKILLed: a drive's client, an arm goal's client, the manipulator (the client of the arm
   controller's trajectory) -> commanded zero;
3. the command stream silent: a teleop stream on ``teleop/cmd_vel`` stops -> zero, from its last command;
4. the active obstacle source stale (the SICK stalled) -> zero, from its last scan;
5. the odometry stale (the navigator reads it through this benchmark's relay, which stops) -> zero, from the
   last odometry relayed;
6. the base controller SIGKILLed mid-drive: only hardware could stop the wheels (no command timeout); measured is
   how fast the goal's client hears ABORTED with the reason, and whether anything moves once the controller is
   respawned (it must not: the goal is over);
7. false stops (``--only false_stops --minutes M``): the base driving between the lab's places and the left arm
   servoed back and forth, nothing unplugged, for M minutes: every hold of the base by a freshness rule (the
   navigator's ``~motion_status`` HELD with ``obstacles_stale`` or ``odometry_stale``) is a false stop, and so
   is every hold of the arm for a silent stream or stale joint states.

``--hogs N`` runs N busy loops beside it. Prints a markdown table and writes bench/results/safety.json.
Usage: python bench/bench_safety.py [--trials N] [--hogs N] [--only halt|holders|stream|obstacles|odometry|controller]
"""
import argparse
import math
import os
import signal
import sys
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import rospy  # noqa: E402
from actionlib_msgs.msg import GoalStatus  # noqa: E402
from control_msgs.msg import GripperCommand, GripperCommandAction, GripperCommandGoal  # noqa: E402
from geometry_msgs.msg import PoseStamped, TwistStamped  # noqa: E402
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from sensor_msgs.msg import LaserScan  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from common import cpu_hogs, loopback_master, pct, print_table, stop_hogs, write_results  # noqa: E402
from temoto_core.action_client import TrackingActionClient  # noqa: E402
from temoto_core.wait import wait_for  # noqa: E402
from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics  # noqa: E402
from temoto_robot_manager.description import GRIPPER_GATE_ACTION, load_file  # noqa: E402
from temoto_robot_manager.msg import MoveArmAction, MoveArmGoal  # noqa: E402
from temoto_robot_manager.paths import DEFAULT_DESCRIPTION  # noqa: E402
from temoto_testing.motion import ARM_CLIENT, GOAL_CLIENT  # noqa: E402
from temoto_testing.sensor_manager import set_cable  # noqa: E402
from vaultbot_sim.kinematics import ROBOT_URDF, quat_from_matrix  # noqa: E402
from vaultbot_sim.msg import ArmState, BaseState, GripperState  # noqa: E402

HANG = 60.0
VAULTBOT = next(r for r in load_file(DEFAULT_DESCRIPTION)[0] if r.name == 'vaultbot')
PLACES = VAULTBOT.navigation.places
LEFT = VAULTBOT.manipulation['left_arm']
HALT = '/temoto/halt'
CASES = ('halt', 'holders', 'stream', 'obstacles', 'odometry', 'controller')
EXTRA = ('false_stops',)               # run only when asked: it takes minutes


class Truth:
    """The sim's ground truth as it arrives: base, arm and gripper states."""

    def __init__(self):
        self.lock = threading.Lock()
        self.base, self.arms, self.gripper = [], [], []
        self._subs = [
            rospy.Subscriber('/vaultbot_sim/base_state', BaseState, lambda m: self._add(self.base, m), queue_size=500,
                             tcp_nodelay=True),
            rospy.Subscriber('/vaultbot_sim/arm_states', ArmState, lambda m: self._add(self.arms, m), queue_size=500,
                             tcp_nodelay=True),
            rospy.Subscriber('/vaultbot_sim/gripper_state', GripperState, lambda m: self._add(self.gripper, m),
                             queue_size=500, tcp_nodelay=True)]

    def _add(self, log, msg):
        with self.lock:
            log.append(msg)
            del log[:-2000]

    def first(self, log, t0, pred):
        """The stamp of the first state in ``log`` stamped after ``t0`` for which ``pred`` holds, or None."""
        with self.lock:
            return next((m.header.stamp.to_sec() for m in log if m.header.stamp.to_sec() > t0 and pred(m)), None)

    def last(self, log):
        with self.lock:
            return log[-1] if log else None


def base_zero(m):
    return m.commanded_linear == 0.0 and m.commanded_angular == 0.0


def left_arm_zero(m):
    return m.arm == 'left_arm' and m.commanded_speed == 0.0


def gripper_zero(m):
    return not m.has_setpoint or m.speed == 0.0


def zero_after(truth, log, t0, pred, what):
    return wait_for(lambda: truth.first(log, t0, pred), HANG, what)


class Bench:
    def __init__(self, launcher):
        self.launcher = launcher
        launcher.node('vaultbot_sim', 'vaultbot_sim', params={'world': 'lab', 'sweep': False, 'hand_motion': False,
                                                              'motor_timeout': 0})
        self.base = launcher.node('vaultbot_sim', 'base_controller')
        self.sick = launcher.node('vaultbot_sim', 'sick_driver')
        self.navigator = self._navigator()
        launcher.node('vaultbot_sim', 'arm_controller', params={'arm': 'left_arm'}, name='left_arm_controller')
        self.manipulator = self._manipulator()
        launcher.node('vaultbot_sim', 'gripper_controller')           # its stops are the gate's
        launcher.node('temoto_robot_manager', 'gripper', params={'description': DEFAULT_DESCRIPTION,
                                                                 'robot': 'vaultbot', 'halt_topic': HALT})
        rospy.init_node('bench_safety', anonymous=True, disable_signals=True)
        self.truth = Truth()
        self.scans = []
        rospy.Subscriber('/sick/scan', LaserScan, lambda m: self.scans.append(m.header.stamp.to_sec()), queue_size=50)
        self.halt = rospy.Publisher(HALT, String, queue_size=5, tcp_nodelay=True)
        self.teleop = rospy.Publisher('/teleop/cmd_vel', TwistStamped, queue_size=5, tcp_nodelay=True)
        self.drive = TrackingActionClient('/move_base', MoveBaseAction)
        self.arm = TrackingActionClient('/left_arm/move_arm', MoveArmAction)
        self.grip = TrackingActionClient('/' + GRIPPER_GATE_ACTION, GripperCommandAction)
        for client in (self.drive, self.arm, self.grip):
            assert client.wait_for_server(rospy.Duration(HANG)), 'a server did not come'
        wait_for(lambda: self.truth.last(self.truth.base) and self.truth.last(self.truth.gripper), HANG, 'the truth')
        wait_for(lambda: self.halt.get_num_connections() >= 3 and self.teleop.get_num_connections() >= 1, HANG,
                 'the motion nodes listening')

    def _navigator(self, args=()):
        return self.launcher.node('temoto_robot_manager', 'navigator', args=list(args), params={
            'description': DEFAULT_DESCRIPTION, 'robot': 'vaultbot', 'obstacle_topic': 'sick/scan',
            'halt_topic': HALT})

    def _manipulator(self):
        return self.launcher.node('temoto_robot_manager', 'manipulator', name='left_arm_manipulator', params={
            'description': DEFAULT_DESCRIPTION, 'robot': 'vaultbot', 'arm': 'left_arm', 'halt_topic': HALT})

    # -- motions ---------------------------------------------------------------------------------------------
    def target(self):
        """Of the drums and home, the one further from where the base is: each drive has room to reach speed."""
        here = self.truth.last(self.truth.base)
        x, y, yaw = max((PLACES['drums'], PLACES['home']), key=lambda p: math.hypot(p[0] - here.x, p[1] - here.y))
        pose = PoseStamped()
        pose.header.frame_id, pose.header.stamp = 'world', rospy.Time.now()
        pose.pose.position.x, pose.pose.position.y = x, y
        pose.pose.orientation.z, pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        return pose

    def driving(self, speed=0.15, client=None):
        def moving():
            if client is not None and client.get_state() not in (GoalStatus.PENDING, GoalStatus.ACTIVE):
                raise RuntimeError('the drive ended before it drove: %s' % client.get_goal_status_text())
            return self.truth.last(self.truth.base).commanded_linear > speed
        wait_for(moving, HANG, 'the base driving')

    def at_rest(self):
        wait_for(lambda: (lambda m: m.linear == 0.0 and m.angular == 0.0)(self.truth.last(self.truth.base)), HANG,
                 'the base at rest')

    def start_drive(self):
        self.drive.send_goal(MoveBaseGoal(target_pose=self.target()))
        self.driving(client=self.drive)

    def end_drive(self):
        if self.drive.get_state() in (GoalStatus.PENDING, GoalStatus.ACTIVE):
            self.drive.cancel_goal()
        self.at_rest()

    def arm_far(self, k):
        q = list(LEFT.named_poses['stow'])
        q[0] += 0.8 if k % 2 == 0 else -0.8
        return q

    def start_arm(self, k):
        self.arm.send_goal(MoveArmGoal(joint_positions=self.arm_far(k), speed_scale=0.3))
        wait_for(lambda: next((m for m in reversed(self.truth.arms[-10:]) if m.arm == 'left_arm'
                               and m.speed > 0.2), None), HANG, 'the left arm moving')

    def arm_home(self):
        self.arm.send_goal(MoveArmGoal(named_pose='stow', speed_scale=0.5))
        wait_for(lambda: self.arm.get_state() not in (GoalStatus.PENDING, GoalStatus.ACTIVE), HANG, 'the arm home')

    def start_grip(self):
        gap = self.truth.last(self.truth.gripper).gap
        self.grip.send_goal(GripperCommandGoal(command=GripperCommand(position=0.0 if gap > 0.04 else 0.085)))
        wait_for(lambda: self.truth.last(self.truth.gripper).speed != 0.0, HANG, 'the fingers moving')

    # -- the cases ----------------------------------------------------------------------------------------------
    def halt_case(self, trials):
        out = {'base': [], 'arm': [], 'gripper': []}
        for k in range(trials):
            self.arm_home()                        # an arm stopped on its way out holds the base (its guard)
            self.start_drive()
            t = time.time()
            self.halt.publish(String('bench stop'))
            out['base'].append(zero_after(self.truth, self.truth.base, t, base_zero, 'the base zero') - t)
            self.at_rest()
            self.start_arm(k)
            t = time.time()
            self.halt.publish(String('bench stop'))
            out['arm'].append(zero_after(self.truth, self.truth.arms, t, left_arm_zero, 'the arm held') - t)
            self.start_grip()
            t = time.time()
            self.halt.publish(String('bench stop'))
            out['gripper'].append(zero_after(self.truth, self.truth.gripper, t, gripper_zero, 'the fingers') - t)
        return out

    def holders_case(self, trials):
        out = {'drive_client': [], 'arm_client': [], 'manipulator': []}
        for k in range(trials):
            self.arm_home()
            pose = self.target().pose
            client = self.launcher.command(GOAL_CLIENT + [str(pose.position.x), str(pose.position.y),
                                                          str(2 * math.atan2(pose.orientation.z, pose.orientation.w))],
                                           'goal_client')
            self.driving()
            t = time.time()
            os.kill(client.pid, signal.SIGKILL)
            out['drive_client'].append(zero_after(self.truth, self.truth.base, t, base_zero, 'the base zero') - t)
            self.at_rest()
            client.stop()
            client = self.launcher.command(ARM_CLIENT + ['left_arm'] + [str(v) for v in self.arm_far(k)] + ['0.3'],
                                           'arm_client')
            wait_for(lambda: next((m for m in reversed(self.truth.arms[-10:]) if m.arm == 'left_arm'
                                   and m.speed > 0.2), None), HANG, 'the left arm moving')
            t = time.time()
            os.kill(client.pid, signal.SIGKILL)
            out['arm_client'].append(zero_after(self.truth, self.truth.arms, t, left_arm_zero, 'the arm held') - t)
            client.stop()
            self.start_arm(k + 1)
            t = time.time()
            os.kill(self.manipulator.pid, signal.SIGKILL)
            out['manipulator'].append(zero_after(self.truth, self.truth.arms, t, left_arm_zero, 'the arm held') - t)
            self.manipulator.stop()
            self.manipulator = self._manipulator()
            assert self.arm.wait_for_server(rospy.Duration(HANG))
        return out

    def stream_case(self, trials):
        out = []
        for k in range(trials):
            last = None
            for _ in range(400):                               # at most 8 s of a 50 Hz stream
                msg = TwistStamped()
                msg.header.stamp = rospy.Time.now()
                msg.twist.angular.z = 0.8 if k % 2 == 0 else -0.8
                self.teleop.publish(msg)
                last = msg.header.stamp.to_sec()
                if self.truth.last(self.truth.base).commanded_angular != 0.0 and \
                        abs(self.truth.last(self.truth.base).angular) > 0.5:
                    break
                time.sleep(0.02)                               # the stream's own pace
            out.append(zero_after(self.truth, self.truth.base, last, base_zero, 'the base zero') - last)
            self.at_rest()
        return out

    def obstacles_case(self, trials):
        out = []
        for k in range(trials):
            self.start_drive()
            cut = time.time()
            set_cable('sick', 'unplugged', 'stall')
            # the first zero after the stall: one from before it (the drive's own start) is not a staleness stop
            z = zero_after(self.truth, self.truth.base, cut, base_zero, 'the base zero')
            out.append(z - max(t for t in self.scans if t <= z))
            self.sick.stop()
            set_cable('sick', 'plugged')
            self.sick = self.launcher.node('vaultbot_sim', 'sick_driver')
            self.end_drive()
        return out

    def odometry_case(self, trials):
        """The navigator on a relay of the odometry that this process stops: the base controller still takes
        commands, so the navigator's zero reaches the motors."""
        self.navigator.stop()
        relay = rospy.Publisher('/odom_relay', Odometry, queue_size=5, tcp_nodelay=True)
        state = {'on': True, 'last': 0.0}

        def forward(msg):
            if state['on']:
                relay.publish(msg)
                state['last'] = time.time()
        sub = rospy.Subscriber('/odom', Odometry, forward, queue_size=5, tcp_nodelay=True)
        self.navigator = self._navigator(['odom:=odom_relay'])
        assert self.drive.wait_for_server(rospy.Duration(HANG))
        out = []
        try:
            for k in range(trials):
                state['on'] = True
                wait_for(lambda: time.time() - state['last'] < 0.05, HANG, 'the relay flowing')
                self.start_drive()
                state['on'] = False
                last = state['last']
                out.append(zero_after(self.truth, self.truth.base, last, base_zero, 'the base zero') - last)
                state['on'] = True
                self.end_drive()
        finally:
            sub.unregister()
            self.navigator.stop()
            self.navigator = self._navigator()
            assert self.drive.wait_for_server(rospy.Duration(HANG))
        return out

    def false_stops_case(self, minutes):
        """Drives between the places and a servo stream on the left arm, healthy, for ``minutes``: the holds."""
        from temoto_core.msg import MotionStatus
        held = []
        sub = rospy.Subscriber('/navigator/motion_status', MotionStatus, lambda m: held.append(m)
                               if m.state == MotionStatus.HELD and m.reason in ('obstacles_stale', 'odometry_stale')
                               else None, queue_size=50)
        servo_says = []
        said = rospy.Subscriber('/left_arm/servo_status', String, lambda m: servo_says.append(m.data), queue_size=50)
        pub = rospy.Publisher('/left_arm/servo_target', PoseStamped, queue_size=5, tcp_nodelay=True)
        wait_for(lambda: pub.get_num_connections() > 0, HANG, 'the manipulator on servo targets')
        self.arm_home()
        stop = threading.Event()

        with open(ROBOT_URDF) as f:                       # the tool at the stowed pose, in the arm's base frame
            hold = ArmKinematics(f.read(), LEFT.base_frame, LEFT.tool_frame, LEFT.joints).fk(LEFT.named_poses['stow'])
        qx, qy, qz, qw = quat_from_matrix(hold)

        def stream():
            tool = PoseStamped()
            tool.header.frame_id = LEFT.base_frame           # 2 cm up and down about the stowed pose (in plan view
            # the arm stays inside the driving outline), a 4 s period
            tool.pose.orientation.x, tool.pose.orientation.y, tool.pose.orientation.z = qx, qy, qz
            tool.pose.orientation.w = qw
            k = 0
            while not stop.is_set():
                tool.header.stamp = rospy.Time.now()
                tool.pose.position.x, tool.pose.position.y = hold[0, 3], hold[1, 3]
                tool.pose.position.z = hold[2, 3] + 0.02 * math.sin(k * 0.02 * 2 * math.pi / 4.0)
                pub.publish(tool)
                k += 1
                stop.wait(0.02)                             # the stream's own pace: 50 Hz
        servo = threading.Thread(target=stream, daemon=True)
        end = time.time() + 60.0 * minutes
        drives = 0
        servo.start()
        try:
            while time.time() < end:
                self.drive.send_goal(MoveBaseGoal(target_pose=self.target()))
                wait_for(lambda: self.drive.get_state() not in (GoalStatus.PENDING, GoalStatus.ACTIVE), 240.0,
                         'the drive to end')
                drives += 1
        finally:
            stop.set()
            servo.join(5.0)
            sub.unregister()
            said.unregister()
        arm_holds = [s for s in servo_says if s.startswith('stopping: no target') or 'no joint states' in s]
        return {'minutes': minutes, 'drives': drives, 'base_holds': [(m.reason, m.text) for m in held],
                'arm_holds': arm_holds}

    def controller_case(self, trials):
        out = {'told': [], 'reasons': [], 'resumed': 0, 'moved_blind_s': []}
        for k in range(trials):
            self.start_drive()
            t = time.time()
            os.kill(self.base.pid, signal.SIGKILL)
            wait_for(lambda: self.drive.get_state() not in (GoalStatus.PENDING, GoalStatus.ACTIVE), HANG,
                     'the goal ended')
            out['told'].append(time.time() - t)
            out['reasons'].append(self.drive.get_goal_status_text())
            self.base.stop()
            self.base = self.launcher.node('vaultbot_sim', 'base_controller')     # the respawn
            zero = zero_after(self.truth, self.truth.base, time.time(), base_zero, 'the respawned zero')
            out['moved_blind_s'].append(zero - t)
            wait_for(lambda: self.truth.last(self.truth.base).header.stamp.to_sec() > zero + 2.0, HANG, '2 s more')
            with self.truth.lock:
                out['resumed'] += any(m.header.stamp.to_sec() > zero and not base_zero(m) for m in self.truth.base)
            self.at_rest()
        return out


def ms(v):
    return '%.1f ms' % (v * 1e3)


def dist(values):
    return '%s / %s (max %s)' % (ms(pct(values, 50)), ms(pct(values, 99)), ms(max(values)))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--trials', type=int, default=20)
    p.add_argument('--hogs', type=int, default=0)
    p.add_argument('--only', choices=CASES + EXTRA)
    p.add_argument('--minutes', type=float, default=10.0, help='of driving and servoing, for false_stops')
    args = p.parse_args()
    master, launcher = loopback_master('bench_safety_')
    hogs = cpu_hogs(args.hogs)
    results, rows = {'hogs': args.hogs, 'trials': args.trials}, []
    try:
        bench = Bench(launcher)
        for case in CASES + EXTRA:
            if args.only != case and (args.only is not None or case in EXTRA):
                continue
            print('bench_safety: %s ...' % case, file=sys.stderr, flush=True)
            results[case] = getattr(bench, case + '_case')(args.minutes if case in EXTRA else args.trials)
    finally:
        stop_hogs(hogs)
        launcher.stop_all()
        master.stop()
    n = args.trials
    if 'halt' in results:
        r = results['halt']
        for part, who in (('base', 'the base\'s command gate (the navigator)'),
                          ('arm', 'the arm\'s command gate (the manipulator)'),
                          ('gripper', 'the gripper\'s controller')):
            rows.append(('halt → the %s commanded zero, p50 / p99 (n=%d); stopped by %s' % (part, n, who),
                         dist(r[part]), '≤ 50 ms p99'))
    if 'holders' in results:
        r = results['holders']
        for key, what, who in (('drive_client', 'a drive\'s client', 'the base\'s command gate (the navigator)'),
                               ('arm_client', 'an arm goal\'s client', 'the arm\'s command gate (the manipulator)'),
                               ('manipulator', 'the manipulator, mid-trajectory', 'the arm\'s controller')):
            rows.append(('%s SIGKILLed → zero, p50 / p99 (n=%d); stopped by %s' % (what, n, who), dist(r[key]),
                         '≤ 100 ms p99'))
    if 'stream' in results:
        rows.append(('teleop stream silent → zero, from its last command, p50 / p99 (n=%d); stopped by the '
                     'base\'s command gate (the stream\'s deadman)' % n, dist(results['stream']),
                     '≤ 100 + 20 = 120 ms p99'))
    if 'obstacles' in results:
        rows.append(('active obstacle source stale (SICK 25 Hz) → zero, from its last scan, p50 / p99 (n=%d); '
                     'stopped by the base\'s command gate (its source guard)' % n, dist(results['obstacles']),
                     '≤ 3 × 40 + 20 = 140 ms p99'))
    if 'odometry' in results:
        rows.append(('odometry stale (50 Hz) → zero, from the last odometry, p50 / p99 (n=%d); stopped by the '
                     'base\'s command gate (its odometry guard)' % n, dist(results['odometry']),
                     '≤ 3 × 20 + 20 = 80 ms p99'))
    if 'controller' in results:
        r = results['controller']
        named = sum('/base_controller is gone' in text for text in r['reasons'])
        rows.append(('base controller SIGKILLed mid-drive → the goal\'s client told ABORTED, p50 / p99 (n=%d; '
                     'naming the controller: %d); told by the navigator' % (n, named), dist(r['told']), '≤ 200 ms p99'))
        rows.append(('… motion resumed after the controller\'s respawn, without a new goal', str(r['resumed']), '0'))
        rows.append(('… the kill → the respawned controller\'s zero: the wheels at their last command, only hardware '
                     'could stop them sooner, p50 / max', '%s / %s' % (ms(pct(r['moved_blind_s'], 50)),
                                                                     ms(max(r['moved_blind_s']))), 'reported'))
    if 'false_stops' in results:
        r = results['false_stops']
        rows.append(('false stops in %.0f min of driving (%d drives) and servoing, nothing unplugged: the base held '
                     'by a freshness rule / the arm held by its stream\'s or its states\' silence'
                     % (r['minutes'], r['drives']), '%d / %d' % (len(r['base_holds']), len(r['arm_holds'])), '0 / 0'))
    print_table('Safety: the stack\'s own stops, motors\' command timeout off (%d CPU hogs)' % args.hogs, rows)
    write_results('safety' if not args.hogs else 'safety_hogs', results)
    return 0


if __name__ == '__main__':
    sys.exit(main())
