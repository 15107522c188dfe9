"""When a failed source may be tried again: one rule for every fail-back (the view's, navigation's obstacles).

No ROS. The view (``temoto_action_engine/view_failover.py``) and the Robot Manager's obstacle failover
(``temoto_robot_manager/obstacle_failover.py``) both return to a better-ranked source once it works again; a
source that does not come back, or comes back and fails again, must not cost a switch every moment.
"""
from __future__ import annotations


class Backoff:
    """When a source may be tried again: exponential backoff, and quarantine for a flapping source.

    Two kinds of failure count apart:

    - a try that did not start (the device is still unplugged) doubles the wait, from ``initial`` to
      ``maximum``. It never quarantines: a camera that stays unplugged for a minute must still be
      taken back within ``maximum`` of its return;
    - a *flap*: the source came up and failed again before it had run a whole hold. Flaps double the
      wait too, and ``quarantine_after`` flaps in a row keep the source out for ``quarantine_s``. So a
      source that toggles at 2 Hz costs at most one switch per window, and the windows grow.

    A source that ran a whole hold is forgiven (:meth:`succeeded`).
    """

    def __init__(self, initial: float, maximum: float, quarantine_after: int, quarantine_s: float) -> None:
        self.initial, self.maximum = initial, maximum
        self.quarantine_after, self.quarantine_s = quarantine_after, quarantine_s
        self.unavailable = 0        # tries in a row that did not start
        self.flaps = 0              # failures in a row within a hold
        self.not_before = 0.0

    def failed(self, now: float, flapped: bool) -> float:
        """Record a failure at ``now``; return the wait until the next try."""
        if flapped:
            self.flaps += 1
        else:
            self.unavailable += 1
        wait = min(self.maximum, self.initial * 2.0 ** (self.flaps + self.unavailable - 1))
        if self.quarantined:
            wait = max(wait, self.quarantine_s)
        self.not_before = now + wait
        return wait

    @property
    def quarantined(self) -> bool:
        return self.flaps >= self.quarantine_after

    def succeeded(self) -> None:
        self.unavailable = self.flaps = 0
        self.not_before = 0.0

    def ready(self, now: float) -> bool:
        return now >= self.not_before
