"""Arm goals and servoing, the rules alone (no ROS): the VaultBot's left arm from its URDF through KDL, the
time parameterisation, the self-collision check, the planner's refusals, and each of the servo's stops.
The same rules across processes are in test_robot_manipulation.py."""
import math

import numpy as np
import pytest

from temoto_robot_manager.manipulation import servo as servo_rules
from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics, KinematicsError, pose_error
from temoto_robot_manager.manipulation.arm_planner import (INVALID_GOAL, NO_SOLUTION, SELF_COLLISION, ArmPlanner,
                                                           GoalRefused, ACCEL)
from temoto_robot_manager.manipulation.joint_motion import time_parameterise
from temoto_robot_manager.manipulation.self_collision import SelfCollision
from temoto_robot_manager.manipulation.servo import Servo
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel
from vaultbot_sim.spec import ARM_JOINTS, STOW_POSE

JOINTS = ['left_%s_joint' % j for j in ARM_JOINTS]
STOW = [STOW_POSE[j] for j in JOINTS]
WRIST_2 = JOINTS.index('left_wrist_2_joint')


@pytest.fixture(scope='module')
def urdf():
    with open(ROBOT_URDF) as f:
        return f.read()


@pytest.fixture(scope='module')
def kin(urdf):
    return ArmKinematics(urdf, 'left_base_link', 'left_tool0', JOINTS)


@pytest.fixture(scope='module')
def body(urdf):
    checker = SelfCollision(urdf, JOINTS, STOW_POSE)
    yield checker
    checker.close()


def touches(body):
    def at(q):
        near = body.nearest(dict(zip(JOINTS, q)), 0.0)
        return '%s touches %s' % (near.link, near.other) if near else None
    return at


def test_kdl_forward_kinematics_matches_the_urdf_and_ik_comes_back(kin):
    model = TreeModel(ROBOT_URDF)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = np.array(STOW) + rng.uniform(-0.8, 0.8, 6)
        cfg = dict(STOW_POSE, **dict(zip(JOINTS, q)))
        truth = np.linalg.inv(model.link_pose('left_base_link', cfg)) @ model.link_pose('left_tool0', cfg)
        assert pose_error(kin.fk(q), truth) < (1e-9, 1e-9)
        solved = kin.ik(truth, STOW)
        dp, da = pose_error(kin.fk(solved), truth)
        assert dp < 1e-4 and da < 1e-3


def test_a_chain_that_is_not_there_is_refused_naming_it(urdf):
    with pytest.raises(KinematicsError, match='no chain from left_base_link to hokuyo_link'):
        ArmKinematics(urdf, 'left_base_link', 'hokuyo_link', JOINTS)
    with pytest.raises(KinematicsError, match='moves left_shoulder_pan_joint'):
        ArmKinematics(urdf, 'left_base_link', 'left_tool0', JOINTS[:3])


def test_a_time_parameterised_motion_keeps_every_joint_within_its_speed_and_acceleration():
    start, goal = [0.0, 1.0, -0.5], [1.5, 0.2, -0.5]
    speeds, accels = [1.0, 0.5, 2.0], [4.0, 2.0, 4.0]
    points = time_parameterise(start, goal, speeds, accels, period=0.01)
    assert points[-1][1] == goal and points[-1][2] == [0.0, 0.0, 0.0]
    previous = (0.0, start, [0.0] * 3)
    for t, q, v in points:
        for j in range(3):
            assert abs(v[j]) <= speeds[j] + 1e-9
            assert abs(v[j] - previous[2][j]) <= accels[j] * (t - previous[0]) + 1e-9
        previous = (t, q, v)
    # the slowest joint sets the pace: joint 1 (0.8 rad at 0.5 rad/s, 2 rad/s^2) takes 0.8 / 0.5 + 0.25 s
    assert points[-1][0] == pytest.approx(0.8 / 0.5 + 0.5 / 2.0, abs=0.011)


def test_the_hold_pose_is_clear_of_the_body_and_a_folded_arm_is_not(body):
    assert body.nearest(STOW_POSE, 0.0) is None
    folded = dict(STOW_POSE, left_elbow_joint=STOW_POSE['left_elbow_joint'] - 1.4)
    near = body.nearest(folded, 0.0)
    assert near is not None and near.distance <= 0.0


@pytest.mark.parametrize('kwargs, code, words', [
    ({}, INVALID_GOAL, 'give exactly one of pose, named_pose and joint_positions (given: none)'),
    ({'named_pose': 'stow', 'joint_positions': STOW}, INVALID_GOAL, '(given: named_pose, joint_positions)'),
    ({'named_pose': 'wave'}, INVALID_GOAL, "named_pose 'wave' is not a pose of this arm (its poses: stow)"),
    ({'joint_positions': STOW[:5]}, INVALID_GOAL, 'joint_positions has 5 values for the 6 joints'),
    ({'joint_positions': STOW[:5] + [float('nan')]}, INVALID_GOAL, 'left_wrist_3_joint is nan, not a finite angle'),
    ({'joint_positions': STOW[:5] + [7.0]}, INVALID_GOAL, 'left_wrist_3_joint at 7.000 rad is beyond'),
    ({'pose': np.diag([1.0, 1.0, 1.0, 1.0]) + np.array([[0, 0, 0, 2.0]] * 3 + [[0, 0, 0, 0]])}, NO_SOLUTION,
     'pose: no joint positions reach the target'),
    ({'joint_positions': STOW, 'speed_scale': 1.5}, INVALID_GOAL, 'speed_scale 1.5 must be in (0, 1]'),
])
def test_a_goal_that_cannot_be_is_refused_naming_its_field(kin, kwargs, code, words):
    planner = ArmPlanner(kin, {'stow': STOW})
    with pytest.raises(GoalRefused) as caught:
        planner.plan(STOW, **kwargs)
    assert caught.value.code == code and words in str(caught.value), str(caught.value)


