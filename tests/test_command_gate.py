"""The command gate's rules (``command_gate.py``): priorities, timeouts, guards and stops. Pure logic; the
navigator's use of it is tested across processes in ``test_navigation.py``."""
import pytest

from temoto_robot_manager.command_gate import CommandGate, Input, Refused, State
from temoto_robot_manager.guards import StopCode, StopReason

GOAL, STREAM = Input('goal', 20), Input('teleop', 10, 0.1)


class Switch:
    """A guard that trips when told to."""

    def __init__(self, code=StopCode.ODOMETRY_STALE, final=False):
        self.reason = None
        self.code, self.final = code, final

    def trip(self, text='tripped'):
        self.reason = StopReason(self.code, text, self.final)

    def clear(self):
        self.reason = None

    def check(self, now):
        return self.reason


def gate_with(*guards):
    sent, said = [], []
    gate = CommandGate('base', [GOAL, STREAM], list(guards), sent.append, 0.0, said.append)
    return gate, sent, said


def test_a_command_passes_when_every_guard_holds_and_its_silence_is_the_deadman():
    gate, sent, said = gate_with(Switch())
    assert said[-1].state is State.IDLE
    assert gate.offer('teleop', 0.5, 1.0).state is State.MOVING and sent == [0.5]
    assert gate.deadline() == pytest.approx(1.1)
    assert gate.enforce(1.09) is None and sent == [0.5], 'not yet'
    lapsed = gate.enforce(1.1)
    assert lapsed.code is StopCode.DEADMAN and sent == [0.5, 0.0] and gate.owner is None
    assert said[-1].state is State.STOPPED and said[-1].text == 'no teleop command for 100 ms'
    assert gate.enforce(2.0) is None and sent == [0.5, 0.0], 'the zero is sent once'


def test_a_tripped_guard_sends_zero_and_says_held_with_its_reason():
    odometry = Switch()
    gate, sent, said = gate_with(odometry)
    gate.offer('goal', 0.4, 0.0)
    odometry.trip('no odometry for 70 ms')
    assert gate.enforce(0.07).code is StopCode.ODOMETRY_STALE and sent == [0.4, 0.0]
    assert (said[-1].state, said[-1].reason, said[-1].text) == (State.HELD, StopCode.ODOMETRY_STALE,
                                                                'no odometry for 70 ms')
    assert gate.offer('goal', 0.4, 0.1).state is State.HELD and sent[-1] == 0.0, 'every command held while it trips'
    assert gate.enforce(0.12) is None, 'an actuator at zero is not zeroed again'
    odometry.clear()
    assert gate.offer('goal', 0.4, 0.2).state is State.MOVING and sent[-1] == 0.4


def test_a_goal_comes_before_a_stream_and_takes_the_base_from_it():
    gate, sent, said = gate_with()
    gate.offer('teleop', 0.3, 0.0)
    gate.offer('goal', 0.0, 0.01, moving=False)
    assert gate.owner == 'goal' and sent[-1] == 0.0 and gate.deadline() is None, 'the stream has no deadline left'
    with pytest.raises(Refused, match='held by goal'):
        gate.offer('teleop', 0.3, 0.02)
    assert sent[-1] == 0.0 and gate.owner == 'goal', 'a refused command changes nothing'
    gate.release('goal', StopReason(StopCode.ENDED, 'arrived'))
    assert said[-1].state is State.STOPPED and said[-1].text == 'arrived'
    assert gate.offer('teleop', 0.3, 0.03).state is State.MOVING and sent[-1] == 0.3


def test_a_stop_zeroes_whoever_commands_and_ends_every_input():
    gate, sent, said = gate_with()
    gate.offer('teleop', 0.3, 0.0)
    gate.stop(StopReason(StopCode.HALTED, 'halted: operator'), 0.05)
    assert sent[-1] == 0.0 and gate.owner is None and gate.deadline() is None
    assert (said[-1].state, said[-1].reason) == (State.STOPPED, StopCode.HALTED)
    gate.stop(StopReason(StopCode.HALTED, 'halted: again'), 0.06)
    assert sent[-2:] == [0.0, 0.0], 'a stop sends zero whatever was sent before'


def test_a_stream_that_goes_on_after_a_stop_must_pause_before_it_moves_again():
    """Chaos, history 6: a servo stream whose sender did not hear the operator's stop went on, and its next targets
    moved the arm again 0.1 s after the halt. A stopped stream must fall silent for its timeout first."""
    gate, sent, said = gate_with()
    gate.offer('teleop', 0.3, 0.0)
    gate.stop(StopReason(StopCode.HALTED, 'halted'), 0.01)
    for k in range(1, 6):                                   # the stream goes on at 50 Hz: each refused
        with pytest.raises(Refused, match='must pause 100 ms'):
            gate.offer('teleop', 0.3, 0.01 + 0.02 * k)
    assert sent == [0.3, 0.0] and said[-1].reason is StopCode.HALTED
    assert gate.offer('teleop', 0.3, 0.11 + 0.1).state is State.MOVING, 'after a pause: a new stream'
    gate.stop(StopReason(StopCode.HALTED, 'halted'), 0.3)
    assert gate.offer('goal', 0.4, 0.31).state is State.MOVING, 'a goal sent after the stop is a new command'


def test_a_command_decided_before_a_stop_is_refused_after_it():
    gate, sent, said = gate_with()
    gate.offer('teleop', 0.3, 0.0)
    gate.stop(StopReason(StopCode.HALTED, 'halted'), 0.05)
    with pytest.raises(Refused, match='decided 1 ms before the base was stopped'):
        gate.offer('goal', 0.4, 0.049)                   # a goal planned while the stop came
    assert sent[-1] == 0.0 and gate.owner is None
    assert gate.offer('goal', 0.4, 0.051).state is State.MOVING, 'a command decided after the stop passes'


def test_the_input_s_own_hold_is_said_and_a_refusal_is_said_only_when_nobody_moves_it():
    gate, sent, said = gate_with()
    gate.offer('goal', 0.0, 0.0, moving=False, held=StopReason(StopCode.BLOCKED, 'an obstacle'))
    assert (said[-1].state, said[-1].reason) == (State.HELD, StopCode.BLOCKED)
    gate.refused(StopReason(StopCode.REFUSED, 'late'))
    assert said[-1].reason is StopCode.BLOCKED, 'the goal still has the base: a stray refusal does not say stopped'
    gate.release('goal', StopReason(StopCode.ENDED, 'canceled'))
    gate.refused(StopReason(StopCode.REFUSED, 'late'))
    assert (said[-1].state, said[-1].reason) == (State.STOPPED, StopCode.REFUSED)


@pytest.mark.parametrize('inputs, words', [
    ([], 'one or more'),
    ([Input('a', 1), Input('a', 2)], 'each named once'),
    ([Input('a', 1), Input('b', 1)], 'distinct priorities'),
])
def test_inputs_that_do_not_say_who_wins_are_refused(inputs, words):
    with pytest.raises(ValueError, match=words):
        CommandGate('base', inputs, [], lambda c: None, 0.0)


def test_an_input_timeout_must_be_positive():
    with pytest.raises(ValueError, match='timeout'):
        Input('teleop', 1, 0.0)
