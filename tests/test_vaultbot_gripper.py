"""The camera arm's gripper: its motor alone, then its controller as a process on a real roscore with a real
actionlib client. It opens, closes on a pole and says it stalled there, refuses bad goals naming the field, and
its faults leave the fingers still. Judged by the sim's ground truth (``/vaultbot_sim/gripper_state``)."""
import math
import sys
import os
import signal

import numpy as np
import pytest
import rospy
from control_msgs.msg import GripperCommand, GripperCommandAction, GripperCommandGoal
from actionlib_msgs.msg import GoalStatus

from temoto_testing import wait_for, wait_receiving
from temoto_testing.sensor_manager import set_cable
from vaultbot_sim import spec
from vaultbot_sim.gripper import MOTOR_TIMEOUT_S, SPEED, STROKE, GripperPlant
from vaultbot_sim.gripper_controller import Refused, check_goal
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel
from vaultbot_sim.msg import GripperState
from vaultbot_sim.urdf_gen import FINGER, GRIPPER_BODY, TEST_POLE_RADIUS, TEST_POLE_XY
from temoto_core import process_group
from temoto_core.action_client import TrackingActionClient

HANG = 30.0
ACTION = '/gripper/gripper_command'


# --- the motor alone ------------------------------------------------------------------------------------
def run(plant, seconds, blocked=lambda gap: False, dt=0.01, start=0.0, command=None):
    """Step ``plant`` for ``seconds``; ``command`` (gap, speed) is re-sent every step as a controller streams it."""
    t = start
    for _ in range(int(round(seconds / dt))):
        t += dt
        if command is not None:
            plant.command(command[0], command[1], t)
        plant.step(t, blocked)
    return t


def test_the_motor_closes_at_its_speed_and_stops_on_an_object_at_its_surface():
    plant = GripperPlant(STROKE)
    plant.step(0.0, lambda gap: False)
    run(plant, 0.1, command=(0.0, 10.0))              # asked faster than it can: at most SPEED
    assert STROKE - plant.gap == pytest.approx(SPEED * 0.1, rel=0.05)
    width = 0.04
    run(plant, 1.0, blocked=lambda gap: gap < width, start=0.1, command=(0.0, SPEED))
    assert width <= plant.gap < width + SPEED * 0.01 / 32 and plant.at_rest and plant.blocked_at is not None


def test_the_motor_stops_by_itself_when_its_setpoint_goes_stale():
    plant = GripperPlant(STROKE)
    plant.step(0.0, lambda gap: False)
    t = run(plant, 0.1, command=(0.0, SPEED))
    assert plant.velocity < 0
    t = run(plant, MOTOR_TIMEOUT_S + 0.02, start=t)  # the controller fell silent
    assert plant.at_rest and plant.tripped_at is not None and plant.tripped_at - 0.1 <= MOTOR_TIMEOUT_S + 0.011
    gap = plant.gap
    run(plant, 0.5, start=t)
    assert plant.gap == gap


@pytest.mark.parametrize('gap, speed, words', [
    (float('nan'), 0.1, 'must be finite'), (0.1, 0.1, 'beyond the stroke'), (-0.01, 0.1, 'beyond the stroke'),
    (0.02, 0.0, 'above 0'),
])
def test_the_motor_refuses_a_bad_setpoint_and_keeps_its_own(gap, speed, words):
    plant = GripperPlant(0.05)
    plant.command(0.03, 0.1, 0.0)
    with pytest.raises(ValueError, match=words):
        plant.command(gap, speed, 1.0)
    assert plant.setpoint == (0.03, 0.1) and plant.command_at == 0.0


@pytest.mark.parametrize('position, effort, words', [
    (float('nan'), 0.0, 'command.position nan'), (0.2, 0.0, 'command.position 0.2000 m is beyond the stroke'),
    (0.02, -1.0, 'command.max_effort -1.0'), (0.02, float('inf'), 'command.max_effort inf'),
    (0.02, 500.0, 'command.max_effort 500 N is above'),
])
def test_a_bad_goal_names_its_field(position, effort, words):
    with pytest.raises(Refused, match=words.replace('.', r'\.')):
        check_goal(position, effort)


