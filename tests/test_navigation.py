"""The navigator: its rules alone (costmap, planner, follower, collision monitor, freshness, goal checks), then the
node as a process between the sim's base and the SICK, judged by the sim's ground truth
(``/vaultbot_sim/base_state``, ``~contacts``), never by the navigator's word."""
import io
import math
import os
import signal
import time

import numpy as np
import pytest
import rospy
from actionlib_msgs.msg import GoalStatus, GoalStatusArray
from geometry_msgs.msg import PoseStamped, TwistStamped
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
from sensor_msgs.msg import LaserScan, PointCloud2
from std_msgs.msg import String

from temoto_robot_manager.navigation import global_planner
from temoto_robot_manager.navigation.collision_monitor import CollisionMonitor, MonitorSettings, Zone
from temoto_robot_manager.command_gate import CommandGate, Refused as GateRefused, State as GateState
from temoto_robot_manager.navigation.costmap import Costmap, Footprint, distance_field
from temoto_robot_manager.description import load_file
from temoto_core.serialized import header_stamp
from temoto_robot_manager.navigation.freshness import Freshness
from temoto_robot_manager.guards import SourceFresh, StopCode, StopReason
from temoto_robot_manager.navigation.navigator import BadGoal, Navigator, Outcome, State
from temoto_robot_manager.paths import DEFAULT_DESCRIPTION
from temoto_robot_manager.navigation.scene_markers import base_scene, stop_pose
from temoto_robot_manager.navigation.teleop_drive import Refused, TeleopDrive, base_inputs
from temoto_testing import wait_for, wait_receiving
from temoto_testing.motion import GOAL_CLIENT, aborted_goal, commanded_zero_after
from temoto_testing.sensor_manager import set_cable
from vaultbot_sim.base import advance
from vaultbot_sim.kinematics import WORLDS, TreeModel
from vaultbot_sim.msg import BaseState, Contact as ContactMsg
from vaultbot_sim.world_map import world_map
from temoto_core.action_client import TrackingActionClient

HANG = 60.0
VAULTBOT = next(r for r in load_file(DEFAULT_DESCRIPTION)[0] if r.name == 'vaultbot')
HUSKY = Footprint.of(VAULTBOT.navigation.footprint, VAULTBOT.navigation.protrusions)   # arms held, the gripper
PLACES = VAULTBOT.navigation.places


@pytest.fixture(scope='module')
def lab():
    grid = world_map(TreeModel(WORLDS['lab']))
    return grid


def lab_costmap(lab):
    return Costmap(lab.origin, lab.resolution, lab.cells > 0, HUSKY)


def quat(yaw):
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


# ----------------------------------------------------------------------------------------------- the rules
def test_the_lab_map_has_the_tables_shelves_and_walls_and_every_place_is_a_valid_goal(lab):
    cm = lab_costmap(lab)
    assert cm.lethal(2.2, 2.2) and cm.lethal(1.0, 3.5), 'a table and the wall are obstacles'
    nav = Navigator(HUSKY, Freshness())
    nav.set_map(cm)
    for name, (x, y, yaw) in PLACES.items():
        assert nav.check(x, y, quat(yaw)) == pytest.approx((x, y, yaw)), 'the place %s is a valid goal' % name
        assert nav.gap_at((x, y, yaw)) >= 0.1, 'the place %s leaves the outline 0.1 m clear' % name


def test_the_distance_field_counts_cells_to_the_nearest_obstacle():
    occupied = np.zeros((9, 9), dtype=bool)
    occupied[4, 4] = True
    d = distance_field(occupied, 3.0)
    assert d[4, 4] == 0 and d[4, 7] == 3 and d[1, 1] == np.inf and d[3, 3] == pytest.approx(math.sqrt(2))


def test_the_planner_goes_round_an_obstacle_and_says_when_there_is_no_way(lab):
    cm = lab_costmap(lab)
    x, y, yaw = PLACES['drums']
    there = (x - 0.8 * math.cos(yaw), y - 0.8 * math.sin(yaw))       # where the robot turns toward the drums
    path = global_planner.plan(cm, (0.0, 0.0), there)
    assert tuple(path[0]) == (0.0, 0.0) and tuple(path[-1]) == there
    assert all(not cm.lethal(x, y) for x, y in path), 'the path keeps the robot out of every obstacle'
    ring = np.array([[there[0] + 1.3 * math.cos(a), there[1] + 1.3 * math.sin(a)] for a in np.arange(0, 6.3, 0.02)])
    cm.mark(ring)                                      # someone fenced the place in
    with pytest.raises(global_planner.NoPath, match='obstacles close every path'):
        global_planner.plan(cm, (0.0, 0.0), there)
    cm.mark(np.zeros((0, 2)))
    assert len(global_planner.plan(cm, (0.0, 0.0), there)), 'the next frame clears the fence'


def test_a_protrusion_is_part_of_the_outline_without_widening_it_all_round():
    body = Footprint(-0.5, 0.64, -0.69, 0.67)
    with_gripper = Footprint.of([-0.5, 0.64, -0.69, 0.67], [[0.55, 0.76, 0.25, 0.38]])
    ahead, beside = np.array([[0.72, 0.3]]), np.array([[0.72, -0.3]])
    assert with_gripper.contains(ahead).all() and not body.contains(ahead).any()
    assert not with_gripper.contains(beside).any()               # only where the gripper is
    assert with_gripper.distance(np.array([[0.86, 0.3]]))[0] == pytest.approx(0.10)
    assert with_gripper.distance(beside)[0] == pytest.approx(0.08)
    assert with_gripper.circumscribed == pytest.approx(body.circumscribed)   # the body's corner is further
    assert with_gripper.inscribed == body.inscribed


