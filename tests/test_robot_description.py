"""Robot description files (temoto_robot_manager/description.py): the VaultBot's own, and every kind of
mistake reported at its line; then `temoto robots check` as a user runs it."""
import dataclasses
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from temoto_core import map_file
from temoto_core.errors import TemotoError
from temoto_robot_manager.navigation.costmap import Footprint
from temoto_robot_manager.description import load_file
from temoto_robot_manager.navigation import navigator
from temoto_robot_manager.selection import choose_robot
from vaultbot_sim.gripper import STROKE
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel, resolve_world
from vaultbot_sim.scene import Scene
from vaultbot_sim.spec import BASE_JOINTS, STOW_POSE
from vaultbot_sim.world_map import world_map

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VAULTBOT = os.path.join(ROOT, 'temoto_robot_manager', 'config', 'vaultbot.yaml')

GOOD = """\
robots:
  - name: rover
    navigation:
      driver: {package: rover_base, executable: base.launch}
      obstacle_sources:
        - {sensor_type: lidar, output_topic: lidar_data}
      places:
        dock: [1.0, 2.0, 0.5]
    manipulation:
      arm:
        controller: {package: rover_arm, executable: arm_controller}
        action: arm/follow_joint_trajectory
        joints: [a, b]
        tool_frame: tool0
        named_poses:
          up: [0.0, 1.0]
    gripper:
      controller: {package: rover_arm, executable: gripper}
      action: gripper/gripper_command
      arm: arm
"""


def write(tmp_path, text, name='robots.yaml'):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_the_vaultbots_description_matches_the_simulated_robot():
    robots, problems = load_file(VAULTBOT)
    assert problems == [] and [r.name for r in robots] == ['vaultbot']
    vaultbot = robots[0]
    assert vaultbot.features == ['navigation', 'manipulation', 'gripper']
    assert vaultbot.gripper.arm == 'left_arm' and vaultbot.gripper.positions['open'] == STROKE
    for arm in vaultbot.manipulation.values():
        assert arm.named_poses['stow'] == pytest.approx([STOW_POSE[j] for j in arm.joints], abs=1e-3)
    assert [s.label for s in vaultbot.navigation.obstacle_sources] == [
        'base LIDAR scan', 'arm LIDAR stitched cloud', 'RGB-D camera cloud']


def test_the_vaultbots_footprint_covers_its_body_with_the_arms_held():
    """The footprint is what the navigator keeps clear and cuts out of its own sensors' points: a body part
    outside it (the gripper's fingers) is seen by the stitched cloud as an obstacle that drives with the robot."""
    vaultbot = load_file(VAULTBOT)[0][0]
    outline = Footprint.of(vaultbot.navigation.footprint, vaultbot.navigation.protrusions)
    scene = Scene(ROBOT_URDF, resolve_world('lab'))
    try:
        scene.set_robot(STOW_POSE)
        p, robot = scene.p, scene.robot
        for link in range(-1, p.getNumJoints(robot, physicsClientId=scene.cid)):
            (lx, ly, _), (hx, hy, _) = p.getAABB(robot, link, physicsClientId=scene.cid)
            name = p.getJointInfo(robot, link, physicsClientId=scene.cid)[12].decode() if link >= 0 else 'base'
            xs, ys = np.meshgrid(np.linspace(lx, hx, 9), np.linspace(ly, hy, 9))
            assert outline.contains(np.stack([xs.ravel(), ys.ravel()], axis=1)).all(), \
                '%s (%.2f..%.2f, %.2f..%.2f) sticks out of the outline %s' % (name, lx, hx, ly, hy, outline.boxes)
    finally:
        scene.close()


def test_every_named_place_of_the_vaultbot_is_free_in_the_lab():
    """A place the robot cannot stand on is a goal that can only fail: each is checked in the lab's geometry."""
    vaultbot = load_file(VAULTBOT)[0][0]
    scene = Scene(ROBOT_URDF, resolve_world('lab'))
    try:
        for place, pose in vaultbot.navigation.places.items():
            scene.set_robot(dict(STOW_POSE, **dict(zip(BASE_JOINTS, pose))))
            assert scene.contacts(margin=0.05) == [], 'place %s %s touches the lab' % (place, pose)
    finally:
        scene.close()


