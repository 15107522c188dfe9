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
"""
from __future__ import annotations

import threading
import time
from typing import Optional

import actionlib
from actionlib import SimpleGoalState
from actionlib_msgs.msg import GoalStatus

UNFINISHED = (GoalStatus.PENDING, GoalStatus.ACTIVE, GoalStatus.PREEMPTING, GoalStatus.RECALLING)
RESULT_GRACE_S = 1.0    # s a terminal status may go without its result; a live server sends both within ms


class TrackingActionClient(actionlib.SimpleActionClient):
    """A SimpleActionClient whose goal handle is kept before any callback of that goal can look for it."""

    def __init__(self, ns: str, action_spec) -> None:
        self._sending = threading.RLock()
        self._terminal_since: Optional[float] = None     # when get_state() first read terminal, the result not in
        super().__init__(ns, action_spec)

    def send_goal(self, goal, done_cb=None, active_cb=None, feedback_cb=None) -> None:
        with self._sending:
            self._terminal_since = None
            super().send_goal(goal, done_cb=done_cb, active_cb=active_cb, feedback_cb=feedback_cb)

    def ended(self) -> bool:
        """Whether the goal has ended with its result here (see the module's doc); for a polling loop."""
        if self.simple_state == SimpleGoalState.DONE:
            return True
        if self.get_state() in UNFINISHED:
            return False
        now = time.monotonic()
        if self._terminal_since is None:
            self._terminal_since = now
        return now - self._terminal_since >= RESULT_GRACE_S

    def _handle_transition(self, gh) -> None:
        with self._sending:
            pass                              # the goal's handle is kept now
        super()._handle_transition(gh)

    def _handle_feedback(self, gh, feedback) -> None:
        with self._sending:
            pass
        super()._handle_feedback(gh, feedback)
