"""VaultBot model and pure logic: URDF names, limits, DH geometry, FK (yourdfpy vs pybullet),
the device table, the wrist sweep, joint history, the stitcher and the CLI's argument errors.
No ROS master needed."""
import math
import subprocess
import sys

import numpy as np
import pytest
import yourdfpy

from vaultbot_sim import spec
from vaultbot_sim.devices import CableWatch, Cable, DeviceError, DeviceTable
from vaultbot_sim.kinematics import (ROBOT_URDF, WORLDS, TreeModel, matrix_from_quat, planar_matrix,
                                     quat_from_matrix)
from vaultbot_sim.motion import JointHistory, WristSweep
from vaultbot_sim.scene import Scene
from vaultbot_sim.stitcher import RollingStitcher, SweepStitcher

SENSOR_FRAMES = ['d435_link', 'd435_optical_frame', 'hokuyo_link', 'sick_link', 'left_tool0', 'right_tool0']


@pytest.fixture(scope='module')
def urdf():
    return yourdfpy.URDF.load(ROBOT_URDF, build_collision_scene_graph=False, load_meshes=False)


@pytest.fixture(scope='module')
def model():
    return TreeModel(ROBOT_URDF)


@pytest.fixture(scope='module')
def scene():
    s = Scene(ROBOT_URDF, WORLDS['test_wall'])
    yield s
    s.close()


def test_names_and_inertials(urdf):
    joints = set(urdf.joint_map)
    for side in ('left', 'right'):
        for j in spec.ARM_JOINTS:
            assert f'{side}_{j}_joint' in joints
    for link in SENSOR_FRAMES + ['base_link', 'base_footprint', 'chassis_link', 'arm_mount_link']:
        assert link in urdf.link_map, link
    for wheel in spec.WHEEL_JOINTS:
        assert wheel in joints
    assert [l.name for l in urdf.robot.links if l.inertial is None] == []
    for world in WORLDS.values():
        w = yourdfpy.URDF.load(world, build_collision_scene_graph=False, load_meshes=False)
        assert [l.name for l in w.robot.links if l.inertial is None] == []
        assert 'person_hand' in w.link_map and spec.PERSON_JOINT in w.joint_map


def test_arm_joint_limits_match_datasheet(urdf):
    for side in ('left', 'right'):
        for j in spec.ARM_JOINTS:
            lim = urdf.joint_map[f'{side}_{j}_joint'].limit
            assert lim.lower == pytest.approx(-2 * math.pi, abs=1e-6)
            assert lim.upper == pytest.approx(2 * math.pi, abs=1e-6)
            assert lim.velocity == pytest.approx(math.pi, abs=1e-6)


def _dh(theta, d, a, alpha):
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                     [0, sa, ca, d], [0, 0, 0, 1]])


def test_arm_matches_ur5_dh_table(model):
    """tool0 relative to the arm base equals the product of the datasheet DH transforms."""
    d = [0.089159, 0, 0, 0.10915, 0.09465, 0.0823]
    a = [0, -0.425, -0.39225, 0, 0, 0]
    alpha = [math.pi / 2, 0, 0, math.pi / 2, -math.pi / 2, 0]
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = rng.uniform(-math.pi, math.pi, 6)
        expect = np.eye(4)
        for i in range(6):
            expect = expect @ _dh(q[i], d[i], a[i], alpha[i])
        for side in ('left', 'right'):
            cfg = {f'{side}_{n}_joint': v for n, v in zip(spec.ARM_JOINTS, q)}
            got = model.transform(f'{side}_tool0', f'{side}_base_link', cfg)
            assert np.allclose(got, expect, atol=1e-9)