def test_a_good_file_loads_every_feature(tmp_path):
    robots, problems = load_file(write(tmp_path, GOOD))
    assert problems == []
    rover = robots[0]
    assert rover.navigation.places == {'dock': (1.0, 2.0, 0.5)} and rover.navigation.cmd_vel_topic == 'cmd_vel'
    assert (rover.navigation.odom_rate, rover.navigation.odom_patience) == (50.0, 0.5), 'the defaults'
    assert rover.manipulation['arm'].named_poses == {'up': (0.0, 1.0)} and rover.gripper.arm == 'arm'
    assert rover.source.endswith('robots.yaml:2')


@pytest.mark.parametrize('old, new, line, words', [
    ('      driver:', '      drivr:', 4, "unknown key robots[0].navigation.drivr (did you mean 'driver'?)"),
    ('        dock: [1.0, 2.0, 0.5]', '        dock: [1.0, 2.0]', 8, 'places.dock must be [x, y, yaw]'),
    ('          up: [0.0, 1.0]', '          up: [0.0, .nan]', 16, 'one position per joint (a, b)'),
    ('      arm: arm', '      arm: other_arm', 20, "gripper.arm 'other_arm' is not an arm of manipulation (arm)"),
    ('  - name: rover', '  - name: 2rover', 2, "robot name '2rover' is not a legal ROS base name"),
    ('      obstacle_sources:\n        - {sensor_type: lidar, output_topic: lidar_data}',
     '      obstacle_sources: []', 5, 'obstacle_sources must be a non-empty list'),
    ('        joints: [a, b]', '        joints: [a, a]', 13, 'joints must list each joint once'),
    ('        action: arm/follow_joint_trajectory', '        action: "arm follow"', 12,
     "action 'arm follow' is not a legal ROS name"),
    ('      places:', '      protrusions: [[0.5, 0.4, 0.0, 0.1]]\n      places:', 7,
     'protrusions[0]: each min must be below its max'),
    ('      places:', '      odom_rate: 0\n      places:', 7,
     'navigation.odom_rate must be a number above 0 and at most 1000, got 0'),
    ('      places:', '      odom_patience: .inf\n      places:', 7,
     'navigation.odom_patience must be a number above 0 and at most 10, got inf'),
])
def test_each_mistake_is_reported_at_its_line_and_the_robot_left_out(tmp_path, old, new, line, words):
    assert old in GOOD
    path = write(tmp_path, GOOD.replace(old, new))
    robots, problems = load_file(path)
    assert robots == [] and len(problems) == 1
    assert problems[0].where == '%s:%d' % (path, line) and words in problems[0].message, str(problems[0])


def test_a_file_that_is_not_yaml_or_holds_no_robots_says_so(tmp_path):
    robots, problems = load_file(write(tmp_path, 'robots:\n  - name: [unclosed\n'))
    assert robots == [] and 'not valid YAML' in problems[0].message and problems[0].where.endswith(':3')
    robots, problems = load_file(write(tmp_path, 'sensors: []\n', 'other.yaml'))
    assert "list under the key 'robots'" in problems[0].message
    robots, problems = load_file(str(tmp_path / 'missing.yaml'))
    assert 'cannot read' in problems[0].message


def test_a_robot_described_twice_keeps_the_first(tmp_path):
    robots, problems = load_file(write(tmp_path, GOOD + GOOD[len('robots:\n'):]))
    assert [r.name for r in robots] == ['rover'] and 'described twice' in problems[0].message
    assert problems[0].where.endswith(':21')


def run_cli(*args):
    return subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'robots'] + list(args), capture_output=True,
                          text=True, timeout=60)


def test_temoto_robots_check_says_what_is_wrong_and_where(tmp_path):
    good = run_cli('check', VAULTBOT)
    assert good.returncode == 0 and good.stdout.startswith('ok    %s:4: vaultbot' % VAULTBOT), good.stdout
    bad_path = write(tmp_path, GOOD.replace('      driver:', '      drivr:'))
    bad = run_cli('check', VAULTBOT, bad_path)
    assert bad.returncode == 1
    assert 'error %s:4: unknown key robots[0].navigation.drivr' % bad_path in bad.stdout, bad.stdout
    env = dict(os.environ, ROS_MASTER_URI='http://127.0.0.1:9')      # nobody there
    listed = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'robots'], capture_output=True, text=True,
                            timeout=60, env=env)
    assert listed.returncode == 1 and 'the Robot Manager does not answer' in listed.stderr, listed.stderr


