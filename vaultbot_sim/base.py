"""The Husky base: its limits, the simulated motors and body, and the controller's command shaping. No ROS.

Two processes share these rules, as a real Husky's computer and its motor drivers do:
- the **base controller** (``base_controller.py``) turns ``cmd_vel`` into wheel speeds within the
  limits below, and streams them to the motors at ``COMMAND_RATE_HZ``;
- the **motors** (:class:`BasePlant`, inside the sim) follow the last wheel command within the same
  physical limits. They carry their own command timeout: a command older than ``MOTOR_TIMEOUT_S`` is
  replaced by zero, so a controller that dies or stalls leaves the base braking, not driving.

Limits, chosen and documented (docs/robots.md): the Husky A200's top speed is 1.0 m/s (datasheet);
its turn rate is capped at 2.0 rad/s as husky_control does. Accelerations are ours: 1.0 m/s^2 and
3.0 rad/s^2 speeding up, 2.0 m/s^2 and 6.0 rad/s^2 braking, so a stop from top speed takes 0.5 s
over 0.25 m.

The base is a differential drive on the two wheel pairs (the Husky skid-steers; without slip in a
kinematic simulation the two are the same). Poses are (x, y, yaw) in the robot's world frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional, Tuple

WHEEL_RADIUS = 0.165
TRACK = 0.571                 # the distance between the left and the right wheels' contact lines
COMMAND_RATE_HZ = 100.0       # the controller's wheel command stream
MOTOR_TIMEOUT_S = 0.04        # the motors' own command timeout: four command periods
CMD_VEL_TIMEOUT_S = 0.25      # the controller's: no cmd_vel for this long, and it commands zero
BISECTIONS = 6                # a touching step is cut to its last free 64th

Pose = Tuple[float, float, float]


@dataclass(frozen=True)
class BaseLimits:
    max_speed: float = 1.0        # m/s
    max_turn: float = 2.0         # rad/s
    accel: float = 1.0            # m/s^2, speeding up
    decel: float = 2.0            # m/s^2, braking
    turn_accel: float = 3.0       # rad/s^2
    turn_decel: float = 6.0       # rad/s^2

    def clamp(self, linear: float, angular: float) -> Tuple[float, float]:
        """A requested velocity within the top speeds (each axis on its own, as diff_drive_controller)."""
        return (max(-self.max_speed, min(self.max_speed, linear)),
                max(-self.max_turn, min(self.max_turn, angular)))

    def braking_time(self, linear: float, angular: float) -> float:
        """Seconds from a zero command to rest at the braking limits."""
        return max(abs(linear) / self.decel, abs(angular) / self.turn_decel)


HUSKY = BaseLimits()


def ramp(current: float, target: float, up: float, down: float, dt: float) -> float:
    """``current`` moved toward ``target`` by at most ``up * dt`` while speeding up and ``down * dt`` while
    slowing down (toward zero, or through it: braking first)."""
    if dt <= 0:
        return current
    slowing = target * current < 0 or abs(target) < abs(current)
    step = (down if slowing else up) * dt
    if abs(target - current) <= step:
        return target
    return current + math.copysign(step, target - current)


def wheel_speeds(linear: float, angular: float) -> Tuple[float, float]:
    """(left, right) wheel speeds in rad/s for a body velocity."""
    return ((linear - angular * TRACK / 2) / WHEEL_RADIUS, (linear + angular * TRACK / 2) / WHEEL_RADIUS)


def body_velocity(left: float, right: float) -> Tuple[float, float]:
    """(linear, angular) for wheel speeds in rad/s: the inverse of :func:`wheel_speeds`."""
    return (left + right) * WHEEL_RADIUS / 2, (right - left) * WHEEL_RADIUS / TRACK


def advance(pose: Pose, linear: float, angular: float, dt: float) -> Pose:
    """The pose after ``dt`` at a constant body velocity (exact on the arc)."""
    x, y, yaw = pose
    if abs(angular) < 1e-9:
        return x + linear * dt * math.cos(yaw), y + linear * dt * math.sin(yaw), yaw
    r = linear / angular
    yaw2 = yaw + angular * dt
    return (x + r * (math.sin(yaw2) - math.sin(yaw)), y - r * (math.cos(yaw2) - math.cos(yaw)),
            math.atan2(math.sin(yaw2), math.cos(yaw2)))


class CommandShaper:
    """The controller's side: the latest ``cmd_vel`` within the top speeds, reached at the acceleration limits,
    and zero at once when ``cmd_vel`` asks for zero or has been silent for ``timeout`` (a dead commander never
    leaves the robot moving; the motors then brake at their own limit)."""

    def __init__(self, limits: BaseLimits = HUSKY, timeout: float = CMD_VEL_TIMEOUT_S) -> None:
        self.limits, self.timeout = limits, timeout
        self.target = (0.0, 0.0)
        self.heard: Optional[float] = None       # when the last cmd_vel arrived
        self.output = (0.0, 0.0)
        self._last: Optional[float] = None

    def request(self, linear: float, angular: float, now: float) -> None:
        if not (math.isfinite(linear) and math.isfinite(angular)):
            raise ValueError('cmd_vel (%r, %r): every value must be finite' % (linear, angular))
        self.target, self.heard = self.limits.clamp(linear, angular), now

    def silent(self, now: float) -> bool:
        return self.heard is None or now - self.heard > self.timeout

    def step(self, now: float) -> Tuple[float, float]:
        """The body velocity to command now."""
        dt = 0.0 if self._last is None else max(0.0, now - self._last)
        self._last = now
        if self.silent(now):
            self.target = (0.0, 0.0)
        if self.target == (0.0, 0.0):
            # a stop is passed on at once: braking is the motors' job, at their own limit, and a navigator's
            # or an operator's stop must not wait out a ramp in the controller before the wheels hear it
            self.output = (0.0, 0.0)
            return self.output
        lim = self.limits
        self.output = (ramp(self.output[0], self.target[0], lim.accel, lim.decel, dt),
                       ramp(self.output[1], self.target[1], lim.turn_accel, lim.turn_decel, dt))
        return self.output


@dataclass
class Contact:
    robot_link: str
    object_link: str
    x: float
    y: float


class BasePlant:
    """The simulated motors and body: the ground truth of where the base is and how fast it moves.

    ``command(left, right, now)`` is the motors' input. ``step(now, touching)`` moves the body: the actual
    velocity follows the command within the physical limits; a command older than ``motor_timeout`` counts as
    zero (the command timeout); a pose where ``touching(pose)`` names a contact is not entered: the base stops at the
    last free pose on its way (a kinematic simulation's collision: blocked, never through).
    """

    def __init__(self, limits: BaseLimits = HUSKY, motor_timeout: float = MOTOR_TIMEOUT_S,
                 pose: Pose = (0.0, 0.0, 0.0)) -> None:
        self.limits, self.motor_timeout = limits, motor_timeout
        self.pose = pose
        self.velocity = (0.0, 0.0)           # actual (linear, angular)
        self.commanded = (0.0, 0.0)          # what the motors are told now
        self.wheels = [0.0, 0.0]             # left and right wheel angles (rad): the encoders
        self.command_at: Optional[float] = None
        self.tripped_at: Optional[float] = None   # when the command timeout last replaced a command by zero
        self._last: Optional[float] = None

    def command(self, left: float, right: float, now: float) -> None:
        if not (math.isfinite(left) and math.isfinite(right)):
            raise ValueError('wheel command (%r, %r): every value must be finite' % (left, right))
        self.commanded = self.limits.clamp(*body_velocity(left, right))
        self.command_at = now
        self.tripped_at = None

    def drop_stale(self, now: float) -> bool:
        """Replace a stale command by zero; True when it does so now (the moment is ``tripped_at``)."""
        stale = self.command_at is None or now - self.command_at > self.motor_timeout
        if stale and self.commanded != (0.0, 0.0):
            self.commanded = (0.0, 0.0)
            self.tripped_at = now
            return True
        return False

    @property
    def at_rest(self) -> bool:
        return self.velocity == (0.0, 0.0)

    def step(self, now: float, touching: Callable[[Pose], Optional[Contact]] = lambda pose: None
             ) -> Optional[Contact]:
        """Advance to ``now``; the contact that stopped the base, if any."""
        dt = 0.0 if self._last is None else min(max(0.0, now - self._last), 0.1)
        self._last = now
        self.drop_stale(now)
        lim = self.limits
        linear = ramp(self.velocity[0], self.commanded[0], lim.accel, lim.decel, dt)
        angular = ramp(self.velocity[1], self.commanded[1], lim.turn_accel, lim.turn_decel, dt)
        # the distance covered is the mean velocity over the step
        mean = ((self.velocity[0] + linear) / 2, (self.velocity[1] + angular) / 2)
        nxt = advance(self.pose, mean[0], mean[1], dt)
        contact = touching(nxt) if nxt != self.pose else None
        moved = 1.0
        if contact is not None:
            # stop where it touched, found by bisection to a 64th of the step: not a whole step short, so that a
            # base pushed on goes on touching (one contact), as a real one would stand against the wall
            moved, hi = 0.0, 1.0
            for _ in range(BISECTIONS):
                mid = (moved + hi) / 2
                if touching(advance(self.pose, mean[0], mean[1], dt * mid)) is None:
                    moved = mid
                else:
                    hi = mid
            nxt = advance(self.pose, mean[0], mean[1], dt * moved)
        left, right = wheel_speeds(*mean)
        self.wheels[0] += left * dt * moved
        self.wheels[1] += right * dt * moved
        self.pose = nxt
        self.velocity = (linear, angular) if contact is None else (0.0, 0.0)
        return contact


class WheelOdometry:
    """The controller's odometry from the wheel encoders, as diff_drive_controller integrates it.

    It starts at ``start`` (the simulation gives the base's true pose once, so that its static ``world ->
    odom`` stays true; a real base would start at zero and drift)."""

    def __init__(self, start: Pose = (0.0, 0.0, 0.0)) -> None:
        self.pose = start
        self.velocity = (0.0, 0.0)
        self._last: Optional[Tuple[float, float, float]] = None     # left angle, right angle, time

    def update(self, left: float, right: float, t: float) -> Pose:
        if self._last is not None:
            l0, r0, t0 = self._last
            dl, dr = (left - l0) * WHEEL_RADIUS, (right - r0) * WHEEL_RADIUS
            ds, dyaw = (dl + dr) / 2, (dr - dl) / TRACK
            x, y, yaw = self.pose
            mid = yaw + dyaw / 2
            yaw2 = yaw + dyaw
            self.pose = (x + ds * math.cos(mid), y + ds * math.sin(mid), math.atan2(math.sin(yaw2), math.cos(yaw2)))
            if t > t0:
                self.velocity = (ds / (t - t0), dyaw / (t - t0))
        self._last = (left, right, t)
        return self.pose