def test_the_collision_monitor_looks_where_the_robot_goes():
    monitor = CollisionMonitor(Footprint.centred(0.99, 0.67))
    ahead = np.array([[0.7, 0.0]])
    assert monitor.check(ahead, 0.5, 0.0).zone is Zone.STOP
    assert monitor.check(ahead, 0.5, 0.0).linear == 0.0
    beside = np.array([[0.0, 0.6]])          # a wall passed alongside, 0.27 m from the side
    assert monitor.check(beside, 0.8, 0.0).zone is Zone.CLEAR
    far = np.array([[1.6, 0.0]])
    slow = monitor.check(far, 0.8, 0.0)
    assert slow.zone is Zone.SLOW and slow.linear == pytest.approx(0.24)
    corner = np.array([[0.49, 0.411]])       # just off the front left corner: a left turn sweeps the corner into it
    assert monitor.check(corner, 0.0, 0.0).zone is Zone.CLEAR
    assert monitor.check(corner, 0.0, 1.0).zone is Zone.STOP
    assert monitor.check(corner, 0.0, -1.0).zone is not Zone.STOP, 'a right turn swings the corner away'


def test_freshness_learns_the_period_and_goes_stale_after_three_of_them():
    f = Freshness(declared=0.04)
    assert not f.fresh(0.0), 'nothing heard: not fresh'
    for k in range(4):
        f.heard(9.84 + 0.04 * k)
    assert not f.fresh(9.97), 'four frames: not proven yet'
    f.heard(10.0)
    assert f.fresh(10.1) and not f.fresh(10.121)
    for k in range(1, 11):
        f.heard(10.0 + 0.5 * k)              # a slow source: 2 Hz
    assert f.period == pytest.approx(0.5)
    assert f.fresh(15.0 + 1.4) and not f.fresh(15.0 + 1.5)


def test_a_slow_consumer_learns_the_sources_period_from_arrivals_not_from_the_frames_it_used():
    """Chaos, seed 17, step 2301: a navigator that made obstacles from one D435 frame in four learnt a period four
    times the camera's, and drove 2.2 s on after the camera stalled. The period comes from every arrival; the
    deadline from the last frame used."""
    f = Freshness()
    for k in range(40):
        t = 0.1 * k                               # the source: 10 Hz
        f.arrived(t)
        if k % 4 == 0:
            f.heard(t)                            # the consumer: one frame in four
    assert f.period == pytest.approx(0.1)
    last_used = 3.6
    assert f.fresh(last_used + 0.29) and not f.fresh(last_used + 0.31), 'stale 3 source periods after the last used'


def test_a_starved_consumer_learns_the_sources_pace_from_its_stamps_and_a_bad_stamp_from_its_arrivals():
    """Chaos, seed 17, step 2299: a navigator on a loaded robot host received some D435 frames late, and the
    interval before each was longer than the camera's: it learnt 0.42 s where the camera sent every 0.34 s, and
    trusted the stalled camera 0.24 s longer than the contract. The frames' stamps say the camera's pace; a
    driver's wrong stamps are bounded by the arrivals."""
    late = Freshness()
    t = 0.0
    for k in range(20):
        t += 0.34
        late.arrived(t + (0.16 if k % 4 == 1 else 0.0), stamp=100.0 + t)   # every fourth frame 160 ms late
    assert late.period == pytest.approx(0.34)
    arrivals_only = Freshness()
    t = 0.0
    for k in range(20):
        t += 0.34
        arrivals_only.arrived(t + (0.16 if k % 4 == 1 else 0.0))
    assert arrivals_only.period == pytest.approx(0.50), 'without stamps, the late frames set the pace'
    wrong = Freshness()
    for k in range(20):
        wrong.arrived(0.1 * k, stamp=100.0 + 10.0 * k)      # stamps 10 s apart, frames every 100 ms
    assert wrong.period == pytest.approx(0.1)


def test_a_header_stamp_is_read_from_the_serialised_frame_alone():
    cloud = PointCloud2()
    cloud.header.stamp = rospy.Time(1795892647, 850000000)
    cloud.header.frame_id = 'd435_depth_optical_frame'
    buff = io.BytesIO()
    cloud.serialize(buff)
    assert header_stamp(buff.getvalue()) == pytest.approx(1795892647.85)
    assert header_stamp(b'') is None and header_stamp(bytes(12)) is None, 'no stamp: arrivals alone'


def test_a_scanner_that_starts_slowly_is_held_to_its_declared_period_once_it_runs_at_it():
    """A SICK restarted after a fault sends its first frames slowly while it warms up. Judged by the median of its
    whole window, it kept a 0.58 s period for a second, and a stall then stopped the robot after 1.7 s."""
    f = Freshness(declared=0.04)
    t = 0.0
    for _ in range(12):                          # warming up: 2 Hz
        t += 0.5
        f.heard(t)
    for _ in range(8):                           # then at its 25 Hz
        t += 0.04
        f.heard(t)
    assert f.period == pytest.approx(0.04)
    assert f.fresh(t + 0.119) and not f.fresh(t + 0.121)


