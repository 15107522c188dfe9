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
"""
from __future__ import annotations

import threading

import actionlib


class TrackingActionClient(actionlib.SimpleActionClient):
    """A SimpleActionClient whose goal handle is kept before any callback of that goal can look for it."""

    def __init__(self, ns: str, action_spec) -> None:
        self._sending = threading.RLock()
        super().__init__(ns, action_spec)

    def send_goal(self, goal, done_cb=None, active_cb=None, feedback_cb=None) -> None:
        with self._sending:
            super().send_goal(goal, done_cb=done_cb, active_cb=active_cb, feedback_cb=feedback_cb)

    def _handle_transition(self, gh) -> None:
        with self._sending:
            pass                              # the goal's handle is kept now
        super()._handle_transition(gh)

    def _handle_feedback(self, gh, feedback) -> None:
        with self._sending:
            pass
        super()._handle_feedback(gh, feedback)
