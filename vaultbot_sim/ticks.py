"""A fixed-rate loop that drops ticks when late, rather than bursting to catch up.

A driver or a controller that falls behind (a busy machine) must send its next message now, not a
burst of stale ones: a burst of old wheel commands or scans is worse than a gap.
"""
from __future__ import annotations

import time
from typing import Optional


class Ticks:
    def __init__(self, period: float) -> None:
        self.period = period
        self.next = time.monotonic()

    def wait(self, wake_by: Optional[float] = None) -> None:
        """Sleep until the next tick, or until ``wake_by`` (``time.monotonic()``) if it comes first; the tick
        is then still to come."""
        self.next += self.period
        wake = self.next if wake_by is None else min(self.next, wake_by)
        delay = wake - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        elif delay < -self.period:
            self.next = time.monotonic()       # late by more than a tick: start again from now
            return
        if wake < self.next:
            self.next -= self.period