def test_a_source_that_jitters_is_judged_by_its_slow_frames_not_its_median():
    f = Freshness()
    t = 0.0
    for k in range(20):
        t += 0.06 if k % 3 else 0.12          # a rendered camera: most frames at 60 ms, every third at 120 ms
        f.heard(t)
    assert f.period == pytest.approx(0.12)
    assert f.fresh(t + 0.35), 'three slow periods have not passed: no false stop'
    assert not f.fresh(t + 0.37), 'silent for three of its slow periods: stale'


def test_a_source_heard_for_a_few_frames_is_never_trusted_longer_than_a_full_window_would_allow():
    """Seed 17, step 2188 (chaos, two hosts): a navigator just restarted took the D435 as its source and had
    9 intervals of it, two of them a stall's; the percentile of so few was the stall's second longest (0.51 s)
    where the full window of 20 gave 0.30 s, and the base drove on a stale camera for 1.5 s. The third longest
    of what is known is never longer than the third longest of the full window."""
    few = [0.30] * 7 + [0.51, 1.75]
    f = Freshness()
    t = 0.0
    for interval in few:
        t += interval
        f.arrived(t)
        f.heard(t)
    assert f.period == pytest.approx(0.30)
    full = sorted(few + [0.30] * 11)                   # the 20 the source sent: any 11 more, its usual period
    assert f.period <= full[int(0.9 * 19)] + 1e-9
    assert not f.fresh(t + 3 * 0.30 + 0.01), 'stale after 3 of the period the full window allows'


def drive(nav, pose, now, limit=4000):
    """The navigator closing the loop on a kinematic base; (final pose, ending, ticks). Every pose on the way
    keeps the robot's whole outline off the map's obstacles."""
    for k in range(limit):
        nav.set_pose(pose)
        nav.set_obstacles(np.zeros((0, 2)), now)
        tick = nav.tick(now)
        if tick.ending is not None:
            return pose, tick.ending, k
        pose = advance(pose, tick.linear, tick.angular, 0.05)
        assert nav.gap_at(pose) > 0.0, 'the outline touched an obstacle at %s' % (pose,)
        now += 0.05
    raise AssertionError('no ending in %d ticks' % limit)


def proven(nav, until=0.0):
    """Five frames of an obstacle source, the last at ``until``: the source is fresh."""
    for k in range(5):
        nav.set_obstacles(np.zeros((0, 2)), until - 0.04 * (4 - k))


@pytest.mark.parametrize('origin, place', [(a, b) for a in sorted(PLACES) for b in sorted(PLACES) if a != b])
def test_the_navigator_drives_from_each_place_to_every_other_on_a_kinematic_base(lab, origin, place):
    nav = Navigator(HUSKY, Freshness(declared=0.04))
    nav.set_map(lab_costmap(lab))
    start = PLACES[origin]
    nav.set_pose(start)
    x, y, yaw = PLACES[place]
    goal = nav.check(x, y, quat(yaw))
    proven(nav)
    nav.start(goal, 0.0)
    pose, ending, _ = drive(nav, start, 0.0)
    assert ending.outcome is Outcome.SUCCEEDED, ending.text
    assert math.hypot(pose[0] - x, pose[1] - y) <= 0.10
    assert abs(math.atan2(math.sin(pose[2] - yaw), math.cos(pose[2] - yaw))) <= math.radians(5)


def test_seeded_goals_anywhere_in_the_lab_end_arrived_or_refused_and_never_touch(lab):
    rng = np.random.default_rng(40)
    cm = lab_costmap(lab)
    nav = Navigator(HUSKY, Freshness(declared=0.04))
    nav.set_map(cm)
    pose, arrived, refused = (0.0, 0.0, 0.0), 0, 0
    x0, y0, x1, y1 = cm.bounds
    for _ in range(25):
        x, y, yaw = rng.uniform(x0, x1), rng.uniform(y0, y1), rng.uniform(-math.pi, math.pi)
        nav.set_pose(pose)
        proven(nav)
        try:
            nav.start(nav.check(x, y, quat(yaw)), 0.0)
        except (BadGoal, global_planner.NoPath):
            refused += 1
            continue
        pose, ending, _ = drive(nav, pose, 0.0)
        assert ending.outcome is Outcome.SUCCEEDED, '(%.2f, %.2f, %.2f): %s' % (x, y, yaw, ending.text)
        arrived += 1
    assert arrived >= 5 and refused >= 5, 'the seed gives both kinds: %d arrived, %d refused' % (arrived, refused)


def test_a_drive_cut_short_anywhere_then_sent_elsewhere_still_arrives(lab):
    """A goal cancelled (or its holder gone) mid-way leaves the robot anywhere, even half backed out of a
    place with no room to turn; the next goal must still get it out and there."""
    rng = np.random.default_rng(7)
    names, driven = sorted(PLACES), 0
    for _ in range(40):
        a, b, c = rng.choice(names, 3)
        if a == b:
            continue
        nav = Navigator(HUSKY, Freshness(declared=0.04))
        nav.set_map(lab_costmap(lab))
        pose, now = PLACES[a], 0.0
        nav.set_pose(pose)
        proven(nav)
        nav.start(nav.check(*PLACES[b][:2], quat(PLACES[b][2])), 0.0)
        for _ in range(int(rng.integers(10, 400))):
            nav.set_pose(pose)
            nav.set_obstacles(np.zeros((0, 2)), now)
            tick = nav.tick(now)
            if tick.ending is not None:
                break
            pose, now = advance(pose, tick.linear, tick.angular, 0.05), now + 0.05
        nav.cancel()
        if c == b and tick.ending is not None:
            continue
        nav.set_pose(pose)
        proven(nav, now)
        nav.start(nav.check(*PLACES[c][:2], quat(PLACES[c][2])), now)
        _, ending, _ = drive(nav, pose, now)
        assert ending.outcome is Outcome.SUCCEEDED, '%s to %s cut at %s, then to %s: %s' % (a, b, pose, c, ending.text)
        driven += 1
    assert driven >= 25


