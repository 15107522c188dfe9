"""The local controller: steer along the global plan within the base's limits, then turn to the goal's heading.

A regulated pure pursuit, as nav2's controller of that name: aim at the plan's point one lookahead
ahead, with the curvature that reaches it; slow down on tight curves and near the goal; turn in
place first when the aim is far off the heading (a differential drive can, and it keeps the robot
on its planned corridor). Within ``GoalTolerance.xy`` of the goal it stops driving and turns to
the goal's yaw. It never drives backwards: the base's scanner looks forward only. No ROS.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Tuple

import numpy as np

Pose = Tuple[float, float, float]


class Phase(enum.Enum):
    DRIVE = 'drive'
    ALIGN = 'align'
    ARRIVED = 'arrived'


@dataclass(frozen=True)
class GoalTolerance:
    xy: float = 0.05                   # m: inside the 0.10 m, with the braking creep to spare
    yaw: float = math.radians(2.0)     # inside the 5 degrees


@dataclass(frozen=True)
class FollowerLimits:
    max_speed: float = 0.8             # m/s, below the Husky's 1.0: indoor, beside people
    min_speed: float = 0.06            # m/s: slower than this the wheels barely turn
    max_turn: float = 1.2              # rad/s
    min_turn: float = 0.12             # rad/s, when aligning
    lookahead: float = 0.6             # m
    rotate_first: float = 0.75         # rad: the aim further off the heading than this is turned to in place
    approach: float = 0.8              # m: slow down linearly within this of the goal
    curve_radius: float = 0.9          # m: below this radius the speed is scaled down with it
    turn_gain: float = 2.0             # rad/s per rad of heading error, turning in place


def wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


class PathFollower:
    def __init__(self, limits: FollowerLimits = FollowerLimits(), tolerance: GoalTolerance = GoalTolerance()):
        self.limits, self.tolerance = limits, tolerance
        self.phase = Phase.DRIVE

    def reset(self) -> None:
        self.phase = Phase.DRIVE

    def _turn(self, error: float) -> float:
        lim = self.limits
        turn = max(lim.min_turn, min(lim.max_turn, lim.turn_gain * abs(error)))
        return math.copysign(turn, error)

    def command(self, pose: Pose, path: np.ndarray, goal_yaw: float) -> Tuple[float, float]:
        """(linear, angular) to command at ``pose`` along ``path`` (N x 2, ending at the goal)."""
        lim, tol = self.limits, self.tolerance
        x, y, yaw = pose
        gx, gy = path[-1]
        to_goal = math.hypot(gx - x, gy - y)
        if self.phase is Phase.DRIVE and to_goal <= tol.xy:
            self.phase = Phase.ALIGN
        if self.phase is not Phase.DRIVE:
            error = wrap(goal_yaw - yaw)
            if abs(error) <= tol.yaw:
                self.phase = Phase.ARRIVED
                return 0.0, 0.0
            self.phase = Phase.ALIGN
            return 0.0, self._turn(error)
        # the aim: the first point of the plan at least a lookahead away, past the nearest one
        d = np.hypot(path[:, 0] - x, path[:, 1] - y)
        nearest = int(np.argmin(d))
        ahead = np.nonzero(d[nearest:] >= lim.lookahead)[0]
        ax, ay = path[nearest + ahead[0]] if len(ahead) else path[-1]
        dx, dy = ax - x, ay - y
        c, s = math.cos(yaw), math.sin(yaw)
        fx, fy = c * dx + s * dy, -s * dx + c * dy          # the aim in the robot's frame
        bearing = math.atan2(fy, fx)
        if abs(bearing) > lim.rotate_first:
            return 0.0, self._turn(bearing)
        reach = max(math.hypot(fx, fy), 1e-6)
        curvature = 2.0 * fy / (reach * reach)
        speed = lim.max_speed
        if abs(curvature) > 1.0 / lim.curve_radius:
            speed *= 1.0 / (lim.curve_radius * abs(curvature))
        speed = min(speed, lim.max_speed * to_goal / lim.approach)
        speed = max(speed, lim.min_speed)
        turn = speed * curvature
        if abs(turn) > lim.max_turn:                           # keep the curvature: slow down instead
            speed *= lim.max_turn / abs(turn)
            turn = math.copysign(lim.max_turn, turn)
        return speed, turn
