"""Arm goals and servoing across processes: the Robot Manager loads the VaultBot's manipulation, whose parts are
each arm's controller and manipulator; goals go through ``<arm>/move_arm`` and targets through
``<arm>/servo_target``, as an action or an operator's hand would send them. Judged by the sim's ground truth
(joint states and ``vaultbot_sim/arm_states``)."""
import math
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import rospy
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from temoto_robot_manager.manipulation.arm_kinematics import pose_error
from temoto_robot_manager.msg import MoveArmAction, MoveArmActionResult, MoveArmGoal, MoveArmResult
from temoto_robot_manager.interface import RobotManagerInterface
from temoto_robot_manager.manipulation.manipulator_node import REST_RAD_S
from temoto_testing import made_interfaces, wait_for, wait_receiving
from temoto_testing.motion import ARM_CLIENT
from temoto_testing.sensor_manager import er_processes, managers_idle, start_robot_manager, start_robot_stack
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel, quat_from_matrix
from vaultbot_sim.msg import ArmState
from vaultbot_sim.spec import ARM_JOINTS, STOW_POSE
from temoto_core.action_client import TrackingActionClient

HANG = 60.0
LEFT = ['left_%s_joint' % j for j in ARM_JOINTS]
STOW = [STOW_POSE[j] for j in LEFT]
MODEL = TreeModel(ROBOT_URDF)


@pytest.fixture(scope='module')
def stack(rospy_client, module_procs, tmp_path_factory):
    module_procs.robot_manager = start_robot_stack(module_procs, tmp_path_factory.mktemp('er_logs'))
    return module_procs


@pytest.fixture(scope='module')
def arm(stack):
    """The VaultBot's manipulation, held for the module: the left arm's MoveArm client."""
    with made_interfaces(RobotManagerInterface) as make:
        rm = make()
        robot = rm.load_robot(['manipulation'], on_status=lambda event: None)   # a part's failure: tested below
        assert {'manipulation.left_arm.manipulator', 'manipulation.right_arm.manipulator'} <= set(robot.parts)
        manager = stack.robot_manager
        client = TrackingActionClient('/left_arm/move_arm', MoveArmAction)
        assert client.wait_for_server(rospy.Duration(HANG)), 'the left arm\'s manipulator'
        yield client
        if stack.robot_manager is manager:      # a test that kills the manager takes the hold with it
            rm.release(robot.resource_id)
    managers_idle(('temoto_robot_manager', 'temoto_sensor_manager', 'temoto_er_manager'), timeout=30)


@pytest.fixture
def truth(collect, arm):
    joints = collect('/joint_states', JointState)
    states = collect('/vaultbot_sim/arm_states', ArmState)
    wait_receiving([joints.sub, states.sub], HANG, 'the sim\'s states')
    wait_for(lambda: joints.last() and states.last(), HANG, 'the first states')
    return joints, states


def here(joints):
    msg = joints.last()
    pos = dict(zip(msg.name, msg.position))
    return [pos[j] for j in LEFT]


def tool_in_base(q):
    cfg = dict(STOW_POSE, **dict(zip(LEFT, q)))
    return MODEL.link_pose('left_tool0', cfg)        # base_link is the model's root


def target_message(target) -> PoseStamped:
    """A servo target (a 4 x 4 pose in base_link) as the manipulator takes it, stamped now."""
    msg = PoseStamped()
    msg.header.frame_id, msg.header.stamp = 'base_link', rospy.Time.now()
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = target[:3, 3]
    (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
     msg.pose.orientation.w) = quat_from_matrix(target)
    return msg


RESULTS = []          # every left-arm MoveArm result on the wire, to explain a result a client did not get
_RESULTS_SUB = []


def _on_result(msg):
    RESULTS.append((msg.status.goal_id.id, msg.status.status, msg.status.text))


def run(client, goal):
    if not _RESULTS_SUB:
        _RESULTS_SUB.append(rospy.Subscriber('/left_arm/move_arm/result', MoveArmActionResult, _on_result))
    client.send_goal(goal)
    if not client.wait_for_result(rospy.Duration(HANG)):
        goal_id = client.gh.comm_state_machine.action_goal.goal_id.id if client.gh else '?'
        raise AssertionError('no result for %s (client state %s, comm state %s); on the wire: %s' % (
            goal_id, client.get_state(), client.gh.get_comm_state() if client.gh else '?',
            [r for r in RESULTS if r[0] == goal_id] or 'nothing for it; last %s' % RESULTS[-3:]))
    return client.get_state(), client.get_result(), client.get_goal_status_text()