@pytest.mark.parametrize('x, y, q, field, words', [
    (float('nan'), 0.0, quat(0), 'position.x', 'finite'),
    (1.0, float('inf'), quat(0), 'position.y', 'finite'),
    (1.0, 0.0, (0.0, 0.0, 0.0, 0.0), 'orientation', 'unit quaternion'),
    (1.0, 0.0, (0.7071, 0.0, 0.0, 0.7071), 'orientation', 'about z only'),
    (40.0, 0.0, quat(0), 'position', 'outside the map'),
    (2.2, 2.2, quat(0), 'position', 'inside an obstacle'),
    (2.2, 0.95, quat(math.pi / 2), 'position', 'would be 0.00 m from an obstacle'),
])
def test_a_bad_goal_is_refused_naming_its_field_and_nothing_starts(lab, x, y, q, field, words):
    nav = Navigator(HUSKY, Freshness(declared=0.04))
    nav.set_map(lab_costmap(lab))
    nav.set_pose((0.0, 0.0, 0.0))
    with pytest.raises(BadGoal, match=words) as err:
        nav.check(x, y, q)
    assert err.value.field.endswith(field)
    assert nav.state is State.IDLE and nav.goal is None


def test_a_stale_source_zeroes_the_command_and_a_fresh_one_resumes(lab):
    nav = Navigator(HUSKY, Freshness(declared=0.04))
    nav.set_map(lab_costmap(lab))
    nav.set_pose((0.0, 0.0, 0.0))
    proven(nav)
    nav.start(nav.check(*PLACES['drums'][:2], quat(PLACES['drums'][2])), 0.0)
    assert nav.tick(0.05).linear > 0
    assert nav.must_stop(0.121) and not nav.must_stop(0.119), 'stale after 3 periods of 40 ms'
    stale = nav.tick(0.13)
    assert (stale.linear, stale.angular, stale.state) == (0.0, 0.0, State.WAITING)
    nav.freshness.reset()                       # the Robot Manager fails over: a new source
    for k in range(4):
        nav.set_obstacles(np.zeros((0, 2)), 0.2 + 0.04 * k)
        assert nav.tick(0.2 + 0.04 * k).state is State.WAITING, 'a new source proves itself first'
    nav.set_obstacles(np.zeros((0, 2)), 0.36)
    assert nav.tick(0.36).state is State.DRIVING


def teleop_at_home(lab, walls=True):
    nav = Navigator(HUSKY, Freshness(declared=0.04))
    if walls:
        nav.set_map(lab_costmap(lab))
    nav.set_pose((0.0, 0.0, 0.0))
    proven(nav)
    return nav, TeleopDrive(nav)


def test_a_teleop_command_is_clamped_and_one_stamped_before_a_stop_is_refused(lab):
    nav, drive = teleop_at_home(lab, walls=False)         # nothing near to slow it: the clamp alone
    d = drive.command(100.0, 100.01, 5.0, -9.0)
    assert (d.linear, d.angular) == (nav.follower.limits.max_speed, -nav.follower.limits.max_turn)
    drive.halt(100.1)
    with pytest.raises(Refused, match='before the operator'):
        drive.command(100.09, 100.11, 0.2, 0.0)
    assert drive.command(100.12, 100.13, 0.2, 0.0).linear == pytest.approx(0.2)


@pytest.mark.parametrize('stamp, linear, words', [
    (99.5, 0.2, 'late: more than 100 ms'),
    (100.2, 0.2, 'in the future'),
    (100.0, math.nan, 'must be finite'),
    (math.inf, 0.2, 'must be finite'),
])
def test_a_bad_teleop_command_is_refused_naming_why(lab, stamp, linear, words):
    nav, drive = teleop_at_home(lab)
    with pytest.raises(Refused, match=words):
        drive.command(stamp, 100.0, linear, 0.0)


def base_gate(nav):
    """The navigator node's gate for ``nav``, sending into a list."""
    sent = []
    gate = CommandGate('base', base_inputs(), [SourceFresh(nav.freshness, lambda: 'sick/scan')] + nav.guards,
                       sent.append, (0.0, 0.0))
    return gate, sent


def test_a_teleop_stream_is_refused_while_a_goal_drives_and_zero_while_the_source_is_stale(lab):
    nav, drive = teleop_at_home(lab)
    gate, sent = base_gate(nav)
    gate.offer('goal', (0.0, 0.0), 0.0, moving=False)
    with pytest.raises(GateRefused, match='held by goal'):
        gate.offer('teleop', (0.2, 0.0), 0.0)
    gate.release('goal', StopReason(StopCode.ENDED, 'canceled'))
    d = drive.command(100.0, 100.0, 0.2, 0.0)
    assert gate.offer('teleop', (d.linear, d.angular), 0.0).state is GateState.MOVING and sent[-1] == (0.2, 0.0)
    d = drive.command(100.2, 100.2, 0.2, 0.0)
    stale = gate.offer('teleop', (d.linear, d.angular), 0.2)
    assert sent[-1] == (0.0, 0.0) and stale.reason is StopCode.OBSTACLES_STALE and 'does not drive blind' in stale.text


