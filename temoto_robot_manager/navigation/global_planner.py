"""The global planner: the cheapest path over the costmap, by A* on its grid (pyastar2d). No ROS.

As navfn and nav2's NavFn do, the plan is a grid search on the costmap, with the robot's size
already in the costs (``costmap.py``), not a sampling planner over the robot's shape. Why A* in C++
(pyastar2d) rather than OMPL: BENCHMARKS.md, "planners", measures both on the same 20 x 20 m grid at
5 cm. A* finds the cheapest path (the costs keep it away from obstacles), always the same one, in
less time; OMPL's RRT-Connect finds *a* path, different each time, and its state checks call
back into Python.

The path is then thinned to one point every ``SPACING`` metres, plus the goal, which is what the
path follower steers along.
"""
from __future__ import annotations

import math
from typing import Tuple

import numpy as np
import pyastar2d

from temoto_robot_manager.navigation.costmap import Costmap

SPACING = 0.10                 # m between the plan's points


class NoPath(Exception):
    """No path joins the start and the goal; the message says why."""


def thin(points: np.ndarray, spacing: float = SPACING) -> np.ndarray:
    """``points`` (N x 2) kept one per ``spacing`` metres of travel, the first and the last always."""
    if len(points) <= 2:
        return points
    steps = np.hypot(*np.diff(points, axis=0).T)
    travelled = np.concatenate([[0.0], np.cumsum(steps)])
    keep = np.unique(np.searchsorted(travelled, np.arange(0.0, travelled[-1], spacing)))
    return np.vstack([points[keep], points[-1:]])


def plan(costmap: Costmap, start: Tuple[float, float], goal: Tuple[float, float]) -> np.ndarray:
    """The path (N x 2, map frame) from ``start`` to ``goal``; raises :class:`NoPath` saying why."""
    weights = costmap.weights(free_around=start)
    si, sj = costmap.cell(*start)
    gi, gj = costmap.cell(*goal)
    if not math.isfinite(weights[gi, gj]):
        raise NoPath('the goal (%.2f, %.2f) is within %.2f m of an obstacle' % (
            goal[0], goal[1], costmap.lethal_cells * costmap.resolution))
    cells = pyastar2d.astar_path(weights, (si, sj), (gi, gj), allow_diagonal=True)
    if cells is None:
        raise NoPath('no way from (%.2f, %.2f) to (%.2f, %.2f): obstacles close every path' % (*start, *goal))
    points = (cells[:, ::-1].astype(float) + 0.5) * costmap.resolution + costmap.origin
    points[0], points[-1] = start, goal          # from where the robot is to exactly where it was sent
    return thin(points)


def length(path: np.ndarray) -> float:
    return float(np.hypot(*np.diff(path, axis=0).T).sum()) if len(path) > 1 else 0.0


def remaining(path: np.ndarray, x: float, y: float) -> Tuple[float, int]:
    """(metres left along ``path`` from its point nearest (x, y), that point's index)."""
    nearest = int(np.argmin(np.hypot(path[:, 0] - x, path[:, 1] - y)))
    tail = path[nearest:]
    return math.hypot(tail[0, 0] - x, tail[0, 1] - y) + length(tail), nearest

