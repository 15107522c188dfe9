"""The gripper's command gate across processes (issue 51): the Robot Manager starts the gripper's controller and its
gate (``gripper_node.py``); clients send goals to the gate. Every stop of the fingers is the gate's, not the
controller's: the controller is not given the operator's stop, and its goal ends *preempted* (the gate cancelled
it) where it used to end "halted". Judged by the sim's ground truth (``vaultbot_sim/gripper_state``).

The controller here closes at 20 mm/s (a 4.3 s stroke), so that "stopped on the way" holds on a loaded machine."""
import os
import signal

import pytest
import rospy
import yaml
from actionlib_msgs.msg import GoalStatus
from control_msgs.msg import (GripperCommand, GripperCommandAction, GripperCommandActionGoal,
                              GripperCommandActionResult, GripperCommandGoal)
from std_msgs.msg import String

from temoto_core.action_client import TrackingActionClient
from temoto_core.msg import MotionStatus
from temoto_robot_manager.description import GRIPPER_GATE_ACTION
from temoto_robot_manager.interface import RobotManagerInterface
from temoto_robot_manager.paths import DEFAULT_DESCRIPTION
from temoto_testing import made_interfaces, wait_for, wait_receiving
from temoto_testing.motion import GRIPPER_CLIENT
from temoto_testing.sensor_manager import er_processes, managers_idle, start_robot_stack
from vaultbot_sim.msg import GripperState

HANG = 60.0
SLOW = 0.02                      # m/s of the gap
CONTROLLER = '/gripper/gripper_command'
GATE = '/' + GRIPPER_GATE_ACTION


@pytest.fixture(scope='module')
def stack(rospy_client, module_procs, tmp_path_factory):
    with open(DEFAULT_DESCRIPTION) as f:
        described = yaml.safe_load(f)
    gripper = described['robots'][0]['gripper']
    gripper['controller']['args'] = '_speed:=%s' % SLOW
    path = tmp_path_factory.mktemp('descriptions') / 'slow_gripper.yaml'
    path.write_text(yaml.safe_dump(described))
    module_procs.robot_manager = start_robot_stack(module_procs, tmp_path_factory.mktemp('er_logs'),
                                                   descriptions=str(path))
    return module_procs


@pytest.fixture
def gripper(stack, collect):
    """The VaultBot's gripper, held for one test: (the gate's client, the sim's gripper states)."""
    states = collect('/vaultbot_sim/gripper_state', GripperState)
    with made_interfaces(RobotManagerInterface) as make:
        rm = make()
        robot = rm.load_robot(['gripper'], on_status=lambda event: None)
        assert {'gripper.controller', 'gripper.node'} <= set(robot.parts), robot.parts
        client = TrackingActionClient(GATE, GripperCommandAction)
        assert client.wait_for_server(rospy.Duration(HANG)), 'the gripper\'s gate'
        wait_receiving([states.sub], HANG, 'the gripper\'s state')
        wait_for(lambda: states.last(), HANG, 'the gripper\'s state')
        yield client, states
        rm.release(robot.resource_id)
    managers_idle(('temoto_robot_manager', 'temoto_sensor_manager', 'temoto_er_manager'), timeout=30)


def across(states) -> float:
    """A gap across the stroke from wherever the fingers are."""
    return 0.085 if states.last().gap < 0.04 else 0.0


def at_rest_after(states, t: float):
    return wait_for(lambda: next((m for m in states.msgs[-20:] if m.header.stamp.to_sec() > t and m.speed == 0.0),
                                 None), HANG, 'the fingers at rest')


def test_the_robot_s_clients_are_given_the_gate_and_a_goal_runs_through_it(gripper):
    client, states = gripper
    with made_interfaces(RobotManagerInterface) as make:
        info = make().robots()
    assert info[0]['gripper']['action'] == GRIPPER_GATE_ACTION, info[0]['gripper']
    goal = across(states)
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=goal)))
    assert client.wait_for_result(rospy.Duration(HANG)), 'the goal never ended'
    assert client.get_state() == GoalStatus.SUCCEEDED, client.get_goal_status_text()
    assert client.get_result().reached_goal and abs(states.last().gap - goal) < 0.002


def test_a_bad_goal_is_rejected_naming_the_field_and_nothing_moves(gripper):
    client, states = gripper
    before = states.last().gap
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=float('nan'))))
    assert client.wait_for_result(rospy.Duration(HANG))
    assert client.get_state() == GoalStatus.REJECTED and 'command.position' in client.get_goal_status_text(), \
        client.get_goal_status_text()
    assert abs(states.last().gap - before) < 0.001


