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
  ends the goal at once, so a respawn finds nothing to resume;
- :class:`SourceFresh`: the active obstacle source heard within 3 of its periods (``freshness.py``). A base that
  drives on obstacles it no longer sees drives blind;
- :class:`ArmsInEnvelope`: every arm inside the outline that navigation keeps clear. The footprint assumes the arms
  at their stowed pose; an arm servoed out past it while the base drives is a part of the robot that nothing
  checks against the world.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Callable, Dict, Iterable, Mapping, Optional, Sequence, Set, Tuple

import numpy as np

from temoto_robot_manager.navigation.costmap import Footprint

STALE_PERIODS = 3          # periods of a stream's declared rate without a message: stale (as for obstacle sources)


class StopCode(enum.Enum):
    """Why a motion is held or stopped: a guard's reason here, and the motion node's own (the ``reason`` of a
    ``temoto_core/MotionStatus``)."""
    ODOMETRY_STALE = 'odometry_stale'
    CONTROLLER_GONE = 'controller_gone'
    ARM_OUTSIDE = 'arm_outside'
    STATE_STALE = 'state_stale'             # an arm's joint states stale: where it is is not known
    OBSTACLES_STALE = 'obstacles_stale'     # the active obstacle source sent nothing for 3 of its periods
    BLOCKED = 'blocked'                     # an obstacle in the stop zone
    HALTED = 'halted'                       # the operator's "stop"
    HOLDER_GONE = 'holder_gone'             # the goal's client, or the manager that started the node, is gone
    DEADMAN = 'deadman'                     # a command stream fell silent
    REFUSED = 'refused'                     # a command or goal refused (late, bad, or while a goal drives)
    ENDED = 'ended'                         # the goal ended by itself (arrived, or aborted for its own reason)


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


class SourceFresh:
    """The obstacle source the base drives on, fresh (``freshness.Freshness``: 3 of its periods, once proven).

    Not final: a goal waits for a fresh frame, from the same source or from the one the Robot Manager fails over to,
    and ends only after the navigator's own patience. ``name()`` says which source, for the text."""

    def __init__(self, freshness, name: Callable[[], str]) -> None:
        self.freshness, self.name = freshness, name

    def check(self, now: float) -> Optional[StopReason]:
        if self.freshness.fresh(now):
            return None
        last = self.freshness.last
        if last is None:
            since = 'nothing heard yet'
        elif self.freshness.deadline() is None:
            since = 'still proving itself: %d frames' % self.freshness.frames
        else:
            since = 'no frame for %.0f ms' % ((now - last) * 1e3)
        return StopReason(StopCode.OBSTACLES_STALE, 'no fresh obstacle source (%s: %s): the base does not drive blind'
                          % (self.name() or 'none named', since))


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


# an arm's skeleton (its chain's axes, K x 3 in the base frame) for its joint positions
Skeleton = Callable[[Sequence[float]], np.ndarray]


class ArmsInEnvelope:
    """Every arm's skeleton (``ArmKinematics.skeleton``: the chain's axes) inside the driving outline shrunk by
    ``inset``, in plan view.

    The outline holds the arms at their stowed pose with their links' thickness; their axes then lie ``inset`` or
    more inside it (the VaultBot's: 4 cm). An axis nearer the outline than that puts the link's surface outside
    it, where the costmap and the collision monitor do not look. Joint states older than ``state_timeout``: where
    the arms are is not known, and that stops the base too."""

    def __init__(self, footprint: Footprint, arms: Mapping[str, Tuple[Sequence[str], Skeleton]], inset: float,
                 state_timeout: float = 0.5) -> None:
        if inset < 0 or not state_timeout > 0:
            raise ValueError('inset %r must be 0 or more, state_timeout %r above 0' % (inset, state_timeout))
        self.footprint, self.inset, self.state_timeout = footprint, inset, state_timeout
        self.arms = {name: (list(joints), skeleton) for name, (joints, skeleton) in arms.items()}
        self._q: Dict[str, Tuple[float, ...]] = {}
        self._heard: Optional[float] = None
        # each arm's verdict, kept with the positions it was made at: an arm that does not move (the camera's, while
        # the Hokuyo's wrist sweeps) costs no kinematics on the next check, which every teleop command makes
        self._verdicts: Dict[str, Tuple[Tuple[float, ...], Optional[str]]] = {}

    def update(self, positions: Mapping[str, float], now: float) -> None:
        """Joint positions (any subset of the robot's joints) heard at ``now`` (monotonic)."""
        for name, (joints, _) in self.arms.items():
            if all(j in positions for j in joints):
                self._q[name] = tuple(float(positions[j]) for j in joints)
        if len(self._q) == len(self.arms):
            self._heard = now

    def check(self, now: float) -> Optional[StopReason]:
        if not self.arms:
            return None
        if self._heard is None or now - self._heard > self.state_timeout:
            return StopReason(StopCode.ARM_OUTSIDE, 'where the arms are is not known (no joint states of %s for '
                              '%.1f s)' % (', '.join(sorted(set(self.arms) - set(self._q)) or sorted(self.arms)),
                                           self.state_timeout))
        for name in sorted(self.arms):
            q = self._q[name]
            known = self._verdicts.get(name)
            if known is None or known[0] != q:
                known = self._verdicts[name] = (q, self._outside(name, q))
            if known[1] is not None:
                return StopReason(StopCode.ARM_OUTSIDE, known[1])
        return None

    def _outside(self, name: str, q: Tuple[float, ...]) -> Optional[str]:
        """Why arm ``name`` at ``q`` is outside the outline, or None."""
        points = self.arms[name][1](q)[:, :2]
        out = ~self.footprint.contains(points, -self.inset)
        if not out.any():
            return None
        # the point furthest out: from the outline shrunk by the inset
        worst = points[out][int(np.argmax(self.footprint.grown(-self.inset).distance(points[out])))]
        return ('%s reaches outside the driving outline at (%.2f, %.2f) in the base frame (its axes must stay %.2f m '
                'inside it): bring it to its stowed pose before driving' % (name, worst[0], worst[1], self.inset))
