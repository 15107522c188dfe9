"""``temoto demo teleop``: the operator moves the robot, and every failure on the way stops what depends on it.

The stages, each waited on by an event or by the simulation's ground truth (never by a sleep):

1. "show the environment": the view, as in the failover demo;
2. a goal pointed through ``/move_base_simple/goal``, as RViz's "2D Nav Goal" points it;
3. "robot please go": the robot drives through the lab towards it;
4. the SICK is unplugged on the way: the base stops (its obstacle source is stale), the source fails over to
   the stitched arm-LIDAR cloud, and the robot arrives;
5. "robot please follow my hand at a tenth": the hand tracker's recorded path moves the camera arm at 0.1x;
6. "robot please close the gripper";
7. the camera arm's controller crashes: the arm is commanded zero, ``follow_hand`` ends FAILED, and the
   failure is said on the feedback topic (and aloud with ``--voice``).

With ``--hosts 2`` the operator's station is a host of its own (its hand tracker, pointer, engine and RViz),
and before stage 7 the link is cut while the arm follows the hand: the arm holds once its servo stream
falls silent (the manipulator's 0.1 s), and the station hears the action fail within the owner liveness
bound (1 s). The station cannot see the robot across the cut, so a second recorder on the robot's host
keeps the robot's side (``robot.bag``: its arm's ground truth and servo stream); the report reads both.

Everything is recorded to ``teleop.bag``, the inputs under inert names (``topics.motion_inputs``), and the
report (``teleop_report.py``) is made from the bag alone.
"""
from __future__ import annotations

import math
import os
import time
from typing import List

import rosgraph
import rospy
import yaml
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import String

import temoto_sensor_manager
from temoto_core.processes import LoggedChild, stop_process_group
from temoto_core.wait import wait_for
from temoto_robot_manager.description import load_file
from temoto_robot_manager.paths import DEFAULT_DESCRIPTION
from vaultbot_sim.msg import ArmState, BaseState

from . import topics as T
from .recording import _subscribed_topics
from .scenario import Demo, DemoOptions, _rel, announce, run_stages, write_station_catalogue
from .teleop_report import write_teleop_report

PLACE = 'drums'                 # where the pointed goal is: 2.3 m ahead, past the SICK's unplug
HAND_SCALE = 'a tenth'           # the dial at 0.1, said as words so that speech can say it too
ARM = 'left_arm'                # the camera's arm, which carries the gripper
DRIVING_MPS = 0.2               # the base counts as driving above this commanded speed
ARRIVAL_TIMEOUT = 120.0         # the drive, with its stop and the obstacle source's failover
FOLLOWED_TARGETS = 150          # servo targets sent while the grab holds: 1.5 s of the hand at 100 Hz
ARM_MOVING = 0.005              # rad/s: the camera arm follows the grabbing hand (0.01 at 0.1x)
SETTLE_FRAMES = 5                # frames RViz draws after a new display's first message, before a screenshot
RECORDER = '/usr/lib/rosbag/record'
ROBOT_RECORDER = '/temoto_demo_robot_record'


