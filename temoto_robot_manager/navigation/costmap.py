"""The navigator's costmap: the map's obstacles and the live obstacle source's, inflated by the robot. No ROS.

Two layers, as move_base's costmap has them:
- the **static layer**, from the map (a saved ``nav_msgs/OccupancyGrid``): each cell's distance to the
  nearest occupied cell, computed once;
- the **obstacle layer**, from the active obstacle source's latest frame only: a frame replaces the
  last, so an obstacle that has gone clears with the next frame, as a scan clears its rays.

A cell is *lethal* when the robot's centre there would leave it no room to turn in place: an
obstacle within its circumscribed radius plus ``PADDING``. The planner never enters one, so
wherever a plan takes the robot it can turn to follow it, its arms included. Beyond, a cost that
falls off with distance keeps paths away from obstacles, up to ``COST_REACH`` further. Places
close to furniture (a table to work at) are lethal by this rule: the robot reaches them on a
straight last stretch, checked for its whole outline, and leaves them backing out along it
(``navigator.py``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

PADDING = 0.15                 # m beyond the circumscribed radius that is still lethal: the monitor's stop margin at a
                               # corner (0.07) and a cell's rounding (0.035), with some to spare
COST_REACH = 0.35              # m beyond the circumscribed radius over which the cost falls to nothing
COST_SCALE = 40.0              # the cost just outside the lethal zone, in cells' worth of travel
OCCUPIED_THRESHOLD = 50        # an OccupancyGrid value at or above this is an obstacle (map_server's 0.65 x 100)


@dataclass(frozen=True)
class Footprint:
    """The robot's outline on the floor, in ``base_link``'s frame (m): everything it carries included, as its
    arms hold while it drives. A rectangle, which need not be centred (the VaultBot's arms reach further
    forward than its bumper does back), and the parts that stick out of it (``protrusions``, rectangles too:
    a gripper ahead of the bumper). A part is kept clear as the body is; it does not widen the outline all
    round, as a rectangle grown to hold it would, and so the turning circle grows only as far as it reaches."""
    x_min: float
    x_max: float
    y_min: float
    y_max: float
    protrusions: Tuple[Tuple[float, float, float, float], ...] = ()

    @classmethod
    def centred(cls, length: float, width: float) -> 'Footprint':
        return cls(-length / 2, length / 2, -width / 2, width / 2)

    @classmethod
    def of(cls, numbers, protrusions=()) -> 'Footprint':
        """From a description's ``footprint``: [length, width] (centred) or [x_min, x_max, y_min, y_max], and
        its ``protrusions``."""
        body = cls.centred(*numbers) if len(numbers) == 2 else cls(*numbers)
        return cls(body.x_min, body.x_max, body.y_min, body.y_max, tuple(tuple(p) for p in protrusions))

    @property
    def boxes(self) -> Tuple[Tuple[float, float, float, float], ...]:
        """The body and each protrusion, as (x_min, x_max, y_min, y_max)."""
        return ((self.x_min, self.x_max, self.y_min, self.y_max),) + self.protrusions

    @property
    def inscribed(self) -> float:
        """From the base's origin to the body's nearest side."""
        return min(-self.x_min, self.x_max, -self.y_min, self.y_max)

    @property
    def circumscribed(self) -> float:
        """From the base's origin to the outline's furthest corner."""
        return max(math.hypot(x, y) for x0, x1, y0, y1 in self.boxes for x in (x0, x1) for y in (y0, y1))

    def grown(self, margin: float) -> 'Footprint':
        """Each box grown by ``margin`` on every side (a negative margin shrinks it)."""
        m = margin
        return Footprint(self.x_min - m, self.x_max + m, self.y_min - m, self.y_max + m,
                         tuple((x0 - m, x1 + m, y0 - m, y1 + m) for x0, x1, y0, y1 in self.protrusions))

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Which points (N x 2, base frame) are inside the outline grown by ``margin``."""
        inside = np.zeros(len(points), dtype=bool)
        for x0, x1, y0, y1 in self.boxes:
            inside |= ((points[:, 0] >= x0 - margin) & (points[:, 0] <= x1 + margin)
                       & (points[:, 1] >= y0 - margin) & (points[:, 1] <= y1 + margin))
        return inside

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Each point's distance (m) from the outline (0 inside)."""
        nearest = np.full(len(points), np.inf)
        for x0, x1, y0, y1 in self.boxes:
            dx = np.maximum(np.maximum(x0 - points[:, 0], points[:, 0] - x1), 0.0)
            dy = np.maximum(np.maximum(y0 - points[:, 1], points[:, 1] - y1), 0.0)
            nearest = np.minimum(nearest, np.hypot(dx, dy))
        return nearest