def test_sensor_frames_fk_yourdfpy_vs_pybullet(urdf, model, scene):
    rng = np.random.default_rng(7)
    names = urdf.actuated_joint_names
    held = dict(spec.STOW_POSE, **{j: 0.02 for j in spec.GRIPPER_JOINTS})
    configs = [held] + [dict(zip(names, rng.uniform(-math.pi, math.pi, len(names)))) for _ in range(4)]
    for cfg in configs:
        urdf.update_cfg(np.array([cfg[n] for n in names]))
        scene.set_robot(cfg)
        for frame in SENSOR_FRAMES:
            ours = urdf.get_transform(frame, 'base_link')
            bullet = scene.robot_link_pose(frame)
            assert np.linalg.norm(ours[:3, 3] - bullet[:3, 3]) < 1e-3, frame
            assert np.abs(ours[:3, :3] - bullet[:3, :3]).max() < 1e-3, frame
            assert np.allclose(model.link_pose(frame, cfg), ours, atol=1e-6), frame


def test_hold_pose_camera_looks_ahead(model):
    t = model.link_pose('d435_optical_frame', spec.STOW_POSE)
    forward = t[:3, 2]
    assert forward[0] > 0.95 and t[2, 3] > 0.9          # looks along +x, from above the mount
    assert t[:3, 1][2] < -0.9                          # image "down" is world down
    h = model.link_pose('hokuyo_link', spec.STOW_POSE)
    assert h[0, 0] > 0.99                              # wrist_3 axis (scan x) points ahead


def test_quaternion_roundtrip():
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        back = np.array(quat_from_matrix(matrix_from_quat(q)))
        assert np.allclose(back, q, atol=1e-9) or np.allclose(back, -q, atol=1e-9)


def test_device_table_rejects_bad_input_without_change():
    table = DeviceTable()
    for args in (('kinect', 'unplugged', 'crash'), ('d435', 'pulled', 'crash'), ('d435', 'unplugged', 'explode')):
        with pytest.raises(DeviceError) as e:
            table.set(*args)
        assert repr(args[0] if args[0] == 'kinect' else args[1] if args[1] == 'pulled' else args[2]) in str(e.value)
    assert all(c.plugged for c in table.all())
    assert table.set('sick', 'unplugged', 'stall') == Cable('sick', False, 'stall')
    assert table.set('hokuyo', 'unplugged', '').mode == 'crash'


def test_cable_watch_verdicts():
    w = CableWatch('d435')
    assert w.verdict is None
    assert w.update([Cable('d435', True)]) == 'run'
    assert w.update([Cable('d435', False, 'stall')]) == 'stall'
    assert w.update([Cable('d435', True)]) == 'stall'   # a stalled driver stays stalled
    assert CableWatch('sick').update([Cable('d435', True)]) == 'crash'   # device missing
    assert CableWatch('hokuyo').update([Cable('hokuyo', False, 'crash')]) == 'crash'
    with pytest.raises(DeviceError):
        CableWatch('lidar')


def test_wrist_sweep_stays_in_range_and_validates_speed():
    s = WristSweep(0.5, amplitude=math.pi / 2, speed=math.pi)
    seen = [s.advance(0.02) for _ in range(500)]
    assert min(seen) >= 0.5 - math.pi / 2 - 1e-9 and max(seen) <= 0.5 + math.pi / 2 + 1e-9
    assert max(seen) - min(seen) > math.pi - 0.1
    for bad in (-1.0, 4.0, float('nan')):
        with pytest.raises(ValueError):
            s.set(True, bad)
    assert s.speed == math.pi
    s.set(False)
    assert s.velocity == 0.0 and s.advance(1.0) == s.position


def test_joint_history_extrapolates_from_latest_sample_before():
    h = JointHistory(max_extrapolation=0.2)
    h.add(1.0, ['a'], [0.0], [1.0])
    h.add(2.0, ['a'], [5.0], [0.0])
    assert h.cfg_at(1.1)['a'] == pytest.approx(0.1)
    assert h.cfg_at(1.9)['a'] == pytest.approx(0.2)      # capped extrapolation
    assert h.cfg_at(2.5)['a'] == pytest.approx(5.0)
    assert h.cfg_at(0.5)['a'] == pytest.approx(0.0)