def settled(joints):
    """Where the arm is once it has stopped (two readings 0.2 s apart agree)."""
    def still():
        a = here(joints)
        t = joints.last().header.stamp
        wait_for(lambda: joints.last().header.stamp.to_sec() > t.to_sec() + 0.2, HANG, 'a later state')
        b = here(joints)
        return b if max(abs(x - y) for x, y in zip(a, b)) < 1e-4 else None
    return wait_for(still, HANG, 'the arm at rest')


def test_named_joint_and_pose_goals_put_the_arm_there(arm, truth):
    joints, _ = truth
    target = list(STOW)
    target[0] += 0.4
    target[3] -= 0.3
    state, result, text = run(arm, MoveArmGoal(joint_positions=target, speed_scale=0.8))
    assert state == GoalStatus.SUCCEEDED and result.error_code == MoveArmResult.SUCCESS, text
    assert max(abs(a - b) for a, b in zip(settled(joints), target)) < 0.02
    # a pose of the tool in base_link: 8 cm forward and 6 cm up from the stowed pose's
    goal_m = tool_in_base(STOW)
    goal_m[:3, 3] += [0.08, 0.0, 0.06]
    pose = PoseStamped()
    pose.header.frame_id = 'base_link'
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = goal_m[:3, 3]
    (pose.pose.orientation.x, pose.pose.orientation.y, pose.pose.orientation.z,
     pose.pose.orientation.w) = quat_from_matrix(goal_m)
    state, result, text = run(arm, MoveArmGoal(pose=pose))
    assert state == GoalStatus.SUCCEEDED, text
    dp, da = pose_error(tool_in_base(settled(joints)), goal_m)
    assert dp < 0.01 and da < 0.02, (dp, da)            # within the controller's 0.01 rad goal tolerance
    state, _, text = run(arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text
    assert max(abs(a - b) for a, b in zip(settled(joints), STOW)) < 0.02


@pytest.mark.parametrize('goal, code, words', [
    (MoveArmGoal(), MoveArmResult.INVALID_GOAL, 'give exactly one of pose, named_pose and joint_positions'),
    (MoveArmGoal(named_pose='wave'), MoveArmResult.INVALID_GOAL, "named_pose 'wave' is not a pose of this arm"),
    (MoveArmGoal(joint_positions=[0.0] * 5), MoveArmResult.INVALID_GOAL, 'joint_positions has 5 values'),
    (MoveArmGoal(joint_positions=STOW[:5] + [float('nan')]), MoveArmResult.INVALID_GOAL, 'is nan, not a finite'),
    (MoveArmGoal(joint_positions=STOW, speed_scale=2.0), MoveArmResult.INVALID_GOAL, 'speed_scale 2.0'),
    ('far', MoveArmResult.NO_SOLUTION, 'pose: no joint positions reach the target'),
    ('frame', MoveArmResult.INVALID_GOAL, "pose.header.frame_id 'nowhere': no transform"),
    ('fold', MoveArmResult.SELF_COLLISION, 'touches the robot\'s own body'),
])
def test_a_goal_that_cannot_be_is_rejected_naming_why_and_nothing_moves(arm, truth, goal, code, words):
    joints, states = truth
    if goal in ('far', 'frame'):
        pose = PoseStamped()
        pose.header.frame_id = 'base_link' if goal == 'far' else 'nowhere'
        pose.pose.position.x, pose.pose.orientation.w = 3.0, 1.0
        goal = MoveArmGoal(pose=pose)
    elif goal == 'fold':
        folded = list(STOW)
        folded[LEFT.index('left_elbow_joint')] -= 1.4
        goal = MoveArmGoal(joint_positions=folded)
    before = here(joints)
    sent = rospy.Time.now()
    state, result, text = run(arm, goal)
    assert state == GoalStatus.REJECTED and result.error_code == code and words in text, (state, text)
    later = wait_for(lambda: next((m for m in reversed(states.msgs) if m.arm == 'left_arm'
                                   and m.header.stamp > sent), None), HANG, 'a state after the refusal')
    assert later.commanded_speed == 0.0 and max(abs(a - b) for a, b in zip(here(joints), before)) < 1e-6


def test_a_goal_whose_client_dies_stops_the_arm(stack, arm, truth):
    joints, states = truth
    far = list(STOW)
    far[0] += 1.5
    client = stack.command(ARM_CLIENT + ['left_arm'] + [str(v) for v in far] + ['0.3'], 'arm_client')
    try:
        wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'left_arm' and m.speed > 0.2), None), HANG,
                 'the arm moving for the client')
        os.kill(client.pid, signal.SIGKILL)
        killed = rospy.Time.now().to_sec()
        stopped = wait_for(lambda: next((m for m in states.msgs[-30:] if m.arm == 'left_arm'
                                         and m.header.stamp.to_sec() > killed and m.commanded_speed == 0.0), None),
                           HANG, 'the arm commanded to stop')
        assert stopped.header.stamp.to_sec() - killed < 5.0          # generous: catches a hang; the bound: bench
        q = settled(joints)
        assert abs(q[0] - far[0]) > 0.1                               # it stopped on the way
    finally:
        client.stop()
    state, _, text = run(arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text


def test_a_second_goal_preempts_the_first_and_the_arm_goes_to_the_second(arm, truth):
    joints, _ = truth
    far = list(STOW)
    far[0] += 1.2
    arm.send_goal(MoveArmGoal(joint_positions=far, speed_scale=0.2))
    wait_for(lambda: abs(here(joints)[0] - STOW[0]) > 0.05, HANG, 'the arm moving to the first goal')
    second = TrackingActionClient('/left_arm/move_arm', MoveArmAction)
    assert second.wait_for_server(rospy.Duration(HANG))
    state, _, text = run(second, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text
    assert arm.wait_for_result(rospy.Duration(HANG))
    assert arm.get_state() == GoalStatus.PREEMPTED and 'preempted by goal' in arm.get_goal_status_text()
    assert max(abs(a - b) for a, b in zip(settled(joints), STOW)) < 0.02


def test_a_burst_of_goals_each_preempting_the_last_ends_every_one(arm, truth):
    """Each goal comes while another runs: the manipulator plans it holding the action server's lock while its
    own loop watches the running goal. Before the watch read the goal's id without that lock, the two locks
    deadlocked: the goal never ended, and the manipulator answered nothing more."""
    joints, _ = truth
    clients = [TrackingActionClient('/left_arm/move_arm', MoveArmAction) for _ in range(6)]
    for client in clients:
        assert client.wait_for_server(rospy.Duration(HANG))
    for k, client in enumerate(clients):
        far = list(STOW)
        far[0] += 0.6 if k % 2 else -0.6
        client.send_goal(MoveArmGoal(joint_positions=far, speed_scale=0.2))
        wait_for(lambda: client.get_state() == GoalStatus.ACTIVE or client.get_state() == GoalStatus.REJECTED,
                 HANG, 'goal %d accepted' % k)
        wait_for(lambda: abs(here(joints)[0] - STOW[0]) > 0.02 or k == 0, HANG, 'the arm moving')
    for k, client in enumerate(clients):
        assert client.wait_for_result(rospy.Duration(HANG)), 'goal %d never ended' % k
    assert [c.get_state() for c in clients] == [GoalStatus.PREEMPTED] * 5 + [GoalStatus.SUCCEEDED]
    state, _, text = run(arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text


def test_the_tool_follows_a_servo_stream_and_the_arm_holds_when_it_falls_silent(arm, truth, collect):
    from trajectory_msgs.msg import JointTrajectory
    joints, states = truth
    commands = collect('/left_arm/servo_command', JointTrajectory)
    start = tool_in_base(settled(joints))
    pub = rospy.Publisher('/left_arm/servo_target', PoseStamped, queue_size=5)
    wait_for(lambda: pub.get_num_connections() > 0, HANG, 'the manipulator to subscribe to the servo targets')
    target = start.copy()
    period, sent = 0.02, 0
    stamps = set()
    for k in range(150):                          # 3 s: the target moves 10 cm along y at 5 cm/s, then waits
        target[1, 3] = start[1, 3] + min(0.10, 0.05 * k * period)
        msg = target_message(target)
        stamps.add(msg.header.stamp)
        pub.publish(msg)
        sent += 1
        time.sleep(period)                        # the stream's own pace, as a hand tracker sends
    silent = rospy.Time.now().to_sec()
    dp, _ = pose_error(tool_in_base(here(joints)), target)
    assert dp < 0.01, dp
    held = wait_for(lambda: next((m for m in states.msgs[-30:] if m.arm == 'left_arm'
                                  and m.header.stamp.to_sec() > silent and m.speed == 0.0), None), HANG,
                    'the arm at rest after the stream')
    assert held.header.stamp.to_sec() - silent < 5.0
    steps = [m for m in commands.msgs if m.points and m.points[0].positions]
    assert len(steps) > 100, 'the servo commands made from the stream'
    assert all(m.header.stamp in stamps for m in steps), 'each servo command carries the stamp of its target'
    pub.unregister()
    state, _, text = run(arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text


def test_a_streamer_s_hold_stops_the_arm_at_once_naming_why(arm, truth, collect):
    """A streamer that knows its input is gone (a hand tracker's late sample) holds the arm through
    <arm>/servo_hold rather than falling silent for the stream's timeout; the status names its reason:
    "stopping" as the hold is sent, "holding" only once the arm is at rest (a streamer hands the arm on when
    it hears it: chaos, seed 17, step 2157)."""
    from temoto_core.msg import MotionStatus
    joints, states = truth
    status = collect('/left_arm/servo_status', String)
    typed = collect('/left_arm/motion_status', MotionStatus)
    hold = rospy.Publisher('/left_arm/servo_hold', String, queue_size=1)
    wait_for(lambda: hold.get_num_connections() > 0, HANG, 'the manipulator to subscribe to holds')
    stop = threading.Event()
    stream = stream_targets('left_arm', tool_in_base(settled(joints)), stop)
    try:
        wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'left_arm' and m.commanded_speed > 0.0),
                              None), HANG, 'the left arm following the stream')
    finally:
        stop.set()
        stream.join(HANG)
    told = rospy.Time.now().to_sec()
    hold.publish(String('no hand sample for 25 ms'))
    wait_for(lambda: next((m for m in states.msgs[-30:] if m.arm == 'left_arm' and m.header.stamp.to_sec() > told
                           and m.commanded_speed == 0.0), None), HANG, 'the left arm commanded to hold')
    stopped = wait_for(lambda: next((m for m in typed.msgs if m.state == MotionStatus.STOPPED
                                     and m.text == 'no hand sample for 25 ms'), None), HANG, 'the typed status')
    assert (stopped.actuator, stopped.reason) == ('left_arm', 'ended'), stopped
    assert any(m.state == MotionStatus.MOVING for m in typed.msgs[:typed.msgs.index(stopped)]), typed.msgs
    said = wait_for(lambda: next((k for k, m in enumerate(status.msgs)
                                  if m.data == 'holding: no hand sample for 25 ms'), None), HANG,
                    'the status to name the streamer\'s reason, not the stream\'s timeout')
    words = [m.data for m in status.msgs[:said]]
    assert 'stopping: no hand sample for 25 ms' in words, words
    # the sim's samples stamped after "holding" was heard were all taken after the manipulator said it
    heard = rospy.Time.now().to_sec() - (time.monotonic() - status.times[said])
    wait_for(lambda: any(m.arm == 'left_arm' and m.header.stamp.to_sec() > heard + 0.1 for m in states.msgs[-30:]),
             HANG, 'the sim\'s states after "holding"')
    moving = [m.speed for m in list(states.msgs) if m.arm == 'left_arm' and m.header.stamp.to_sec() >= heard
              and m.speed >= REST_RAD_S]
    assert not moving, 'the arm still moved after the manipulator said it held: %s rad/s' % moving
    hold.unregister()
    state, _, text = run(arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text


def test_stop_mid_trajectory_holds_the_arm_and_says_why_typed(arm, truth, collect):
    """The operator's stop while a trajectory runs: the arm's gate cancels it at once (the controller holds), the
    goal ends ABORTED naming the stop, and ``<arm>/motion_status`` says STOPPED with the code ``halted``."""
    from temoto_core.msg import MotionStatus
    joints, states = truth
    typed = collect('/left_arm/motion_status', MotionStatus)
    halt = rospy.Publisher('/temoto/halt', String, queue_size=5, tcp_nodelay=True)
    wait_for(lambda: halt.get_num_connections() > 0, HANG, 'the manipulator listening for a stop')
    far = [q + (0.6 if k == 0 else 0.0) for k, q in enumerate(settled(joints))]
    arm.send_goal(MoveArmGoal(joint_positions=far, speed_scale=0.3))
    wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'left_arm' and m.commanded_speed > 0.0), None),
             HANG, 'the left arm moving')
    wait_for(lambda: typed.last() is not None and typed.last().state == MotionStatus.MOVING, HANG, 'said moving')
    halted = rospy.Time.now().to_sec()
    halt.publish(String('test stop'))
    assert arm.wait_for_result(rospy.Duration(HANG)), 'the goal never ended'
    assert arm.get_state() == GoalStatus.ABORTED and 'halted: test stop' in arm.get_goal_status_text()
    said = wait_for(lambda: typed.last() if typed.last().state == MotionStatus.STOPPED else None, HANG, 'stopped')
    assert (said.actuator, said.reason, said.text) == ('left_arm', 'halted', 'halted: test stop'), said
    rest = wait_for(lambda: next((m for m in states.msgs[-30:] if m.arm == 'left_arm'
                                  and m.header.stamp.to_sec() > halted and m.speed == 0.0), None), HANG, 'at rest')
    assert abs(here(joints)[0] - far[0]) > 0.05, 'the arm stopped on its way, not at the goal'
    assert rest.header.stamp.to_sec() - halted < 5.0
    halt.unregister()
    state, _, text = run(arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text


def test_a_servo_stream_that_goes_on_after_a_stop_does_not_move_the_arm_until_it_pauses(arm, truth, collect):
    """Chaos, history 6, seed 17, step 127: a stream whose sender did not hear the operator's stop went on, and its
    targets, stamped after the stop, moved the arm again 0.1 s later. A stopped stream must pause first."""
    from temoto_core.msg import MotionStatus
    joints, states = truth
    typed = collect('/left_arm/motion_status', MotionStatus)
    halt = rospy.Publisher('/temoto/halt', String, queue_size=5, tcp_nodelay=True)
    wait_for(lambda: halt.get_num_connections() > 0, HANG, 'the manipulator listening for a stop')
    stop = threading.Event()
    stream = stream_targets('left_arm', tool_in_base(settled(joints)), stop)
    try:
        wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'left_arm' and m.commanded_speed > 0.0),
                              None), HANG, 'the left arm following the stream')
        halt.publish(String('test stop'))
        wait_for(lambda: typed.last() is not None and typed.last().reason == 'halted', HANG, 'the stop heard')
        stopped = rospy.Time.now().to_sec()
        # the stream goes on for a second, stamped after the stop
        wait_for(lambda: states.last().header.stamp.to_sec() > stopped + 1.0, HANG, 'a second of the stream')
    finally:
        stop.set()
        stream.join(HANG)
    moved = [m.commanded_speed for m in list(states.msgs) if m.arm == 'left_arm'
             and m.header.stamp.to_sec() > stopped + 0.05 and m.commanded_speed > 0.0]
    assert not moved, 'the stream moved the arm after the stop: %s rad/s' % moved[:5]
    # a new stream, after a pause, follows again
    stop = threading.Event()
    stream = stream_targets('left_arm', tool_in_base(settled(joints)), stop)
    try:
        wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'left_arm' and m.commanded_speed > 0.0),
                              None), HANG, 'a new stream followed')
    finally:
        stop.set()
        stream.join(HANG)
    halt.unregister()
    state, _, text = run(arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text


def test_a_streamer_s_hold_brakes_the_arm_where_it_is_and_never_pulls_it_back(arm, truth):
    """A hold is a brake, not a position: sent as the joints' positions last seen, it pulled an arm back to
    them, and an arm already given back to its sweep was pulled back at the sweep's speed (seed 17, steps
    1263 and 1509). From the hold on, no joint turns against the way it was going."""
    joints, states = truth
    hold = rospy.Publisher('/left_arm/servo_hold', String, queue_size=1)
    wait_for(lambda: hold.get_num_connections() > 0, HANG, 'the manipulator to subscribe to holds')
    stop = threading.Event()
    stream = stream_targets('left_arm', tool_in_base(settled(joints)), stop)
    try:
        wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'left_arm' and m.speed > 0.02), None),
                 HANG, 'the left arm moving after the stream')
    finally:
        stop.set()
        stream.join(HANG)
    told = rospy.Time.now().to_sec()
    hold.publish(String('a hold, not a position'))
    held = wait_for(lambda: next((m for m in states.msgs[-30:] if m.arm == 'left_arm'
                                  and m.header.stamp.to_sec() > told and m.commanded_speed == 0.0), None), HANG,
                    'the left arm commanded to hold')
    moment = held.header.stamp.to_sec()
    settled(joints)
    samples = [(m.header.stamp.to_sec(), dict(zip(m.name, m.velocity))) for m in list(joints.msgs)
               if all(j in m.name for j in LEFT)]
    before = [v for t, v in samples if t <= moment]
    after = [(t, v) for t, v in samples if t > moment]
    assert before and len(after) >= 10, (len(before), len(after))
    going = {j: before[-1][j] for j in LEFT if abs(before[-1][j]) > 1e-3}
    assert going, 'no joint was moving when the hold came: %s' % before[-1]
    back = [(round(t - moment, 3), j, v[j]) for t, v in after for j, v0 in going.items() if v[j] * v0 < -1e-9]
    assert back == [], 'joints turned back after the hold: %s' % back[:5]
    hold.unregister()
    state, _, text = run(arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text


def test_servo_targets_held_up_on_the_way_are_not_followed_late(arm, truth, collect):
    """Over a link that was cut, TCP keeps a stream's targets and delivers them, seconds late, when the link is
    back (the two-host teleop demo found it): they must not move the arm, since whoever sent them may have let
    go meanwhile. A target sent now is followed."""
    joints, states = truth
    status = collect('/left_arm/servo_status', String)
    start = tool_in_base(settled(joints))
    pub = rospy.Publisher('/left_arm/servo_target', PoseStamped, queue_size=50)
    wait_for(lambda: pub.get_num_connections() > 0, HANG, 'the manipulator to subscribe to the servo targets')
    target = start.copy()
    target[1, 3] += 0.05
    before = len(states.msgs)
    for _ in range(25):                               # a burst, as a healed link delivers what it kept
        late = target_message(target)
        late.header.stamp = rospy.Time.now() - rospy.Duration(3.0)
        pub.publish(late)
    wait_for(lambda: any('refusing servo targets sent' in m.data for m in status.msgs), HANG,
             'the status to say the late targets are refused')
    moved = [m for m in states.msgs[before:] if m.arm == 'left_arm' and m.commanded_speed > 0.0]
    assert moved == [], 'late targets moved the arm'
    wait_for(lambda: pub.publish(target_message(target)) or next(
        (m for m in states.msgs[-5:] if m.arm == 'left_arm' and m.commanded_speed > 0.0), None), HANG,
        'the arm following a target sent now')
    pub.unregister()
    state, _, text = run(arm, MoveArmGoal(named_pose='stow'))
    assert state == GoalStatus.SUCCEEDED, text


def test_temoto_robots_arm_moves_an_arm_and_refuses_what_cannot_be(arm, truth):
    joints, _ = truth
    unknown = temoto('arm', 'tail_arm', 'stow')
    assert unknown.returncode == 2 and "vaultbot has no arm 'tail_arm' (its arms: left_arm, right_arm)" in \
        unknown.stderr, unknown.stderr
    both = temoto('arm', 'left_arm', 'stow', '--joints', '0', '0')
    assert both.returncode == 2 and 'give one of a named POSE, --joints and --pose (given: POSE, --joints)' in \
        both.stderr, both.stderr
    short = temoto('arm', 'left_arm', '--joints', '0.1', '0.2')
    assert short.returncode == 1 and 'refused: joint_positions has 2 values for the 6 joints' in short.stdout, \
        short.stdout + short.stderr
    target = list(STOW)
    target[0] += 0.3
    moved = temoto('arm', 'left_arm', '--joints', *[str(v) for v in target], '--speed', '0.9')
    assert moved.returncode == 0 and 'there' in moved.stdout, moved.stdout + moved.stderr
    assert max(abs(a - b) for a, b in zip(settled(joints), target)) < 0.02
    back = temoto('arm', 'left_arm', 'stow')
    assert back.returncode == 0, back.stdout + back.stderr


def temoto(*args, timeout=120):
    return subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'robots'] + list(args), capture_output=True,
                          text=True, timeout=timeout)


