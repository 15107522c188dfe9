"""Synthetic sensor data for the Output Manager's tests and benchmark.

Messages whose colours are known, so a screenshot can be checked pixel by
pixel: a pure-colour organised cloud (like the D435's 424x240 RGB cloud), a
LaserScan arc, and a solid-colour image.
"""
from __future__ import annotations

import threading
from typing import Tuple

import numpy as np
import rospy
from sensor_msgs.msg import Image, LaserScan, PointCloud2, PointField


def cloud_msg(frame_id: str = 'base_link', width: int = 424, height: int = 240,
              rgb: Tuple[int, int, int] = (255, 0, 255), distance: float = 2.0) -> PointCloud2:
    """An organised cloud: a flat wall ``distance`` m ahead (x forward), one solid colour."""
    u, v = np.meshgrid(np.linspace(-1.0, 1.0, width, dtype=np.float32),
                       np.linspace(-0.6, 0.6, height, dtype=np.float32))
    pts = np.zeros((height, width), dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('rgb', '<f4')])
    pts['x'] = distance
    pts['y'] = -u
    pts['z'] = 0.6 - v
    packed = np.uint32((rgb[0] << 16) | (rgb[1] << 8) | rgb[2])
    pts['rgb'] = np.full((height, width), packed, dtype=np.uint32).view(np.float32)
    msg = PointCloud2()
    msg.header.frame_id = frame_id
    msg.height, msg.width = height, width
    msg.fields = [PointField('x', 0, PointField.FLOAT32, 1), PointField('y', 4, PointField.FLOAT32, 1),
                  PointField('z', 8, PointField.FLOAT32, 1), PointField('rgb', 12, PointField.FLOAT32, 1)]
    msg.is_bigendian = False
    msg.point_step = 16
    msg.row_step = 16 * width
    msg.is_dense = True
    msg.data = pts.tobytes()
    return msg


def scan_msg(frame_id: str = 'base_link', beams: int = 1081, distance: float = 2.0) -> LaserScan:
    msg = LaserScan()
    msg.header.frame_id = frame_id
    msg.angle_min, msg.angle_max = -2.356, 2.356
    msg.angle_increment = (msg.angle_max - msg.angle_min) / (beams - 1)
    msg.range_min, msg.range_max = 0.1, 30.0
    msg.ranges = [distance] * beams
    msg.intensities = [100.0] * beams
    return msg


def image_msg(frame_id: str = 'camera', width: int = 160, height: int = 120,
              rgb: Tuple[int, int, int] = (0, 255, 0)) -> Image:
    msg = Image()
    msg.header.frame_id = frame_id
    msg.height, msg.width = height, width
    msg.encoding = 'rgb8'
    msg.step = 3 * width
    msg.data = bytes(rgb) * (width * height)
    return msg


class RepeatingPublisher:
    """Publishes one message at a fixed rate on a thread (fresh stamp each time) until stopped."""

    def __init__(self, topic: str, msg, rate_hz: float, queue_size: int = 2):
        self.msg = msg
        self.period = 1.0 / rate_hz
        self.pub = rospy.Publisher(topic, type(msg), queue_size=queue_size)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True, name='pub ' + topic)
        self.count = 0

    def start(self) -> 'RepeatingPublisher':
        self._thread.start()
        return self

    def _loop(self) -> None:
        while not self._stop.wait(self.period):
            self.msg.header.stamp = rospy.Time.now()
            self.pub.publish(self.msg)
            self.count += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.pub.unregister()
