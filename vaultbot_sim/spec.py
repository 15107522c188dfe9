"""Facts about the VaultBot's devices and its stowed pose, in one place.

Sensor figures are the devices' datasheet ones. The hold
pose was found with kinematics.solve_tool_pose: the D435 sits at about
(0.62, 0.32, 1.12) m in base_link looking ahead, pitched 8 degrees down, and the
Hokuyo at (0.62, -0.32, 1.05) m with its scan plane's x axis (= wrist_3 axis)
pointing ahead, so turning wrist_3 sweeps the plane over the front hemisphere.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

ARM_JOINTS = ['shoulder_pan', 'shoulder_lift', 'elbow', 'wrist_1', 'wrist_2', 'wrist_3']
WHEEL_JOINTS = ['front_left_wheel_joint', 'front_right_wheel_joint', 'rear_left_wheel_joint',
                'rear_right_wheel_joint']

_LEFT = [-0.121, -1.694, -1.673, -3.018, -1.789, -0.802]
_RIGHT = [0.579, -1.537, -1.999, -2.748, -0.991, -2.356]
STOW_POSE: dict[str, float] = {**{w: 0.0 for w in WHEEL_JOINTS},
                               **{f'left_{n}_joint': q for n, q in zip(ARM_JOINTS, _LEFT)},
                               **{f'right_{n}_joint': q for n, q in zip(ARM_JOINTS, _RIGHT)}}

# The base's place in the robot's world frame, published with the joint states as three virtual joints (the
# simulation's ground truth; not URDF joints): every driver poses its copy of the world from them.
BASE_JOINTS = ('base_x', 'base_y', 'base_yaw')

SWEEP_JOINT = 'right_wrist_3_joint'
# The robot's own body at STOW_POSE, in base_link (x_min, x_max, y_min, y_max, z_min, z_max; m), with 5 cm
# around it: the stitcher drops the scanner's hits on its own robot inside it, scan by scan, before a moving
# base would smear them out of the body (tests/test_vaultbot_model.py checks it against the URDF).
SELF_BOX = (-0.55, 0.80, -0.74, 0.72, -0.05, 1.33)
# the camera arm's gripper: each finger's joint is half the gap between the pads (urdf_gen.py)
GRIPPER_JOINTS = ('gripper_left_finger_joint', 'gripper_right_finger_joint')
PERSON_JOINT = 'person_shoulder_joint'

# sensors, the base's and the arms' controllers, and the operator's hand tracker: each has a cable that
# `temoto sim unplug` pulls
DEVICES = ('d435', 'hokuyo', 'sick', 'site_lidar', 'base', 'left_arm', 'right_arm', 'gripper', 'hand_tracker')
STATES = ('plugged', 'unplugged')
MODES = ('crash', 'stall')


@dataclass(frozen=True)
class LaserSpec:
    frame: str
    fov_deg: float
    resolution_deg: float
    rate_hz: float
    range_min: float
    range_max: float

    @property
    def beams(self) -> int:
        return int(round(self.fov_deg / self.resolution_deg)) + 1

    @property
    def angle_min(self) -> float:
        return -math.radians(self.fov_deg) / 2

    @property
    def angle_increment(self) -> float:
        return math.radians(self.fov_deg) / (self.beams - 1)


HOKUYO = LaserSpec('hokuyo_link', 270.0, 0.25, 40.0, 0.1, 30.0)                   # 1081 beams
SICK = LaserSpec('sick_link', 190.0, 190.0 / 1140, 25.0, 0.1, 80.0)                # 1141 beams (0.1667 deg)
# Not on the robot: a 2D scanner on a post in the lab's far corner, looking at the robot, wired to the
# operator's station (two hosts: it stays in reach when the robot's link fails).
SITE_LIDAR = LaserSpec('site_lidar_link', 270.0, 0.5, 20.0, 0.1, 30.0)             # 541 beams
SITE_LIDAR_POSE = (4.6, -3.0, 0.5, 2.563)      # x, y, z (m) and yaw (rad) in the robot's world frame


@dataclass(frozen=True)
class CameraSpec:
    frame: str = 'd435_optical_frame'
    width: int = 424
    height: int = 240
    hfov_deg: float = 69.0       # colour FOV: the cloud is depth-registered to the colour camera
    rate_hz: float = 30.0
    range_min: float = 0.1
    range_max: float = 10.0


D435 = CameraSpec()
