"""An arm against the world: its chain kept clear of the map's obstacles, for a goal's way and for the servo. No ROS.

The self-collision check keeps an arm off the robot's own body; nothing kept it off the world, and an arm goal or a
servo target could reach into a shelf beside the robot. The map (``nav_msgs/OccupancyGrid``: what stands on the
floor, in the band of heights the robot occupies) is the world the robot knows. Each point of the arm's skeleton
(``ArmKinematics.skeleton``: its axes) that is within that band must be at least ``margin`` (the links' thickness,
the description's ``world_margin``) from every occupied cell in plan view.

It is conservative: a 2D map says what stands on a cell, not how high, so an arm is kept out of the air above a
table as well as out of the table. Unknown cells (and the world beyond the map) count as free, as the navigator
counts them.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence, Tuple

import numpy as np

from temoto_robot_manager.navigation.costmap import OCCUPIED_THRESHOLD

BAND = (0.02, 2.0)          # m above the floor: the heights a map marks (the sim's map is drawn in this band)


class WorldClearance:
    def __init__(self, margin: float, reach: float = 0.0, band: Tuple[float, float] = BAND) -> None:
        """``margin``: the clearance every point keeps; ``reach``: how far (m, at least ``margin``) ``nearest`` looks,
        so that a servo can slow down before the margin, not only halt at it."""
        if not margin > 0:
            raise ValueError('margin %r must be above 0' % margin)
        self.margin, self.band = margin, band
        self.reach = max(margin, reach)
        self._occupied: Optional[np.ndarray] = None       # rows = y from the origin
        self._origin = (0.0, 0.0)
        self._resolution = 1.0
        self._window = np.zeros((0, 2), dtype=int)         # the cells around a point's that the reach can touch

    @property
    def known(self) -> bool:
        """A map has come: the world can be checked."""
        return self._occupied is not None

    def set_map(self, origin: Tuple[float, float], resolution: float, width: int, height: int, data) -> None:
        """A ``nav_msgs/OccupancyGrid``'s fields."""
        cells = int(math.ceil(self.reach / resolution))
        span = np.arange(-cells, cells + 1)
        self._window = np.stack(np.meshgrid(span, span, indexing='ij'), axis=-1).reshape(-1, 2)
        self._origin, self._resolution = origin, resolution
        self._occupied = np.asarray(data, dtype=np.int16).reshape(height, width) >= OCCUPIED_THRESHOLD

    def nearest(self, points_base: np.ndarray, base_in_map: np.ndarray) -> Optional[Tuple[float, np.ndarray]]:
        """The arm's points (K x 3, in its base frame, whose pose in the map is ``base_in_map``, 4 x 4) nearest the
        map's obstacles: (its distance to them in plan view, the point in the map), when within ``reach``; None
        when farther, or when no map has come."""
        if self._occupied is None or not len(points_base):
            return None
        pts = (base_in_map[:3, :3] @ points_base.T).T + base_in_map[:3, 3]
        pts = pts[(pts[:, 2] >= self.band[0]) & (pts[:, 2] <= self.band[1])]
        if not len(pts):
            return None
        res, (ox, oy) = self._resolution, self._origin
        here = np.floor((pts[:, :2] - (ox, oy)) / res).astype(int)[:, ::-1]        # (row, col) of each point
        cells = here[:, None, :] + self._window[None, :, :]                          # K x W x (row, col)
        h, w = self._occupied.shape
        inside = (cells[..., 0] >= 0) & (cells[..., 0] < h) & (cells[..., 1] >= 0) & (cells[..., 1] < w)
        hit = np.zeros(inside.shape, dtype=bool)
        hit[inside] = self._occupied[cells[..., 0][inside], cells[..., 1][inside]]
        if not hit.any():
            return None
        # each point's distance to the occupied cells' squares near it, exactly
        lo_x, lo_y = ox + cells[..., 1] * res, oy + cells[..., 0] * res
        dx = np.maximum(np.maximum(lo_x - pts[:, None, 0], pts[:, None, 0] - (lo_x + res)), 0.0)
        dy = np.maximum(np.maximum(lo_y - pts[:, None, 1], pts[:, None, 1] - (lo_y + res)), 0.0)
        distance = np.where(hit, np.hypot(dx, dy), np.inf)
        k, c = np.unravel_index(int(np.argmin(distance)), distance.shape)
        if distance[k, c] > self.reach:
            return None
        return float(distance[k, c]), pts[k]

    def free(self, points_base: np.ndarray, base_in_map: np.ndarray) -> Optional[Tuple[float, str]]:
        """(how far the arm is beyond its margin, m: at or below 0 it touches; a text naming where), when the arm is
        within ``reach`` of an obstacle."""
        near = self.nearest(points_base, base_in_map)
        if near is None:
            return None
        distance, (x, y, z) = near
        return distance - self.margin, ('%.2f m from the map\'s obstacle at (%.2f, %.2f), %.2f m up (it keeps %.2f m '
                                        'clear)' % (distance, x, y, z, self.margin))

    def touch(self, points_base: np.ndarray, base_in_map: np.ndarray) -> Optional[str]:
        """Why the arm's points come within the margin of the map's obstacles, or None (also when no map has
        come)."""
        near = self.free(points_base, base_in_map)
        return 'it would come %s' % near[1] if near is not None and near[0] < 0 else None


def way_touch(touch, start: Sequence[float], goal: Sequence[float], step_rad: float) -> Optional[Tuple[float, str]]:
    """The first place (the fraction of the way, and why) where ``touch(q)`` finds a contact on the straight
    joint-space way from ``start`` to ``goal``, checked every ``step_rad``; None when the way is clear."""
    span = max((abs(g - s) for s, g in zip(start, goal)), default=0.0)
    steps = max(1, int(math.ceil(span / step_rad)))
    for k in range(1, steps + 1):
        f = k / steps
        why = touch([s + (g - s) * f for s, g in zip(start, goal)])
        if why:
            return f, why
    return None
