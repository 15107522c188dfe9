"""The motion guards' rules alone (``temoto_robot_manager/guards.py``), and the navigator's use of the odometry guard.
Across processes, the base controller killed mid-drive is in ``tests/test_base_controller_loss.py``."""
import math

import numpy as np
import pytest

from temoto_robot_manager.command_gate import CommandGate
from temoto_robot_manager.navigation.costmap import Costmap, Footprint
from temoto_robot_manager.description import load_file
from temoto_robot_manager.navigation.freshness import Freshness
from temoto_robot_manager.guards import OdometryFresh, PublisherAlive, StopCode
from temoto_robot_manager.navigation.navigator import Navigator, Outcome, State
from temoto_robot_manager.paths import DEFAULT_DESCRIPTION
from temoto_robot_manager.navigation.teleop_drive import TeleopDrive, base_inputs
from vaultbot_sim.kinematics import WORLDS, TreeModel
from vaultbot_sim.world_map import world_map

VAULTBOT = next(r for r in load_file(DEFAULT_DESCRIPTION)[0] if r.name == 'vaultbot')
HUSKY = Footprint.of(VAULTBOT.navigation.footprint, VAULTBOT.navigation.protrusions)


def test_odometry_is_stale_after_three_declared_periods_and_final_after_its_patience():
    guard = OdometryFresh(rate=50.0, patience=0.5)
    assert guard.check(0.0).code is StopCode.ODOMETRY_STALE and not guard.check(0.0).final, 'none heard yet'
    guard.heard(1.0)
    assert guard.check(1.059) is None and guard.deadline() == pytest.approx(1.06)
    stale = guard.check(1.061)
    assert stale.code is StopCode.ODOMETRY_STALE and not stale.final and '3 periods of 50 Hz' in stale.text
    assert guard.check(1.5).final and 'the goal ends after 0.5 s' in guard.check(1.5).text
    guard.heard(1.6)
    assert guard.check(1.61) is None, 'fresh again once odometry comes'


@pytest.mark.parametrize('rate, patience, periods', [(0.0, 0.5, 3), (50.0, 0.0, 3), (50.0, 0.5, 0)])
def test_an_odometry_guard_with_a_bad_figure_is_refused_naming_it(rate, patience, periods):
    with pytest.raises(ValueError, match='rate'):
        OdometryFresh(rate, patience, periods)


def test_a_publisher_seen_then_lost_is_reported_once_and_one_never_seen_is_nobodys_concern():
    live = {'/base_controller'}
    watch = PublisherAlive(lambda: live, 'the odometry\'s publisher')
    assert watch.poll() is None
    live = set()
    lost = watch.poll()
    assert lost.code is StopCode.CONTROLLER_GONE and lost.final
    assert lost.text == 'the odometry\'s publisher /base_controller is gone (its connection closed)'
    assert watch.poll() is None, 'reported once'
    live = {'/base_controller'}                  # respawned: watched again
    assert watch.poll() is None
    live = set()
    assert watch.poll() is not None


@pytest.fixture(scope='module')
def lab_navigator_parts():
    return world_map(TreeModel(WORLDS['lab']))


def driving(lab):
    """A navigator driving toward the drums, its obstacle source and odometry fresh at t = 0."""
    nav = Navigator(HUSKY, Freshness(declared=0.04), odometry=OdometryFresh(50.0, 0.5))
    nav.set_map(Costmap(lab.origin, lab.resolution, lab.cells > 0, HUSKY))
    nav.set_pose((0.0, 0.0, 0.0), 0.0)
    for k in range(5):
        nav.set_obstacles(np.zeros((0, 2)), -0.04 * (4 - k))
    x, y, yaw = VAULTBOT.navigation.places['drums']
    nav.start(nav.check(x, y, (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))), 0.0)
    return nav


def test_stale_odometry_zeroes_the_drive_fresh_odometry_resumes_it_and_its_patience_ends_the_goal(
        lab_navigator_parts):
    nav = driving(lab_navigator_parts)
    nav.set_obstacles(np.zeros((0, 2)), 0.05)
    assert nav.tick(0.05).linear > 0.0
    assert nav.must_stop(0.061) and not nav.must_stop(0.059), 'stale after 3 periods of 20 ms'
    assert nav.stop_deadline() == pytest.approx(0.06), 'the odometry\'s deadline is the earlier one'
    held = nav.tick(0.07)
    assert (held.linear, held.angular, held.state, held.ending) == (0.0, 0.0, State.HELD, None)
    nav.set_pose((0.0, 0.0, 0.0), 0.08)
    nav.set_obstacles(np.zeros((0, 2)), 0.08)
    assert nav.tick(0.09).state is State.DRIVING, 'it drives on when odometry is back'
    nav.set_obstacles(np.zeros((0, 2)), 0.6)
    ended = nav.tick(0.6)
    assert ended.ending.outcome is Outcome.ABORTED and 'no odometry for 520 ms' in ended.ending.text
    assert nav.goal is None and nav.tick(0.61).linear == 0.0


def test_a_goal_is_refused_while_the_odometry_is_stale(lab_navigator_parts):
    nav = driving(lab_navigator_parts)
    nav.cancel()
    with pytest.raises(ValueError, match='may not drive now: no odometry for'):
        nav.start(nav.goal or (2.0, 0.0, 0.0), 0.2)


