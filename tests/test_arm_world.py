"""An arm kept off the world (issue 51): an arm goal whose way reaches into the map's obstacles is refused, and a
servo stream toward them halts before contact. The rule alone (``world_clearance.py``), then across processes in a
world whose box stands where the left arm can reach, judged by the simulation's ground truth."""
import time

import numpy as np
import pytest
import rospy
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from temoto_core.action_client import TrackingActionClient
from temoto_robot_manager.interface import RobotManagerInterface
from temoto_robot_manager.manipulation import servo as servo_rules
from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics
from temoto_robot_manager.manipulation.servo import Servo
from temoto_robot_manager.manipulation.world_clearance import WorldClearance
from temoto_robot_manager.msg import MoveArmAction, MoveArmGoal, MoveArmResult
from temoto_testing import made_interfaces, wait_for, wait_receiving
from temoto_testing.sensor_manager import managers_idle, start_robot_stack
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel, quat_from_matrix
from vaultbot_sim.msg import ArmState, Contact
from vaultbot_sim.spec import ARM_JOINTS, STOW_POSE

HANG = 60.0
LEFT = ['left_%s_joint' % j for j in ARM_JOINTS]
STOW = [STOW_POSE[j] for j in LEFT]
MODEL = TreeModel(ROBOT_URDF)
# the left arm turned out to its side: the tool 0.27 m beyond the driving outline's side (y 0.67 m)
REACH = [q + d for q, d in zip(STOW, (1.2, 0.0, 0.6, 0.0, 0.0, 0.0))]
BOX = 0.16                       # m: the box's side, around where REACH puts the tool


def tool(q):
    return MODEL.link_pose('left_tool0', dict(STOW_POSE, **dict(zip(LEFT, q))))


# -------------------------------------------------------------------------------------------------- the rule
def grid_with(cells, resolution=0.05, size=40):
    """A size x size map from (-1, -1) with ``cells`` (row, col) occupied."""
    data = np.zeros((size, size), dtype=np.int8)
    for i, j in cells:
        data[i, j] = 100
    world = WorldClearance(0.05)
    world.set_map((-1.0, -1.0), resolution, size, size, data.ravel())
    return world


def test_a_point_within_the_margin_of_an_obstacle_touches_and_one_above_the_band_does_not():
    world = grid_with([(20, 30)])                   # the cell from (0.50, 0.00) to (0.55, 0.05)
    here = np.eye(4)
    assert world.touch(np.array([[0.40, 0.02, 1.0]]), here) is None, '10 cm away: clear'
    why = world.touch(np.array([[0.40, 0.02, 1.0], [0.47, 0.02, 1.0]]), here)
    assert why is not None and '(0.47, 0.02), 1.00 m up' in why and 'keeps 0.05 m clear' in why, why
    assert world.touch(np.array([[0.52, 0.02, 2.5]]), here) is None, 'above what a map marks'
    moved = np.eye(4)
    moved[:3, 3] = (0.1, 0.0, 0.0)                  # the arm's base 10 cm on: the same point now touches
    assert world.touch(np.array([[0.40, 0.02, 1.0]]), moved) is not None
    assert WorldClearance(0.05).touch(np.array([[0.5, 0.0, 1.0]]), here) is None, 'no map: nothing to check'
    with pytest.raises(ValueError, match='margin'):
        WorldClearance(0.0)


