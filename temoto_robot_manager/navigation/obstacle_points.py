"""An obstacle source's frame as points on the floor plan, in the base's frame.

Each source is flattened the same way, whatever it is (the issue's SICK scan, stitched arm-LIDAR
cloud or D435 cloud): its points are brought into the base's frame, those in the height band the
robot occupies are kept, the robot's own footprint is cut out (a scanner sees the body it sits on),
and what is left is thinned to one point per ``CELL`` of floor.
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Transform
from sensor_msgs.msg import LaserScan, PointCloud2, PointField

from temoto_robot_manager.navigation.costmap import Footprint

BAND = (0.05, 2.0)             # m above the base's origin: above the floor, below the arms' reach
SELF_MARGIN = 0.05             # m around the footprint counted as the robot itself
CELL = 0.05                    # m: the costmap's resolution

_DTYPES = {PointField.FLOAT32: '<f4', PointField.FLOAT64: '<f8'}


def matrix_of(t: Transform) -> np.ndarray:
    """A geometry_msgs/Transform as a 4x4 matrix."""
    return matrix_of_pose(t.translation, t.rotation)


def matrix_of_pose(position, orientation) -> np.ndarray:
    """A position (x, y, z) and a unit quaternion (x, y, z, w), as in a Pose or a Transform, as a 4x4 matrix."""
    x, y, z, w = orientation.x, orientation.y, orientation.z, orientation.w
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = position.x, position.y, position.z
    return m


def scan_points(scan: LaserScan) -> np.ndarray:
    """The scan's hits (N x 3) in its own frame."""
    ranges = np.asarray(scan.ranges, dtype=float)
    angles = scan.angle_min + scan.angle_increment * np.arange(len(ranges))
    hit = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges < scan.range_max)
    r, a = ranges[hit], angles[hit]
    return np.stack([r * np.cos(a), r * np.sin(a), np.zeros(len(r))], axis=1)


def cloud_points(cloud: PointCloud2) -> np.ndarray:
    """The cloud's finite points (N x 3) in its own frame; raises ValueError when it has no x, y, z."""
    fields = {f.name: f for f in cloud.fields}
    if not all(k in fields for k in 'xyz'):
        raise ValueError('a PointCloud2 without x, y and z fields')
    if cloud.is_bigendian:
        raise ValueError('a big-endian PointCloud2')
    names = list('xyz')
    try:
        dtype = np.dtype({'names': names, 'formats': [_DTYPES[fields[k].datatype] for k in names],
                          'offsets': [fields[k].offset for k in names], 'itemsize': cloud.point_step})
    except KeyError:
        raise ValueError('x, y and z must be FLOAT32 or FLOAT64') from None
    count = cloud.width * cloud.height
    raw = np.frombuffer(cloud.data, dtype=dtype, count=count) if cloud.row_step == cloud.width * cloud.point_step \
        else np.concatenate([np.frombuffer(cloud.data, dtype=dtype, count=cloud.width, offset=row * cloud.row_step)
                             for row in range(cloud.height)])
    pts = np.stack([raw['x'], raw['y'], raw['z']], axis=1).astype(float)
    return pts[np.isfinite(pts).all(axis=1)]


def base_points(frame, sensor_to_base: np.ndarray, footprint: Footprint) -> np.ndarray:
    """``frame`` (a LaserScan or a PointCloud2) as floor points (N x 2) in the base's frame."""
    pts = scan_points(frame) if isinstance(frame, LaserScan) else cloud_points(frame)
    if not len(pts):
        return np.zeros((0, 2))
    pts = pts @ sensor_to_base[:3, :3].T + sensor_to_base[:3, 3]
    keep = (pts[:, 2] >= BAND[0]) & (pts[:, 2] <= BAND[1])
    if isinstance(frame, LaserScan):
        keep[:] = True                   # a planar scanner's plane is the band it watches, wherever it is mounted
    xy = pts[keep, :2]
    xy = xy[~footprint.contains(xy, SELF_MARGIN)]
    if not len(xy):
        return xy
    cells = np.unique(np.floor(xy / CELL).astype(np.int64), axis=0)
    return (cells + 0.5) * CELL
