"""A joint-space motion, time-parameterised within each joint's speed and acceleration limits. No ROS.

The arm moves along the straight line from the start to the goal in joint space, every joint starting
and ending together, with a trapezoidal speed profile along the line (a triangle when the line is too
short to reach full speed): the slowest joint sets the pace, so no joint exceeds its own limits. This
is what MoveIt's time parameterisation gives a two-point path; a straight line in joint space keeps
the path predictable for the self-collision check, which samples it.
"""
from __future__ import annotations

import math
from typing import List, Sequence, Tuple

Point = Tuple[float, List[float], List[float]]      # (seconds from the start, positions, velocities)

SAMPLE_PERIOD_S = 0.05       # between two points of the trajectory sent to the controller


def profile(distance: float, speed: float, accel: float) -> Tuple[float, float]:
    """(duration, peak speed) of a trapezoid covering ``distance`` from rest to rest."""
    if distance <= 0.0:
        return 0.0, 0.0
    ramp = speed / accel                      # time to full speed
    if accel * ramp * ramp >= distance:        # never reaches full speed: a triangle
        peak = math.sqrt(distance * accel)
        return 2 * peak / accel, peak
    return distance / speed + ramp, speed


def position_on(t: float, duration: float, peak: float, accel: float) -> Tuple[float, float]:
    """(s, ds/dt) at ``t`` along a unit-length trapezoid of ``duration`` and ``peak``."""
    if duration <= 0.0:
        return 1.0, 0.0
    t = min(max(t, 0.0), duration)
    ramp = peak / accel
    if t < ramp:
        return 0.5 * accel * t * t, accel * t
    if t > duration - ramp:
        left = duration - t
        return 1.0 - 0.5 * accel * left * left, accel * left
    return 0.5 * accel * ramp * ramp + peak * (t - ramp), peak


def time_parameterise(start: Sequence[float], goal: Sequence[float], speeds: Sequence[float],
                      accels: Sequence[float], period: float = SAMPLE_PERIOD_S) -> List[Point]:
    """Points every ``period`` from ``start`` (at rest) to ``goal`` (at rest), the first at t = period."""
    if not (len(start) == len(goal) == len(speeds) == len(accels)):
        raise ValueError('start, goal, speeds and accels differ in length')
    delta = [g - s for s, g in zip(start, goal)]
    # along the unit line s in [0, 1]: joint j moves delta_j * s, so ds/dt <= v_j / |delta_j| for each joint
    speed = min((v / abs(d) for d, v in zip(delta, speeds) if d), default=0.0)
    accel = min((a / abs(d) for d, a in zip(delta, accels) if d), default=0.0)
    if speed <= 0.0:
        return [(period, list(goal), [0.0] * len(goal))]
    duration, peak = profile(1.0, speed, accel)
    points: List[Point] = []
    steps = max(1, int(math.ceil(duration / period)))
    for k in range(1, steps + 1):
        t = min(k * period, duration)
        s, ds = position_on(t, duration, peak, accel)
        velocities = [d * ds for d in delta] if k < steps else [0.0] * len(delta)
        points.append((t, [a + d * s for a, d in zip(start, delta)] if k < steps else list(goal), velocities))
    return points