def test_the_base_s_gate_holds_a_teleop_command_while_the_odometry_is_stale(lab_navigator_parts):
    nav = driving(lab_navigator_parts)
    nav.cancel()
    nav.set_obstacles(np.zeros((0, 2)), 0.1)
    sent = []
    gate = CommandGate('base', base_inputs(), nav.guards, sent.append, (0.0, 0.0))
    decision = TeleopDrive(nav).command(10.0, 10.0, 0.0, 0.5)
    said = gate.offer('teleop', (decision.linear, decision.angular), 0.1)
    assert sent == [(0.0, 0.0)] and said.reason is StopCode.ODOMETRY_STALE and said.text.startswith('no odometry')


def test_a_lost_controller_aborts_the_goal_naming_it(lab_navigator_parts):
    nav = driving(lab_navigator_parts)
    live = {'/base_controller'}
    watch = PublisherAlive(lambda: live, 'the odometry\'s publisher')
    watch.poll()
    live = set()
    ended = nav.abort(watch.poll())
    assert ended.ending.outcome is Outcome.ABORTED and (ended.linear, ended.angular) == (0.0, 0.0)
    assert ended.ending.text == ('the odometry\'s publisher /base_controller is gone (its connection closed): '
                                 'the robot stopped')
    assert nav.goal is None


@pytest.fixture(scope='module')
def arms_guard():
    from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics
    from temoto_robot_manager.guards import ArmsInEnvelope
    from vaultbot_sim.kinematics import ROBOT_URDF
    with open(ROBOT_URDF) as f:
        urdf = f.read()
    arms = {a.name: (a.joints, ArmKinematics(urdf, 'base_link', a.tool_frame, a.joints).skeleton)
            for a in VAULTBOT.manipulation.values()}
    return lambda: ArmsInEnvelope(HUSKY, arms, VAULTBOT.navigation.arm_inset)


def held_positions(**moved):
    """Every arm joint at the VaultBot's stowed pose, but for ``moved`` (joint: radians added)."""
    out = {}
    for arm in VAULTBOT.manipulation.values():
        out.update(zip(arm.joints, arm.named_poses['stow']))
    for joint, delta in moved.items():
        out[joint] += delta
    return out


def test_arms_at_their_hold_pose_pass_and_an_elbow_swung_out_holds_the_base_naming_the_arm(arms_guard):
    guard = arms_guard()
    assert guard.check(0.0).code is StopCode.ARM_OUTSIDE and 'not known' in guard.check(0.0).text
    guard.update(held_positions(), 0.0)
    assert guard.check(0.1) is None
    guard.update(held_positions(left_elbow_joint=1.0), 0.2)
    out = guard.check(0.2)
    assert out.code is StopCode.ARM_OUTSIDE and not out.final
    assert out.text.startswith('left_arm reaches outside the driving outline at (') and 'stowed pose' in out.text
    guard.update(held_positions(right_shoulder_pan_joint=-1.5), 0.3)
    assert guard.check(0.3).text.startswith('right_arm reaches outside'), guard.check(0.3).text
    guard.update(held_positions(), 0.4)
    assert guard.check(0.4) is None
    assert 'not known' in guard.check(1.0).text, 'joint states 0.6 s old: where the arms are is not known'


def test_a_robot_without_arms_has_nothing_to_keep_inside():
    from temoto_robot_manager.guards import ArmsInEnvelope
    assert ArmsInEnvelope(HUSKY, {}, 0.04).check(0.0) is None


def test_an_arm_outside_holds_a_goal_which_drives_on_once_it_is_back(lab_navigator_parts, arms_guard):
    guard = arms_guard()
    nav = Navigator(HUSKY, Freshness(declared=0.04), guards=[guard])
    nav.set_map(Costmap(lab_navigator_parts.origin, lab_navigator_parts.resolution, lab_navigator_parts.cells > 0,
                        HUSKY))
    nav.set_pose((0.0, 0.0, 0.0))
    for k in range(5):
        nav.set_obstacles(np.zeros((0, 2)), -0.04 * (4 - k))
    guard.update(held_positions(left_elbow_joint=1.0), 0.0)
    x, y, yaw = VAULTBOT.navigation.places['drums']
    goal = nav.check(x, y, (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))
    with pytest.raises(ValueError, match='may not drive now: left_arm reaches outside'):
        nav.start(goal, 0.0)
    guard.update(held_positions(), 0.0)
    nav.start(goal, 0.0)
    nav.set_obstacles(np.zeros((0, 2)), 0.05)
    assert nav.tick(0.05).linear > 0.0
    guard.update(held_positions(left_elbow_joint=1.0), 0.06)
    nav.set_obstacles(np.zeros((0, 2)), 0.1)
    held = nav.tick(0.1)
    assert (held.linear, held.angular, held.state) == (0.0, 0.0, State.HELD)
    assert nav.held_by.text.startswith('left_arm reaches outside')
    guard.update(held_positions(), 0.15)
    nav.set_obstacles(np.zeros((0, 2)), 0.15)
    assert nav.tick(0.15).state is State.DRIVING
