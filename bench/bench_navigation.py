#!/usr/bin/env python3
"""Navigation benchmark: the planners, seeded drives, and the navigator's stops from the sim's ground truth.

1. **planners** (in process): A* (pyastar2d, the navigator's) and, when it is importable, OMPL's
   RRT-Connect on the same costmaps: 20 x 20 m at 5 cm, seeded boxes, seeded start and goal
   pairs in free space. Plan time p50 / p95, and the path's length against A*'s;
2. **seeded drives** (in process): the navigator closing the loop on a kinematic base in the lab,
   from a seeded pose to seeded goals: arrived within 0.10 m and 5 degrees, refused at once
   (and why), and every pose checked for the outline touching the map;
3. **across processes**, the sim in the lab with its base controller, the SICK and the navigator:
   - the obstacle source goes stale while driving (its cable pulled in stall mode): the last
     scan's stamp -> the first ground-truth state with zero commanded;
   - a bad goal -> the client hears REJECTED (the four kinds in turn), and nothing moves;
   - the goal's client SIGKILLed while driving -> zero commanded;
   - drives to the described places in turn, some with the SICK stalled on the way: contacts,
     arrival within 0.10 m and 5 degrees;
4. **the Robot Manager SIGKILLed during a drive** (``--only manager``): the sim, the ER, Sensor and Robot
   Managers, the Robot Manager with a journal under its warm-respawn parent, the robot loaded through it:
   the kill -> the first ground-truth state with zero commanded, and -> the manager's registry answering
   again, recovered and equal to the one before (as bench_recovery.py measures the other managers).
5. **a teleop stream** (``--only teleop``): the sim, the SICK and the navigator: a stream on
   ``teleop/cmd_vel`` falls silent -> zero commanded (the navigator's watch), alternating with the same
   stream straight on ``cmd_vel`` (the base controller's timeout); the SICK stalled under the stream.

Prints a markdown table and writes bench/results/navigation.json.
Usage: python bench/bench_navigation.py [--pairs N] [--drives N] [--trials N] [--hogs N]
                                        [--only planners|drives|stops|manager|teleop]
"""
import argparse
import json
import math
import os
import signal
import sys
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402

from common import cpu_hogs, loopback_master, pct, print_table, stop_hogs  # noqa: E402
from temoto_robot_manager.navigation import global_planner  # noqa: E402
from temoto_robot_manager.navigation.costmap import Costmap, Footprint  # noqa: E402
from temoto_robot_manager.description import load_file  # noqa: E402
from temoto_robot_manager.navigation.freshness import Freshness  # noqa: E402
from temoto_robot_manager.navigation.navigator import BadGoal, Navigator, Outcome  # noqa: E402
from temoto_robot_manager.paths import DEFAULT_DESCRIPTION  # noqa: E402
from vaultbot_sim.base import advance  # noqa: E402
from vaultbot_sim.kinematics import WORLDS, TreeModel  # noqa: E402
from vaultbot_sim.world_map import world_map  # noqa: E402
from temoto_core.action_client import TrackingActionClient  # noqa: E402

HANG = 60.0
VAULTBOT = next(r for r in load_file(DEFAULT_DESCRIPTION)[0] if r.name == 'vaultbot')
FOOTPRINT = Footprint.of(VAULTBOT.navigation.footprint, VAULTBOT.navigation.protrusions)
PLACES = VAULTBOT.navigation.places


def quat(yaw):
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


# ------------------------------------------------------------------------------------------------ planners
def random_grid(rng, size=400, boxes=25):
    occupied = np.zeros((size, size), dtype=bool)
    occupied[[0, -1], :] = occupied[:, [0, -1]] = True
    for _ in range(boxes):
        i, j = rng.integers(0, size, 2)
        h, w = rng.integers(4, 30, 2)
        occupied[i:i + h, j:j + w] = True
    return occupied


def free_pairs(rng, cm, n):
    pairs, tries = [], 0
    x0, y0, x1, y1 = cm.bounds
    while len(pairs) < n and tries < 100 * n:
        tries += 1
        a, b = rng.uniform((x0, y0), (x1, y1)), rng.uniform((x0, y0), (x1, y1))
        if cm.lethal(*a) or cm.lethal(*b) or math.dist(a, b) < 5.0:
            continue
        pairs.append((tuple(a), tuple(b)))
    return pairs