# --- the controller as a process ---------------------------------------------------------------------------
def straddling_pose():
    """The base pose [x, y, yaw] at which the open fingers straddle the test world's pole, mid-pad."""
    cfg = dict(spec.STOW_POSE, **{j: STROKE / 2 for j in spec.GRIPPER_JOINTS})
    grasp = TreeModel(ROBOT_URDF).link_pose('gripper_link', cfg) @ np.array(
        [0.0, 0.0, GRIPPER_BODY[2] + FINGER[2] - 0.015, 1.0])
    return [float(TEST_POLE_XY[0] - grasp[0]), float(TEST_POLE_XY[1] - grasp[1]), 0.0]


def last(log):
    return log.last()


@pytest.fixture
def gripper(procs, rospy_client, collect):
    states = collect('/vaultbot_sim/gripper_state', GripperState)
    procs.node('vaultbot_sim', 'vaultbot_sim', params={'world': 'test_wall', 'sweep': False, 'hand_motion': False,
                                                       'base_pose': straddling_pose()})
    controller = procs.node('vaultbot_sim', 'gripper_controller')
    client = TrackingActionClient(ACTION, GripperCommandAction)
    assert client.wait_for_server(rospy_client.Duration(HANG)), 'the gripper\'s action server'
    wait_receiving([states.sub], HANG, 'the gripper\'s state')
    wait_for(lambda: states.last(), HANG, 'the first gripper state')
    yield dict(states=states, controller=controller, client=client)
    client.cancel_all_goals()


def command(client, position, effort=0.0):
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=position, max_effort=effort)))
    assert client.wait_for_result(rospy.Duration(HANG)), 'no result'
    return client.get_state(), client.get_result(), client.get_goal_status_text()


def test_closing_on_the_pole_stalls_at_its_width_and_opening_reaches_the_stroke(gripper):
    client, states = gripper['client'], gripper['states']
    state, result, text = command(client, 0.0, effort=60.0)
    assert state == GoalStatus.SUCCEEDED, text
    assert result.stalled and not result.reached_goal and result.effort == 60.0, result
    truth = last(states)
    # the pads stop at the pole's surface: its diameter, within the motor's last step
    assert truth.gap == pytest.approx(2 * TEST_POLE_RADIUS, abs=0.003) and truth.blocked
    assert result.position == pytest.approx(truth.gap, abs=0.001) and 'stalled at' in text
    state, result, text = command(client, STROKE)
    assert state == GoalStatus.SUCCEEDED and result.reached_goal and not result.stalled, text
    # reached means there and at rest: a goal that ended while the fingers still moved left them short of it
    assert result.position == pytest.approx(STROKE, abs=1e-4)
    assert last(states).gap == pytest.approx(STROKE, abs=1e-4) and last(states).speed == 0.0


@pytest.mark.parametrize('position, effort, words', [
    (0.5, 0.0, 'command.position 0.5000 m is beyond the stroke'), (float('nan'), 0.0, 'command.position nan'),
    (0.01, -5.0, 'command.max_effort -5.0'),
])
def test_a_bad_goal_is_aborted_naming_its_field_and_nothing_moves(gripper, position, effort, words):
    before = last(gripper['states'])
    state, _, text = command(gripper['client'], position, effort)
    assert state == GoalStatus.ABORTED and words in text, text
    refused = rospy.Time.now()
    after = wait_for(lambda: next((m for m in reversed(gripper['states'].msgs) if m.header.stamp > refused), None),
                     HANG, 'a state after the refusal')
    assert after.gap == before.gap and not after.has_setpoint


def test_a_controller_killed_mid_close_leaves_the_fingers_still_within_the_motor_timeout(gripper):
    client, states = gripper['client'], gripper['states']
    command(client, 0.0)                            # closed on the pole; now open it, and kill it on the way
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=STROKE)))
    wait_for(lambda: last(states).speed > 0.0, HANG, 'the fingers to open')
    os.kill(gripper['controller'].pid, signal.SIGKILL)
    killed = rospy.Time.now().to_sec()
    stopped = wait_for(lambda: next((m for m in reversed(states.msgs) if m.command_stale and m.speed == 0.0), None),
                       HANG, 'the motor to drop the dead controller\'s setpoint')
    assert stopped.header.stamp.to_sec() - killed < MOTOR_TIMEOUT_S + 0.2     # generous: catches a hang only
    gap = last(states).gap
    assert gap < STROKE - 0.002                     # it stopped on the way, not at the end
    wait_for(lambda: len([m for m in states.msgs if m.header.stamp > stopped.header.stamp]) >= 10, HANG,
             'ten more states')
    assert all(m.gap == gap and m.speed == 0.0 for m in states.msgs if m.header.stamp > stopped.header.stamp)