def test_a_controller_that_crashes_mid_goal_aborts_it_naming_the_controller(arm, truth):
    joints, _ = truth
    far = list(STOW)
    far[0] -= 1.2
    arm.send_goal(MoveArmGoal(joint_positions=far, speed_scale=0.3))
    wait_for(lambda: abs(here(joints)[0] - STOW[0]) > 0.1, HANG, 'the arm moving')
    pid = next(p['pid'] for p in er_processes() if 'left_arm_controller' in str(p['command']))
    os.kill(pid, signal.SIGKILL)
    assert arm.wait_for_result(rospy.Duration(HANG))
    assert arm.get_state() == GoalStatus.ABORTED
    assert arm.get_result().error_code == MoveArmResult.CONTROLLER_FAILED, arm.get_goal_status_text()
    assert 'controller' in arm.get_goal_status_text()
    q = settled(joints)
    assert abs(q[0] - far[0]) > 0.1 and math.isfinite(q[0])


def test_the_arm_holds_at_once_when_the_robot_manager_dies_mid_goal(stack, truth):
    """The right arm (its controller is whole): the manager that started its manipulator is SIGKILLed while a goal
    runs; the goal ends naming it and the arm holds, before any respawn."""
    _, states = truth
    right = TrackingActionClient('/right_arm/move_arm', MoveArmAction)
    assert right.wait_for_server(rospy.Duration(HANG))
    far = [STOW_POSE['right_%s_joint' % j] for j in ARM_JOINTS]
    far[0] += 1.2
    right.send_goal(MoveArmGoal(joint_positions=far, speed_scale=0.3))
    wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'right_arm' and m.speed > 0.2), None), HANG,
             'the right arm moving')
    os.kill(stack.robot_manager.pid, signal.SIGKILL)
    killed = rospy.Time.now().to_sec()
    held = wait_for(lambda: next((m for m in states.msgs[-30:] if m.arm == 'right_arm'
                                  and m.header.stamp.to_sec() > killed and m.commanded_speed == 0.0), None),
                    HANG, 'the right arm commanded to hold')
    assert held.header.stamp.to_sec() - killed < 5.0               # generous: catches a hang
    assert right.wait_for_result(rospy.Duration(HANG))
    assert right.get_state() == GoalStatus.ABORTED
    assert 'the Robot Manager that started this manipulator is gone' in right.get_goal_status_text()
    # the manager's parts go with it (the ER Manager sees its consumer die); a new manager starts clean
    wait_for(lambda: not any('manipulator' in str(p['command']) for p in er_processes()), HANG,
             'the manipulators released with their dead manager')
    stack.robot_manager = start_robot_manager(stack)