def test_the_servo_nears_the_world_slowly_and_halts_with_its_margin_kept_between_checks():
    """The tool servoed at the box, the world checked one step in five (as the node does): within 2 cm of the margin
    the arm moves at a fifth of its speed or less, so that a hold passed on late stops it short, and once halted no
    step between two checks moves it on (before, four steps in five went on at full speed: CI at ed0d926)."""
    with open(ROBOT_URDF) as f:
        kin = ArmKinematics(f.read(), 'left_base_link', 'left_tool0', LEFT)
    box = tool(REACH)[:3, 3]
    resolution, size = 0.02, 200                                 # a 4 m map around base_link
    data = np.zeros((size, size), dtype=np.int8)
    lo = np.floor((box[:2] - BOX / 2 + 2.0) / resolution).astype(int)
    hi = np.ceil((box[:2] + BOX / 2 + 2.0) / resolution).astype(int)
    data[lo[1]:hi[1], lo[0]:hi[0]] = 100
    world = WorldClearance(0.05, reach=0.05 + servo_rules.WORLD_SLOW)
    world.set_map((-2.0, -2.0), resolution, size, size, data.ravel())
    base = MODEL.link_pose('left_base_link', STOW_POSE)
    servo = Servo(kin, 0.008, world=lambda q: world.free(kin.skeleton(q), base))
    q, target, halts = list(STOW), tool(REACH), 0
    near = []                                                    # (free distance, fastest point's speed)
    for k in range(1500):                                        # 12 s of steps at most
        step = servo.step(q, np.linalg.inv(base) @ target, check=k % 5 == 0)
        free = world.free(kin.skeleton(q), base)
        if free is not None and free[0] < 0.02 and not step.halted:
            ahead = kin.skeleton(np.array(q) + np.array(step.velocities) * 0.01)
            near.append((free[0], np.max(np.linalg.norm(ahead - kin.skeleton(q), axis=1)) / 0.01))
        if step.halted:
            assert 'would touch the world' in step.why, step.why
            halts += 1
            if halts >= 10:
                break
        q = step.positions
    assert halts >= 10, 'the servo never halted for the world'
    assert world.touch(kin.skeleton(q), base) is None, 'the arm came within its margin'
    fastest = max((v for _, v in near), default=0.0)
    assert fastest <= 0.02 / servo_rules.WORLD_SLOW * servo_rules.MAX_LINEAR * 1.5, 'within 2 cm of the margin at %.3f m/s' % fastest


# -------------------------------------------------------------------------------------------- across processes
def box_world(path, centre):
    x, y = centre
    link = lambda name, geometry, z: (                                                  # noqa: E731
        '<link name="%s"><inertial><origin xyz="0 0 0"/><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" '
        'iyz="0" izz="0"/></inertial><visual><origin xyz="0 0 %s"/><geometry>%s</geometry></visual><collision>'
        '<origin xyz="0 0 %s"/><geometry>%s</geometry></collision></link>' % (name, z, geometry, z, geometry))
    joint = lambda name, xyz: ('<joint name="%s_joint" type="fixed"><parent link="world"/><child link="%s"/>'   # noqa
                               '<origin xyz="%s"/></joint>' % (name, name, xyz))
    path.write_text('<?xml version="1.0"?><robot name="box_world"><link name="world"/>%s%s%s%s</robot>' % (
        link('floor', '<box size="20 20 0.05"/>', -0.025), joint('floor', '0 0 0'),
        link('box', '<box size="%s %s 1.2"/>' % (BOX, BOX), 0.6), joint('box', '%s %s 0' % (x, y))))
    return str(path)


@pytest.fixture(scope='module')
def left_arm(rospy_client, module_procs, tmp_path_factory):
    at = tool(REACH)[:3, 3]
    world = box_world(tmp_path_factory.mktemp('world') / 'box_world.urdf', (at[0], at[1]))
    module_procs.robot_manager = start_robot_stack(module_procs, tmp_path_factory.mktemp('er_logs'), world=world,
                                                   hand_motion=False)
    with made_interfaces(RobotManagerInterface) as make:
        rm = make()
        robot = rm.load_robot(['manipulation'], on_status=lambda event: None)
        client = TrackingActionClient('/left_arm/move_arm', MoveArmAction)
        assert client.wait_for_server(rospy.Duration(HANG)), 'the left arm\'s manipulator'
        yield client
        rm.release(robot.resource_id)
    managers_idle(('temoto_robot_manager', 'temoto_sensor_manager', 'temoto_er_manager'), timeout=30)


