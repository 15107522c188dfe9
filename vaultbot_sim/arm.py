"""The UR5 arms' joint motors, simulated: what they accept, and how they stop on their own. No ROS.

An arm's controller (``arm_controller.py``) streams a *setpoint* per joint, a position and the
velocity to pass it with, at ``COMMAND_RATE_HZ``. The motors track it within the UR5's limits:
pi rad/s per joint (the datasheet) and ``ACCEL`` rad/s^2 (ours), and never beyond a joint's range.
They carry a command timeout as the base's motors do: a setpoint older than ``MOTOR_TIMEOUT_S`` is
dropped, and the joints brake to a hold where they are. A controller that dies or stalls leaves
the arm holding, not moving.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Mapping, Optional, Sequence, Tuple

from vaultbot_sim.base import ramp

COMMAND_RATE_HZ = 100.0
MOTOR_TIMEOUT_S = 0.04
SPEED = math.pi                 # rad/s, every UR5 joint
ACCEL = 8.0                     # rad/s^2, ours: a joint at full speed stops within 0.4 s and 0.62 rad
TRACKING_GAIN = 20.0            # 1/s: how hard a motor closes a position error beyond the setpoint's velocity


@dataclass(frozen=True)
class JointRange:
    lower: float
    upper: float

    def clamp(self, q: float) -> float:
        return min(self.upper, max(self.lower, q))


class ArmPlant:
    """Six joint motors: the ground truth of where an arm's joints are and how fast they turn."""

    def __init__(self, joints: Sequence[str], start: Mapping[str, float], ranges: Mapping[str, JointRange],
                 motor_timeout: float = MOTOR_TIMEOUT_S) -> None:
        self.joints = list(joints)
        self.ranges = {j: ranges[j] for j in self.joints}
        self.position: Dict[str, float] = {j: float(start[j]) for j in self.joints}
        self.velocity: Dict[str, float] = {j: 0.0 for j in self.joints}
        self.setpoint: Optional[Dict[str, Tuple[float, float]]] = None     # joint -> (position, velocity)
        self.motor_timeout = motor_timeout
        self.command_at: Optional[float] = None
        self.tripped_at: Optional[float] = None
        self.held = False          # commanded at least once: someone holds this arm (the sweep yields)
        self.released_at = 0.0     # when it was last given back, on the senders' clock (their stamps')
        self._last: Optional[float] = None

    def command(self, setpoint: Mapping[str, Tuple[float, float]], now: float, sent: float = 0.0) -> bool:
        """A setpoint for every joint of this arm; raises ValueError naming what is wrong, and changes nothing.
        ``sent``: its stamp (0: none). One sent before the arm was given back takes nothing (False): it was on
        its way from a controller switched off since, whose last words, the give-back, came by another way."""
        missing = [j for j in self.joints if j not in setpoint]
        if missing:
            raise ValueError('no setpoint for %s' % ', '.join(missing))
        extra = sorted(set(setpoint) - set(self.joints))
        if extra:
            raise ValueError('not joints of this arm: %s' % ', '.join(extra))
        for j, (q, v) in setpoint.items():
            if not (math.isfinite(q) and math.isfinite(v)):
                raise ValueError('%s: position %r and velocity %r must be finite' % (j, q, v))
        if sent and sent < self.released_at:
            return False
        self.setpoint = {j: (self.ranges[j].clamp(q), max(-SPEED, min(SPEED, v))) for j, (q, v) in setpoint.items()}
        self.command_at, self.tripped_at, self.held = now, None, True
        return True

    def stop(self, now: float) -> bool:
        """Brake to a hold where the joints are (a UR's stopj): no setpoint, and no command timeout trip either. An arm
        nobody holds (given back to the simulation's stowed pose or sweep) has nothing to hold: the stop is moot
        and takes nothing, as a command to a controller switched off does not reach the motors (a controller's
        hold that came after the give-back once took the wrist from its sweep, seed 17, step 2157). False then."""
        if not self.held:
            return False
        self.setpoint, self.command_at, self.tripped_at = None, now, None
        return True

    def release(self, sent: float = 0.0) -> None:
        """Nobody holds the arm any more: the simulation's stowed pose (and sweep) drive it again from here.
        ``sent``: the give-back's moment on the senders' clock; setpoints stamped before it take nothing."""
        self.held, self.setpoint = False, None
        self.velocity = {j: 0.0 for j in self.joints}
        self.released_at = max(self.released_at, sent)

    def drop_stale(self, now: float) -> bool:
        """Drop a stale setpoint (the joints brake to a hold); True when it does so now."""
        if self.setpoint is not None and (self.command_at is None or now - self.command_at > self.motor_timeout):
            self.setpoint = None
            self.tripped_at = now
            return True
        return False

    @property
    def at_rest(self) -> bool:
        return all(v == 0.0 for v in self.velocity.values())

    def step(self, now: float) -> None:
        dt = 0.0 if self._last is None else min(max(0.0, now - self._last), 0.1)
        self._last = now
        self.drop_stale(now)
        if dt <= 0.0:
            return
        for j in self.joints:
            v, q = self.velocity[j], self.position[j]
            if self.setpoint is None:
                want = 0.0
            else:
                q_set, v_set = self.setpoint[j]
                e = q_set - q
                # the error closed proportionally, but never faster than the joint can brake to it (no overshoot)
                fix = math.copysign(min(TRACKING_GAIN * abs(e), math.sqrt(2 * ACCEL * abs(e))), e)
                want = max(-SPEED, min(SPEED, v_set + fix))
            v2 = ramp(v, want, ACCEL, ACCEL, dt)
            q2 = q + (v + v2) / 2 * dt
            r = self.ranges[j]
            if q2 != r.clamp(q2):          # the range's end: a hard stop
                q2, v2 = r.clamp(q2), 0.0
            self.position[j], self.velocity[j] = q2, v2
