"""Driving the base by a stream of velocity commands (the operator's hand), under the navigator's guards. No ROS.

A goal is one command that the navigator plans and drives; a teleoperated base is a stream, and a stream is
only as safe as what happens when it stops, lies or goes blind. twist_mux holds a stream for 0.5 s after its
last command; MoveIt Servo for 0.1 s. Here a command, on ``teleop/cmd_vel`` (``TwistStamped``):

- is **refused** while a goal drives: one commander at a time (the Robot Manager gives the navigation to one
  holder; a stray stream must not fight a goal);
- is **refused** when it is late (stamped more than ``MAX_AGE_S`` ago: a link that held it and delivers it
  now), stamped in the future by as much, stamped before the operator's last "stop", or not finite. The stamp
  is on the robot's clock: the node turns a station's stamp into it first (``temoto_core/clocks.py``);
- is **clamped** to the follower's top speeds;
- becomes **zero** while the obstacle source is not fresh, or a guard holds the base (``guards.py``: the
  odometry stale, an arm outside the outline): the base never drives blind, whoever commands it;
- passes the **collision monitor**, as a goal's commands do: zero in the stop zone, slowed in the slow zone;
- **lasts** ``TIMEOUT_S``: when the stream is silent that long, the base is commanded zero once (the
  base controller's own cmd_vel timeout, 0.25 s, stays behind it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from temoto_robot_manager.collision_monitor import Zone
from temoto_robot_manager.guards import StopCode
from temoto_robot_manager.navigator import Navigator

TIMEOUT_S = 0.1              # a silent stream: zero after this (MoveIt Servo's incoming command timeout)
MAX_AGE_S = 0.1              # a command stamped this long ago is late: refused (as the manipulator's servo)


class Refused(ValueError):
    """A teleop command the navigator will not take; the message says why."""


@dataclass(frozen=True)
class Decision:
    linear: float
    angular: float
    why: str = ''            # '' when passed as asked (clamped at most); else what held or slowed it
    held: Optional[StopCode] = None      # what holds it at zero, if something does


class TeleopDrive:
    def __init__(self, nav: Navigator, timeout: float = TIMEOUT_S, max_age: float = MAX_AGE_S) -> None:
        if not timeout > 0 or not max_age > 0:
            raise ValueError('timeout %r and max_age %r must be above 0' % (timeout, max_age))
        self.nav, self.timeout, self.max_age = nav, timeout, max_age
        self.until: Optional[float] = None        # when the current command runs out (monotonic)
        self.halted_stamp = -math.inf             # the stamp (wall clock) of the operator's last "stop"

    @property
    def active(self) -> bool:
        """A command stream drives the base now (until ``deadline()``)."""
        return self.until is not None

    def deadline(self) -> Optional[float]:
        return self.until

    def command(self, stamp: float, wall_now: float, now: float, linear: float, angular: float) -> Decision:
        """One command stamped ``stamp`` (this host's wall clock: ``clocks.PeerClocks`` turns a sender's into it), arriving at ``wall_now`` / ``now`` (monotonic): what to
        command the base. Raises ``Refused``; a refused command changes nothing."""
        if self.nav.goal is not None:
            raise Refused('a navigation goal is driving the base: cancel it before teleoperating')
        if not all(math.isfinite(v) for v in (stamp, linear, angular)):
            raise Refused('linear %r, angular %r, stamp %r: every value must be finite' % (linear, angular, stamp))
        if stamp <= self.halted_stamp:
            raise Refused('stamped before the operator\'s stop')
        if wall_now - stamp > self.max_age:
            raise Refused('sent %.0f ms ago (late: more than %.0f ms)' % ((wall_now - stamp) * 1e3,
                                                                           self.max_age * 1e3))
        if stamp - wall_now > self.max_age:
            raise Refused('stamped %.0f ms in the future: its stamp is wrong' % ((stamp - wall_now) * 1e3))
        lim = self.nav.follower.limits
        linear = max(-lim.max_speed, min(lim.max_speed, linear))
        angular = max(-lim.max_turn, min(lim.max_turn, angular))
        self.until = now + self.timeout
        if self.nav.pose is None:
            return Decision(0.0, 0.0, 'the robot\'s pose is not known yet (no odometry): the map is not checked',
                            StopCode.ODOMETRY_STALE)
        if not self.nav.freshness.fresh(now):
            return Decision(0.0, 0.0, 'no fresh obstacle source: the base does not drive blind', StopCode.OBSTACLES_STALE)
        stop = self.nav.guard_stop(now)
        if stop is not None:
            return Decision(0.0, 0.0, 'held: %s' % stop.text, stop.code)
        if linear == 0.0 and angular == 0.0:
            return Decision(0.0, 0.0)
        verdict = self.nav.monitor.check(self.nav.monitor_points(), linear, angular)
        if verdict.zone is Zone.STOP:
            return Decision(0.0, 0.0, 'an obstacle %.2f m away, in the stop zone' % verdict.nearest, StopCode.BLOCKED)
        if verdict.zone is Zone.SLOW:
            return Decision(verdict.linear, verdict.angular, 'slowed: an obstacle %.2f m away' % verdict.nearest)
        return Decision(verdict.linear, verdict.angular)

    def expire(self, now: float) -> bool:
        """At (or after) ``deadline()``: whether the stream ran out now (the base must be commanded zero)."""
        if self.until is None or now < self.until:
            return False
        self.until = None
        return True

    def end(self) -> None:
        """The stream ends with nothing to command (a goal took the base over)."""
        self.until = None

    def halt(self, stamp: float) -> None:
        """The operator's "stop": the stream ends, and nothing stamped before it is taken."""
        self.halted_stamp = max(self.halted_stamp, stamp)
        self.until = None
