"""The hand in navigation mode: how far the grabbed hand has moved becomes the base's velocity. No ROS.

The original drove the base with the palm's position times a gain of 100 (10 for manipulation). Here, as for
the arm, the clutch (``hand_clutch.py``) anchors at the grab, so the hand's *motion since the grab* counts,
scaled by the dial: the hand pushed forward drives forward, pushed aside turns the robot, and the hand
brought back to where it grabbed stops it. The clutch is given the identity as its "tool", so what it returns
is the hand's motion times the dial's scale and ``GAIN_NAVIGATION``.

A hand is never perfectly still: within ``DEAD_ZONE_M`` of the grab (of the hand's own motion, whatever the
scale) the base stays at rest, and beyond it the command grows from zero, not from a step.
"""
from __future__ import annotations

from typing import Tuple

import numpy as np

GAIN_NAVIGATION = 10.0       # the original's ratio of navigation to manipulation (100 / 10)
TURN_PER_M = 2.0             # rad/s per metre of the scaled hand's sideways motion (5 cm at 1x: 1 rad/s)
DEAD_ZONE_M = 0.005          # of the hand's own motion: a trembling hand does not creep


def _outside_dead_zone(v: float) -> float:
    if abs(v) <= DEAD_ZONE_M:
        return 0.0
    return v - DEAD_ZONE_M if v > 0 else v + DEAD_ZONE_M


def velocity_of(offset: np.ndarray, k: float) -> Tuple[float, float]:
    """(linear m/s, angular rad/s) for the clutch's ``offset`` (its target's translation: the hand's motion
    since the grab times ``k``, the dial's scale times the gain). The hand's x is the base's forward, its y
    the base's left (REP 103), so a hand moved left turns the robot left."""
    if not k > 0:
        raise ValueError('k %r must be above 0' % k)
    if not np.all(np.isfinite(offset[:2])):
        return 0.0, 0.0
    forward, left = (_outside_dead_zone(float(v) / k) * k for v in offset[:2])
    return forward, TURN_PER_M * left
