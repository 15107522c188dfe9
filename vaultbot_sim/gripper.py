"""The camera arm's parallel gripper, simulated: its motor, how it stops on an object, and on its own. No ROS.

The gripper's controller (``gripper_controller.py``) streams a setpoint, the gap it wants between the
pads and the speed to close or open it with, at its command rate. The motor moves both fingers
towards it at that speed, at most ``SPEED`` (a Robotiq 2F-85's 150 mm/s), never beyond the stroke.
A finger that meets an object stops there, as a real finger's motor stalls against it: the
simulation asks ``blocked(gap)`` before it enters a gap, and keeps the last free one.

Like the arms' motors, it carries a command timeout: a setpoint older than ``MOTOR_TIMEOUT_S`` is dropped,
and the fingers stop where they are. A controller that dies or stalls leaves the gripper holding what
it holds, not closing on.
"""
from __future__ import annotations

import math
from typing import Callable, Optional, Tuple

STROKE = 0.085              # m: the widest gap between the pads (urdf_gen.GRIPPER_STROKE)
SPEED = 0.15                # m/s of the gap at most
MOTOR_TIMEOUT_S = 0.04
BISECTIONS = 6              # a blocked step is refined to a 64th of it

Blocked = Callable[[float], bool]       # does this gap overlap the world?


class GripperPlant:
    """The gap between the pads: the ground truth of where the fingers are and how fast they move."""

    def __init__(self, gap: float = STROKE, motor_timeout: float = MOTOR_TIMEOUT_S) -> None:
        self.gap = min(STROKE, max(0.0, float(gap)))
        self.velocity = 0.0                  # m/s of the gap (negative: closing)
        self.setpoint: Optional[Tuple[float, float]] = None    # (gap, speed)
        self.motor_timeout = motor_timeout
        self.command_at: Optional[float] = None
        self.tripped_at: Optional[float] = None
        self.blocked_at: Optional[float] = None    # the gap where an object stopped the fingers, while it does
        self._last: Optional[float] = None

    def command(self, gap: float, speed: float, now: float) -> None:
        """A setpoint; raises ValueError naming what is wrong, and changes nothing."""
        if not (math.isfinite(gap) and math.isfinite(speed)):
            raise ValueError('gap %r and speed %r must be finite' % (gap, speed))
        if not 0.0 <= gap <= STROKE:
            raise ValueError('gap %.4f m is beyond the stroke [0, %.3f] m' % (gap, STROKE))
        if speed <= 0.0:
            raise ValueError('speed %.4f m/s must be above 0' % speed)
        self.setpoint = (gap, min(speed, SPEED))
        self.command_at, self.tripped_at = now, None

    def stop(self, now: float) -> None:
        """Stop where the fingers are (and keep squeezing what they hold): no setpoint, no command timeout trip."""
        self.setpoint, self.command_at, self.tripped_at, self.velocity = None, now, None, 0.0

    def drop_stale(self, now: float) -> bool:
        """Drop a stale setpoint (the fingers stop); True when it does so now."""
        if self.setpoint is not None and (self.command_at is None or now - self.command_at > self.motor_timeout):
            self.setpoint, self.tripped_at, self.velocity = None, now, 0.0
            return True
        return False

    @property
    def at_rest(self) -> bool:
        return self.velocity == 0.0

    def step(self, now: float, blocked: Blocked) -> None:
        dt = 0.0 if self._last is None else min(max(0.0, now - self._last), 0.1)
        self._last = now
        self.drop_stale(now)
        if dt <= 0.0:
            return
        if self.setpoint is None:
            self.velocity = 0.0
            return
        want, speed = self.setpoint
        step = max(-speed * dt, min(speed * dt, want - self.gap))
        if step == 0.0:
            self.velocity = 0.0
            return
        target = self.gap + step
        if blocked(target):
            # a finger meets an object: the last free gap of this step, by bisection
            free, lo, hi = self.gap, 0.0, 1.0
            for _ in range(BISECTIONS):
                mid = (lo + hi) / 2
                gap = self.gap + step * mid
                if blocked(gap):
                    hi = mid
                else:
                    free, lo = gap, mid
            target = free
            self.blocked_at = free
        else:
            self.blocked_at = None
        self.velocity = (target - self.gap) / dt
        self.gap = target
