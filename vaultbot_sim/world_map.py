"""The lab's map: the world's collision shapes within the robot's height, as a 2D occupancy grid. No ROS.

A real robot's map comes from SLAM, saved once and served by a map server. The simulated lab is
known exactly, so its map is drawn from the world URDF instead: every box and cylinder whose
height range meets the band a base can hit (``BAND``) marks the cells under it. A cell is marked
when any part of the shape's footprint falls in it (the footprint is sampled at a quarter of a
cell), so a shelf's 3 cm side still blocks its cell at 5 cm.

The grid follows ``nav_msgs/OccupancyGrid``: row-major from the origin corner, 100 occupied,
0 free.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Tuple

import numpy as np

from vaultbot_sim.kinematics import TreeModel

RESOLUTION = 0.05              # m per cell, as a navigation map is usually saved
BAND = (0.02, 2.0)             # heights (m) the robot's body and arms occupy: the floor is below, the ceiling above
MARGIN = 0.5                   # m of free border around the shapes' extent
OCCUPIED, FREE = 100, 0


@dataclass(frozen=True)
class GridMap:
    origin: Tuple[float, float]      # the corner of cell (0, 0), in the world frame (m)
    resolution: float
    cells: np.ndarray                # int8, rows = y, columns = x

    @property
    def size(self) -> Tuple[int, int]:
        """(width, height) in cells."""
        return self.cells.shape[1], self.cells.shape[0]


def _samples(half_x: float, half_y: float, step: float) -> np.ndarray:
    xs = np.linspace(-half_x, half_x, max(2, int(math.ceil(2 * half_x / step)) + 1))
    ys = np.linspace(-half_y, half_y, max(2, int(math.ceil(2 * half_y / step)) + 1))
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size), np.ones(gx.size)])


def footprints(world: TreeModel, cfg: Mapping[str, float] = {}, band: Tuple[float, float] = BAND,
               step: float = RESOLUTION / 4) -> np.ndarray:
    """Points (N x 2, world frame) covering every collision shape's footprint that meets ``band``."""
    out = []
    for link in world.urdf.robot.links:
        pose = world.link_pose(link.name, cfg)
        for collision in link.collisions:
            geometry = collision.geometry
            origin = collision.origin if collision.origin is not None else np.eye(4)
            m = pose @ origin
            if geometry.box is not None:
                sx, sy, sz = geometry.box.size
                pts = _samples(sx / 2, sy / 2, step)
                # the box's corners give its height range, whatever its rotation
                corners = np.array([[x, y, z, 1.0] for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2)
                                    for z in (-sz / 2, sz / 2)]).T
                zs = (m @ corners)[2]
            elif geometry.cylinder is not None:
                r, length = geometry.cylinder.radius, geometry.cylinder.length
                pts = _samples(r, r, step)
                pts = pts[:, pts[0] ** 2 + pts[1] ** 2 <= r * r + 1e-12]
                zs = np.array([m[2, 3] - length / 2, m[2, 3] + length / 2])
            else:
                continue                   # meshes and spheres: the lab has none
            if zs.max() < band[0] or zs.min() > band[1]:
                continue
            out.append((m @ pts)[:2].T)
    return np.concatenate(out) if out else np.zeros((0, 2))


def rasterize(points: np.ndarray, resolution: float = RESOLUTION, margin: float = MARGIN) -> GridMap:
    """The grid that holds ``points`` with ``margin`` around them, each point's cell occupied."""
    lo = np.floor((points.min(axis=0) - margin) / resolution) * resolution
    hi = points.max(axis=0) + margin
    width, height = (np.ceil((hi - lo) / resolution)).astype(int)
    cells = np.full((height, width), FREE, dtype=np.int8)
    ij = np.floor((points - lo) / resolution).astype(int)
    cells[ij[:, 1], ij[:, 0]] = OCCUPIED
    return GridMap((float(lo[0]), float(lo[1])), resolution, cells)


def world_map(world: TreeModel, resolution: float = RESOLUTION) -> GridMap:
    """The map of a world URDF at its rest pose."""
    points = footprints(world)
    if not len(points):
        raise ValueError('%s: no collision box or cylinder meets heights %.2f to %.2f m' % (world.path, *BAND))
    return rasterize(points, resolution)
