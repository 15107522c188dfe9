"""The operator's pointed goal: RViz's own tools point, and "Robot please go" drives there.

The paper's operator points at a place in the scene and then says "Robot please go". Pointing and going are
two acts: a goal pointed with RViz's "2D Nav Goal" or "Publish Point" must not move the robot by itself (a
robot that drives because someone clicked is a robot nobody asked to move), and it must still be there when
the words come. So the pointer keeps the last one, shows it in the scene until it is used or replaced, and
hands it to the ``navigate`` action, which then says it is used.

``PointedGoal`` is the logic, without ROS: what was pointed, whether it is still to be used, and whether a
pointed pose is one the robot can be sent to at all (finite, in a frame, a turn about z only).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

NO_HEADING = (0.0, 0.0, 0.0, 0.0)     # a clicked point has no heading: the driver faces it from where it is


class BadPointing(ValueError):
    """A pointed goal that cannot be a goal; the message names the field."""


@dataclass(frozen=True)
class Pointed:
    frame: str
    x: float
    y: float
    quaternion: Tuple[float, float, float, float]      # x, y, z, w; NO_HEADING for a point
    source: str                                         # 'nav_goal' or 'clicked_point'
    stamp: float                                        # when it was pointed (s, the pointer's clock)

    @property
    def has_heading(self) -> bool:
        return self.quaternion != NO_HEADING

    def yaw(self) -> Optional[float]:
        if not self.has_heading:
            return None
        qx, qy, qz, qw = self.quaternion
        return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))

    def describe(self) -> str:
        heading = '%.0f deg' % math.degrees(self.yaw()) if self.has_heading else 'no heading'
        return '(%.2f, %.2f, %s) in %s' % (self.x, self.y, heading, self.frame)


def checked(frame: str, position: Tuple[float, float, float], quaternion: Optional[Tuple[float, ...]],
            source: str, stamp: float) -> Pointed:
    """A pointed goal from RViz's message fields; raises BadPointing naming what is wrong."""
    frame = (frame or '').strip()
    if not frame:
        raise BadPointing('header.frame_id is empty: a pointed goal needs its frame')
    for name, v in zip(('x', 'y', 'z'), position):
        if not math.isfinite(v):
            raise BadPointing('position.%s is %r, not a finite number' % (name, v))
    if quaternion is None:
        return Pointed(frame, float(position[0]), float(position[1]), NO_HEADING, source, stamp)
    if not all(math.isfinite(v) for v in quaternion):
        raise BadPointing('orientation %r is not finite' % (tuple(quaternion),))
    qx, qy, qz, qw = quaternion
    norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if abs(norm - 1.0) > 0.01:
        raise BadPointing('orientation has norm %.3f, not a unit quaternion' % norm)
    if abs(qx) > 0.01 or abs(qy) > 0.01:
        raise BadPointing('orientation tilts (x %.3f, y %.3f): a goal turns about z only' % (qx, qy))
    return Pointed(frame, float(position[0]), float(position[1]), (qx / norm, qy / norm, qz / norm, qw / norm),
                   source, stamp)


class PointedGoal:
    """The last goal pointed, until it is used or replaced."""

    def __init__(self) -> None:
        self.current: Optional[Pointed] = None
        self.used_by = ''

    def point(self, pointed: Pointed) -> None:
        self.current, self.used_by = pointed, ''

    def use(self, by: str) -> Optional[Pointed]:
        """Mark the goal used (it leaves the scene); returns what was used, or None when nothing was pointed."""
        used, self.current = self.current, None
        if used is not None:
            self.used_by = by
        return used