def test_a_way_through_the_robots_own_body_is_refused_before_anything_moves(kin, body):
    planner = ArmPlanner(kin, {}, touches(body))
    folded = list(STOW)
    folded[JOINTS.index('left_elbow_joint')] -= 1.4
    with pytest.raises(GoalRefused) as caught:
        planner.plan(STOW, joint_positions=folded)
    assert caught.value.code == SELF_COLLISION and 'of the way: ' in str(caught.value)


def test_a_pose_goal_plans_to_the_pose_within_the_limits(kin, body):
    planner = ArmPlanner(kin, {}, touches(body))
    target = kin.fk(STOW)
    target[:3, 3] += [0.05, -0.1, 0.1]
    points = planner.plan(STOW, pose=target, speed_scale=0.4)
    assert pose_error(kin.fk(points[-1][1]), target) < (1e-4, 1e-3)
    for _, _, v in points:
        assert max(abs(x) for x in v) <= 0.4 * math.pi + 1e-9
    assert points[-1][0] > 0 and ACCEL > 0


def run_servo(servo, q, target, steps):
    for _ in range(steps):
        step = servo.step(q, target)
        q = step.positions
    return q, step


def test_the_servo_brings_the_tool_onto_a_target(kin):
    servo = Servo(kin, 0.01)
    target = kin.fk(STOW)
    target[:3, 3] += [0.08, 0.05, -0.06]
    q, step = run_servo(servo, STOW, target, 300)
    assert pose_error(kin.fk(q), target)[0] < 1e-4 and not step.halted


def test_the_servo_keeps_each_joint_within_its_speed(kin):
    servo = Servo(kin, 0.01)
    target = kin.fk(STOW)
    target[:3, 3] += [0.5, 0.0, 0.0]
    step = servo.step(STOW, target)
    assert max(abs(v) for v in step.velocities) <= math.pi + 1e-9
    tip = kin.jacobian(STOW) @ np.array(step.velocities)
    assert np.linalg.norm(tip[:3]) <= servo_rules.MAX_LINEAR + 1e-6


def test_the_servo_slows_then_halts_towards_a_singularity_and_lets_the_arm_back_out(kin):
    """The UR's wrist singularity: wrist_2 at 0 aligns wrist_1's and wrist_3's axes."""
    servo = Servo(kin, 0.01)
    q = list(STOW)
    q[WRIST_2] = -0.35
    toward = list(q)
    toward[WRIST_2] = 0.0
    target = kin.fk(toward)
    conditions, halted = [], None
    for _ in range(400):
        step = servo.step(q, target)
        conditions.append(step.condition)
        if step.halted:
            halted = step
            break
        q = step.positions
    assert halted is not None and 'near a singularity' in halted.why, conditions[-3:]
    assert servo_rules.SINGULARITY_STOP <= halted.condition < servo_rules.SINGULARITY_STOP * 1.5
    assert max(conditions[:-1]) >= servo_rules.SINGULARITY_SLOW    # it went through the slow band first
    back = servo.step(q, kin.fk(STOW))            # away from it: not slowed by it
    assert not back.halted and back.scale > 0


def test_the_servo_halts_a_joint_at_its_margin(kin):
    servo = Servo(kin, 0.01)
    q = list(STOW)
    q[0] = kin.limits[0].upper - 0.05                # within the 0.1 rad margin
    target_q = list(q)
    target_q[0] = kin.limits[0].upper                # and asked further
    step = servo.step(q, kin.fk(target_q))
    assert step.halted and 'left_shoulder_pan_joint' in step.why and 'range\'s end' in step.why


def test_the_servo_halts_before_the_arm_touches_the_body(kin, body):
    def distance(q, margin):
        near = body.nearest(dict(zip(JOINTS, q)), margin)
        return near.distance if near else None
    servo = Servo(kin, 0.01, distance)
    # the tool sent across the robot, towards the other arm (a point in base_link)
    arm_in_base = TreeModel(ROBOT_URDF).link_pose('left_base_link', STOW_POSE)
    target = kin.fk(STOW)
    target[:3, 3] = (np.linalg.inv(arm_in_base) @ np.array([0.6, -0.3, 1.0, 1.0]))[:3]
    q, halted = list(STOW), None
    for _ in range(600):
        step = servo.step(q, target)
        if step.halted:
            halted = step
            break
        q = step.positions
    assert halted is not None and 'own body' in halted.why
    assert body.nearest(dict(zip(JOINTS, q)), 0.0) is None       # it stopped short: never touched