def test_a_teleop_command_into_an_obstacle_is_zeroed_by_the_collision_monitor(lab):
    nav, drive = teleop_at_home(lab)
    nav.set_obstacles(np.array([[0.75, 0.0]]), 0.0)          # just ahead of the bumper
    ahead = drive.command(100.0, 100.0, 0.8, 0.0)
    assert (ahead.linear, ahead.angular) == (0.0, 0.0) and 'stop zone' in ahead.held.text
    back = drive.command(100.01, 100.01, -0.3, 0.0)
    assert back.linear == pytest.approx(-0.3) or 'slowed' in back.why, back


def test_the_scene_draws_the_stop_zone_where_the_robot_would_stop_on_its_command():
    settings = MonitorSettings()
    assert stop_pose(0.0, 0.0, settings) == (0.0, 0.0, 0.0)
    reach, y, yaw = stop_pose(0.8, 0.0, settings)
    braking = 0.8 / settings.decel
    assert reach == pytest.approx(0.8 * (settings.latency + braking / 2)) and y == 0.0 and yaw == 0.0
    x, y, yaw = stop_pose(0.0, 1.2, settings)
    assert x == pytest.approx(0.0) and yaw > 0.0, 'turning in place: the zone turns, it does not move'
    scene = base_scene(HUSKY, 'base_link', 0.8, 0.0, 0)
    footprint, zone = scene.markers
    assert len(footprint.points) == 8 * len(HUSKY.boxes), 'four sides of each box, as point pairs'
    assert len(zone.points) == 2 * len(footprint.points), 'the grown outline here, and where it would stop'
    ahead = max(p.x for p in zone.points)
    assert ahead == pytest.approx(max(b[1] for b in HUSKY.boxes) + settings.stop_margin + reach)


# ----------------------------------------------------------------------------------------- across processes
SIM_PARAMS = {'world': 'lab', 'sweep': False, 'hand_motion': False}


def bring_up(procs, rospy_client, collect, sim_params):
    truth = collect('/vaultbot_sim/base_state', BaseState)
    contacts = collect('/vaultbot_sim/contacts', ContactMsg)
    procs.node('vaultbot_sim', 'vaultbot_sim', params=sim_params)
    base = procs.node('vaultbot_sim', 'base_controller')
    sick = procs.node('vaultbot_sim', 'sick_driver')
    navigator = procs.node('temoto_robot_manager', 'navigator',
                           params={'description': DEFAULT_DESCRIPTION, 'robot': 'vaultbot',
                                   'obstacle_topic': 'sick/scan'})
    client = TrackingActionClient('/move_base', MoveBaseAction)
    assert client.wait_for_server(rospy_client.Duration(HANG)), 'the navigator\'s move_base action'
    wait_receiving([truth.sub, contacts.sub], HANG, 'the sim\'s ground truth')
    return dict(truth=truth, contacts=contacts, client=client, navigator=navigator, sick=sick, base=base)


@pytest.fixture
def navigation(procs, rospy_client, collect):
    """The sim in the lab, the base controller, the SICK, the navigator, and the ground truth."""
    yield bring_up(procs, rospy_client, collect, SIM_PARAMS)


@pytest.fixture
def navigation_on_bare_motors(procs, rospy_client, collect):
    """As ``navigation``, with motors that keep their last command for ever (no command timeout): every stop is
    the stack's own."""
    yield bring_up(procs, rospy_client, collect, dict(SIM_PARAMS, motor_timeout=0.0))


def target(rospy, x, y, yaw, frame='world'):
    pose = PoseStamped()
    pose.header.frame_id, pose.header.stamp = frame, rospy.Time.now()
    pose.pose.position.x, pose.pose.position.y = x, y
    pose.pose.orientation.z, pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return pose


def send(client, pose):
    client.send_goal(MoveBaseGoal(target_pose=pose))


def finished(client, bound=HANG):
    wait_for(lambda: client.get_state() not in (GoalStatus.PENDING, GoalStatus.ACTIVE), bound,
             'the goal to end')
    return client.get_state(), client.get_goal_status_text()


def test_a_goal_through_move_base_drives_the_base_there_without_a_contact(navigation, rospy_client):
    truth, client = navigation['truth'], navigation['client']
    x, y, yaw = PLACES['table']
    wait_for(lambda: truth.last() is not None, HANG, 'the base state')
    send(client, target(rospy_client, x, y, yaw))
    state, text = finished(client, 120.0)
    assert state == GoalStatus.SUCCEEDED, text
    wait_for(lambda: truth.last().linear == 0.0 and truth.last().angular == 0.0, HANG, 'the base at rest')
    end = truth.last()
    assert math.hypot(end.x - x, end.y - y) <= 0.10, 'the sim has the base at (%.3f, %.3f)' % (end.x, end.y)
    assert abs(math.atan2(math.sin(end.yaw - yaw), math.cos(end.yaw - yaw))) <= math.radians(5)
    assert end.contacts == 0 and not navigation['contacts'].msgs