def stream_targets(arm, start, stop: threading.Event, bound_s: float = 20.0) -> threading.Thread:
    """Servo targets for ``arm`` at 50 Hz, sliding along y at 2 cm/s from ``start``, until ``stop``."""
    pub = rospy.Publisher('/%s/servo_target' % arm, PoseStamped, queue_size=5)
    wait_for(lambda: pub.get_num_connections() > 0, HANG, 'the manipulator to subscribe to the servo targets')

    def run():
        target = start.copy()
        for k in range(int(bound_s / 0.02)):
            if stop.wait(0.02):               # the stream's own pace, as a hand tracker sends
                break
            target[1, 3] = start[1, 3] + 0.02 * k * 0.02
            pub.publish(target_message(target))
        pub.unregister()
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_a_servo_stream_holds_at_once_when_the_robot_manager_dies_while_it_goes_on(stack, collect, manager_back):
    """The manager that started the manipulators is SIGKILLed while the right arm follows a servo stream: the arm
    holds before any respawn, while its stream still goes on (not a deadman later)."""
    states = collect('/vaultbot_sim/arm_states', ArmState)
    joints = collect('/joint_states', JointState)
    status = collect('/right_arm/servo_status', String)
    with made_interfaces(RobotManagerInterface) as make:
        make().load_robot(['manipulation'], on_status=lambda event: None)
        wait_receiving([states.sub, joints.sub, status.sub], HANG, 'the arm states, joints and servo status')
        last = wait_for(joints.last, HANG, 'the joint states')
        tool = MODEL.link_pose('right_tool0', dict(STOW_POSE, **dict(zip(last.name, last.position))))
        stop = threading.Event()
        stream = stream_targets('right_arm', tool, stop)
        try:
            wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'right_arm' and m.commanded_speed > 0.0),
                                  None), HANG, 'the right arm following the stream')
            os.kill(stack.robot_manager.pid, signal.SIGKILL)
            killed = rospy.Time.now().to_sec()
            held = wait_for(lambda: next((m for m in states.msgs[-40:] if m.arm == 'right_arm'
                                          and m.header.stamp.to_sec() > killed and m.commanded_speed == 0.0), None),
                            HANG, 'the right arm commanded to hold')
            assert stream.is_alive(), 'the arm held only when its stream ended'
        finally:
            stop.set()
            stream.join(HANG)
        assert held.header.stamp.to_sec() - killed < 5.0               # generous: catches a hang
        assert any('Robot Manager that started this manipulator is away' in m.data for m in status.msgs)