class TeleopDemo(Demo):
    def __init__(self, opts: DemoOptions) -> None:
        super().__init__(opts)
        self.bag_path = os.path.join(opts.out_dir, 'teleop.bag')
        self.base: List[BaseState] = []
        self.arms: List[ArmState] = []
        self.feedback: List[tuple] = []       # (arrival, text)
        self.targets = 0

    def recorded_extra(self) -> List[str]:
        return T.teleop_topics(self.opts.namespace, self._robot_ns)

    # ------------------------------------------------------------------ --hosts 2
    def _station_catalogue(self, workdir: str) -> str:
        """The station's scanner and the operator's hand sources, joined to the robot's simulation (its
        cables)."""
        path = write_station_catalogue(self.opts.robot, workdir)
        with open(path) as f:
            catalogue = yaml.safe_load(f)
        with open(os.path.join(os.path.dirname(temoto_sensor_manager.__file__), 'config', 'hands.yaml')) as f:
            hands = yaml.safe_load(f)['sensors']
        for entry in hands:
            if entry['executable'] == 'hand_tracker_driver':
                entry['args'] = '_sim_ns:=/%s/vaultbot_sim' % self.opts.robot
        catalogue['sensors'] += hands
        with open(path, 'w') as f:
            yaml.safe_dump(catalogue, f)
        return path

    def start(self) -> None:
        super().start()
        if self.hosts is not None:
            self._start_robot_recorder()

    def _start_robot_recorder(self) -> None:
        robot = self._robot_ns
        topics = [T.of_robot(robot, 'vaultbot_sim/arm_states'), T.of_robot(robot, '%s/servo_command' % ARM),
                  T.of_robot(robot, '%s/servo_target' % ARM), T.of_robot(robot, 'vaultbot_sim/base_state')]
        self.robot_bag = os.path.join(self.opts.out_dir, 'robot.bag')
        argv = [RECORDER, '-O', self.robot_bag, '--lz4'] + topics + ['__name:=' + ROBOT_RECORDER.lstrip('/')]
        env = self._env(self.hosts.robot)
        self.robot_recorder = LoggedChild(self.hosts.argv(self.hosts.robot, argv), env,
                                          os.path.join(self.opts.out_dir, 'logs', 'robot_record.log'), 'robot_record')
        wait_for(lambda: set(topics) <= _subscribed_topics(self.master.uri, ROBOT_RECORDER), 15.0,
                 'the robot\'s recorder to subscribe')
        self.progress.line('recording the robot\'s side on its host: %s' % _rel(self.robot_bag))

    def stop(self):
        recorder = getattr(self, 'robot_recorder', None)
        if recorder is not None:
            if self.hosts is not None:
                self.hosts.link(True)
            stop_process_group(recorder.proc, sigint_grace=10.0)
            self.robot_recorder = None
        return super().stop()

    def _cut_while_following(self) -> None:
        """Cut the link while the arm follows the hand; the station must hear the action fail within 1 s."""
        wait_for(lambda: self.arms and self.arms[-1].commanded_speed > ARM_MOVING, self.opts.stage_timeout,
                 'the arm moving with the hand')
        since = time.monotonic()
        self._mark('link_down')
        self.hosts.link(False)
        failing = self.watcher.wait_action(lambda e: e.get('event') == 'failing' and e.get('action') == 'follow_hand',
                                           since, self.opts.stage_timeout, 'follow_hand to fail across the cut')
        self.results['cut_failing_s'] = failing['arrival'] - since
        self.progress.line('link cut while following: the station heard follow_hand fail %.2f s later'
                           % (failing['arrival'] - since))
        healed = time.monotonic()
        self._mark('link_up')
        self.hosts.link(True)
        self.watcher.wait_action(lambda e: e.get('event') == 'state' and e.get('action') == 'follow_hand'
                                 and e.get('state') == 'FAILED', since, self.opts.stage_timeout,
                                 'follow_hand to end FAILED once the link is back')
        self.progress.line('link plugged back: follow_hand released what it held (%.2f s)'
                           % (time.monotonic() - healed))
        since = self.say('robot please follow my hand at %s' % HAND_SCALE)
        self._action('following', since, 'the arm to follow the hand again')
        self.progress.line('"follow my hand" again')

    def _init_rospy(self, env) -> None:
        super()._init_rospy(env)
        robot, ns = self._robot_ns, self.opts.namespace
        rospy.Subscriber(T.of_robot(robot, 'vaultbot_sim/base_state'), BaseState, self._keep(self.base),
                         queue_size=200, tcp_nodelay=True)
        rospy.Subscriber(T.of_robot(robot, 'vaultbot_sim/arm_states'), ArmState,
                         lambda m: m.arm == ARM and self._keep(self.arms)(m), queue_size=200, tcp_nodelay=True)
        rospy.Subscriber(T.action_feedback(ns), String, lambda m: self.feedback.append((time.monotonic(), m.data)),
                         queue_size=100)
        rospy.Subscriber(T.of_robot(robot, '%s/servo_target' % ARM), PoseStamped, self._count_target, queue_size=100)
        self.point_pub = rospy.Publisher('/move_base_simple/goal', PoseStamped, queue_size=1)

    @staticmethod
    def _keep(into: list):
        def keep(msg) -> None:
            into.append(msg)
            del into[:-400]
        return keep

    def _count_target(self, _msg) -> None:
        self.targets += 1

    def _wait_services(self, env) -> None:
        super()._wait_services(env)
        ns = (self._robot_ns or self.opts.namespace).strip('/')
        master = rosgraph.Master('/temoto_demo')
        wait_for(lambda: '/%s/temoto_robot_manager/load_robot' % ns in {s for s, _ in master.getSystemState()[2]},
                 60.0, 'the Robot Manager')

    # ------------------------------------------------------------------ the operator's acts
    def say(self, text: str) -> float:
        """Say ``text`` (typed on the chatter, or spoken with --voice); returns when it was said."""
        since = time.monotonic()
        self._mark('say', text=text, voice=self.opts.voice)
        if self.opts.voice:
            self.heard.clear()
            self._speak(text)
        else:
            self.chatter.publish(String(data=text))
        return since

    def point(self, place: str) -> None:
        """RViz's "2D Nav Goal" on a place of the robot's description; returns once the pointer keeps it."""
        x, y, yaw = next(r for r in load_file(DEFAULT_DESCRIPTION)[0] if r.name == 'vaultbot').navigation.places[place]
        kept = []
        sub = rospy.Subscriber('/%s/pointed_goal' % self.opts.namespace.strip('/'), PoseStamped,
                               lambda m: kept.append(m.header.frame_id))
        try:
            wait_for(lambda: self.point_pub.get_num_connections() > 0, 20.0, 'the pointer listening')
            goal = PoseStamped()
            goal.header.frame_id, goal.header.stamp = 'world', rospy.Time.now()
            goal.pose.position.x, goal.pose.position.y = x, y
            goal.pose.orientation.z, goal.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            self._mark('point', place=place, x=x, y=y, yaw=yaw)
            self.point_pub.publish(goal)
            wait_for(lambda: 'world' in kept, 10.0, 'the pointer to keep the goal')
        finally:
            sub.unregister()

    def heard_feedback(self, since: float, *parts: str) -> str:
        found = wait_for(lambda: next((text for at, text in self.feedback if at >= since
                                       and all(p in text for p in parts)), None), self.opts.stage_timeout,
                         'feedback saying %s' % ' '.join(parts))
        return found

    def _base_zero_after(self, t0: float) -> float:
        """The sim's first commanded zero of the base stamped after ``t0`` (wall clock), as a stamp."""
        return wait_for(lambda: next((s.header.stamp.to_sec() for s in list(self.base)
                                      if s.header.stamp.to_sec() > t0 and s.commanded_linear == 0.0
                                      and s.commanded_angular == 0.0), None), 10.0, 'the base commanded zero')

    def _arm_zero_after(self, t0: float) -> float:
        return wait_for(lambda: next((a.header.stamp.to_sec() for a in list(self.arms)
                                      if a.header.stamp.to_sec() > t0 and a.commanded_speed == 0.0), None), 10.0,
                        'the arm commanded zero')

    def _action(self, event: str, since: float, what: str, timeout: float = 0.0) -> dict:
        return self.watcher.wait_action(lambda e: e.get('event') == event, since, timeout or self.opts.stage_timeout,
                                        what, graph='*')

    # ------------------------------------------------------------------ the stages
    def scenario(self) -> None:
        self.show_first_view()
        self.progress.line('the view on screen after "show the environment"')
        self._set_operator_view()
        self._screenshot('view')
        self._hold_host()
        # 2, 3: point, then go
        self.point(PLACE)
        self.progress.line('goal pointed (2D Nav Goal): the %s' % PLACE)
        since = self.say('robot please go')
        self._action('driving', since, 'the robot to drive')
        wait_for(lambda: self.base and self.base[-1].commanded_linear > DRIVING_MPS, self.opts.stage_timeout,
                 'the base driving')
        self.progress.line('"robot please go": driving to the pointed goal')
        # the scene while it drives: the plan, the footprint and its stop zone reaching ahead
        zone = self.watcher.wait_action(lambda e: e.get('event') == 'scene_shown' and 'stop zone' in
                                        e.get('display', ''), since, self.opts.stage_timeout,
                                        'the stop zone in the scene', graph='*')
        self.watcher.wait_first_frame(zone['topic'], since, self.opts.stage_timeout)
        self._screenshot('driving', settle_frames=SETTLE_FRAMES)
        # 4: the SICK goes on the way
        cut = time.time()
        since = time.monotonic()
        self._mark('unplug', device='sick', mode='crash')
        self.set_device('sick', False, 'crash')
        zero = self._base_zero_after(cut)
        self.results['sick_zero_s'] = zero - cut
        self.progress.line('SICK unplugged: the base commanded zero %.0f ms later' % (1e3 * (zero - cut)))
        taken = self.heard_feedback(since, 'obstacles from')
        self.progress.line('obstacles now from %s' % taken.split('obstacles from ', 1)[1].split(' on ')[0])
        self._action('arrived', since, 'the robot to arrive', ARRIVAL_TIMEOUT)
        end = self.base[-1]
        self.results['arrived'] = {'x': end.x, 'y': end.y, 'yaw': end.yaw, 'contacts': end.contacts}
        self.progress.line('arrived at the pointed goal (%.2f, %.2f), %d contacts' % (end.x, end.y, end.contacts))
        self._screenshot('arrived')
        # 5: the hand
        since = self.say('robot please follow my hand at %s' % HAND_SCALE)
        self._action('following', since, 'the arm to follow the hand')
        start = self.targets
        wait_for(lambda: self.targets - start >= FOLLOWED_TARGETS, self.opts.stage_timeout,
                 'the arm following the grabbing hand')
        self.progress.line('"follow my hand at %s": the arm follows the hand at 0.1x' % HAND_SCALE)
        # 6: the gripper
        since = self.say('robot please close the gripper')
        done = self.watcher.wait_action(lambda e: e.get('event') in ('grasped', 'gripper_reached'), since,
                                        self.opts.stage_timeout, 'the gripper to close')
        self.progress.line('"close the gripper": %s' % ('holding an object' if done['event'] == 'grasped'
                                                        else 'closed'))
        self._screenshot('gripper', settle_frames=SETTLE_FRAMES)
        if self.hosts is not None:
            self._cut_while_following()
        # 7: the arm's controller crashes while the arm follows the hand
        wait_for(lambda: self.arms and self.arms[-1].commanded_speed > ARM_MOVING, self.opts.stage_timeout,
                 'the arm moving with the hand')
        cut = time.time()
        since = time.monotonic()
        self._mark('unplug', device=ARM, mode='crash')
        self.set_device(ARM, False, 'crash')
        zero = self._arm_zero_after(cut)
        self.results['arm_zero_s'] = zero - cut
        self.progress.line('%s controller crashed: the arm commanded zero %.0f ms later' % (ARM, 1e3 * (zero - cut)))
        failing = self.watcher.wait_action(lambda e: e.get('event') == 'failing' and e.get('action') == 'follow_hand',
                                           since, self.opts.stage_timeout, 'follow_hand to say it fails')
        said = self.heard_feedback(since, 'follow_hand', 'failing')
        self.results['follow_hand_failing_s'] = failing['arrival'] - since
        self.results['announced'] = said
        self.progress.line('follow_hand failing %.0f ms after the crash, and said so' % (
            1e3 * (failing['arrival'] - since)))
        failed = self.watcher.wait_action(lambda e: e.get('event') == 'state' and e.get('action') == 'follow_hand'
                                          and e.get('state') == 'FAILED', since, self.opts.stage_timeout,
                                          'follow_hand to end FAILED')
        self.results['follow_hand_failed_s'] = failed['arrival'] - since
        self.progress.line('follow_hand FAILED, the arm\'s processes released')
        self.set_device(ARM, True)
        self._empty_view()


def run_teleop(opts: DemoOptions) -> int:
    demo = TeleopDemo(opts)
    announce('temoto demo teleop: the operator moves the robot', opts)

    def report(demo: TeleopDemo) -> None:
        rep = write_teleop_report(demo.bag_path, opts.out_dir, opts.namespace)
        demo.results['report'] = rep.summary
        demo.progress.line('report %s' % _rel(rep.path))
    return run_stages(demo, 'temoto demo teleop', report)