def ompl_plan(cm, start, goal, budget=1.0):
    """RRT-Connect in the plane (OMPL 2's Python bindings), each state checked against the costmap's lethal
    cells, the solution simplified; None if none is found within ``budget`` seconds."""
    from ompl import base as ob, geometric as og, util as ou       # optional: measured where it is installed
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    space = ob.RealVectorStateSpace(2)
    bounds = ob.RealVectorBounds(2)
    x0, y0, x1, y1 = cm.bounds
    bounds.setLow(0, x0)
    bounds.setHigh(0, x1 - 1e-6)
    bounds.setLow(1, y0)
    bounds.setHigh(1, y1 - 1e-6)
    space.setBounds(bounds)
    space.setLongestValidSegmentFraction(cm.resolution / max(x1 - x0, y1 - y0))
    setup = og.SimpleSetup(space)
    setup.setStateValidityChecker(lambda s: not cm.lethal(s[0], s[1]))
    a, b = space.allocState(), space.allocState()
    a[0], a[1], b[0], b[1] = start[0], start[1], goal[0], goal[1]
    setup.setStartAndGoalStates(a, b)
    setup.setPlanner(og.RRTConnect(setup.getSpaceInformation()))
    if not setup.solve(budget) or not setup.haveExactSolutionPath():
        return None
    setup.simplifySolution()
    path = setup.getSolutionPath()
    return np.array([[path.getState(k)[0], path.getState(k)[1]] for k in range(path.getStateCount())])


