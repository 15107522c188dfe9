"""The laser_stitcher node: hokuyo/scan + /joint_states -> laser_stitcher/cloud (base_link)."""
from __future__ import annotations

import math
import threading

import rospy
from sensor_msgs.msg import JointState, LaserScan, PointCloud2
from std_msgs.msg import Header

from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel
from vaultbot_sim.motion import JointHistory
from vaultbot_sim.rosmsgs import cloud_message
from vaultbot_sim.spec import SWEEP_JOINT
from vaultbot_sim.stitcher import SweepStitcher


class StitcherNode:
    def __init__(self):
        sim_ns = rospy.get_param('~sim_ns', '/vaultbot_sim').rstrip('/')
        urdf = rospy.get_param('~robot_urdf', rospy.get_param(sim_ns + '/robot_urdf', ROBOT_URDF))
        self.base_frame = rospy.get_param('~base_frame', 'base_link')
        self.stitcher = SweepStitcher(TreeModel(urdf), rospy.get_param('~sweep_joint', SWEEP_JOINT),
                                      sensor_frame=rospy.get_param('~sensor_frame', 'hokuyo_link'),
                                      base_frame=self.base_frame,
                                      sweep_angle=float(rospy.get_param('~sweep_angle', math.pi)),
                                      max_window=float(rospy.get_param('~max_window', 3.0)))
        self.hist = JointHistory()
        self.lock = threading.Lock()
        self.pub = rospy.Publisher('laser_stitcher/cloud', PointCloud2, queue_size=2, tcp_nodelay=True)
        rospy.Subscriber('/joint_states', JointState, self._on_js, queue_size=50, tcp_nodelay=True)
        rospy.Subscriber('hokuyo/scan', LaserScan, self._on_scan, queue_size=50, tcp_nodelay=True)

    def _on_js(self, msg: JointState) -> None:
        with self.lock:
            self.hist.add(msg.header.stamp.to_sec(), msg.name, msg.position, msg.velocity)

    def _on_scan(self, scan: LaserScan) -> None:
        t = scan.header.stamp.to_sec()
        with self.lock:
            cfg = self.hist.cfg_at(t)
            if cfg is None:
                return
            pts = self.stitcher.add(t, scan.ranges, scan.angle_min, scan.angle_increment, cfg)
        if pts is not None and len(pts):
            self.pub.publish(cloud_message(pts, Header(stamp=scan.header.stamp, frame_id=self.base_frame),
                                           dense=True))