@pytest.fixture
def manager_back(stack):
    """A test that SIGKILLs the Robot Manager: once it has ended, its parts are released and a new one serves."""
    yield
    wait_for(lambda: not any('manipulator' in str(p['command']) for p in er_processes()), HANG,
             'the manipulators released with their dead manager')
    stack.robot_manager = start_robot_manager(stack)


def right_arm_moving(make, truth, on_status):
    """The robot's manipulation loaded, and a goal of the right arm's 1.2 rad away on its shoulder, moving; its
    client, the arm's joints and the goal's positions."""
    joints, states = truth
    make().load_robot(['manipulation'], on_status=on_status)
    right = TrackingActionClient('/right_arm/move_arm', MoveArmAction)
    assert right.wait_for_server(rospy.Duration(HANG))
    names = ['right_%s_joint' % j for j in ARM_JOINTS]
    here = dict(zip(joints.last().name, joints.last().position))
    far = [here[j] for j in names]
    far[0] += 1.2 if far[0] < 0.0 else -1.2
    right.send_goal(MoveArmGoal(joint_positions=far, speed_scale=0.3))
    wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'right_arm' and m.speed > 0.2), None), HANG,
             'the right arm moving')
    return right, names, far


def test_a_manipulator_stopped_mid_goal_ends_the_goal_naming_it_and_the_arm_holds(stack, truth):
    """A stop signal (the ER Manager's unload: most often its manager died, and the signal may come before the
    manipulator's loop has seen the death) ends the goal ABORTED naming it, and the arm holds, before the node
    shuts down. Before, the node shut down at once and the goal's client heard nothing."""
    _, states = truth
    failures = []
    with made_interfaces(RobotManagerInterface) as make:
        right, _, _ = right_arm_moving(make, truth, failures.append)
        pid = next(p['pid'] for p in er_processes() if 'right_arm_manipulator' in str(p['command']))
        os.kill(pid, signal.SIGINT)
        stopped = rospy.Time.now().to_sec()
        assert right.wait_for_result(rospy.Duration(HANG)), 'the goal never ended'
        assert right.get_state() == GoalStatus.ABORTED, right.get_goal_status_text()
        assert right.get_goal_status_text() == 'the manipulator was stopped: the arm holds'
        wait_for(lambda: next((m for m in states.msgs[-30:] if m.arm == 'right_arm'
                               and m.header.stamp.to_sec() > stopped and m.commanded_speed == 0.0), None),
                 HANG, 'the right arm commanded to hold')
        # the robot FAILED once the node is gone: the next test's load is then a new robot, not this broken one
        wait_for(lambda: any('right_arm_manipulator' in e.message for e in failures), HANG, 'the robot FAILED')