def bench_planners(pairs_n, seed=39):
    rng = np.random.default_rng(seed)
    results = {'astar': [], 'ompl': [], 'ratio': [], 'ompl_failed': 0}
    try:
        import ompl  # noqa: F401
        have_ompl = True
    except ImportError:
        have_ompl = False
    for grid_k in range(5):
        cm = Costmap((-10.0, -10.0), 0.05, random_grid(rng), FOOTPRINT)
        for start, goal in free_pairs(rng, cm, pairs_n // 5):
            t = time.perf_counter()
            try:
                path = global_planner.plan(cm, start, goal)
            except global_planner.NoPath:
                continue
            results['astar'].append(time.perf_counter() - t)
            if have_ompl:
                t = time.perf_counter()
                other = ompl_plan(cm, start, goal)
                if other is None:
                    results['ompl_failed'] += 1
                    continue
                results['ompl'].append(time.perf_counter() - t)
                results['ratio'].append(global_planner.length(other) / global_planner.length(path))
    results['have_ompl'] = have_ompl
    return results


# ------------------------------------------------------------------------------------------------ seeded drives
def bench_drives(n, seed=40):
    rng = np.random.default_rng(seed)
    grid = world_map(TreeModel(WORLDS['lab']))
    cm = Costmap(grid.origin, grid.resolution, grid.cells > 0, FOOTPRINT)
    nav = Navigator(FOOTPRINT, Freshness(declared=0.04))
    nav.set_map(cm)
    pose = (0.0, 0.0, 0.0)
    out = {'arrived': 0, 'failed': [], 'refused': {}, 'touches': 0, 'errors': [], 'seconds': []}
    x0, y0, x1, y1 = cm.bounds
    for _ in range(20 * n):                          # seeded goals until n are driven (most points are refused)
        if out['arrived'] + len(out['failed']) >= n:
            break
        x, y, yaw = rng.uniform(x0, x1), rng.uniform(y0, y1), rng.uniform(-math.pi, math.pi)
        nav.set_pose(pose)
        for k in range(5):
            nav.set_obstacles(np.zeros((0, 2)), -0.04 * (4 - k))
        try:
            nav.start(nav.check(x, y, quat(yaw)), 0.0)
        except (BadGoal, global_planner.NoPath) as err:
            kind = 'no way in' if isinstance(err, global_planner.NoPath) else str(err).split(': ', 1)[1][:40]
            out['refused'][kind] = out['refused'].get(kind, 0) + 1
            continue
        now = 0.0
        for _ in range(6000):
            nav.set_pose(pose)
            nav.set_obstacles(np.zeros((0, 2)), now)
            tick = nav.tick(now)
            if tick.ending is not None:
                break
            pose = advance(pose, tick.linear, tick.angular, 0.05)
            out['touches'] += nav.gap_at(pose) <= 0.0
            now += 0.05
        if tick.ending is not None and tick.ending.outcome is Outcome.SUCCEEDED:
            out['arrived'] += 1
            out['seconds'].append(now)
            out['errors'].append((math.hypot(pose[0] - x, pose[1] - y),
                                  abs(math.atan2(math.sin(pose[2] - yaw), math.cos(pose[2] - yaw)))))
        else:
            out['failed'].append(tick.ending.text if tick.ending else 'no ending in 300 s')
    return out


# ------------------------------------------------------------------------------------------------ across processes
def navigator_stack(launcher):
    """The sim in the lab, its base controller, the SICK and the navigator, and this process subscribed to the
    ground truth; (the SICK's process, the base states, the scans' stamps)."""
    import rospy
    from sensor_msgs.msg import LaserScan
    from vaultbot_sim.msg import BaseState
    launcher.node('vaultbot_sim', 'vaultbot_sim', params={'world': 'lab', 'sweep': False, 'hand_motion': False})
    launcher.node('vaultbot_sim', 'base_controller')
    sick = launcher.node('vaultbot_sim', 'sick_driver')
    launcher.node('temoto_robot_manager', 'navigator', params={
        'description': DEFAULT_DESCRIPTION, 'robot': 'vaultbot', 'obstacle_topic': 'sick/scan'})
    rospy.init_node('bench_navigation', anonymous=True, disable_signals=True)
    states, scans = [], []
    rospy.Subscriber('/vaultbot_sim/base_state', BaseState, states.append, queue_size=200, tcp_nodelay=True)
    rospy.Subscriber('/sick/scan', LaserScan, lambda m: scans.append(m.header.stamp.to_sec()), queue_size=50)
    return sick, states, scans


def bench_stops(trials, drives, hogs):
    import rospy
    from actionlib_msgs.msg import GoalStatus
    from geometry_msgs.msg import PoseStamped
    from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
    from temoto_core.wait import wait_for
    from temoto_testing.motion import GOAL_CLIENT
    from temoto_testing.sensor_manager import set_cable

    master, launcher = loopback_master('bench_navigation_')
    hog_procs = cpu_hogs(hogs)
    out = {'stale': [], 'refusal': [], 'refusal_moved': 0, 'client_killed': [], 'drives': []}
    try:
        sick, states, scans = navigator_stack(launcher)
        from actionlib_msgs.msg import GoalStatusArray
        seen = []
        rospy.Subscriber('/move_base/status', GoalStatusArray, lambda m: seen.append(
            [(st.goal_id.id, st.status, st.text) for st in m.status_list]), queue_size=5)
        client = TrackingActionClient('/move_base', MoveBaseAction)
        assert client.wait_for_server(rospy.Duration(HANG)), 'the navigator'
        wait_for(lambda: states, HANG, 'the base state')

        def goal(x, y, yaw, frame='world'):
            p = PoseStamped()
            p.header.frame_id, p.header.stamp = frame, rospy.Time.now()
            p.pose.position.x, p.pose.position.y = x, y
            p.pose.orientation.z, p.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            return MoveBaseGoal(target_pose=p)

        def ended(bound=240.0):
            wait_for(lambda: client.get_state() not in (GoalStatus.PENDING, GoalStatus.ACTIVE), bound, 'the goal')
            return client.get_state()

        def driving(ours=True):
            def moving():
                if ours and client.get_state() in (GoalStatus.REJECTED, GoalStatus.ABORTED):
                    raise RuntimeError('goal ended: %s' % client.get_goal_status_text())
                return states[-1].commanded_linear > 0.3
            try:
                wait_for(moving, HANG, 'the base driving')
            except TimeoutError:
                raise TimeoutError('the base did not drive: goals %s; base %s' % (seen[-1] if seen else None,
                                                                                 states[-1])) from None

        def zero_after(t0):
            return wait_for(lambda: next((s.header.stamp.to_sec() for s in states[-20:]
                                          if s.header.stamp.to_sec() > t0 and s.commanded_linear == 0.0
                                          and s.commanded_angular == 0.0), None), HANG, 'zero commanded')

        def fresh_sick():
            nonlocal sick
            sick.stop()
            set_cable('sick', 'plugged')
            sick = launcher.node('vaultbot_sim', 'sick_driver')

        order = ['shelf', 'home', 'drums', 'home', 'table', 'home']
        where = {'at': 'home'}

        def next_place(k):
            """The k-th place of the tour, or the one after it if the robot is there already."""
            name = order[k % len(order)]
            if name == where['at']:
                name = order[(k + 1) % len(order)]
            where['at'] = name
            return name
        print('bench_navigation: stale source x %d ...' % trials, file=sys.stderr, flush=True)
        for k in range(trials):
            client.send_goal(goal(*PLACES[next_place(k)]))
            driving()
            cut = time.time()
            set_cable('sick', 'unplugged', 'stall')
            # the first zero after the stall: zero_after(cut - 1.0) once took zeros from before it (18 to 38 ms,
            # less than one SICK period: no staleness stop can be that quick)
            z = zero_after(cut)
            last = max(t for t in scans if t <= z)
            out['stale'].append(z - last)
            fresh_sick()
            if ended() != GoalStatus.SUCCEEDED:
                print('  trial %d: %s' % (k, client.get_goal_status_text()), file=sys.stderr)
        print('bench_navigation: bad goals x %d ...' % (4 * trials), file=sys.stderr, flush=True)
        bad = [(1.0, 0.0, 0.0, 'nowhere'), (float('nan'), 0.0, 0.0, 'world'), (40.0, 0.0, 0.0, 'world'),
               (2.2, 2.2, 0.0, 'world')]
        for k in range(4 * trials):
            before = len(states)
            heard = threading.Event()
            t = time.perf_counter()
            client.send_goal(goal(*bad[k % 4]), done_cb=lambda state, result: heard.set())
            assert heard.wait(HANG), 'no answer to a bad goal'
            out['refusal'].append(time.perf_counter() - t)
            ended(HANG)
            out['refusal_moved'] += any(s.commanded_linear or s.commanded_angular for s in states[before:])
        print('bench_navigation: client killed x %d ...' % trials, file=sys.stderr, flush=True)
        for k in range(trials):
            if where['at'] != 'home':                   # each trial drives from home to a place
                client.send_goal(goal(*PLACES['home']))
                ended()
                where['at'] = 'home'
            x, y, yaw = PLACES[('shelf', 'drums', 'table')[k % 3]]
            proc = launcher.command(GOAL_CLIENT + [str(x), str(y), str(yaw)], 'goal_client')
            try:
                driving(ours=False)
            except TimeoutError as err:
                raise TimeoutError('%s; the client\'s log:\n%s' % (err, proc.log())) from None
            os.kill(proc.pid, signal.SIGKILL)
            killed = time.time()
            out['client_killed'].append(zero_after(killed) - killed)
            wait_for(lambda: states[-1].linear == 0.0 and states[-1].angular == 0.0, HANG, 'at rest')
            where['at'] = None                         # stopped on the way: at no place
        print('bench_navigation: drives x %d ...' % drives, file=sys.stderr, flush=True)
        for k in range(drives):
            name = next_place(k)
            x, y, yaw = PLACES[name]
            contacts = states[-1].contacts
            started = time.time()
            client.send_goal(goal(x, y, yaw))
            stalled = k % 5 == 4                       # one in five: the SICK goes silent on the way
            if stalled:
                driving()
                set_cable('sick', 'unplugged', 'stall')
                wait_for(lambda: states[-1].commanded_linear == 0.0, HANG, 'stopped')
                fresh_sick()
            state = ended()
            wait_for(lambda: states[-1].linear == 0.0 and states[-1].angular == 0.0, HANG, 'at rest')
            end = states[-1]
            out['drives'].append({'place': name, 'stalled': stalled, 'state': state,
                                  'text': client.get_goal_status_text(), 'seconds': time.time() - started,
                                  'error_m': math.hypot(end.x - x, end.y - y),
                                  'error_deg': math.degrees(abs(math.atan2(math.sin(end.yaw - yaw),
                                                                           math.cos(end.yaw - yaw)))),
                                  'contacts': end.contacts - contacts})
    finally:
        stop_hogs(hog_procs)
        launcher.stop_all()
        master.stop()
    return out


def bench_teleop(trials, hogs):
    """A teleop stream on ``teleop/cmd_vel`` falls silent → the base commanded zero (the navigator's 0.1 s watch),
    beside the same stream sent straight to ``cmd_vel`` (the base controller's 0.25 s timeout, what a twist_mux
    setup relies on); and the SICK stalled while the stream turns the base → zero, from its last scan."""
    import rospy
    from geometry_msgs.msg import Twist, TwistStamped
    from temoto_core.wait import wait_for
    from temoto_testing.sensor_manager import set_cable

    master, launcher = loopback_master('bench_navigation_teleop_')
    hog_procs = cpu_hogs(hogs)
    out = {'silence': [], 'silence_cmd_vel': [], 'stale': []}
    try:
        sick, states, scans = navigator_stack(launcher)
        teleop = rospy.Publisher('/teleop/cmd_vel', TwistStamped, queue_size=5, tcp_nodelay=True)
        raw = rospy.Publisher('/cmd_vel', Twist, queue_size=5, tcp_nodelay=True)
        wait_for(lambda: states and teleop.get_num_connections() and raw.get_num_connections(), HANG,
                 'the navigator and the base controller listening')

        def turn(pub, stamped, seconds, sign):
            """Stream a slow turn at 50 Hz for ``seconds``; the wall time of the last command sent."""
            rate, last = rospy.Rate(50), None
            for _ in range(int(seconds * 50)):
                if stamped:
                    msg = TwistStamped()
                    msg.header.stamp = rospy.Time.now()
                    msg.twist.angular.z = sign * 0.4
                else:
                    msg = Twist()
                    msg.angular.z = sign * 0.4
                last = time.time()
                pub.publish(msg)
                rate.sleep()
            return last

        def zero_after(t0, since=None):
            """The first commanded zero stamped after ``t0``, among the states from index ``since`` (else the
            latest ones)."""
            return wait_for(lambda: next((s.header.stamp.to_sec() for s in (states[since:] if since is not None
                                                                              else states[-40:])
                                          if s.header.stamp.to_sec() > t0 and s.commanded_angular == 0.0), None),
                            HANG, 'zero commanded')

        print('bench_navigation: teleop stream silent x %d ...' % (2 * trials), file=sys.stderr, flush=True)
        for k in range(2 * trials):           # the two paths alternate, so the machine's noise hits both
            through = k % 2 == 0
            last = turn(teleop if through else raw, through, 0.4, 1 if k % 4 < 2 else -1)
            out['silence' if through else 'silence_cmd_vel'].append(zero_after(last) - last)
            wait_for(lambda: states[-1].angular == 0.0, HANG, 'at rest')
        print('bench_navigation: SICK stalled under a teleop stream x %d ...' % trials, file=sys.stderr, flush=True)

        def keep_turning(stop):
            """The stream at 50 Hz on its own thread, so nothing the bench does between pauses it."""
            rate = rospy.Rate(50)
            for _ in range(int(HANG * 50)):
                if stop.is_set():
                    return
                msg = TwistStamped()
                msg.header.stamp = rospy.Time.now()
                msg.twist.angular.z = 0.4
                teleop.publish(msg)
                rate.sleep()
        for k in range(trials):
            stop = threading.Event()
            streamer = threading.Thread(target=keep_turning, args=(stop,), daemon=True)
            streamer.start()
            try:
                wait_for(lambda: states[-1].commanded_angular > 0.0, HANG, 'the stream turning the base')
                since, last_scan = len(states), scans[-1]
                set_cable('sick', 'unplugged', 'stall')
                z = zero_after(last_scan, since)
                out['stale'].append(z - max(t for t in scans if t <= z))
            finally:
                stop.set()
                streamer.join(5.0)
            sick.stop()
            set_cable('sick', 'plugged')
            sick = launcher.node('vaultbot_sim', 'sick_driver')
            wait_for(lambda: len(scans) > 10 and time.time() - scans[-1] < 0.2, HANG, 'the SICK back')
            wait_for(lambda: states[-1].angular == 0.0, HANG, 'at rest')
    finally:
        stop_hogs(hog_procs)
        launcher.stop_all()
        master.stop()
    return out


def bench_manager(trials, hogs):
    import rospy
    from actionlib_msgs.msg import GoalStatus
    from geometry_msgs.msg import PoseStamped
    from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
    from temoto_core import master_lookup
    from temoto_core.wait import wait_for
    from temoto_robot_manager.interface import RobotManagerInterface
    from temoto_testing.sensor_manager import (GENEROUS_ALLOWANCE, recovered_registry, start_er_manager,
                                               start_robot_manager, start_sensor_manager, start_sim)
    from vaultbot_sim.msg import BaseState

    master, launcher = loopback_master('bench_navigation_manager_')
    hog_procs = cpu_hogs(hogs)
    out = {'zero': [], 'at_rest': [], 'recovered': [], 'taken_again': [], 'unequal': 0, 'parts_lost': 0,
           'not_driven': []}
    rm = None
    try:
        rospy.init_node('bench_navigation', anonymous=True, disable_signals=True)
        start_sim(launcher, hand_motion=False)
        launcher.node('vaultbot_sim', 'base_controller')
        start_er_manager(launcher, os.path.join(launcher.workdir, 'er_logs'))
        start_sensor_manager(launcher, extra='', first_data_allowance=GENEROUS_ALLOWANCE)
        start_robot_manager(launcher, journal=os.path.join(launcher.workdir, 'rm.sqlite'))
        states = []
        rospy.Subscriber('/vaultbot_sim/base_state', BaseState, states.append, queue_size=200, tcp_nodelay=True)
        rm = RobotManagerInterface()
        robot = rm.load_robot(['navigation'])
        client = TrackingActionClient('/move_base', MoveBaseAction)
        assert client.wait_for_server(rospy.Duration(HANG)), 'the navigator'
        wait_for(lambda: states, HANG, 'the base state')
        navigator = robot.parts['navigation.controller']

        def manager_pid():
            uri = master_lookup.lookup_node(master.uri, '/temoto_robot_manager')
            return master_lookup.node_pid(uri) if uri else None

        print('bench_navigation: the Robot Manager SIGKILLed mid-drive x %d ...' % trials, file=sys.stderr,
              flush=True)
        tour = ['shelf', 'drums', 'table']                  # each far from the one before

        def send(k):
            """Send the k-th drive; while the navigator has not heard the new manager yet it refuses goals
            ('away'): send again until it takes one. Returns when it is taken."""
            x, y, yaw = PLACES[tour[k % len(tour)]]
            for _ in range(500):
                p = PoseStamped()
                p.header.frame_id, p.header.stamp = 'world', rospy.Time.now()
                p.pose.position.x, p.pose.position.y = x, y
                p.pose.orientation.z, p.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
                client.send_goal(MoveBaseGoal(target_pose=p))
                wait_for(lambda: client.get_state() != GoalStatus.PENDING, HANG, 'an answer to the goal')
                if client.get_state() != GoalStatus.REJECTED:
                    return
                if 'away' not in client.get_goal_status_text():
                    raise RuntimeError('trial %d: refused: %s' % (k, client.get_goal_status_text()))
                time.sleep(0.01)
            raise RuntimeError('trial %d: the navigator refused 500 goals: the manager stayed away' % k)

        send(0)
        k = 0
        for attempt in range(2 * trials):
            if k >= trials:
                break
            before = wait_for(lambda: recovered_registry('temoto_robot_manager'), HANG, 'the registry')

            def moving():
                return client.get_state() not in (GoalStatus.PENDING, GoalStatus.ACTIVE) or \
                    states[-1].commanded_linear > 0.3 or states[-1].commanded_angular > 0.3
            wait_for(moving, HANG, 'the base driving')
            if client.get_state() not in (GoalStatus.PENDING, GoalStatus.ACTIVE):
                # stopped by the last kill where the next drive cannot start (too near an obstacle): counted,
                # and the tour goes on to the next place
                out['not_driven'].append(client.get_goal_status_text())
                send(attempt + 1)
                continue
            time.sleep(0.2 * (k % 5))                        # a seeded moment of the drive
            victim = manager_pid()
            os.kill(victim, signal.SIGKILL)
            killed = time.time()
            zero = wait_for(lambda: next((s.header.stamp.to_sec() for s in states[-30:]
                                          if s.header.stamp.to_sec() > killed and s.commanded_linear == 0.0
                                          and s.commanded_angular == 0.0), None), HANG, 'zero commanded')
            rest = wait_for(lambda: next((s.header.stamp.to_sec() for s in states[-30:]
                                          if s.header.stamp.to_sec() > killed and s.linear == 0.0
                                          and s.angular == 0.0), None), HANG, 'at rest')
            after = wait_for(lambda: manager_pid() not in (None, victim)
                             and recovered_registry('temoto_robot_manager'), HANG, 'the registry recovered')
            out['recovered'].append(time.time() - killed)
            out['zero'].append(zero - killed)
            out['at_rest'].append(rest - killed)
            out['unequal'] += after != before
            out['parts_lost'] += navigator not in json.dumps(after)
            wait_for(lambda: client.get_state() not in (GoalStatus.PENDING, GoalStatus.ACTIVE), HANG, 'the goal')
            send(attempt + 1)
            out['taken_again'].append(time.time() - killed)
            k += 1
        client.cancel_all_goals()
        rm.release(robot.resource_id)
    finally:
        if rm is not None:
            rm.shutdown()
        stop_hogs(hog_procs)
        launcher.stop_all()
        master.stop()
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--pairs', type=int, default=100, help='planner start/goal pairs')
    p.add_argument('--drives', type=int, default=100, help='seeded kinematic drives; a tenth of them across processes')
    p.add_argument('--trials', type=int, default=20, help='trials of each stop case across processes')
    p.add_argument('--hogs', type=int, default=0)
    p.add_argument('--only', choices=('planners', 'drives', 'stops', 'manager', 'teleop'))
    args = p.parse_args()
    results = {'hogs': args.hogs}
    rows = []
    ms = lambda v: '%.1f ms' % (v * 1e3)  # noqa: E731
    if args.only in (None, 'planners'):
        print('bench_navigation: planners x %d ...' % args.pairs, file=sys.stderr, flush=True)
        r = results['planners'] = bench_planners(args.pairs)
        rows.append(('A* (pyastar2d) on 20 x 20 m at 5 cm, with the costmap, p50 / p95 (n=%d)' % len(r['astar']),
                     '%s / %s' % (ms(pct(r['astar'], 50)), ms(pct(r['astar'], 95))), '≤ 50 ms p95'))
        if r['have_ompl']:
            rows.append(('OMPL RRT-Connect, simplified, same pairs, p50 / p95 (n=%d; %d not found in 1 s)'
                         % (len(r['ompl']), r['ompl_failed']),
                         '%s / %s' % (ms(pct(r['ompl'], 50)), ms(pct(r['ompl'], 95))), 'for comparison'))
            rows.append(('… its path against A*\'s, length ratio p50 / max', '%.2f / %.2f' % (
                pct(r['ratio'], 50), max(r['ratio'])), 'A* is cheapest by its costs'))
        else:
            rows.append(('OMPL RRT-Connect', 'not installed here', 'BENCHMARKS.md has a run with it'))
    if args.only in (None, 'drives'):
        print('bench_navigation: seeded drives x %d ...' % args.drives, file=sys.stderr, flush=True)
        d = results['drives'] = bench_drives(args.drives)
        tried = d['arrived'] + len(d['failed'])
        rows.append(('seeded goals in the lab, kinematic base: arrived / driven (refused at once: %d)'
                     % sum(d['refused'].values()), '%d / %d' % (d['arrived'], tried), '≥ 95 %'))
        if d['errors']:
            rows.append(('… arrival error, max (position / heading)', '%.3f m / %.1f°' % (
                max(e for e, _ in d['errors']), math.degrees(max(a for _, a in d['errors']))), '≤ 0.10 m / 5°'))
        rows.append(('… poses with the outline touching the map', str(d['touches']), '0'))
    if args.only in (None, 'stops'):
        s = results['stops'] = bench_stops(args.trials, max(1, args.drives // 10), args.hogs)
        rows.append(('obstacle source stale (SICK 25 Hz stalled) → commanded zero, from its last scan, p50 / p99'
                     ' (n=%d)' % len(s['stale']), '%s / %s (max %s)' % (ms(pct(s['stale'], 50)),
                                                                      ms(pct(s['stale'], 99)), ms(max(s['stale']))),
                     '≤ 3 × 40 + 20 = 140 ms'))
        rows.append(('a bad goal → REJECTED at the client, p50 / p99 (n=%d; moved: %d)' % (
            len(s['refusal']), s['refusal_moved']), '%s / %s' % (ms(pct(s['refusal'], 50)),
                                                                ms(pct(s['refusal'], 99))), '≤ 20 ms, nothing moves'))
        rows.append(('the goal\'s client SIGKILLed while driving → commanded zero, p50 / max (n=%d)'
                     % len(s['client_killed']), '%s / %s' % (ms(pct(s['client_killed'], 50)),
                                                            ms(max(s['client_killed']))),
                     '≤ 300 ms (as a dead commander: the cmd_vel timeout + 50 ms)'))
        dv = s['drives']
        ok = [x for x in dv if x['state'] == 3 and x['error_m'] <= 0.10 and x['error_deg'] <= 5.0]
        rows.append(('drives to the places across processes (%d with the SICK stalled on the way): reached /'
                     ' driven; contacts' % sum(x['stalled'] for x in dv),
                     '%d / %d; %d' % (len(ok), len(dv), sum(x['contacts'] for x in dv)), '≥ 95 %; 0'))
    if args.only in (None, 'teleop'):
        t = results['teleop'] = bench_teleop(args.trials, args.hogs)
        rows.append(('a teleop stream (`teleop/cmd_vel`) falls silent → commanded zero, from its last command, '
                     'p50 / p99 (n=%d)' % len(t['silence']), '%s / %s (max %s)' % (
                         ms(pct(t['silence'], 50)), ms(pct(t['silence'], 99)), ms(max(t['silence']))),
                     '≤ the stream\'s 0.1 s + 20 ms = 120 ms (MoveIt Servo: 0.1 s; twist_mux: 0.5 s)'))
        rows.append(('… the same stream straight to `cmd_vel` (the controller\'s timeout), p50 / p99 (n=%d)'
                     % len(t['silence_cmd_vel']), '%s / %s' % (ms(pct(t['silence_cmd_vel'], 50)),
                                                              ms(pct(t['silence_cmd_vel'], 99))), 'for comparison'))
        rows.append(('… ratio of the medians (controller / navigator)', '%.1f x' % (
            pct(t['silence_cmd_vel'], 50) / pct(t['silence'], 50)), '-'))
        rows.append(('the SICK stalled under a teleop stream → commanded zero, from its last scan, p50 / max (n=%d)'
                     % len(t['stale']), '%s / %s' % (ms(pct(t['stale'], 50)), ms(max(t['stale']))),
                     '≤ 3 × 40 + 20 = 140 ms'))
    if args.only in (None, 'manager'):
        m = results['manager'] = bench_manager(args.trials, args.hogs)
        rows.append(('the Robot Manager SIGKILLed while driving → commanded zero, p50 / p99 (n=%d); at rest, p99'
                     % len(m['zero']), '%s / %s (max %s); %s' % (ms(pct(m['zero'], 50)), ms(pct(m['zero'], 99)),
                                                                 ms(max(m['zero'])), ms(pct(m['at_rest'], 99))),
                     '≤ the cmd_vel timeout + 50 ms = 300 ms'))
        rows.append(('… its registry recovered, equal to before, p50 / p95 (unequal: %d; parts lost: %d)'
                     % (m['unequal'], m['parts_lost']), '%s / %s' % (ms(pct(m['recovered'], 50)),
                                                                     ms(pct(m['recovered'], 95))), '≤ 1 s p95'))
        rows.append(('… next drives that could not start where a kill had stopped the robot', '%d: %s' % (
            len(m['not_driven']), '; '.join(sorted(set(m['not_driven'])))[:200]), 'reported'))
        rows.append(('… the navigator takes goals again (refused as \'away\' before), p50 / p95',
                     '%s / %s' % (ms(pct(m['taken_again'], 50)), ms(pct(m['taken_again'], 95))), '-'))
    print_table('Navigation (%d CPU hogs)' % args.hogs, rows)
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'navigation%s.json' % ('_' + args.only if args.only else '')),
              'w') as f:
        json.dump(results, f, indent=1, default=str)
    return 0


if __name__ == '__main__':
    sys.exit(main())