def test_the_safety_numbers_are_read_from_the_description_and_reach_the_navigator(tmp_path):
    numbers = ('      max_speed: 0.4\n      max_turn: 0.9\n      stop_margin: 0.08\n      slow_margin: 0.3\n'
               '      braking: 1.5\n      stale_periods: 4\n      teleop_timeout: 0.25\n      teleop_max_age: 0.2\n')
    path = write(tmp_path, GOOD.replace('      places:\n', numbers + '      places:\n').replace(
        '        tool_frame: tool0\n', '        tool_frame: tool0\n        servo_timeout: 0.2\n'))
    robots, problems = load_file(path)
    assert not problems, problems
    navigation = robots[0].navigation
    nav = navigator.described(navigation)
    assert (nav.follower.limits.max_speed, nav.follower.limits.max_turn) == (0.4, 0.9)
    settings = nav.monitor.settings
    assert (settings.stop_margin, settings.slow_margin, settings.decel) == (0.08, 0.3, 1.5)
    assert nav.freshness.periods == 4
    assert (navigation.teleop_timeout, navigation.teleop_max_age) == (0.25, 0.2)
    assert robots[0].manipulation['arm'].servo_timeout == 0.2


@pytest.mark.parametrize('numbers, words', [
    ('      stop_margin: 0.3\n      slow_margin: 0.1\n', 'slow_margin 0.10 must be at least its stop_margin 0.30'),
    ('      stale_periods: 0\n', 'stale_periods must be a whole number from 1 to 20, got 0'),
    ('      stale_periods: 2.5\n', 'stale_periods must be a whole number'),
    ('      teleop_timeout: 0\n', 'teleop_timeout must be a number above 0'),
    ('      max_speed: .nan\n', 'max_speed must be a number above'),
])
def test_a_safety_number_out_of_its_range_is_named_at_its_line(tmp_path, numbers, words):
    path = write(tmp_path, GOOD.replace('      places:\n', numbers + '      places:\n'))
    robots, problems = load_file(path)
    assert not robots and len(problems) == 1 and words in str(problems[0]), problems
    key = words.split()[0]
    line = next(k for k, row in enumerate(open(path).read().splitlines(), 1) if row.strip().startswith(key + ':'))
    assert problems[0].where == '%s:%d' % (path, line), problems[0].where


def sim_map(tmp_path):
    out = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'sim', 'map', 'lab', str(tmp_path / 'lab.yaml')],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and (tmp_path / 'lab.pgm').exists(), out.stderr
    return str(tmp_path / 'lab.yaml')


def test_a_map_written_as_map_server_saves_one_reads_back_cell_for_cell(tmp_path):
    grid = world_map(TreeModel(resolve_world('lab')))
    back = map_file.read(sim_map(tmp_path))
    assert back.origin == pytest.approx(grid.origin) and back.resolution == grid.resolution
    assert back.cells.shape == grid.cells.shape and (back.cells == grid.cells).all()


def test_temoto_robots_check_with_a_map_names_a_place_the_robot_cannot_stand_on(tmp_path):
    """A place inside the drums passed the check (it read the file, not the world); with ``--map`` every place is
    checked as the navigator checks a goal, and the error names the place's line."""
    lab = sim_map(tmp_path)
    good = run_cli('check', VAULTBOT, '--map', lab)
    assert good.returncode == 0 and '4 places checked against %s' % lab in good.stdout, good.stdout
    with open(VAULTBOT) as f:
        text = f.read()
    line = next(k for k, row in enumerate(text.splitlines(), 1) if row.strip().startswith('drums:'))
    x, y, _ = load_file(VAULTBOT)[0][0].navigation.places['drums']
    moved = text.replace(next(row for row in text.splitlines() if row.strip().startswith('drums:')),
                         '        drums: [%.2f, %.2f, 0.0]' % (x + 0.9, y))         # into the drums themselves
    bad = run_cli('check', write(tmp_path, moved), '--map', lab)
    assert bad.returncode == 1, bad.stdout
    where = '%s:%d' % (tmp_path / 'robots.yaml', line)
    assert 'error %s: place drums: places.drums.position' % where in bad.stdout, bad.stdout
    assert 'ok ' not in bad.stdout, 'a robot with a place it cannot stand on is not ok'
    broken = write(tmp_path, 'image: lab.pgm\nresolution: -1\norigin: [0, 0, 0]\n', 'broken.yaml')
    refused = run_cli('check', VAULTBOT, '--map', broken)
    assert refused.returncode == 1 and 'resolution must be above 0' in refused.stdout, refused.stdout