def test_a_manipulator_killed_mid_goal_leaves_no_trajectory_running(stack, truth, collect):
    """Issue 51, hole 2: the manipulator (the client of the controller's trajectory goal) SIGKILLed mid-goal. Its
    controller watched nobody, and ran the trajectory to its end. It now watches its goal's client
    (``temoto_core/goal_holders.py``): the arm holds short of the goal, and the trajectory ends naming the client."""
    from control_msgs.msg import FollowJointTrajectoryActionResult
    joints, states = truth
    results = collect('/right_arm/follow_joint_trajectory/result', FollowJointTrajectoryActionResult)
    with made_interfaces(RobotManagerInterface) as make:
        _, names, far = right_arm_moving(make, truth, lambda event: None)
        pid = next(p['pid'] for p in er_processes() if 'right_arm_manipulator' in str(p['command']))
        killed = rospy.Time.now().to_sec()       # taken before: the controller may hear of the death first
        os.kill(pid, signal.SIGKILL)
        ended = wait_for(lambda: next((r for r in results.msgs if r.header.stamp.to_sec() > killed), None), HANG,
                         'the controller\'s trajectory to end')
        assert ended.status.status == GoalStatus.PREEMPTED, ended.status.text
        assert ended.status.text == 'its client /right_arm_manipulator is gone: holding where it is', ended.status.text
        stopped = wait_for(lambda: next((m for m in states.msgs[-30:] if m.arm == 'right_arm'
                                         and m.header.stamp.to_sec() > killed and m.commanded_speed == 0.0), None),
                           HANG, 'the right arm commanded to hold')
        assert stopped.header.stamp.to_sec() - killed < 5.0          # generous: catches a hang; the bound: bench
        wait_for(lambda: next((m for m in states.msgs[-5:] if m.arm == 'right_arm' and m.header.stamp.to_sec()
                               > stopped.header.stamp.to_sec() and m.speed == 0.0), None), HANG, 'the arm at rest')
        rest = dict(zip(joints.last().name, joints.last().position))
        assert abs(rest[names[0]] - far[0]) > 0.1, 'the arm stopped on its way, not at the trajectory\'s end'
