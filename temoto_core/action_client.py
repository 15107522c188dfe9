"""actionlib's SimpleActionClient without the race that loses a quick goal's end.

``SimpleActionClient.send_goal`` publishes the goal inside ``ActionClient.send_goal`` and only then keeps
the returned handle as ``self.gh``. A server that answers at once (a refusal takes 1 to 2 ms here) can
have its status or result handled on a subscriber thread before that assignment: the transition
callback compares the handle with ``self.gh``, still the previous goal's (or None), logs "Got a
transition callback on a goal handle that we're not tracking" and drops it. A dropped DONE leaves
``wait_for_result`` waiting for ever and the ``done_cb`` never called: a robot's goal that nobody hears
end. The tests found it losing about one quick refusal in a hundred.

Here ``send_goal`` holds a lock until ``self.gh`` is set, and the callbacks take it before they look at
``self.gh``; nothing else changes. The callbacks run on the client's subscriber threads and send_goal
takes no lock of theirs, so the lock cannot deadlock.

A second race: ``get_state()`` reads the goal's status as the server's status topic last gave it, and the
result comes on another topic, on its own connection. A goal polled with ``get_state()`` can read SUCCEEDED
while ``get_result()`` is still None: a clean-clone suite failed a gripper that had closed ("the gripper did
not close: reached 0.0 mm"). ``ended()`` is the poll that waits for the result: true once it has arrived,
or once the status has been terminal for ``RESULT_GRACE_S`` without one (a server that died between the
two; the result is then None, and the caller says so).

A third: a goal sent while its server restarts is lost. ``wait_for_server`` knows a server by its node's
name, which its next incarnation shares: the dead one's status and its connection, not yet seen closed,
pass for the new one's, and the goal goes to a dead socket or to nobody. Not latched, it never reaches the
new server, which lists it in no status: the goal is never acknowledged, never ends, and its caller hears
nothing (chaos, seed 17, step 7407: a gripper goal sent 0.2 s after its controller was restarted). A goal
still unacknowledged after ``ACK_RESEND_S`` is published again (``redeliver``): a server ignores a goal
id it already has, so a duplicate is harmless, and the new incarnation, connected by then, takes it.
"""
from __future__ import annotations

import threading
import time
from typing import Optional

import actionlib
import rospy
from actionlib import CommState, SimpleGoalState
from actionlib_msgs.msg import GoalStatus

UNFINISHED = (GoalStatus.PENDING, GoalStatus.ACTIVE, GoalStatus.PREEMPTING, GoalStatus.RECALLING)
RESULT_GRACE_S = 1.0    # s a terminal status may go without its result; a live server sends both within ms
# s without an acknowledgement after which a goal is sent again: a live server lists a new goal in its next
# status (5 Hz, so within 0.2 s), and a cut link delays the answer, not the resent copies' harmlessness
ACK_RESEND_S = 0.5


def unacknowledged(gh) -> bool:
    """Whether the server has not yet listed ``gh``'s goal in any status (``actionlib.ClientGoalHandle``)."""
    return gh is not None and gh.get_comm_state() == CommState.WAITING_FOR_GOAL_ACK


def redeliver(gh) -> bool:
    """Publish ``gh``'s goal again if its server has not acknowledged it; True if it did (see the module's doc).
    The same goal id: a server that has it already ignores the copy."""
    if not unacknowledged(gh):
        return False
    machine = gh.comm_state_machine
    machine.send_goal_fn(machine.action_goal)
    return True


class TrackingActionClient(actionlib.SimpleActionClient):
    """A SimpleActionClient whose goal handle is kept before any callback of that goal can look for it."""

    def __init__(self, ns: str, action_spec) -> None:
        self._sending = threading.RLock()
        self._terminal_since: Optional[float] = None     # when get_state() first read terminal, the result not in
        self._sent_at = 0.0                               # when the goal was last published
        self.resent = 0                                   # how often the goal was published again
        super().__init__(ns, action_spec)

    def send_goal(self, goal, done_cb=None, active_cb=None, feedback_cb=None) -> None:
        with self._sending:
            self._terminal_since = None
            self._sent_at, self.resent = time.monotonic(), 0
            super().send_goal(goal, done_cb=done_cb, active_cb=active_cb, feedback_cb=feedback_cb)

    def ended(self) -> bool:
        """Whether the goal has ended with its result here (see the module's doc); for a polling loop, which
        also sends again a goal its server has not acknowledged for ``ACK_RESEND_S``."""
        if self.simple_state == SimpleGoalState.DONE:
            return True
        now = time.monotonic()
        if self._redelivered(now):
            return False
        if self.get_state() in UNFINISHED:
            return False
        if self._terminal_since is None:
            self._terminal_since = now
        return now - self._terminal_since >= RESULT_GRACE_S

    def wait_for_result(self, timeout=rospy.Duration()) -> bool:
        """actionlib's, in slices, sending again meanwhile a goal its server has not acknowledged."""
        if self.gh is None:
            return super().wait_for_result(timeout)          # actionlib says that no goal was sent
        deadline = None if timeout.is_zero() else time.monotonic() + timeout.to_sec()
        while True:
            left = ACK_RESEND_S if deadline is None else min(ACK_RESEND_S, deadline - time.monotonic())
            if left > 0 and super().wait_for_result(rospy.Duration(left)):
                return True
            if rospy.is_shutdown() or (deadline is not None and time.monotonic() >= deadline):
                return self.simple_state == SimpleGoalState.DONE
            self._redelivered(time.monotonic())

    def _redelivered(self, now: float) -> bool:
        if now - self._sent_at >= ACK_RESEND_S and redeliver(self.gh):
            self._sent_at = now
            self.resent += 1
            return True
        return False

    def _handle_transition(self, gh) -> None:
        with self._sending:
            pass                              # the goal's handle is kept now
        super()._handle_transition(gh)

    def _handle_feedback(self, gh, feedback) -> None:
        with self._sending:
            pass
        super()._handle_feedback(gh, feedback)
