"""What one command of a teleop stream (the operator's hand driving the base) asks of the base, checked. No ROS.

A goal is one command that the navigator plans and drives; a teleoperated base is a stream, and a stream is
only as safe as what happens when it stops, lies or goes blind. This class judges the command itself; the base's
command gate (``command_gate.py``) does the rest, as for every input: the stream's deadman (``TIMEOUT_S``, MoveIt
Servo's: twist_mux holds a stream for 0.5 s), its place below a goal (a stream is refused while a goal drives:
one commander at a time), and the guards (the obstacle source fresh, the odometry, the arms inside the outline).
A command, on ``teleop/cmd_vel`` (``TwistStamped``):

- is **refused** when it is late (stamped more than ``MAX_AGE_S`` ago: a link that held it and delivers it
  now), stamped in the future by as much, stamped before the operator's last "stop", or not finite. The stamp
  is on the robot's clock: the node turns a station's stamp into it first (``temoto_core/clocks.py``);
- is **clamped** to the follower's top speeds;
- is **zero** while the robot's pose is unknown (nothing to check the map against);
- passes the **collision monitor**, as a goal's commands do: zero in the stop zone, slowed in the slow zone.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

from temoto_robot_manager.navigation.collision_monitor import Zone
from temoto_robot_manager.command_gate import Input
from temoto_robot_manager.guards import StopCode, StopReason
from temoto_robot_manager.navigation.navigator import Navigator

TIMEOUT_S = 0.1              # a silent stream: zero after this (MoveIt Servo's incoming command timeout)
MAX_AGE_S = 0.1              # a command stamped this long ago is late: refused (as the manipulator's servo)


def base_inputs(timeout: float = TIMEOUT_S) -> Tuple[Input, Input]:
    """The base's gate's inputs, highest first, with the stream's deadman ``timeout``. A goal above the stream: the
    Robot Manager gives the navigation to one holder, and a stray stream must not fight a goal; a goal accepted
    takes the base from a stream at once."""
    return Input('goal', 20), Input('teleop', 10, timeout)


class Refused(ValueError):
    """A teleop command the navigator will not take; the message says why."""


@dataclass(frozen=True)
class Decision:
    linear: float
    angular: float
    why: str = ''            # '' when passed as asked (clamped at most); else what slowed it
    held: Optional[StopReason] = None      # what holds it at zero, if something does

    @property
    def moving(self) -> bool:
        return self.linear != 0.0 or self.angular != 0.0


class TeleopDrive:
    def __init__(self, nav: Navigator, max_age: float = MAX_AGE_S) -> None:
        if not max_age > 0:
            raise ValueError('max_age %r must be above 0' % max_age)
        self.nav, self.max_age = nav, max_age
        self.halted_stamp = -math.inf             # the stamp (wall clock) of the operator's last "stop"

    def command(self, stamp: float, wall_now: float, linear: float, angular: float) -> Decision:
        """One command stamped ``stamp`` (this host's wall clock: ``clocks.PeerClocks`` turns a sender's into it),
        arriving at ``wall_now``: what to offer the base's gate. Raises ``Refused``; a refused command changes
        nothing."""
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
        if self.nav.pose is None:
            return Decision(0.0, 0.0, held=StopReason(
                StopCode.ODOMETRY_STALE, 'the robot\'s pose is not known yet (no odometry): the map is not checked'))
        if linear == 0.0 and angular == 0.0:
            return Decision(0.0, 0.0)
        verdict = self.nav.monitor.check(self.nav.monitor_points(), linear, angular)
        if verdict.zone is Zone.STOP:
            return Decision(0.0, 0.0, held=StopReason(
                StopCode.BLOCKED, 'an obstacle %.2f m away, in the stop zone' % verdict.nearest))
        if verdict.zone is Zone.SLOW:
            return Decision(verdict.linear, verdict.angular, 'slowed: an obstacle %.2f m away' % verdict.nearest)
        return Decision(verdict.linear, verdict.angular)

    def halt(self, stamp: float) -> None:
        """The operator's "stop" (or a lost controller): nothing stamped before it is taken."""
        self.halted_stamp = max(self.halted_stamp, stamp)
