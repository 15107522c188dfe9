"""The collision monitor: the last check between a velocity command and the wheels. No ROS.

Modelled on nav2's collision monitor, with its two zones as footprints swept along the command
("approach" polygons), so a zone looks where the robot is going and not at the wall it drives past:
- **stop zone**: the footprint plus ``stop_margin``, swept over the time the robot needs to stop
  (the command's latency plus its braking time at the base's limits). An obstacle point in it: the
  command becomes zero.
- **slow zone**: the footprint plus ``slow_margin``, swept over ``slow_time``. An obstacle point in it:
  the command is scaled to ``slow_factor``.

The points are the active obstacle source's latest frame and the map's obstacles near the robot,
both in the base's frame. The monitor checks every command the navigator sends, so it is the one
rule no planner or follower bug can get past.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from temoto_robot_manager.navigation.costmap import Footprint


class Zone(enum.Enum):
    CLEAR = 'clear'
    SLOW = 'slow'
    STOP = 'stop'


@dataclass(frozen=True)
class MonitorSettings:
    stop_margin: float = 0.05          # m around the footprint
    slow_margin: float = 0.20          # m
    latency: float = 0.10              # s from a command to the wheels, with a period of the navigator to spare
    decel: float = 2.0                 # m/s^2, the base's braking limit
    turn_decel: float = 6.0            # rad/s^2
    slow_time: float = 1.2             # s the slow zone looks ahead
    slow_factor: float = 0.3
    step: float = 0.05                 # s between the swept poses


@dataclass(frozen=True)
class Verdict:
    zone: Zone
    linear: float
    angular: float
    nearest: float                     # m from the footprint to the nearest point (inf: none)


class CollisionMonitor:
    def __init__(self, footprint: Footprint, settings: MonitorSettings = MonitorSettings()) -> None:
        self.footprint, self.settings = footprint, settings

    def swept_hit(self, points: np.ndarray, linear: float, angular: float, horizon: float, margin: float) -> bool:
        """Whether any point (N x 2, base frame) meets the footprint plus ``margin`` on the way along
        (``linear``, ``angular``) for ``horizon`` seconds."""
        if not len(points):
            return False
        reach = self.footprint.circumscribed + margin + abs(linear) * horizon
        near = points[np.hypot(points[:, 0], points[:, 1]) <= reach]
        if not len(near):
            return False
        steps = max(1, int(math.ceil(horizon / self.settings.step)))
        for k in range(steps + 1):
            t = horizon * k / steps
            yaw = angular * t
            if abs(angular) > 1e-6:
                px, py = linear / angular * math.sin(yaw), linear / angular * (1 - math.cos(yaw))
            else:
                px, py = linear * t, 0.0
            c, s = math.cos(yaw), math.sin(yaw)
            rel = near - (px, py)
            local = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)
            if self.footprint.contains(local, margin).any():
                return True
        return False

    def nearest(self, points: np.ndarray) -> float:
        return float(self.footprint.distance(points).min()) if len(points) else math.inf

    def check(self, points: np.ndarray, linear: float, angular: float) -> Verdict:
        """The command (``linear``, ``angular``) as it may go to the wheels, given obstacle ``points``."""
        st = self.settings
        nearest = self.nearest(points)
        if linear == 0.0 and angular == 0.0:
            return Verdict(Zone.CLEAR, 0.0, 0.0, nearest)
        braking = max(abs(linear) / st.decel, abs(angular) / st.turn_decel)
        if self.swept_hit(points, linear, angular, st.latency + braking, st.stop_margin):
            return Verdict(Zone.STOP, 0.0, 0.0, nearest)
        if self.swept_hit(points, linear, angular, st.slow_time, st.slow_margin):
            return Verdict(Zone.SLOW, linear * st.slow_factor, angular * st.slow_factor, nearest)
        return Verdict(Zone.CLEAR, linear, angular, nearest)