def disk_offsets(radius_cells: float) -> Tuple[np.ndarray, np.ndarray]:
    """(offsets as (di, dj) rows, their distances in cells) within ``radius_cells``, nearest first."""
    r = int(math.ceil(radius_cells))
    di, dj = np.mgrid[-r:r + 1, -r:r + 1]
    d = np.hypot(di, dj).ravel()
    keep = d <= radius_cells
    order = np.argsort(d[keep], kind='stable')
    return np.stack([di.ravel()[keep], dj.ravel()[keep]], axis=1)[order], d[keep][order]


def distance_field(occupied: np.ndarray, reach_cells: float) -> np.ndarray:
    """Each cell's distance (cells) to the nearest ``occupied`` one, up to ``reach_cells`` (inf beyond)."""
    h, w = occupied.shape
    r = int(math.ceil(reach_cells))
    padded = np.zeros((h + 2 * r, w + 2 * r), dtype=bool)
    padded[r:r + h, r:r + w] = occupied
    dist = np.full((h, w), np.inf, dtype=np.float32)
    offsets, distances = disk_offsets(reach_cells)
    for (di, dj), d in zip(offsets, distances):       # nearest first: a cell keeps the first distance it gets
        hit = padded[r + di:r + di + h, r + dj:r + dj + w]
        dist[hit & np.isinf(dist)] = d
    return dist