@pytest.mark.parametrize('pose_args, words', [
    ((1.0, 0.0, 0.0, 'nowhere'), 'target_pose.header.frame_id: unknown frame'),
    ((float('nan'), 0.0, 0.0, 'world'), 'target_pose.pose.position.x: must be a finite number'),
    ((40.0, 0.0, 0.0, 'world'), 'outside the map'),
    ((2.2, 2.2, 0.0, 'world'), 'inside an obstacle'),
])
def test_a_bad_goal_is_rejected_at_once_naming_the_field_and_the_base_never_moves(navigation, rospy_client,
                                                                                   pose_args, words):
    truth, client = navigation['truth'], navigation['client']
    sent = time.monotonic()
    send(client, target(rospy_client, *pose_args))
    state, text = finished(client)
    assert state == GoalStatus.REJECTED and words in text, text
    assert time.monotonic() - sent < 10.0
    assert all(s.commanded_linear == 0.0 and s.commanded_angular == 0.0 for s in truth.msgs)


def test_the_base_stops_when_the_obstacle_source_goes_stale_and_drives_on_when_one_is_back(navigation, procs,
                                                                                          rospy_client, collect):
    truth, client = navigation['truth'], navigation['client']
    scans = collect('/sick/scan', LaserScan)
    x, y, yaw = PLACES['shelf']
    send(client, target(rospy_client, x, y, yaw))
    wait_for(lambda: truth.last() is not None and truth.last().commanded_linear > 0.2, HANG, 'the base driving')
    set_cable('sick', 'unplugged', 'stall')            # the driver lives on and says nothing: only silence tells
    zero = wait_for(lambda: next((s for s in truth.msgs[-5:] if s.commanded_linear == 0.0
                                  and s.commanded_angular == 0.0), None), HANG, 'the base commanded to zero')
    last_scan = scans.msgs[-1].header.stamp.to_sec()
    assert zero.header.stamp.to_sec() - last_scan < 1.0, 'zero %.3f s after the last scan: 3 periods are 0.12 s' % (
        zero.header.stamp.to_sec() - last_scan)
    wait_for(lambda: truth.last().linear == 0.0 and truth.last().angular == 0.0, HANG, 'the base at rest')
    assert client.get_state() == GoalStatus.ACTIVE, 'the goal waits for a fresh source; it is not over'
    rest = truth.last()
    navigation['sick'].stop()
    set_cable('sick', 'plugged')
    procs.node('vaultbot_sim', 'sick_driver')
    state, text = finished(client, 120.0)
    assert state == GoalStatus.SUCCEEDED, text
    assert math.hypot(truth.last().x - rest.x, truth.last().y - rest.y) > 0.5, 'it drove on once a scan was back'
    assert truth.last().contacts == 0


def killed_mid_drive(holder, truth, statuses):
    """SIGKILL the goal's holder: the base is commanded zero (within a hang's bound), comes to rest without a
    contact, and the goal's end is returned (ABORTED, its text naming why)."""
    os.kill(holder.pid, signal.SIGKILL)
    killed = time.time()
    zero = commanded_zero_after(truth.msgs, killed, HANG)
    assert zero.header.stamp.to_sec() - killed < 5.0
    ended = aborted_goal(statuses.msgs, HANG)
    wait_for(lambda: truth.last().linear == 0.0, HANG, 'the base at rest')
    assert truth.last().contacts == 0
    return ended


def test_the_base_stops_when_the_goal_s_client_dies_mid_drive(navigation, procs, collect):
    truth = navigation['truth']
    statuses = collect('/move_base/status', GoalStatusArray)
    x, y, yaw = PLACES['drums']
    client = procs.command(GOAL_CLIENT + [str(x), str(y), str(yaw)], 'goal_client')
    wait_for(lambda: truth.last() is not None and truth.last().commanded_linear > 0.15, HANG, 'the base driving')
    ended = killed_mid_drive(client, truth, statuses)
    assert 'client /goal_client' in ended.text and 'is gone' in ended.text, ended.text


def test_the_base_stops_when_a_goal_s_sender_dies_before_it_watched_the_status(navigation, procs, collect):
    """Chaos, seed 17, step 3471: a client SIGKILLed 5 ms after sending a drive had not yet connected to the
    status, so the navigator never saw it go, and the base drove on for 3 s. A sender never seen among the
    status's subscribers is asked at its node's port: alive, it holds its goal; dead, the goal ends."""
    truth = navigation['truth']
    statuses = collect('/move_base/status', GoalStatusArray)
    x, y, yaw = PLACES['drums']
    sender = procs.command(GOAL_CLIENT + [str(x), str(y), str(yaw), '--raw'], 'goal_sender')
    wait_for(lambda: truth.last() is not None and truth.last().commanded_linear > 0.15, HANG, 'the base driving')
    since = truth.last().header.stamp.to_sec()
    # a live sender that does not watch the status still holds its goal
    wait_for(lambda: truth.last().header.stamp.to_sec() > since + 1.0, HANG, 'a second of the drive')
    assert truth.last().commanded_linear > 0.0 or truth.last().commanded_angular != 0.0, 'the goal was dropped'
    ended = killed_mid_drive(sender, truth, statuses)
    assert 'client /goal_client' in ended.text and 'died before its connection' in ended.text, ended.text


def stream(pub, rospy, linear, angular, until, rate=50.0, limit=2000, age=0.0):
    """Teleop commands at ``rate`` Hz until ``until()`` holds (at most ``limit`` of them), stamped ``age`` s ago."""
    sleeper = rospy.Rate(rate)
    for _ in range(limit):
        msg = TwistStamped()
        msg.header.stamp = rospy.Time.from_sec(rospy.get_time() - age)
        msg.twist.linear.x, msg.twist.angular.z = linear, angular
        pub.publish(msg)
        if until():
            return
        sleeper.sleep()
    raise AssertionError('the condition did not come within %d commands' % limit)


