"""The laser_stitcher node: hokuyo/scan + /joint_states (+ odom) -> laser_stitcher/cloud (base_link).

The base's odometry (``odom``, when a base controller publishes it) places each scan where the base
was when it was taken, so a cloud gathered while driving shows the world where it is now
(``stitcher.py``).

``~mode: rolling`` (default) publishes the latest sweep's worth of scans
(``RollingStitcher``) at ``~publish_rate`` Hz, driven by the scans themselves:
the first cloud goes out as soon as the window holds ``~min_scans`` scans (a few
tens of ms after the driver's first scan), then one at most every period. A
stalled scanner therefore stalls the cloud too (nothing stale is republished),
and every cloud carries the stamp of its newest scan. ``~mode: sweep`` publishes
one cloud per finished sweep instead (``SweepStitcher``).
"""
from __future__ import annotations

import math
import threading

import rospy
from temoto_core import params
from nav_msgs.msg import Odometry
from sensor_msgs.msg import JointState, LaserScan, PointCloud2
from std_msgs.msg import Header

from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel, planar_matrix
from vaultbot_sim.motion import JointHistory
from vaultbot_sim.rosmsgs import cloud_message
from vaultbot_sim.spec import SELF_BOX, SWEEP_JOINT
from vaultbot_sim.stitcher import RollingStitcher, SweepStitcher

MODES = ('rolling', 'sweep')
BASE = ('x', 'y', 'yaw')              # the base's pose in odom, kept as a JointHistory of three "joints"
# a scan arriving this share of a period early still publishes (scan stamps jitter; 40 Hz scans at 10 Hz
# would otherwise alternate between 3 and 5 scans per cloud)
PERIOD_SLACK = 0.1


class StitcherNode:
    def __init__(self):
        # Advertised first, before the kinematic model is built: subscribers (RViz's roscpp takes ~0.25 s
        # to connect to a new publisher on a busy machine) connect meanwhile and get the first cloud.
        self.pub = rospy.Publisher('laser_stitcher/cloud', PointCloud2, queue_size=2, tcp_nodelay=True)
        self.published = False
        sim_ns = rospy.resolve_name(params.text('sim_ns', 'vaultbot_sim', empty=False)).rstrip('/')
        urdf = rospy.get_param('~robot_urdf', rospy.get_param(sim_ns + '/robot_urdf', ROBOT_URDF))
        # the cloud is computed in the robot's own (unprefixed) model, and stamped with its robot's frame
        self.base_frame = params.text('base_frame', 'base_link', empty=False)
        self.frame_prefix = str(rospy.get_param(sim_ns + '/frame_prefix', ''))
        self.mode = params.text('mode', 'rolling', choices=MODES)
        self.period = 1.0 / params.number('publish_rate', 10.0, above=0, maximum=100)
        self.min_scans = params.number('min_scans', 3, minimum=1, integer=True)
        self_box = rospy.get_param('~self_box', list(SELF_BOX))
        if not (isinstance(self_box, list) and len(self_box) == 6 and all(isinstance(v, (int, float)) for v in self_box)):
            raise ValueError('~self_box must be [x_min, x_max, y_min, y_max, z_min, z_max] in the base frame, '
                             'got %r' % (self_box,))
        common = dict(sensor_frame=params.text('sensor_frame', 'hokuyo_link', empty=False),
                      base_frame=self.base_frame, sweep_angle=params.number('sweep_angle', math.pi, above=0),
                      self_box=tuple(float(v) for v in self_box))
        model, joint = TreeModel(urdf), params.text('sweep_joint', SWEEP_JOINT, empty=False)
        if self.mode == 'rolling':
            # max_window: a back-and-forth wrist last saw the far end of its travel a whole period ago
            self.stitcher = RollingStitcher(model, joint, max_window=params.number('max_window', 4.5, above=0),
                                            angle_bin=params.number('angle_bin', math.pi / 80, above=0), **common)
        else:
            self.stitcher = SweepStitcher(model, joint, max_window=params.number('max_window', 3.0, above=0),
                                          **common)
        self.last_published: float | None = None    # stamp of the last cloud (rolling mode)
        self.hist = JointHistory()
        self.base_hist = JointHistory()
        self.lock = threading.Lock()
        rospy.Subscriber('joint_states', JointState, self._on_js, queue_size=50, tcp_nodelay=True)
        rospy.Subscriber('odom', Odometry, self._on_odom, queue_size=50, tcp_nodelay=True)
        rospy.Subscriber('hokuyo/scan', LaserScan, self._on_scan, queue_size=50, tcp_nodelay=True)

    def _on_js(self, msg: JointState) -> None:
        with self.lock:
            self.hist.add(msg.header.stamp.to_sec(), msg.name, msg.position, msg.velocity)

    def _on_odom(self, msg: Odometry) -> None:
        q, v = msg.pose.pose.orientation, msg.twist.twist
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        with self.lock:
            if not len(self.base_hist):
                # the scans held so far were placed with the base at the origin of odom: start again
                self.stitcher.clear()
            self.base_hist.add(msg.header.stamp.to_sec(), BASE,
                               (msg.pose.pose.position.x, msg.pose.pose.position.y, yaw),
                               (v.linear.x * math.cos(yaw), v.linear.x * math.sin(yaw), v.angular.z))

    def _on_scan(self, scan: LaserScan) -> None:
        t = scan.header.stamp.to_sec()
        with self.lock:
            cfg = self.hist.cfg_at(t)
            if cfg is None:
                return
            pose = self.base_hist.cfg_at(t)
            base = planar_matrix(pose['x'], pose['y'], pose['yaw']) if pose is not None else None
            if self.mode == 'sweep':
                pts = self.stitcher.add(t, scan.ranges, scan.angle_min, scan.angle_increment, cfg, base)
            else:
                self.stitcher.add(t, scan.ranges, scan.angle_min, scan.angle_increment, cfg, base)
                pts = self._due(t)
        if pts is not None and len(pts):
            self.pub.publish(cloud_message(pts, Header(stamp=scan.header.stamp, frame_id=self.frame_prefix + self.base_frame),
                                           dense=True))
            if not self.published:
                self.published = True
                rospy.loginfo('laser_stitcher: first cloud published (%d points)', len(pts))

    def _due(self, t: float):
        """The window's cloud when one is due at scan stamp ``t``, else None (caller holds the lock)."""
        if len(self.stitcher) < self.min_scans:
            return None
        last = self.last_published
        if last is not None and last <= t < last + self.period * (1.0 - PERIOD_SLACK):
            return None
        self.last_published = t
        return self.stitcher.cloud()
