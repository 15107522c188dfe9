"""A goal's status and its result come on two topics; ``TrackingActionClient.ended()`` waits for the result
(temoto_core/action_client.py). Against a server whose two topics are driven by hand, over real TCPROS, so
that the result can be held back after the status says SUCCEEDED: what a busy host does by chance.

A clean-clone suite lost a closed gripper so: the engine's loop read SUCCEEDED from ``get_state()``, found
``get_result()`` still None, and failed the action ("the gripper did not close: reached 0.0 mm").
"""
import pytest
import rospy
from actionlib_msgs.msg import GoalID, GoalStatus, GoalStatusArray
from control_msgs.msg import (GripperCommand, GripperCommandAction, GripperCommandActionFeedback,
                              GripperCommandActionGoal, GripperCommandActionResult, GripperCommandGoal)

from temoto_core import action_client
from temoto_core.action_client import TrackingActionClient
from temoto_core.wait import wait_for

NS = '/held_back_result'
HANG = 20.0         # generous: catches a client that never hears the server


class HandDrivenServer:
    """The three topics of an action server, published when the test says."""

    def __init__(self) -> None:
        self.goals = []
        # latched: the client counts a server as there once it has had one status message
        self.status = rospy.Publisher(NS + '/status', GoalStatusArray, queue_size=10, latch=True)
        self.result = rospy.Publisher(NS + '/result', GripperCommandActionResult, queue_size=10)
        self.feedback = rospy.Publisher(NS + '/feedback', GripperCommandActionFeedback, queue_size=10)
        self.goal_sub = rospy.Subscriber(NS + '/goal', GripperCommandActionGoal, self.goals.append)
        self.cancel_sub = rospy.Subscriber(NS + '/cancel', GoalID, lambda _msg: None)
        self.status.publish(GoalStatusArray())

    def say_status(self, goal: GripperCommandActionGoal, state: int) -> None:
        msg = GoalStatusArray()
        msg.header.stamp = rospy.Time.now()
        msg.status_list = [GoalStatus(goal_id=goal.goal_id, status=state, text='reached 10.0 mm')]
        self.status.publish(msg)

    def send_result(self, goal: GripperCommandActionGoal, position: float) -> None:
        msg = GripperCommandActionResult()
        msg.header.stamp = rospy.Time.now()
        msg.status = GoalStatus(goal_id=goal.goal_id, status=GoalStatus.SUCCEEDED, text='reached 10.0 mm')
        msg.result.position, msg.result.reached_goal = position, True
        self.result.publish(msg)

    def close(self) -> None:
        for topic in (self.status, self.result, self.feedback, self.goal_sub, self.cancel_sub):
            topic.unregister()


@pytest.fixture
def server_and_client(rospy_client):
    server = HandDrivenServer()
    client = TrackingActionClient(NS, GripperCommandAction)
    assert client.wait_for_server(rospy.Duration(HANG)), 'the client to see the server'
    wait_for(lambda: server.goal_sub.get_num_connections() > 0, HANG, 'the server to hear the client')
    yield server, client
    client.action_client.stop()
    server.close()


def _send(server, client):
    before = len(server.goals)
    client.send_goal(GripperCommandGoal(command=GripperCommand(position=0.01)))
    return wait_for(lambda: server.goals[before] if len(server.goals) > before else None, HANG,
                    'the goal at the server')


def test_a_goal_has_not_ended_until_its_result_arrives(server_and_client):
    server, client = server_and_client
    goal = _send(server, client)
    server.say_status(goal, GoalStatus.SUCCEEDED)
    wait_for(lambda: client.get_state() == GoalStatus.SUCCEEDED, HANG, 'the status read SUCCEEDED')
    # the status says SUCCEEDED, the result is not here: the goal has not ended for a poller
    assert client.get_result() is None
    assert not client.ended()
    server.send_result(goal, 0.01)
    wait_for(client.ended, HANG, 'the goal to end with its result')
    assert client.get_result().position == pytest.approx(0.01)


def test_a_terminal_status_whose_result_never_comes_ends_after_the_grace(server_and_client):
    server, client = server_and_client
    goal = _send(server, client)
    server.say_status(goal, GoalStatus.SUCCEEDED)
    wait_for(lambda: client.get_state() == GoalStatus.SUCCEEDED, HANG, 'the status read SUCCEEDED')
    assert not client.ended()
    wait_for(client.ended, action_client.RESULT_GRACE_S + HANG, 'the goal to end without a result')
    assert client.get_result() is None
    # a new goal starts its own grace
    goal = _send(server, client)
    server.say_status(goal, GoalStatus.ACTIVE)
    wait_for(lambda: client.get_state() == GoalStatus.ACTIVE, HANG, 'the new goal active')
    assert not client.ended()
