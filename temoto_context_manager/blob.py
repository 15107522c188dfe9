"""Finding a brightly coloured object in an xyz+rgb point cloud (ROS-free, numpy).

The cloud is decoded straight from ``PointCloud2.data`` with a structured dtype
built from its fields, so a 424x240 cloud costs a few milliseconds.
"""
from typing import Optional, Sequence, Tuple

import numpy as np

_DATATYPES = {1: 'i1', 2: 'u1', 3: 'i2', 4: 'u2', 5: 'i4', 6: 'u4', 7: 'f4', 8: 'f8'}


def cloud_array(fields: Sequence, point_step: int, data: bytes, big_endian: bool = False) -> np.ndarray:
    """A structured array of the cloud's points (``fields``: sensor_msgs/PointField-like objects)."""
    order = '>' if big_endian else '<'
    dtype = np.dtype({'names': [f.name for f in fields],
                      'formats': [order + _DATATYPES[f.datatype] for f in fields],
                      'offsets': [f.offset for f in fields], 'itemsize': point_step})
    return np.frombuffer(data, dtype=dtype)


def find_blob(points: np.ndarray, target_rgb: Tuple[int, int, int], tolerance: int,
              min_points: int) -> Optional[Tuple[float, float, float, int]]:
    """Centroid (x, y, z, n) of the finite points within ``tolerance`` of ``target_rgb`` per channel, or None."""
    if 'rgb' not in points.dtype.names:
        raise ValueError('the cloud has no rgb field (fields: %s)' % ', '.join(points.dtype.names))
    rgb = np.ascontiguousarray(points['rgb']).view(np.uint32)
    r = ((rgb >> 16) & 0xFF).astype(np.int16)
    g = ((rgb >> 8) & 0xFF).astype(np.int16)
    b = (rgb & 0xFF).astype(np.int16)
    tr, tg, tb = target_rgb
    mask = (np.abs(r - tr) <= tolerance) & (np.abs(g - tg) <= tolerance) & (np.abs(b - tb) <= tolerance)
    x, y, z = points['x'][mask], points['y'][mask], points['z'][mask]
    finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    n = int(finite.sum())
    if n < min_points:
        return None
    return float(x[finite].mean()), float(y[finite].mean()), float(z[finite].mean()), n


def parse_rgb(text: str) -> Tuple[int, int, int]:
    parts = [p.strip() for p in str(text).split(',')]
    if len(parts) != 3 or not all(p.isdigit() and 0 <= int(p) <= 255 for p in parts):
        raise ValueError('target_rgb must be "R,G,B" with each in 0..255, got %r' % (text,))
    return int(parts[0]), int(parts[1]), int(parts[2])