def run(client, goal):
    client.send_goal(goal)
    assert client.wait_for_result(rospy.Duration(HANG)), 'the goal never ended'
    return client.get_state(), client.get_result(), client.get_goal_status_text()


def test_an_arm_goal_into_the_world_is_refused_naming_it_and_nothing_moves(left_arm, collect):
    states = collect('/vaultbot_sim/arm_states', ArmState)
    wait_receiving([states.sub], HANG, 'the arms\' states')
    wait_for(lambda: states.last(), HANG, 'the first state')
    sent = time.monotonic()
    state, result, text = run(left_arm, MoveArmGoal(joint_positions=REACH, speed_scale=0.5))
    assert state == GoalStatus.REJECTED, text
    assert result.error_code == MoveArmResult.WORLD_COLLISION and 'touches the world' in result.error_string, \
        result.error_string
    assert "the map's obstacle at" in result.error_string, result.error_string
    moved = [m for m, t in zip(list(states.msgs), list(states.times)) if t > sent and m.arm == 'left_arm'
             and m.commanded_speed > 0.0]
    assert not moved, 'the refused goal moved the arm'
    # a goal that keeps clear of the box runs: the check refuses the world, not every reach
    clear = [q + (0.3 if k == 0 else 0.0) for k, q in enumerate(STOW)]
    state, _, text = run(left_arm, MoveArmGoal(joint_positions=clear, speed_scale=0.5))
    assert state == GoalStatus.SUCCEEDED, text
    state, _, text = run(left_arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text


def test_a_servo_stream_toward_the_world_halts_before_contact(left_arm, collect):
    """The tool servoed along the way to the box: the servo halts (``servo_status`` says the world), and the sim
    reports no contact of the arm with the box."""
    status = collect('/left_arm/servo_status', String)
    contacts = collect('/vaultbot_sim/contacts', Contact)
    joints = collect('/joint_states', JointState)
    wait_receiving([joints.sub, contacts.sub], HANG, 'the sim')
    wait_for(lambda: joints.last(), HANG, 'the joint states')
    pub = rospy.Publisher('/left_arm/servo_target', PoseStamped, queue_size=5)
    wait_for(lambda: pub.get_num_connections() > 0, HANG, 'the manipulator to subscribe to the servo targets')
    start, goal = tool(STOW), tool(REACH)
    for k in range(250):                                  # 5 s at 50 Hz: from the stowed pose into the box
        f = min(1.0, k / 200.0)
        target = goal.copy()
        target[:3, 3] = start[:3, 3] + f * (goal[:3, 3] - start[:3, 3])
        msg = PoseStamped()
        msg.header.frame_id, msg.header.stamp = 'base_link', rospy.Time.now()
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = target[:3, 3]
        (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
         msg.pose.orientation.w) = quat_from_matrix(start)
        pub.publish(msg)
        if any('would touch the world' in m.data for m in status.msgs):
            break
        time.sleep(0.02)                                  # the stream's own pace
    pub.unregister()
    halted = [m.data for m in status.msgs if 'would touch the world' in m.data]
    assert halted, 'the servo never halted for the world: %s' % [m.data for m in status.msgs][-5:]
    # judged once the arm rests: a contact comes after the halt, if the arm brakes into the box
    first = next(k for k, m in enumerate(status.msgs) if 'would touch the world' in m.data)
    wait_for(lambda: any(m.data.startswith('holding:') for m in list(status.msgs)[first:]), HANG,
             'the arm at rest after the halt')
    touched = [c for c in contacts.msgs if c.object_link == 'box']
    assert not touched, 'the arm touched the box: %s' % touched[0]
    here = dict(zip(joints.last().name, joints.last().position))
    gap = np.linalg.norm(tool([here[j] for j in LEFT])[:2, 3] - goal[:2, 3])
    assert gap > BOX / 2, 'the tool stopped %.3f m from the box\'s centre: inside it' % gap
    state, _, text = run(left_arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text
