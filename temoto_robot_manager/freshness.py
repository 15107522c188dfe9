"""Is the obstacle source fresh? Its frame period, learnt from its frames, and its deadline. No ROS.

The navigator must not drive on obstacles it saw too long ago: the source is *stale* once
``STALE_PERIODS`` of its frame periods pass without a frame (the issue's bound; nav2's collision
monitor has a fixed ``source_timeout`` of 2 s instead). The period is the median of the last
frames' intervals, so one late frame does not stretch it, and a source that is slow by design
(a stitched cloud at 2 Hz) gets its own deadline, not the scanner's.
"""
from __future__ import annotations

import statistics
from collections import deque
from typing import Optional

STALE_PERIODS = 3
WINDOW = 10                    # intervals the period is the median of


class Freshness:
    def __init__(self, periods: int = STALE_PERIODS, first_period: Optional[float] = None) -> None:
        self.periods = periods
        self.first_period = first_period     # until two frames have come: the source's nominal period, if known
        self.last: Optional[float] = None
        self._intervals: deque = deque(maxlen=WINDOW)

    def reset(self) -> None:
        """A new source: nothing heard from it yet."""
        self.last = None
        self._intervals.clear()

    def heard(self, now: float) -> None:
        if self.last is not None and now > self.last:
            self._intervals.append(now - self.last)
        self.last = now

    @property
    def period(self) -> Optional[float]:
        if self._intervals:
            return statistics.median(self._intervals)
        return self.first_period

    def deadline(self) -> Optional[float]:
        """When the source goes stale if no frame comes; None: it has never been fresh."""
        period = self.period
        if self.last is None or period is None:
            return None
        return self.last + self.periods * period

    def fresh(self, now: float) -> bool:
        deadline = self.deadline()
        return deadline is not None and now < deadline
