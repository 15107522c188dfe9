"""Rules a motion command must pass, one small class each, and the typed reason a rule gives when it trips. No ROS.

A guard watches one thing that a motion depends on. Asked, it says whether a command may pass now, and if not, why,
as a :class:`StopReason`: a code that a program can act on, and a text for the operator. A reason is *final* when
the goal it stops cannot go on by itself: the goal then ends ABORTED with that text, and nothing moves again
without a new goal. A reason that is not final holds the command at zero until the guard passes again (the goal
waits, as it waits for a fresh obstacle source).

Guards here:
- :class:`OdometryFresh`: odometry heard within ``STALE_PERIODS`` of the driver's declared period; stale for
  ``patience``, the goal ends. A drive on a pose that no longer moves with the robot is a blind drive;
- :class:`PublisherAlive`: the node that publishes what a motion reads (the base controller's odometry) is alive,
  told by its connection's end, which the kernel gives the moment the process dies (a crash, a SIGKILL). A base
  controller that died and was respawned drove on toward the old goal 2.6 s later, and nobody was told: its death
  ends the goal at once, so a respawn finds nothing to resume.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Callable, Iterable, Optional, Set

STALE_PERIODS = 3          # periods of a stream's declared rate without a message: stale (as for obstacle sources)


class StopCode(enum.Enum):
    """Why a guard stops a motion."""
    ODOMETRY_STALE = 'odometry_stale'
    CONTROLLER_GONE = 'controller_gone'


@dataclass(frozen=True)
class StopReason:
    code: StopCode
    text: str
    final: bool = False          # the goal ends ABORTED with ``text``; it does not wait for the guard to pass

    def __str__(self) -> str:
        return self.text


class OdometryFresh:
    """Odometry heard within ``STALE_PERIODS`` periods of the driver's declared ``rate``.

    Judged by arrivals on the monotonic clock, never by the sender's stamps: a robot and a station with skewed
    clocks must neither stop for nothing nor drive on stale odometry. The declared rate, not a learnt one: the
    robot description says what the driver publishes, and a guard that learnt a slow pace from a starving driver
    would stop the robot later than its description promises."""

    def __init__(self, rate: float, patience: float, periods: int = STALE_PERIODS) -> None:
        if not rate > 0 or not patience > 0 or periods < 1:
            raise ValueError('rate %r and patience %r must be above 0, periods %r at least 1'
                             % (rate, patience, periods))
        self.period, self.patience, self.periods = 1.0 / rate, patience, periods
        self.last: Optional[float] = None

    @property
    def timeout(self) -> float:
        """Seconds without odometry before it is stale."""
        return self.periods * self.period

    def heard(self, now: float) -> None:
        self.last = now if self.last is None else max(self.last, now)

    def deadline(self) -> Optional[float]:
        """When the odometry goes stale if none comes; None before the first."""
        return None if self.last is None else self.last + self.timeout

    def check(self, now: float) -> Optional[StopReason]:
        if self.last is None:
            return StopReason(StopCode.ODOMETRY_STALE, 'no odometry heard yet')
        age = now - self.last
        if age < self.timeout:
            return None
        final = age >= self.patience
        return StopReason(StopCode.ODOMETRY_STALE, 'no odometry for %.0f ms (stale after %d periods of %.0f Hz%s)'
                          % (age * 1e3, self.periods, 1.0 / self.period,
                             '; the goal ends after %.1f s' % self.patience if final else ''), final)


class PublisherAlive:
    """The nodes that publish a topic a motion reads, alive: once seen, a publisher whose connection is gone died.

    ``publishers()`` gives the publishers whose connection is open now (``rospy_internals.live_publishers``,
    which reads the socket, not rospy's count). A publisher never seen is nobody's concern; one that comes back
    (a respawn) is watched again from its first connection."""

    def __init__(self, publishers: Callable[[], Iterable[str]], what: str) -> None:
        self._publishers = publishers
        self.what = what
        self._seen: Set[str] = set()

    def poll(self) -> Optional[StopReason]:
        """A final reason once for each publisher lost since the last poll, or None."""
        live = set(self._publishers())
        lost, self._seen = self._seen - live, live
        if not lost:
            return None
        return StopReason(StopCode.CONTROLLER_GONE, '%s %s is gone (its connection closed)'
                          % (self.what, ', '.join(sorted(lost))), final=True)