def test_the_description_reads_without_a_master():
    env = {k: v for k, v in os.environ.items() if k != 'ROS_MASTER_URI'}
    out = subprocess.run([sys.executable, '-c', textwrap.dedent('''
        from temoto_robot_manager.description import load_file
        print(len(load_file(%r)[0]))''' % VAULTBOT)], capture_output=True, text=True, timeout=60, env=env)
    assert out.stdout.strip() == '1', out.stderr


@pytest.mark.parametrize('name, features, words', [
    ('', ['flying'], "unknown feature 'flying' (features: navigation, manipulation, gripper)"),
    ('', ['navigation', 'gripper'],
     'no described robot has navigation, gripper (described: rover: navigation; crane: manipulation, gripper)'),
    ('rover', ['gripper'], 'robot rover has no gripper (it has: navigation)'),
    ('husky_9', [], "no robot 'husky_9' is described (described: crane, rover)"),
])
def test_a_request_no_robot_serves_is_refused_naming_why(tmp_path, name, features, words):
    robots = described(tmp_path)
    with pytest.raises(TemotoError) as caught:
        choose_robot(robots, lambda n: 0.5, name, features)
    assert words in str(caught.value)


def test_the_most_reliable_robot_with_every_feature_is_chosen(tmp_path):
    robots = described(tmp_path)
    assert choose_robot(robots, lambda n: 0.5, '', ['manipulation']).name == 'crane'
    both = dict(robots, crane2=dataclasses.replace(robots['crane'], name='crane2'))
    assert choose_robot(both, {'rover': 0.9, 'crane': 0.2, 'crane2': 0.7}.get, '', ['gripper']).name == 'crane2'


@pytest.mark.parametrize('positions, words', [
    ('{open: 0.085, closed: 0.0}', ''),
    ('{open: -0.01}', 'gripper.positions.open must be a gap from 0 to 1 m, got -0.01'),
    ('{open: wide}', "gripper.positions.open must be a gap from 0 to 1 m, got 'wide'"),
    ('[0.085]', 'gripper.positions must map names to gaps in metres'),
])
def test_gripper_positions_are_gaps_in_metres(tmp_path, positions, words):
    path = tmp_path / 'rover.yaml'
    path.write_text(GOOD + '      positions: %s\n' % positions)
    robots, problems = load_file(str(path))
    if not words:
        assert problems == [] and robots[0].gripper.positions == {'open': 0.085, 'closed': 0.0}
    else:
        assert [str(p) for p in problems] == ['%s:%d: %s' % (path, GOOD.count('\n') + 1, words)]


def described(tmp_path):
    """Two robots: a rover that only drives, a crane with an arm and a gripper."""
    path = tmp_path / 'two.yaml'
    path.write_text(textwrap.dedent("""\
        robots:
          - name: rover
            navigation:
              driver: {package: rover_base, executable: base.launch}
              obstacle_sources:
                - {sensor_type: lidar, output_topic: lidar_data}
          - name: crane
            manipulation:
              arm:
                controller: {package: crane, executable: arm_controller}
                action: arm/follow_joint_trajectory
                joints: [a, b]
                tool_frame: tool0
            gripper:
              controller: {package: crane, executable: gripper}
              action: gripper/gripper_command
              arm: arm
        """))
    robots, problems = load_file(str(path))
    assert problems == []
    return {r.name: r for r in robots}