@pytest.mark.parametrize('mode', ['crash', 'stall'])
def test_an_unplugged_gripper_fails_as_a_controller_does_and_the_fingers_stay(gripper, mode):
    client, states = gripper['client'], gripper['states']
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=0.0)))
    wait_for(lambda: last(states).speed < 0.0, HANG, 'the fingers to close')
    set_cable('gripper', 'unplugged', mode)
    try:
        if mode == 'crash':
            wait_for(lambda: not gripper['controller'].alive(), HANG, 'the controller to exit')
            assert gripper['controller'].returncode == 1
        stopped = wait_for(lambda: next((m for m in reversed(states.msgs) if m.command_stale), None), HANG,
                           'the motor to stop the fingers')
        assert stopped.speed == 0.0 and not math.isclose(stopped.gap, 2 * TEST_POLE_RADIUS, abs_tol=0.003)
        if mode == 'stall':
            assert gripper['controller'].alive()
            assert client.get_state() == GoalStatus.ACTIVE      # silent: no result, as a hung driver gives none
    finally:
        set_cable('gripper', 'plugged')


def test_a_goals_client_killed_mid_stroke_stops_the_fingers(gripper, procs):
    """Found by chaos (history 5): the fingers went on to the end of their stroke after the goal's client died."""
    states = gripper['states']
    command(gripper['client'], 0.0)                       # closed on the pole
    script = ('import rospy, actionlib, sys\n'
              'from control_msgs.msg import GripperCommandAction, GripperCommandGoal, GripperCommand\n'
              'rospy.init_node("gripper_goal_client", anonymous=True)\n'
              'c = actionlib.SimpleActionClient("%s", GripperCommandAction)\n'
              'c.wait_for_server(rospy.Duration(60))\n'
              'c.send_goal(GripperCommandGoal(command=GripperCommand(position=%r)))\n'
              'print("sent", flush=True)\n'
              'rospy.spin()\n' % (ACTION, STROKE))
    other = procs.command([sys.executable, '-c', script], 'gripper_goal_client')
    wait_for(lambda: last(states).speed > 0.0, HANG, 'the fingers to open for the other client')
    os.kill(other.pid, signal.SIGKILL)
    killed = rospy.Time.now().to_sec()
    at_rest = wait_for(lambda: next((m for m in reversed(states.msgs) if m.header.stamp.to_sec() > killed
                                     and m.speed == 0.0), None), HANG, 'the fingers at rest')
    assert at_rest.header.stamp.to_sec() - killed < 0.4, 'the fingers moved on %.2f s after their client died' % (
        at_rest.header.stamp.to_sec() - killed)
    assert at_rest.gap < STROKE - 0.005, 'they went on to the end of the stroke'


def test_a_goal_sent_while_its_controller_restarts_reaches_the_new_one(gripper, procs):
    """Chaos, seed 17, step 7407: a goal sent just after the gripper's controller was restarted was never
    acknowledged, and its client heard nothing. The new incarnation shares the old one's name, which is all
    actionlib knows a server by; the goal, not latched, went to the dead one. Sent again while it is not
    acknowledged, it reaches the new one, which answers it (here: refuses it, naming the field)."""
    client = gripper['client']
    old = gripper['controller']
    os.kill(old.pid, signal.SIGKILL)
    wait_for(lambda: process_group.ended(old.pid), HANG, 'the controller to end')
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=0.02, max_effort=-1.0)))
    procs.node('vaultbot_sim', 'gripper_controller')
    assert client.wait_for_result(rospy.Duration(HANG)), 'the goal was never answered'
    assert client.get_state() == GoalStatus.ABORTED, client.get_goal_status_text()
    assert 'command.max_effort -1.0' in client.get_goal_status_text()
    assert client.resent >= 1
