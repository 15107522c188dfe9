"""The sensor drivers: D435 (RGB-D), Hokuyo UTM-30LX and SICK LMS511 (2D lasers) on the robot, the site
LIDAR, a 2D laser fixed in the lab, and the operator's hand tracker."""
from __future__ import annotations

import time

import numpy as np
import rospy
from temoto_core import params
from sensor_msgs.msg import CameraInfo, Image, LaserScan, PointCloud2
from std_msgs.msg import Header
from temoto_core.msg import HandSample
from tf2_msgs.msg import TFMessage

from vaultbot_sim.driver import DriverBase
from vaultbot_sim.hand_path import HandPath
from vaultbot_sim.render_worker import RenderWorker
from vaultbot_sim.rosmsgs import DepthProjector, camera_info, cloud_message, image_message, scan_message, tf_message
from vaultbot_sim.scene import Intrinsics
from vaultbot_sim.spec import D435, HOKUYO, SICK, SITE_LIDAR, SITE_LIDAR_POSE, LaserSpec


class LaserDriver(DriverBase):
    spec: LaserSpec
    topic = ''

    def __init__(self):
        self.default_rate = self.spec.rate_hz
        self.pub = rospy.Publisher(self.topic, LaserScan, queue_size=5, tcp_nodelay=True)   # first: see DriverBase
        super().__init__()
        self.threads = params.number('ray_threads', 1, minimum=1, maximum=16, integer=True)
        self.angles = self.spec.angle_min + np.arange(self.spec.beams) * self.spec.angle_increment

    def sensor_pose(self) -> np.ndarray:
        return self.scene.robot_link_pose(self.spec.frame)

    def publish(self, stamp: rospy.Time) -> None:
        pose = self.sensor_pose()
        ranges = self.scene.laser(pose, self.angles, self.spec.range_min, self.spec.range_max, self.threads)
        self.pub.publish(scan_message(self.spec, ranges, Header(stamp=stamp, frame_id=self.frame_prefix + self.spec.frame)))


class HokuyoDriver(LaserDriver):
    device = 'hokuyo'
    spec = HOKUYO
    topic = 'hokuyo/scan'


class SickDriver(LaserDriver):
    device = 'sick'
    spec = SICK
    topic = 'sick/scan'


class SiteLidarDriver(LaserDriver):
    """A scanner on a post in the lab: its pose is fixed in the world, and it says so on /tf_static itself,
    so a station that runs it can draw its scans while the robot's link is down (the robot's static frames
    are latched there already)."""
    device = 'site_lidar'
    spec = SITE_LIDAR
    topic = 'site_lidar/scan'

    def __init__(self):
        super().__init__()
        x, y, z, yaw = SITE_LIDAR_POSE
        self.pose = np.eye(4)
        self.pose[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
        self.pose[:3, 3] = (x, y, z)
        self.tf_static = rospy.Publisher('/tf_static', TFMessage, queue_size=1, latch=True)
        self.tf_static.publish(tf_message([(self.frame_prefix + 'world', self.frame_prefix + self.spec.frame,
                                            self.pose)], rospy.Time.now()))

    def sensor_pose(self) -> np.ndarray:
        return self.pose


class D435Driver(DriverBase):
    device = 'd435'
    default_rate = D435.rate_hz

    def __init__(self):
        # first: see DriverBase
        self.pub_points = rospy.Publisher('d435/depth_registered/points', PointCloud2, queue_size=2, tcp_nodelay=True)
        self.pub_image = rospy.Publisher('d435/color/image_raw', Image, queue_size=2, tcp_nodelay=True)
        self.pub_info = rospy.Publisher('d435/color/camera_info', CameraInfo, queue_size=2, tcp_nodelay=True)
        self.intr = Intrinsics.from_hfov(D435.width, D435.height, D435.hfov_deg)
        super().__init__()
        self.projector = DepthProjector(self.intr, D435.range_min, D435.range_max)

    def make_scene(self):
        # rendering runs in a child process; see render_worker.py for why
        self.worker = RenderWorker(self.robot_urdf, self.world_urdf, self.renderer, D435.frame, self.intr,
                                   D435.range_min, D435.range_max + 0.5)
        return None

    def close(self) -> None:
        self.worker.close()

    def publish(self, stamp: rospy.Time) -> None:
        # Pipelined: the child renders this tick's frame while we project and publish the previous
        # one. Each frame keeps the stamp of the joint state it was rendered from.
        pending, self.pending = getattr(self, 'pending', None), stamp
        if pending is not None:
            rgb, z = self.worker.result()
        self.worker.request(*self.cfg)
        if pending is None:
            return
        header = Header(stamp=pending, frame_id=self.frame_prefix + D435.frame)
        # Build only what someone listens to; the cloud is the expensive part.
        if self.pub_points.get_num_connections():
            pts = self.projector.project(z, rgb)
            self.pub_points.publish(cloud_message(pts, header, width=self.intr.width, height=self.intr.height))
        if self.pub_image.get_num_connections():
            self.pub_image.publish(image_message(rgb, header))
        self.pub_info.publish(camera_info(self.intr, header))


class HandTrackerDriver(DriverBase):
    """A hand tracker on the operator's station, as a Leap Motion: the palm's pose and the grab strength, at
    100 Hz, replayed from a path (``~path``: a file of keyframes, ``hand_path.py``; the default path
    otherwise). It has a cable like the robot's devices (``hand_tracker``), so it can be unplugged."""
    device = 'hand_tracker'
    default_rate = 100.0
    sees_the_lab = False                  # on the operator's station, where the robot's joint states may not be

    def __init__(self):
        self.pub = rospy.Publisher('hand/sample', HandSample, queue_size=10, tcp_nodelay=True)
        self.frame = params.text('frame', 'hand_tracker', empty=False)
        path = rospy.get_param('~path', '')
        try:
            self.path = HandPath.read(path) if path else HandPath()
        except (OSError, ValueError) as err:
            rospy.logerr('hand_tracker: ~path: %s', err)
            raise SystemExit(2)
        super().__init__()
        self.t0 = time.monotonic()

    def make_scene(self):
        return None                       # it sees a hand, not the lab

    def publish(self, stamp: rospy.Time) -> None:
        _, x, y, z, grab = self.path.at(time.monotonic() - self.t0)
        msg = HandSample(tracked=True, grab_strength=grab)
        msg.header.stamp, msg.header.frame_id = stamp, self.frame
        msg.palm.position.x, msg.palm.position.y, msg.palm.position.z = x, y, z
        msg.palm.orientation.w = 1.0
        self.pub.publish(msg)