def test_stop_is_the_gate_s_and_a_goal_sent_before_it_is_rejected_after_it(gripper, collect):
    """Issue 51, hole 3, now without the controller's help: the controller has no halt topic, so the fingers stop
    because the gate cancelled the controller's goal."""
    client, states = gripper
    controller_results = collect(CONTROLLER + '/result', GripperCommandActionResult)
    gate_results = collect(GATE + '/result', GripperCommandActionResult)
    motion = collect('/gripper/motion_status', MotionStatus)
    halt = rospy.Publisher('/temoto/halt', String, queue_size=5, tcp_nodelay=True)
    raw = rospy.Publisher(GATE + '/goal', GripperCommandActionGoal, queue_size=5)
    wait_for(lambda: halt.get_num_connections() > 0 and raw.get_num_connections() > 0, HANG, 'the gate listening')
    controller = next(p for p in er_processes() if 'gripper_controller' in str(p['command']))
    assert 'halt_topic' not in str(controller['command']), controller['command']
    goal = across(states)
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=goal)))
    wait_for(lambda: states.last().speed != 0.0, HANG, 'the fingers moving')
    before = rospy.Time.now()
    halt.publish(String('test stop'))
    halted = rospy.Time.now().to_sec()
    assert client.wait_for_result(rospy.Duration(HANG)), 'the goal never ended'
    assert client.get_state() == GoalStatus.ABORTED, client.get_goal_status_text()
    assert client.get_goal_status_text() == 'halted: test stop; the fingers stop where they are'
    rest = at_rest_after(states, halted)
    assert abs(rest.gap - goal) > 0.005, 'the fingers stopped on their way, not at the goal'
    ended = wait_for(lambda: next((r for r in controller_results.msgs if r.header.stamp.to_sec() > halted), None),
                     HANG, 'the controller\'s goal to end')
    assert ended.status.status == GoalStatus.PREEMPTED, ended.status.text       # cancelled by the gate
    stopped = wait_for(lambda: next((m for m in motion.msgs if m.state == 3 and m.reason == 'halted'), None), HANG,
                       'the gate saying STOPPED')
    assert 'test stop' in stopped.text, stopped.text
    # a goal stamped before the stop, arriving after it
    late = GripperCommandActionGoal()
    late.header.stamp = late.goal_id.stamp = before
    late.goal_id.id = 'late_gripper_goal'
    late.goal.command.position = goal
    raw.publish(late)
    refused = wait_for(lambda: next((r for r in gate_results.msgs if r.status.goal_id.id == 'late_gripper_goal'),
                                    None), HANG, 'the late goal\'s end')
    assert refused.status.status == GoalStatus.REJECTED and 'before the operator\'s stop' in refused.status.text, \
        refused.status.text
    assert abs(states.last().gap - rest.gap) < 0.001, 'the late goal moved the fingers'


def test_a_goal_whose_client_is_killed_stops_the_fingers_naming_it(stack, gripper, collect):
    _, states = gripper
    motion = collect('/gripper/motion_status', MotionStatus)
    goal = across(states)
    client = stack.command(GRIPPER_CLIENT + [GATE, str(goal)], 'gripper_client')
    try:
        wait_for(lambda: states.last().speed != 0.0, HANG, 'the fingers moving for the client')
        os.kill(client.pid, signal.SIGKILL)
        killed = rospy.Time.now().to_sec()
        told = wait_for(lambda: next((m for m in motion.msgs if m.reason == 'holder_gone'), None), HANG,
                        'the gate saying its holder is gone')
        assert '/gripper_client' in told.text and told.state == 3, told
        rest = at_rest_after(states, killed)
        assert abs(rest.gap - goal) > 0.005, 'the fingers went on to the dead client\'s goal'
    finally:
        client.stop()


def test_a_controller_killed_mid_stroke_ends_the_goal_naming_it(stack, gripper):
    client, states = gripper
    goal = across(states)
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=goal)))
    wait_for(lambda: states.last().speed != 0.0, HANG, 'the fingers moving')
    pid = next(p['pid'] for p in er_processes() if 'gripper_controller' in str(p['command']))
    os.kill(pid, signal.SIGKILL)
    killed = rospy.Time.now().to_sec()
    assert client.wait_for_result(rospy.Duration(HANG)), 'the goal never ended'
    assert client.get_state() == GoalStatus.ABORTED, client.get_goal_status_text()
    assert 'the gripper\'s controller is gone' in client.get_goal_status_text(), client.get_goal_status_text()
    rest = at_rest_after(states, killed)           # the motor's own command timeout; nothing of the stack's runs
    assert abs(rest.gap - goal) > 0.005, 'the fingers reached the goal of a dead controller'