def test_a_teleop_stream_drives_the_base_and_its_silence_stops_it(navigation, rospy_client, collect):
    truth = navigation['truth']
    status = collect('/teleop/status', String)
    pub = rospy_client.Publisher('/teleop/cmd_vel', TwistStamped, queue_size=5, tcp_nodelay=True)
    wait_for(lambda: pub.get_num_connections() > 0, HANG, 'the navigator listening')
    # a late stream (a link that held it) is refused, and nothing moves
    stream(pub, rospy_client, 0.0, 0.5, lambda: status.last() is not None, age=0.5)
    assert status.last().data.startswith('refused: sent') and 'late' in status.last().data, status.last()
    assert all(s.commanded_angular == 0.0 for s in truth.msgs)
    # a live stream turns it in place
    yaw0 = truth.last().yaw
    stream(pub, rospy_client, 0.0, 0.5, lambda: abs(truth.last().yaw - yaw0) > 0.2)
    assert truth.last().commanded_angular > 0.0 and status.last().data == 'driving'
    last = rospy_client.get_time()
    zero = commanded_zero_after(truth.msgs, last, HANG)
    assert zero.header.stamp.to_sec() - last < 2.0, 'a hang, not a timing goal (bench_teleop measures it)'
    wait_for(lambda: status.last().data.startswith('stopped: no teleop command'), HANG, 'the stream said over')
    wait_for(lambda: truth.last().angular == 0.0, HANG, 'the base at rest')


def test_a_teleop_stream_does_not_drive_blind(navigation, rospy_client, collect):
    truth = navigation['truth']
    status = collect('/teleop/status', String)
    pub = rospy_client.Publisher('/teleop/cmd_vel', TwistStamped, queue_size=5, tcp_nodelay=True)
    wait_for(lambda: pub.get_num_connections() > 0, HANG, 'the navigator listening')
    stream(pub, rospy_client, 0.0, 0.5, lambda: truth.last().commanded_angular > 0.0)
    set_cable('sick', 'unplugged', 'stall')
    try:
        stream(pub, rospy_client, 0.0, 0.5, lambda: status.last().data.startswith('held: no fresh obstacle source'))
        stream(pub, rospy_client, 0.0, 0.5, lambda: truth.last().commanded_angular == 0.0)
        at = rospy_client.get_time()
        stream(pub, rospy_client, 0.0, 0.5, lambda: rospy_client.get_time() - at > 1.0)
        assert all(s.commanded_angular == 0.0 for s in truth.msgs if s.header.stamp.to_sec() > at), \
            'the stream went on; the base stayed at zero'
    finally:
        set_cable('sick', 'plugged')


def respawned_controller_drives_nowhere(procs, truth, rospy_client):
    """Start a base controller again (the respawn base.launch makes): it commands zero, and for the next two
    seconds of the sim's ground truth nothing is commanded to move."""
    procs.node('vaultbot_sim', 'base_controller')
    zero = commanded_zero_after(truth.msgs, rospy_client.get_time(), HANG)
    since = zero.header.stamp.to_sec()
    wait_for(lambda: truth.last().header.stamp.to_sec() > since + 2.0, HANG, 'two seconds after the respawn')
    moved = [s for s in truth.msgs if s.header.stamp.to_sec() > since
             and (s.commanded_linear != 0.0 or s.commanded_angular != 0.0)]
    assert not moved, 'the base was commanded to move after the respawn: %s' % moved[0]
    assert truth.last().linear == 0.0 and truth.last().angular == 0.0


def test_a_base_controller_killed_mid_drive_ends_the_goal_naming_it_and_its_respawn_drives_nowhere(
        navigation_on_bare_motors, procs, rospy_client, collect):
    """Issue 51, hole 4: a base controller SIGKILLed mid-drive and respawned drove on toward the old goal 2.6 s
    later, and nobody was told. Its death now ends the goal at once, naming it; the respawned controller finds no
    goal, and nothing moves. The motors keep their last command (no command timeout): between the death and the
    respawn only hardware could stop the wheels, so only the goal's end and what follows are asserted here."""
    from temoto_core.msg import MotionStatus
    nav = navigation_on_bare_motors
    truth, client = nav['truth'], nav['client']
    status = collect('/navigator/motion_status', MotionStatus)
    x, y, yaw = PLACES['drums']
    send(client, target(rospy_client, x, y, yaw))
    wait_for(lambda: truth.last() is not None and truth.last().commanded_linear > 0.15, HANG, 'the base driving')
    wait_for(lambda: status.last() is not None and status.last().state == MotionStatus.MOVING, HANG, 'said moving')
    os.kill(nav['base'].pid, signal.SIGKILL)
    state, text = finished(client)
    assert state == GoalStatus.ABORTED, text
    assert '/base_controller is gone' in text and 'the robot stopped' in text, text
    said = wait_for(lambda: status.last() if status.last().state == MotionStatus.STOPPED else None, HANG, 'stopped')
    assert (said.actuator, said.reason) == ('base', 'controller_gone') and said.text == text, said
    respawned_controller_drives_nowhere(procs, truth, rospy_client)