class Costmap:
    """A grid in the map's frame: cells (row i = y, column j = x) from ``origin`` at ``resolution``."""

    def __init__(self, origin: Tuple[float, float], resolution: float, occupied: np.ndarray,
                 footprint: Footprint) -> None:
        if resolution <= 0 or occupied.ndim != 2 or not occupied.size:
            raise ValueError('a costmap needs a positive resolution and a non-empty 2D grid')
        self.origin = (float(origin[0]), float(origin[1]))
        self.resolution = float(resolution)
        self.footprint = footprint
        self.shape = occupied.shape
        self.lethal_cells = (footprint.circumscribed + PADDING) / resolution
        self.reach_cells = (footprint.circumscribed + COST_REACH) / resolution
        self.static_distance = distance_field(occupied.astype(bool), self.reach_cells)
        self.static_occupied = np.argwhere(occupied)          # (i, j) of the map's obstacles
        self._disk, _ = disk_offsets(self.lethal_cells)
        self.dynamic_points = np.zeros((0, 2))
        self._dynamic_cells: set = set()
        self._dynamic_grid: Optional[np.ndarray] = None
        self._static_weights = self._weights(self.static_distance)

    @classmethod
    def from_grid(cls, origin: Tuple[float, float], resolution: float, width: int, height: int, data,
                  footprint: Footprint) -> 'Costmap':
        """From a ``nav_msgs/OccupancyGrid``'s fields (unknown, -1, counts as free: the map is the lab's own)."""
        cells = np.asarray(data, dtype=np.int16).reshape(height, width)
        return cls(origin, resolution, cells >= OCCUPIED_THRESHOLD, footprint)

    def _weights(self, distance: np.ndarray) -> np.ndarray:
        """A* weights: 1 far from obstacles, rising toward them, inf where the robot cannot be."""
        span = max(self.reach_cells - self.lethal_cells, 1e-6)
        falloff = np.clip((self.reach_cells - distance) / span, 0.0, 1.0)
        weights = (1.0 + COST_SCALE * falloff ** 2).astype(np.float32)
        weights[distance <= self.lethal_cells] = np.inf
        return weights

    # -- cells and the world ----------------------------------------------------------------------------------
    def cell(self, x: float, y: float) -> Tuple[int, int]:
        return (int(math.floor((y - self.origin[1]) / self.resolution)),
                int(math.floor((x - self.origin[0]) / self.resolution)))

    def point(self, i: int, j: int) -> Tuple[float, float]:
        """The centre of cell (i, j) in the map's frame."""
        return (self.origin[0] + (j + 0.5) * self.resolution, self.origin[1] + (i + 0.5) * self.resolution)

    def inside(self, x: float, y: float) -> bool:
        i, j = self.cell(x, y)
        return 0 <= i < self.shape[0] and 0 <= j < self.shape[1]

    @property
    def bounds(self) -> Tuple[float, float, float, float]:
        """(x min, y min, x max, y max) of the grid (m)."""
        return (self.origin[0], self.origin[1], self.origin[0] + self.shape[1] * self.resolution,
                self.origin[1] + self.shape[0] * self.resolution)

    def _nearest_dynamic(self, x: float, y: float) -> float:
        """Metres from (x, y) to the source's nearest point (inf without one)."""
        pts = self.dynamic_points
        return float(np.hypot(pts[:, 0] - x, pts[:, 1] - y).min()) if len(pts) else math.inf

    def clearance(self, x: float, y: float) -> float:
        """Metres from (x, y) to the nearest known obstacle, of either layer (inf beyond the cost's reach)."""
        i, j = self.cell(x, y)
        return min(float(self.static_distance[i, j]) * self.resolution, self._nearest_dynamic(x, y))

    def lethal(self, x: float, y: float) -> bool:
        i, j = self.cell(x, y)
        return bool(self.static_distance[i, j] <= self.lethal_cells
                    or self._nearest_dynamic(x, y) <= self.lethal_cells * self.resolution)

    def occupied(self, x: float, y: float) -> bool:
        """Whether an obstacle of either layer is in the cell of (x, y)."""
        i, j = self.cell(x, y)
        return bool(self.static_distance[i, j] == 0 or (i, j) in self._dynamic_cells)

    # -- the obstacle layer -----------------------------------------------------------------------------------
    def mark(self, points: np.ndarray) -> None:
        """Replace the obstacle layer with ``points`` (N x 2, map frame). Its inflated grid is drawn only when a
        plan asks for it (``weights``, once a second): drawn for every frame, it cost 63 ms of a 40 ms scan
        period, and the single-point questions (``lethal``, ``clearance``) need only the points."""
        self.dynamic_points = points
        self._dynamic_grid = None
        self._dynamic_cells = set()
        if len(points):
            ij = np.floor((points[:, ::-1] - (self.origin[1], self.origin[0])) / self.resolution).astype(np.int64)
            self._dynamic_cells = set(map(tuple, np.unique(ij, axis=0).tolist()))

    @property
    def dynamic_lethal(self) -> np.ndarray:
        """The cells within the lethal radius of the source's points. A point on one of the map's obstacles (most
        of them: a scan sees the walls the map has) adds nothing the map's layer has not, and is skipped."""
        if self._dynamic_grid is None:
            lethal = np.zeros(self.shape, dtype=bool)
            ij = np.array(sorted(self._dynamic_cells), dtype=np.int64).reshape(-1, 2)
            inside = (ij[:, 0] >= 0) & (ij[:, 0] < self.shape[0]) & (ij[:, 1] >= 0) & (ij[:, 1] < self.shape[1])
            ij = ij[inside]
            ij = ij[self.static_distance[ij[:, 0], ij[:, 1]] > 1.0]
            if len(ij):
                stamped = (ij[:, None, :] + self._disk[None, :, :]).reshape(-1, 2)
                ok = ((stamped[:, 0] >= 0) & (stamped[:, 0] < self.shape[0]) & (stamped[:, 1] >= 0)
                      & (stamped[:, 1] < self.shape[1]))
                lethal[stamped[ok, 0], stamped[ok, 1]] = True
            self._dynamic_grid = lethal
        return self._dynamic_grid

    def weights(self, free_around: Optional[Tuple[float, float]] = None) -> np.ndarray:
        """The planner's weights, both layers. ``free_around``: the robot's place, whose lethal cells become
        merely costly, so a robot parked close to something can still plan its way out (navfn clears the
        robot's footprint likewise)."""
        weights = self._static_weights.copy()
        weights[self.dynamic_lethal] = np.inf
        if free_around is not None:
            i, j = self.cell(*free_around)
            cells = np.array([i, j]) + self._disk
            ok = ((cells[:, 0] >= 0) & (cells[:, 0] < self.shape[0]) & (cells[:, 1] >= 0)
                  & (cells[:, 1] < self.shape[1]))
            cells = cells[ok]
            sub = weights[cells[:, 0], cells[:, 1]]
            weights[cells[:, 0], cells[:, 1]] = np.where(np.isinf(sub), 1.0 + 2 * COST_SCALE, sub)
        return weights

    def static_points(self, x: float, y: float, radius: float) -> np.ndarray:
        """The map's obstacle cells within ``radius`` of (x, y), as points (N x 2, map frame)."""
        centres = (self.static_occupied[:, ::-1] + 0.5) * self.resolution + self.origin
        near = np.hypot(centres[:, 0] - x, centres[:, 1] - y) <= radius
        return centres[near]

    def points_near(self, x: float, y: float, radius: float) -> np.ndarray:
        """Both layers' obstacles within ``radius`` of (x, y): the map's cells and the source's latest points."""
        dyn = self.dynamic_points
        if len(dyn):
            dyn = dyn[np.hypot(dyn[:, 0] - x, dyn[:, 1] - y) <= radius]
        static = self.static_points(x, y, radius)
        return np.vstack([static, dyn]) if len(dyn) else static

