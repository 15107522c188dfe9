"""The Robot Manager end to end: load_robot starts each feature's parts through the ER and Sensor Managers as
linked sub-resources; a part's failure reaches the robot's holder; an unload leaves nothing running.
Shared by the module: roscore, vaultbot_sim with its base controller, and the three managers."""
import os
import signal
import subprocess
import sys
import threading

import pytest

from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_testing import wait_for
from temoto_testing.sensor_manager import er_processes, robot_info, start_robot_stack
from vaultbot_sim.msg import GripperState

HANG = 60.0
ARM_CONTROLLERS = {'left_arm_controller', 'right_arm_controller'}


@pytest.fixture(scope='module')
def stack(rospy_client, module_procs, tmp_path_factory):
    module_procs.robot_manager = start_robot_stack(module_procs, tmp_path_factory.mktemp('er_logs'))
    return module_procs


def running_labels():
    return {' '.join(p['command']) if isinstance(p['command'], list) else p['command'] for p in er_processes()}


def arm_controllers_running():
    return {name for name in ARM_CONTROLLERS if any(name in label for label in running_labels())}


def test_a_robot_with_every_feature_runs_its_parts_and_an_unload_stops_them(rmi):
    rm = rmi()
    robot = rm.load_robot(['navigation', 'manipulation'])
    assert robot.robot_name == 'vaultbot' and robot.features == ('navigation', 'manipulation')
    assert robot.parts['navigation.driver'].startswith('runs with the robot')
    assert robot.parts['navigation.obstacles'].startswith('base LIDAR scan (sick_lms511) on ')
    assert robot.parts['manipulation.left_arm.controller'].startswith('process ')
    assert arm_controllers_running() == ARM_CONTROLLERS
    loaded = robot_info()['robots'][0]['loaded']
    assert [entry['features'] for entry in loaded] == [['navigation', 'manipulation']]
    listed = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'robots'], capture_output=True, text=True,
                            timeout=60)
    assert listed.returncode == 0 and 'vaultbot' in listed.stdout and 'navigation, manipulation (' in listed.stdout, \
        listed.stdout + listed.stderr
    rm.release(robot.resource_id)
    wait_for(lambda: not arm_controllers_running(), HANG, 'the arm controllers to stop')
    assert robot_info()['robots'][0]['loaded'] == []


def test_a_stopped_manager_is_said_as_not_answering_with_the_error_its_callers_catch(rmi, stack):
    """Found by chaos (history 5): ``robots()`` let rospy's ``ServiceException`` out, which is not a
    ``ROSException``, so a motion action asked while the manager was stopped failed with no reason of its own."""
    rm = rmi()
    os.kill(stack.robot_manager.pid, signal.SIGSTOP)
    try:
        with pytest.raises(OSError, match='the Robot Manager does not answer on /.*/robots'):
            rm.robot_with('navigation', timeout=0.5)
    finally:
        os.kill(stack.robot_manager.pid, signal.SIGCONT)
    assert rm.robot_with('navigation')['name'] == 'vaultbot'


def test_a_crashed_part_reaches_the_holder_as_failed_naming_it(rmi):
    heard = []
    got = threading.Event()

    def on_status(event):
        heard.append(event)
        got.set()
    rm = rmi()
    robot = rm.load_robot(['manipulation'], on_status=on_status)
    pid = next(p['pid'] for p in er_processes() if 'left_arm_controller' in str(p['command']))
    before = robot_info()['robots'][0]['reliability']
    os.kill(pid, signal.SIGKILL)
    assert got.wait(HANG), 'no status reached the robot\'s holder'
    event = heard[0]
    assert event.code == ResourceStatus.FAILED and event.resource_id == robot.resource_id
    assert 'arm_controller' in str(event.message) + ' '.join(str(f) for f in event.error_stack)
    wait_for(lambda: robot_info()['robots'][0]['reliability'] < before, HANG, 'the robot to be less reliable')
    rm.release(robot.resource_id)
    wait_for(lambda: not arm_controllers_running(), HANG, 'the other arm controller to stop too')


@pytest.mark.parametrize('features, name, code, words', [
    (['flying'], '', ErrorCode.BAD_REQUEST, "unknown feature 'flying'"),
    ([], 'husky_9', ErrorCode.ROBOT_NOT_FOUND, "no robot 'husky_9' is described (described: vaultbot)"),
])
def test_a_bad_request_is_refused_naming_what_is_wrong_and_starts_nothing(rmi, features, name, code, words):
    before = running_labels()
    with pytest.raises(TemotoError) as caught:
        rmi().load_robot(features, robot_name=name)
    assert any(f.code == code for f in caught.value.stack) and words in str(caught.value), str(caught.value)
    assert running_labels() == before


def test_the_gripper_loads_with_its_controller_and_the_cli_opens_and_closes_it(stack, collect):
    truth = collect('/vaultbot_sim/gripper_state', GripperState)
    wait_for(lambda: truth.last(), HANG, 'the gripper\'s ground truth')
    unknown = temoto('gripper', 'sideways')
    assert unknown.returncode == 2 and "give a position of vaultbot (closed, open) or a gap in m" in unknown.stderr, \
        unknown.stdout + unknown.stderr
    assert not gripper_controller_running()
    closed = temoto('gripper', 'close')
    assert closed.returncode == 0 and 'gripper to 0.0 mm' in closed.stdout and 'done: reached' in closed.stdout, \
        closed.stdout + closed.stderr
    wait_for(lambda: truth.last().gap == pytest.approx(0.0, abs=0.002), HANG, 'the gripper closed')
    wait_for(lambda: not gripper_controller_running(), HANG, 'the controller released with the command\'s hold')
    refused = temoto('gripper', '0.5')
    beyond = 'failed: the gripper\'s controller ended the motion: command.position 0.5000 m is beyond the stroke'
    assert refused.returncode == 1 and beyond in refused.stdout, refused.stdout + refused.stderr
    opened = temoto('gripper', 'open', '--effort', '40')
    assert opened.returncode == 0 and 'done: reached 85.0 mm' in opened.stdout, opened.stdout + opened.stderr
    wait_for(lambda: truth.last().gap == pytest.approx(0.085, abs=0.002), HANG, 'the gripper open')
    wait_for(lambda: not gripper_controller_running(), HANG, 'the controller released again')
    assert robot_info()['robots'][0]['loaded'] == []


def gripper_controller_running():
    return any('gripper_controller' in label for label in running_labels())


def temoto(*args, timeout=120):
    return subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'robots'] + list(args), capture_output=True,
                          text=True, timeout=timeout)
