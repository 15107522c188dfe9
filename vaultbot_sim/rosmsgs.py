"""Building the ROS messages the sim and drivers publish, from numpy arrays.

Clouds are numpy structured arrays serialised with tobytes(): 1.7 ms for 77k points,
against 11+ ms for point_cloud2.create_cloud.
"""
from __future__ import annotations

from typing import Iterable

import numpy as np
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import CameraInfo, Image, LaserScan, PointCloud2, PointField
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from vaultbot_sim.kinematics import quat_from_matrix
from vaultbot_sim.scene import Intrinsics
from vaultbot_sim.spec import LaserSpec

XYZRGB = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('rgb', '<u4')])
XYZ = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4')])


def tf_message(transforms: Iterable[tuple[str, str, np.ndarray]], stamp) -> TFMessage:
    out = []
    for parent, child, m in transforms:
        ts = TransformStamped()
        ts.header.stamp = stamp
        ts.header.frame_id = parent
        ts.child_frame_id = child
        ts.transform.translation.x, ts.transform.translation.y, ts.transform.translation.z = (
            float(m[0, 3]), float(m[1, 3]), float(m[2, 3]))
        q = quat_from_matrix(m)
        r = ts.transform.rotation
        r.x, r.y, r.z, r.w = q
        out.append(ts)
    return TFMessage(transforms=out)


def _fields(dtype: np.dtype) -> list[PointField]:
    # rgb travels as FLOAT32 carrying packed 0x00RRGGBB bits, as PCL and RViz expect.
    return [PointField(name=n, offset=dtype.fields[n][1], datatype=PointField.FLOAT32, count=1)
            for n in dtype.names]


def cloud_message(points: np.ndarray, header: Header, width: int | None = None,
                  height: int = 1, dense: bool = False) -> PointCloud2:
    width = len(points) if width is None else width
    return PointCloud2(header=header, height=height, width=width, fields=_fields(points.dtype),
                       is_bigendian=False, point_step=points.dtype.itemsize,
                       row_step=points.dtype.itemsize * width, data=points.tobytes(), is_dense=dense)


def pack_rgb(rgb: np.ndarray) -> np.ndarray:
    rgb = rgb.astype(np.uint32)
    return (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]


class DepthProjector:
    """Depth image (z in metres) + colour -> organised xyz+rgb cloud in the optical frame."""

    def __init__(self, intr: Intrinsics, range_min: float, range_max: float):
        self.intr, self.range_min, self.range_max = intr, range_min, range_max
        u = (np.arange(intr.width, dtype=np.float32) - intr.cx) / intr.fx
        v = (np.arange(intr.height, dtype=np.float32) - intr.cy) / intr.fy
        self.ux, self.vy = np.meshgrid(u, v)
        self.out = np.empty((intr.height, intr.width), dtype=XYZRGB)

    def project(self, z: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        z = z.astype(np.float32, copy=True)
        z[(z < self.range_min) | (z > self.range_max)] = np.nan
        out = self.out
        out['x'] = self.ux * z
        out['y'] = self.vy * z
        out['z'] = z
        out['rgb'] = pack_rgb(rgb)
        return out


def camera_info(intr: Intrinsics, header: Header) -> CameraInfo:
    return CameraInfo(header=header, height=intr.height, width=intr.width, distortion_model='plumb_bob',
                      D=[0.0] * 5, K=intr.k(), R=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
                      P=[intr.fx, 0.0, intr.cx, 0.0, 0.0, intr.fy, intr.cy, 0.0, 0.0, 0.0, 1.0, 0.0])


def image_message(rgb: np.ndarray, header: Header) -> Image:
    h, w = rgb.shape[:2]
    return Image(header=header, height=h, width=w, encoding='rgb8', is_bigendian=0, step=3 * w,
                 data=np.ascontiguousarray(rgb).tobytes())


def scan_message(spec: LaserSpec, ranges: np.ndarray, header: Header) -> LaserScan:
    return LaserScan(header=header, angle_min=spec.angle_min,
                     angle_max=spec.angle_min + spec.angle_increment * (spec.beams - 1),
                     angle_increment=spec.angle_increment, time_increment=0.0,
                     scan_time=1.0 / spec.rate_hz, range_min=spec.range_min, range_max=spec.range_max,
                     ranges=ranges.tolist(), intensities=[])