def test_odometry_that_stops_ends_the_goal_after_its_patience_naming_it(navigation_on_bare_motors, procs,
                                                                        rospy_client, collect):
    """The base controller stalled (its process up, silent): the navigator hears no odometry, commands zero at its
    deadline (3 periods), and ends the goal after the description's ``odom_patience``, naming the odometry. The
    stalled controller replaced, nothing moves."""
    nav = navigation_on_bare_motors
    truth, client = nav['truth'], nav['client']
    x, y, yaw = PLACES['drums']
    send(client, target(rospy_client, x, y, yaw))
    wait_for(lambda: truth.last() is not None and truth.last().commanded_linear > 0.15, HANG, 'the base driving')
    set_cable('base', 'unplugged', 'stall')
    state, text = finished(client)
    assert state == GoalStatus.ABORTED and 'no odometry for' in text and 'the goal ends after 0.5 s' in text, text
    nav['base'].stop()
    set_cable('base', 'plugged')
    respawned_controller_drives_nowhere(procs, truth, rospy_client)


def test_a_goal_sent_before_a_stop_that_arrives_after_it_is_rejected(navigation, rospy_client, collect):
    """Issue 51, hole 3: a drive goal stamped before the operator's stop, arriving after it (it was on its way), was
    accepted and drove. It is rejected naming the stamp, and nothing moves."""
    from move_base_msgs.msg import MoveBaseActionGoal
    truth = navigation['truth']
    statuses = collect('/move_base/status', GoalStatusArray)
    halt = rospy_client.Publisher('/temoto/halt', String, queue_size=5, tcp_nodelay=True)
    raw = rospy_client.Publisher('/move_base/goal', MoveBaseActionGoal, queue_size=5)
    wait_for(lambda: halt.get_num_connections() > 0 and raw.get_num_connections() > 0, HANG, 'the navigator')
    teleop = collect('/teleop/status', String)
    before = rospy_client.Time.now()
    halt.publish(String('test stop'))
    wait_for(lambda: teleop.last() is not None and teleop.last().data == 'halted: test stop', HANG,
             'the navigator to hear the stop')
    x, y, yaw = PLACES['drums']
    late = MoveBaseActionGoal()
    late.header.stamp = late.goal_id.stamp = before
    late.goal_id.id = 'late_drive'
    late.goal.target_pose = target(rospy_client, x, y, yaw)
    raw.publish(late)
    ended = wait_for(lambda: next((st for m in statuses.msgs[-3:] for st in m.status_list
                                   if st.goal_id.id == 'late_drive'), None), HANG, 'the late goal\'s status')
    assert ended.status == GoalStatus.REJECTED and 'goal_id.stamp: sent' in ended.text, ended.text
    assert all(s.commanded_linear == 0.0 and s.commanded_angular == 0.0 for s in truth.msgs)


def test_an_arm_swung_out_of_the_outline_holds_the_drive_and_its_return_lets_it_go_on(navigation_on_bare_motors,
                                                                                      rospy_client, collect):
    """Issue 51, hole 6: the footprint holds the arms at their stowed pose, and nothing stopped an arm being moved out
    past it while the base drove. The navigator now keeps every arm inside the outline (its URDF chain, from the
    joint states): an arm out holds the base at zero, a goal sent then is refused naming the arm, and the drive
    goes on once the arm is back. The arm is moved as its controller would, by setpoints to the sim's motors."""
    from sensor_msgs.msg import JointState
    from temoto_core.msg import MotionStatus
    nav = navigation_on_bare_motors
    truth, client = nav['truth'], nav['client']
    status = collect('/navigator/motion_status', MotionStatus)
    arm = VAULTBOT.manipulation['left_arm']
    joints = collect('/joint_states', JointState)
    motors = rospy_client.Publisher('/left_arm/joint_command', JointState, queue_size=5, tcp_nodelay=True)
    wait_for(lambda: motors.get_num_connections() > 0 and joints.last() is not None, HANG, 'the sim\'s arm motors')

    def move_arm(elbow_delta):
        q = list(arm.named_poses['stow'])
        q[2] += elbow_delta
        msg = JointState(name=list(arm.joints), position=q, velocity=[0.0] * len(q))
        msg.header.stamp = rospy_client.Time.now()
        motors.publish(msg)
        wait_for(lambda: abs(dict(zip(joints.last().name, joints.last().position))[arm.joints[2]] - q[2]) < 0.01,
                 HANG, 'the left elbow at %.2f rad' % q[2])

    x, y, yaw = PLACES['drums']
    send(client, target(rospy_client, x, y, yaw))
    wait_for(lambda: truth.last() is not None and truth.last().commanded_linear > 0.15, HANG, 'the base driving')
    out_at = rospy_client.get_time()
    move_arm(1.0)
    commanded_zero_after(truth.msgs, out_at, HANG)
    wait_for(lambda: truth.last().linear == 0.0 and truth.last().angular == 0.0, HANG, 'the base at rest')
    assert client.get_state() == GoalStatus.ACTIVE, 'held, not ended: ' + client.get_goal_status_text()
    held = wait_for(lambda: status.last() if status.last().state == MotionStatus.HELD else None, HANG, 'said held')
    assert held.reason == 'arm_outside' and held.text.startswith('left_arm reaches outside'), held
    rest = truth.last()
    move_arm(0.0)
    state, text = finished(client, 120.0)
    assert state == GoalStatus.SUCCEEDED, text
    assert math.hypot(truth.last().x - rest.x, truth.last().y - rest.y) > 0.3, 'it drove on once the arm was back'
    # and a goal sent with the arm out is refused, naming it
    move_arm(1.0)
    send(client, target(rospy_client, 0.0, 0.0, 0.0))
    state, text = finished(client)
    assert state == GoalStatus.REJECTED and 'left_arm reaches outside the driving outline' in text, text