def test_stitcher_emits_one_cloud_per_sweep_in_base_frame(model):
    st = SweepStitcher(model, spec.SWEEP_JOINT, sweep_angle=math.pi, max_window=100.0)
    ranges = np.full(spec.HOKUYO.beams, 2.0)
    ranges[::2] = np.inf
    centre = spec.STOW_POSE[spec.SWEEP_JOINT]
    clouds = []
    for k in range(81):   # 0 .. pi in steps of pi/40, then one more
        cfg = dict(spec.STOW_POSE)
        cfg[spec.SWEEP_JOINT] = centre - math.pi / 2 + k * math.pi / 40
        out = st.add(k * 0.025, ranges, spec.HOKUYO.angle_min, spec.HOKUYO.angle_increment, cfg)
        if out is not None:
            clouds.append((k, out))
    assert [k for k, _ in clouds] == [40, 80]
    cloud = clouds[0][1]
    assert len(cloud) == 41 * (spec.HOKUYO.beams // 2)           # finite beams of 41 scans
    h = model.link_pose('hokuyo_link', spec.STOW_POSE)[:3, 3]
    dist = np.sqrt((cloud['x'] - h[0]) ** 2 + (cloud['y'] - h[1]) ** 2 + (cloud['z'] - h[2]) ** 2)
    assert np.allclose(dist, 2.0, atol=1e-4)                       # points 2 m from the sensor, in base_link


def wall_ranges(model, cfg, base, wall_x):
    """A Hokuyo scan at ``cfg`` on a base at ``base`` (odom) of the plane x = ``wall_x`` of odom."""
    sensor = base @ model.transform('hokuyo_link', 'base_link', cfg)
    a = spec.HOKUYO.angle_min + np.arange(spec.HOKUYO.beams) * spec.HOKUYO.angle_increment
    dx = sensor[0, 0] * np.cos(a) + sensor[0, 1] * np.sin(a)
    with np.errstate(divide='ignore'):
        r = (wall_x - sensor[0, 3]) / dx
    return np.where((dx > 1e-3) & (r < 30.0), r, np.inf)


@pytest.mark.parametrize('kind', ['rolling', 'sweep'])
def test_a_cloud_stitched_while_driving_shows_a_wall_where_it_is_now(model, kind):
    """The base drives at 1 m/s towards a wall 4 m ahead while the wrist sweeps for 1 s: every point of the
    cloud is on the wall, seen from where the base is at the newest scan, not smeared along the metre driven."""
    st = RollingStitcher(model, spec.SWEEP_JOINT) if kind == 'rolling' else \
        SweepStitcher(model, spec.SWEEP_JOINT, sweep_angle=math.pi, max_window=100.0)
    centre, wall, out, x = spec.STOW_POSE[spec.SWEEP_JOINT], 4.0, None, 0.0
    for k in range(41):                        # pi of wrist in 1 s, 40 Hz scans, the base at 1 m/s
        cfg = dict(spec.STOW_POSE)
        cfg[spec.SWEEP_JOINT] = centre - math.pi / 2 + k * math.pi / 40
        x = k * 0.025
        base = planar_matrix(x, 0.0, 0.0)
        done = st.add(k * 0.025, wall_ranges(model, cfg, base, wall), spec.HOKUYO.angle_min,
                      spec.HOKUYO.angle_increment, cfg, base)
        out = done if kind == 'sweep' and done is not None else out
    cloud = st.cloud() if kind == 'rolling' else out
    assert len(cloud) > 1000
    assert np.allclose(cloud['x'], wall - x, atol=1e-6), (cloud['x'].min(), cloud['x'].max())


def test_the_self_box_holds_the_robot_at_its_hold_pose_with_a_margin(urdf):
    """The stitcher drops hits inside ``SELF_BOX`` as the robot's own: every link must be in it."""
    import pybullet as p
    cid = p.connect(p.DIRECT)
    try:
        robot = p.loadURDF(ROBOT_URDF, useFixedBase=True, physicsClientId=cid)
        joints = {p.getJointInfo(robot, j, physicsClientId=cid)[1].decode(): j
                  for j in range(p.getNumJoints(robot, physicsClientId=cid))}
        for name, q in spec.STOW_POSE.items():
            p.resetJointState(robot, joints[name], q, physicsClientId=cid)
        x0, x1, y0, y1, z0, z1 = spec.SELF_BOX
        for link in range(-1, p.getNumJoints(robot, physicsClientId=cid)):
            lo, hi = p.getAABB(robot, link, physicsClientId=cid)
            assert x0 + 0.03 <= lo[0] and hi[0] <= x1 - 0.03 and y0 + 0.03 <= lo[1] and hi[1] <= y1 - 0.03 \
                and z0 + 0.03 <= lo[2] and hi[2] <= z1 - 0.03, (link, lo, hi)
    finally:
        p.disconnect(cid)


def test_hits_on_the_robot_itself_are_dropped_before_a_moving_base_could_leave_them_behind(model):
    """A beam that ends on the robot's own body moves with the robot: kept in odom, it would trail behind a
    driving base as an obstacle just outside the footprint. Each scan's own hits go before it is kept."""
    st = RollingStitcher(model, spec.SWEEP_JOINT, self_box=spec.SELF_BOX)
    centre = spec.STOW_POSE[spec.SWEEP_JOINT]
    for k in range(41):
        cfg = dict(spec.STOW_POSE)
        cfg[spec.SWEEP_JOINT] = centre - math.pi / 2 + k * math.pi / 40
        # every beam ends 5 cm from the scanner, on the robot's own arm; nothing else is in sight
        st.add(k * 0.025, np.full(spec.HOKUYO.beams, 0.05), spec.HOKUYO.angle_min, spec.HOKUYO.angle_increment,
               cfg, planar_matrix(k * 0.025, 0.0, 0.0))
    assert len(st.cloud()) == 0
    unfiltered = RollingStitcher(model, spec.SWEEP_JOINT)
    unfiltered.add(0.0, np.full(spec.HOKUYO.beams, 0.05), spec.HOKUYO.angle_min, spec.HOKUYO.angle_increment,
                   dict(spec.STOW_POSE), planar_matrix(0.0, 0.0, 0.0))
    assert len(unfiltered.cloud()) == spec.HOKUYO.beams       # what the filter takes away


def test_cli_rejects_unknown_device_and_mode(capsys):
    from vaultbot_sim.cli import main
    for argv in (['unplug', 'kinect'], ['unplug', 'd435', '--mode', 'explode'], ['plug']):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'kinect'" in err and "invalid choice: 'explode'" in err


def test_cli_reports_sim_not_running():
    # no master on this port: a clear error and exit code 1, in a subprocess to keep our env clean
    import socket
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
    env = dict(__import__('os').environ, ROS_MASTER_URI=f'http://127.0.0.1:{port}')
    r = subprocess.run([sys.executable, '-m', 'vaultbot_sim.cli', 'status'], env=env, capture_output=True,
                       text=True, timeout=30)
    assert r.returncode == 1
    assert 'not running' in r.stderr


def test_a_robots_frame_prefix_and_origin_are_checked_and_named_when_wrong():
    from vaultbot_sim.sim_node import frame_prefix, origin_matrix
    assert frame_prefix('') == '' and frame_prefix(None) == ''
    assert frame_prefix('vaultbot_2') == 'vaultbot_2/' == frame_prefix('/vaultbot_2/')
    with pytest.raises(ValueError, match="~frame_prefix '2 bots'"):
        frame_prefix('2 bots')
    m = origin_matrix([1.0, 8.0, math.pi / 2])
    assert np.allclose(m @ [1.0, 0.0, 0.0, 1.0], [1.0, 9.0, 0.0, 1.0])    # x of the robot's world -> +y here
    for bad in ([1.0, 2.0], 'north', [0.0, float('nan'), 0.0]):
        with pytest.raises(ValueError, match='~origin'):
            origin_matrix(bad)
