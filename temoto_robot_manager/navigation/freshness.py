"""Is the obstacle source fresh? Its frame period, learnt from its frames, and its deadline. No ROS.

The navigator must not drive on obstacles it saw too long ago: the source is *stale* once
``STALE_PERIODS`` of its frame periods pass without a frame (the issue's bound; nav2's collision
monitor has a fixed ``source_timeout`` of 2 s instead). The period is learnt from the source's own
frames, so a source that is slow by design (a stitched cloud, a camera rendered on a busy
machine) gets its own deadline, not the scanner's:
- a source that declares its period (a ``LaserScan``'s ``scan_time``) is held to it, or to the
  median of its last ``RECENT`` intervals if it is slower than it says: the SICK stops the robot within
  3 x 40 ms, also right after it was restarted (its slow first frames are soon forgotten);
- a source that does not (a ``PointCloud2``) is judged by the ``PERCENTILE`` of its last
  ``WINDOW`` intervals, not their median: a camera whose frames come every 60 to 120 ms
  stopped the robot every few seconds with the median (measured: 7 false stops in a 16 s
  drive on the D435), while one that goes silent still stops it within 3 of its slow periods.
  That percentile of a full window is its third longest interval (``learnt_period``); of fewer
  intervals, the third longest of those, never a longer one: the percentile of a few intervals is
  one of the longest, and a source heard for a few seconds, with one stall among them, was
  trusted for 3 of the stall's length (chaos, seed 17, step 2188: a navigator just restarted
  learnt 0.51 s from 9 intervals of a D435 whose 20 gave 0.30 s).

The period is learnt from every frame that *arrives* (``arrived``), the deadline runs from the last frame
that was *used* (``heard``). An interval is the shorter of the arrivals' and the frames' own header stamps':
a consumer starved on a loaded host receives a frame late, and the interval before it is longer than the
source's (a navigator restarted 6 s before learnt 0.42 s of a D435 the watch heard at 0.34 s, and trusted
it 0.24 s longer: chaos, seed 17, step 2299); a driver's stamps may be wrong, but its arrivals then bound
them. Each clock errs long, so the shorter is the nearer the source's own pace. A consumer that turns frames into
obstacles more slowly than they come uses only some of them; learnt from those alone, the period was that of the consumer, not of the source, and a
D435 that stalled under a loaded navigator stopped the base 2.2 s later, not 3 source periods (chaos, seed
17, step 2301).
"""
from __future__ import annotations

import statistics
from collections import deque
from typing import Optional

STALE_PERIODS = 3
WINDOW = 20                    # intervals the period is learnt from
PROVEN = 5                     # frames a new source sends before it counts as fresh: its first frames come
                               # irregularly while the connection settles (measured: 3 false stops in 0.4 s)
PERCENTILE = 0.9
RECENT = 5                     # intervals a source that declares its period is judged by, when slower than it says
# the PERCENTILE of a full WINDOW, as the rank from the longest: the third longest of 20
RANK_FROM_LONGEST = WINDOW - int(PERCENTILE * (WINDOW - 1))


def shorter_interval(arrival: float, stamps: Optional[float]) -> float:
    """An interval between two frames: the arrivals', or the stamps' when they have one that is shorter."""
    return min(arrival, stamps) if stamps is not None and stamps > 0 else arrival


def learnt_period(intervals) -> Optional[float]:
    """The period of a source that declares none: the ``PERCENTILE`` of its last ``WINDOW`` intervals, the
    ``RANK_FROM_LONGEST``-th longest. Of fewer intervals, that rank of those (the shortest of them, if fewer
    still): more intervals can only make it longer, so it is never more lenient than the full window's."""
    ordered = sorted(list(intervals)[-WINDOW:])
    if not ordered:
        return None
    return ordered[max(0, len(ordered) - RANK_FROM_LONGEST)]


class Pace:
    """A source's last ``WINDOW`` intervals between frames, and the period they give.

    Each interval is taken by ``shorter_interval``. The chaos watch works the same contract out with code of its
    own (``temoto_chaos/motion_truth.py``): a checker never judges with the code it checks.
    """

    def __init__(self, declared: Optional[float] = None) -> None:
        self.declared = declared                 # the period the source says it has, if it says
        self.intervals: deque = deque(maxlen=WINDOW)
        self._arrival: Optional[float] = None    # when the last frame arrived
        self._stamp: Optional[float] = None      # its header stamp, if it had one

    def clear(self) -> None:
        self.intervals.clear()
        self._arrival = self._stamp = None

    def arrived(self, now: float, stamp: Optional[float] = None) -> None:
        """A frame arrived at ``now``; ``stamp``: its header stamp, if it has one."""
        if self._arrival is not None and now > self._arrival:
            between = stamp - self._stamp if stamp is not None and self._stamp is not None else None
            self.intervals.append(shorter_interval(now - self._arrival, between))
        self._arrival, self._stamp = now, stamp

    def period(self) -> Optional[float]:
        if self.declared is not None:
            # a source that says its period (a LaserScan's scan_time) is held to it, unless it is slower
            # than it says
            # judged by its *recent* intervals: a scanner restarted after a fault sends its first frames slowly
            # while it warms up, and a median over the whole window then kept a 0.58 s period for a second:
            # a stall then stopped the robot after 1.7 s, not 0.12 s (bench_navigation --only teleop)
            recent = list(self.intervals)[-RECENT:]
            if len(recent) >= 3:
                return max(self.declared, statistics.median(recent))
            return self.declared
        return learnt_period(self.intervals)


class Freshness:
    def __init__(self, periods: int = STALE_PERIODS, declared: Optional[float] = None) -> None:
        self.periods = periods
        self.pace = Pace(declared)
        self.last: Optional[float] = None       # when the last frame used arrived
        self.frames = 0
        self._counting_arrivals = False

    def reset(self) -> None:
        """A new source: nothing heard from it yet."""
        self.last = None
        self.frames = 0
        self.pace.clear()

    def arrived(self, now: float, stamp: Optional[float] = None) -> None:
        """A frame arrived, to be used or not: the period is learnt from these (once any is told). ``stamp``:
        its header stamp, if it has one."""
        self._counting_arrivals = True
        self.pace.arrived(now, stamp)

    def heard(self, now: float) -> None:
        """A frame that arrived at ``now`` was used: the source is fresh until its deadline from then."""
        if not self._counting_arrivals and self.last is not None and now > self.last:
            self.pace.intervals.append(now - self.last)
        self.last = now if self.last is None else max(self.last, now)
        self.frames += 1

    @property
    def period(self) -> Optional[float]:
        return self.pace.period()

    def deadline(self) -> Optional[float]:
        """When the source goes stale if no frame comes; None: it has not proven fresh yet."""
        period = self.period
        if self.last is None or period is None or self.frames < PROVEN:
            return None
        return self.last + self.periods * period

    def fresh(self, now: float) -> bool:
        deadline = self.deadline()
        return deadline is not None and now < deadline
