"""Generate vaultbot_sim/urdf/vaultbot.urdf and the worlds from the datasheet figures.

Why a generator: the UR5 chain is fully determined by its DH table, and writing
the 60-odd links, inertials and joints of two arms, a base and two rooms by hand
invites copy errors. The generated files are committed (pybullet, yourdfpy and
RViz read them directly); rerun `python -m vaultbot_sim.urdf_gen` after editing.

DH convention: T(i-1 -> i) = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i). Joint i turns
about z of frame i-1, so in URDF joint i+1's origin in link i is
xyz=(a_i, 0, d_i) rpy=(alpha_i, 0, 0). The zero configuration of the URDF is the
DH zero configuration.
"""
from __future__ import annotations

import math
import os
from typing import Iterable

from vaultbot_sim.spec import GRIPPER_JOINTS

PI = math.pi

# --- datasheet figures (the devices' public datasheets) -------------------------
HUSKY_LENGTH, HUSKY_WIDTH, HUSKY_HEIGHT = 0.990, 0.670, 0.390
WHEEL_RADIUS, WHEEL_WIDTH = 0.165, 0.099
WHEELBASE, TRACK = 0.512, 0.571
HUSKY_MASS = 50.0

UR5_D = [0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823]
UR5_A = [0.0, -0.425, -0.39225, 0.0, 0.0, 0.0]
UR5_ALPHA = [PI / 2, 0.0, 0.0, PI / 2, -PI / 2, 0.0]
UR5_JOINTS = ['shoulder_pan', 'shoulder_lift', 'elbow', 'wrist_1', 'wrist_2', 'wrist_3']
UR5_LINKS = ['shoulder_link', 'upper_arm_link', 'forearm_link', 'wrist_1_link', 'wrist_2_link',
             'wrist_3_link']
UR5_LINK_MASS = [3.7, 8.393, 2.275, 1.219, 1.219, 0.1879]
UR5_LIMIT = 2 * PI
UR5_VELOCITY = PI
UR5_EFFORT = [150.0, 150.0, 150.0, 28.0, 28.0, 28.0]

MOUNT_HEIGHT = 0.40          # arm bases above the top plate
ARM_MOUNT_X = 0.10
ARM_MOUNT_Y = 0.20
ARM_TILT = PI / 4            # arm base z tilted outward
ARM_YAW = 0.0

SICK_XYZ = (0.58, 0.0, 0.30)  # front window of the LMS511, 0.3 m above ground

# Robot joints: the camera rides on the left arm, the Hokuyo on the right arm.
CAMERA_ARM = 'left'
LIDAR_ARM = 'right'

# A parallel gripper on the camera arm (a Robotiq 2F-85's figures): its fingers close along the flange's
# y axis; each finger's joint is half the gap between the pads.
GRIPPER_STROKE = 0.085        # m between the pads, fully open
GRIPPER_BODY = (0.05, 0.09, 0.10)   # x, y, z (along the flange normal) of the housing
FINGER = (0.02, 0.012, 0.05)  # a finger's x, y (its thickness) and z (its length past the housing)
D435_RISE = 0.055             # m from the housing's top face to the camera's centre


def fmt(*v: float) -> str:
    return ' '.join(f'{x:.10g}' for x in v)


def box_inertia(m: float, x: float, y: float, z: float) -> tuple:
    return (m * (y * y + z * z) / 12, m * (x * x + z * z) / 12, m * (x * x + y * y) / 12)


def cyl_inertia(m: float, r: float, h: float) -> tuple:
    i = m * (3 * r * r + h * h) / 12
    return (i, i, m * r * r / 2)


def sphere_inertia(m: float, r: float) -> tuple:
    i = 2 * m * r * r / 5
    return (i, i, i)


class UrdfWriter:
    """Tiny string builder for primitive-only URDF."""

    def __init__(self, name: str):
        self.name = name
        self.parts: list[str] = []
        self.materials: dict[str, tuple] = {}

    def material(self, name: str, rgba: tuple) -> None:
        self.materials[name] = rgba

    def link(self, name: str, visuals: Iterable[tuple] = (), mass: float = 0.1,
             inertia: tuple = (1e-4, 1e-4, 1e-4), com: tuple = (0, 0, 0),
             collide: bool = True) -> None:
        """visuals: (shape, dims, xyz, rpy, material); shape in box|cylinder|sphere."""
        out = [f'  <link name="{name}">',
               '    <inertial>',
               f'      <origin xyz="{fmt(*com)}" rpy="0 0 0"/>',
               f'      <mass value="{mass:.6g}"/>',
               f'      <inertia ixx="{inertia[0]:.6g}" ixy="0" ixz="0" iyy="{inertia[1]:.6g}" '
               f'iyz="0" izz="{inertia[2]:.6g}"/>',
               '    </inertial>']
        for shape, dims, xyz, rpy, mat in visuals:
            geom = self._geometry(shape, dims)
            out += ['    <visual>',
                    f'      <origin xyz="{fmt(*xyz)}" rpy="{fmt(*rpy)}"/>',
                    f'      <geometry>{geom}</geometry>',
                    f'      <material name="{mat}"/>',
                    '    </visual>']
            if collide:
                out += ['    <collision>',
                        f'      <origin xyz="{fmt(*xyz)}" rpy="{fmt(*rpy)}"/>',
                        f'      <geometry>{geom}</geometry>',
                        '    </collision>']
        out.append('  </link>')
        self.parts.append('\n'.join(out))

    @staticmethod
    def _geometry(shape: str, dims: tuple) -> str:
        if shape == 'box':
            return f'<box size="{fmt(*dims)}"/>'
        if shape == 'cylinder':
            return f'<cylinder radius="{dims[0]:.6g}" length="{dims[1]:.6g}"/>'
        if shape == 'sphere':
            return f'<sphere radius="{dims[0]:.6g}"/>'
        raise ValueError(f'unknown shape {shape!r}')

    def joint(self, name: str, jtype: str, parent: str, child: str, xyz=(0, 0, 0), rpy=(0, 0, 0),
              axis=(0, 0, 1), lower: float = 0.0, upper: float = 0.0, velocity: float = 0.0,
              effort: float = 0.0) -> None:
        out = [f'  <joint name="{name}" type="{jtype}">',
               f'    <parent link="{parent}"/>',
               f'    <child link="{child}"/>',
               f'    <origin xyz="{fmt(*xyz)}" rpy="{fmt(*rpy)}"/>']
        if jtype != 'fixed':
            out.append(f'    <axis xyz="{fmt(*axis)}"/>')
        if jtype in ('revolute', 'prismatic'):
            out.append(f'    <limit lower="{lower:.10g}" upper="{upper:.10g}" '
                       f'effort="{effort:.6g}" velocity="{velocity:.10g}"/>')
        elif jtype == 'continuous':
            out.append(f'    <limit effort="{effort:.6g}" velocity="{velocity:.10g}"/>')
        out.append('  </joint>')
        self.parts.append('\n'.join(out))

    def text(self) -> str:
        mats = [f'  <material name="{n}"><color rgba="{fmt(*c)}"/></material>'
                for n, c in self.materials.items()]
        return ('<?xml version="1.0"?>\n'
                '<!-- GENERATED by vaultbot_sim/urdf_gen.py: edit the generator, not this file -->\n'
                f'<robot name="{self.name}">\n' + '\n'.join(mats + self.parts) + '\n</robot>\n')


# --- robot ---------------------------------------------------------------------

def _ur5_arm(w: UrdfWriter, side: str, parent: str, xyz: tuple, rpy: tuple) -> None:
    base = f'{side}_base_link'
    w.link(base, [('cylinder', (0.075, 0.05), (0, 0, 0.025), (0, 0, 0), 'ur_grey')],
           mass=4.0, inertia=cyl_inertia(4.0, 0.075, 0.05), com=(0, 0, 0.025))
    w.joint(f'{side}_base_mount_joint', 'fixed', parent, base, xyz, rpy)
    prev = base
    origin = ((0, 0, 0), (0, 0, 0))
    for i in range(6):
        link = f'{side}_{UR5_LINKS[i]}'
        d, a = UR5_D[i], UR5_A[i]
        vis = [('cylinder', (0.06 if i < 3 else 0.045, 0.12 if i < 3 else 0.09), (0, 0, 0), (0, 0, 0),
                'ur_blue' if i % 2 == 0 else 'ur_grey')]
        if d > 0.0 and i < 5:
            vis.append(('cylinder', (0.045, d), (0, 0, d / 2), (0, 0, 0), 'ur_grey'))
        if abs(a) > 0.0:
            vis.append(('cylinder', (0.05 if i == 1 else 0.04, abs(a)), (a / 2, 0, d),
                        (0, PI / 2, 0), 'ur_grey'))
        if i == 5:  # tool flange disc
            vis.append(('cylinder', (0.0375, d), (0, 0, d / 2), (0, 0, 0), 'ur_grey'))
        m = UR5_LINK_MASS[i]
        length = max(abs(a), d, 0.1)
        w.link(link, vis, mass=m, inertia=cyl_inertia(m, 0.05, length), com=(a / 2, 0, d / 2))
        w.joint(f'{side}_{UR5_JOINTS[i]}_joint', 'revolute', prev, link, origin[0], origin[1],
                axis=(0, 0, 1), lower=-UR5_LIMIT, upper=UR5_LIMIT, velocity=UR5_VELOCITY,
                effort=UR5_EFFORT[i])
        origin = ((a, 0, d), (UR5_ALPHA[i], 0, 0))
        prev = link
    tool = f'{side}_tool0'
    w.link(tool, [], mass=0.01, inertia=(1e-6, 1e-6, 1e-6))
    w.joint(f'{side}_tool0_joint', 'fixed', prev, tool, origin[0], origin[1])


def _gripper(w: UrdfWriter, flange: str) -> None:
    """The housing on the flange, and two fingers on prismatic joints (0: closed, STROKE / 2: open)."""
    bx, by, bz = GRIPPER_BODY
    w.link('gripper_link', [('box', GRIPPER_BODY, (0, 0, bz / 2), (0, 0, 0), 'sensor_dark')],
           mass=0.9, inertia=box_inertia(0.9, bx, by, bz), com=(0, 0, bz / 2))
    w.joint('gripper_joint', 'fixed', flange, 'gripper_link')
    fx, fy, fz = FINGER
    for joint, sgn in zip(GRIPPER_JOINTS, (1, -1)):
        link = joint.replace('_joint', '_link')
        # the pad (inner face) is at y = sgn * q: the finger's box lies outside it
        w.link(link, [('box', FINGER, (0, sgn * fy / 2, fz / 2), (0, 0, 0), 'ur_grey')],
               mass=0.05, inertia=box_inertia(0.05, fx, fy, fz), com=(0, sgn * fy / 2, fz / 2))
        w.joint(joint, 'prismatic', 'gripper_link', link, (0, 0, bz), axis=(0, sgn, 0), lower=0.0,
                upper=GRIPPER_STROKE / 2, velocity=0.075, effort=235.0)


def robot_urdf() -> str:
    w = UrdfWriter('vaultbot')
    w.material('husky_yellow', (0.95, 0.75, 0.05, 1))
    w.material('husky_black', (0.1, 0.1, 0.1, 1))
    w.material('mount_grey', (0.5, 0.5, 0.55, 1))
    w.material('ur_grey', (0.75, 0.75, 0.78, 1))
    w.material('ur_blue', (0.35, 0.55, 0.8, 1))
    w.material('sensor_dark', (0.15, 0.15, 0.18, 1))
    w.material('sick_blue', (0.1, 0.3, 0.7, 1))

    # base_link sits at the ground under the chassis centre (as husky_description does).
    w.link('base_link', [], mass=0.01, inertia=(1e-6, 1e-6, 1e-6))
    w.link('base_footprint', [], mass=0.01, inertia=(1e-6, 1e-6, 1e-6))
    w.joint('base_footprint_joint', 'fixed', 'base_link', 'base_footprint')
    body_w = TRACK - WHEEL_WIDTH - 0.04
    body_z0, body_z1 = 0.10, HUSKY_HEIGHT
    body_h = body_z1 - body_z0
    w.link('chassis_link', [
        ('box', (HUSKY_LENGTH, body_w, body_h - 0.02), (0, 0, 0), (0, 0, 0), 'husky_yellow'),
        ('box', (HUSKY_LENGTH - 0.1, HUSKY_WIDTH - 0.02, 0.02), (0, 0, body_h / 2 - 0.01), (0, 0, 0),
         'husky_black'),
    ], mass=HUSKY_MASS, inertia=box_inertia(HUSKY_MASS, HUSKY_LENGTH, body_w, body_h))
    w.joint('chassis_joint', 'fixed', 'base_link', 'chassis_link', (0, 0, body_z0 + body_h / 2))
    for fb, x in (('front', WHEELBASE / 2), ('rear', -WHEELBASE / 2)):
        for lr, y in (('left', TRACK / 2), ('right', -TRACK / 2)):
            name = f'{fb}_{lr}_wheel'
            w.link(f'{name}_link', [('cylinder', (WHEEL_RADIUS, WHEEL_WIDTH), (0, 0, 0), (PI / 2, 0, 0),
                                     'husky_black')],
                   mass=2.637, inertia=cyl_inertia(2.637, WHEEL_RADIUS, WHEEL_WIDTH))
            w.joint(f'{name}_joint', 'continuous', 'base_link', f'{name}_link', (x, y, WHEEL_RADIUS),
                    axis=(0, 1, 0), velocity=1.0 / WHEEL_RADIUS, effort=100)
    # raised arm mount: a column and a cross bar, 0.4 m above the top plate
    top = HUSKY_HEIGHT
    w.link('arm_mount_link', [
        ('box', (0.12, 0.12, MOUNT_HEIGHT - 0.04), (0, 0, (MOUNT_HEIGHT - 0.04) / 2), (0, 0, 0), 'mount_grey'),
        ('box', (0.14, 2 * ARM_MOUNT_Y + 0.16, 0.04), (0, 0, MOUNT_HEIGHT - 0.02), (0, 0, 0), 'mount_grey'),
    ], mass=8.0, inertia=box_inertia(8.0, 0.14, 0.5, MOUNT_HEIGHT), com=(0, 0, MOUNT_HEIGHT / 2))
    w.joint('arm_mount_joint', 'fixed', 'base_link', 'arm_mount_link', (ARM_MOUNT_X, 0, top))
    for side, sgn in (('left', 1), ('right', -1)):
        _ur5_arm(w, side, 'arm_mount_link', (0, sgn * ARM_MOUNT_Y, MOUNT_HEIGHT),
                 (-sgn * ARM_TILT, 0, sgn * ARM_YAW))

    _gripper(w, f'{CAMERA_ARM}_tool0')
    # RealSense D435 (90 x 25 x 25 mm) on a bracket over the gripper, looking along the flange normal past
    # the fingertips: its frustum (42 degrees high) clears the fingers, so the gripper is never in its cloud.
    # d435_link: x forward (ROS body convention), origin at the front glass; its z ("up" in the image) is
    # the flange's -x, so the bracket rises along -x.
    w.link('d435_bracket_link', [('box', (D435_RISE, 0.03, 0.01), (-D435_RISE / 2, 0, 0), (0, 0, 0), 'mount_grey')],
           mass=0.05, inertia=box_inertia(0.05, D435_RISE, 0.03, 0.01))
    w.joint('d435_bracket_joint', 'fixed', f'{CAMERA_ARM}_tool0', 'd435_bracket_link',
            (-GRIPPER_BODY[0] / 2, 0, GRIPPER_BODY[2] - 0.005))
    w.link('d435_link', [('box', (0.025, 0.09, 0.025), (-0.0125, 0, 0), (0, 0, 0), 'sensor_dark')],
           mass=0.072, inertia=box_inertia(0.072, 0.025, 0.09, 0.025), com=(-0.0125, 0, 0))
    w.joint('d435_joint', 'fixed', f'{CAMERA_ARM}_tool0', 'd435_link',
            (-GRIPPER_BODY[0] / 2 - D435_RISE, 0, GRIPPER_BODY[2]), (0, -PI / 2, 0))
    w.link('d435_optical_frame', [], mass=0.001, inertia=(1e-8, 1e-8, 1e-8))
    w.joint('d435_optical_joint', 'fixed', 'd435_link', 'd435_optical_frame', (0, 0, 0),
            (-PI / 2, 0, -PI / 2))
    # Hokuyo UTM-30LX (60 x 60 x 87 mm) on the lidar arm's flange; its scan plane (x-y) contains the
    # wrist_3 axis (its x), so turning wrist_3 sweeps the plane around and covers 3D.
    w.link('hokuyo_link', [('box', (0.077, 0.06, 0.06), (-0.0485, 0, 0), (0, 0, 0), 'sensor_dark')],
           mass=0.37, inertia=box_inertia(0.37, 0.087, 0.06, 0.06), com=(-0.0485, 0, 0))
    w.joint('hokuyo_joint', 'fixed', f'{LIDAR_ARM}_tool0', 'hokuyo_link', (0, 0, 0.087), (0, -PI / 2, 0))
    # SICK LMS511 (160 x 155 x 185 mm) on the front of the base; origin at its window.
    w.link('sick_link', [('box', (0.16, 0.155, 0.185), (-0.08, 0, 0), (0, 0, 0), 'sick_blue')],
           mass=3.7, inertia=box_inertia(3.7, 0.16, 0.155, 0.185), com=(-0.08, 0, 0))
    w.joint('sick_joint', 'fixed', 'base_link', 'sick_link', SICK_XYZ)
    return w.text()


# --- worlds --------------------------------------------------------------------

def _static(w: UrdfWriter, name: str, visuals: list, xyz: tuple, yaw: float = 0.0) -> None:
    w.link(name, visuals, mass=0.0, inertia=(0, 0, 0))
    w.joint(f'{name}_joint', 'fixed', 'world', name, xyz, (0, 0, yaw))


def _table(w, name, xyz, yaw=0.0, size=(1.2, 0.7, 0.75)):
    lx, ly, h = size
    vis = [('box', (lx, ly, 0.04), (0, 0, h - 0.02), (0, 0, 0), 'wood')]
    for sx in (-1, 1):
        for sy in (-1, 1):
            vis.append(('box', (0.05, 0.05, h - 0.04), (sx * (lx / 2 - 0.05), sy * (ly / 2 - 0.05),
                                                        (h - 0.04) / 2), (0, 0, 0), 'metal'))
    _static(w, name, vis, xyz, yaw)


def _shelf(w, name, xyz, yaw=0.0):
    vis = [('box', (0.4, 0.03, 1.8), (0, -0.585, 0.9), (0, 0, 0), 'metal'),
           ('box', (0.4, 0.03, 1.8), (0, 0.585, 0.9), (0, 0, 0), 'metal')]
    for z in (0.1, 0.6, 1.1, 1.6):
        vis.append(('box', (0.4, 1.2, 0.03), (0, 0, z), (0, 0, 0), 'shelf_blue'))
    vis.append(('box', (0.3, 0.4, 0.25), (0, -0.3, 0.74), (0, 0, 0), 'cardboard'))
    vis.append(('box', (0.3, 0.3, 0.3), (0, 0.25, 1.265), (0, 0, 0), 'cardboard'))
    _static(w, name, vis, xyz, yaw)


def _person(w: UrdfWriter, xyz: tuple, yaw: float) -> None:
    """A person-sized figure with a bright green hand on a waving arm (person_shoulder_joint)."""
    _static(w, 'person_body', [
        ('cylinder', (0.07, 0.85), (0, 0.1, 0.425), (0, 0, 0), 'trousers'),
        ('cylinder', (0.07, 0.85), (0, -0.1, 0.425), (0, 0, 0), 'trousers'),
        ('box', (0.24, 0.42, 0.6), (0, 0, 1.15), (0, 0, 0), 'shirt'),
        ('sphere', (0.11,), (0, 0, 1.6), (0, 0, 0), 'skin'),
        ('cylinder', (0.045, 0.6), (0, 0.25, 1.15), (0, 0, 0), 'shirt'),
    ], xyz, yaw)
    w.link('person_arm', [('cylinder', (0.045, 0.55), (0, 0, -0.275), (0, 0, 0), 'shirt')],
           mass=2.0, inertia=cyl_inertia(2.0, 0.045, 0.55), com=(0, 0, -0.275))
    # shoulder on the figure's right side, arm raised forward-sideways; the joint waves it.
    w.joint('person_shoulder_joint', 'revolute', 'person_body', 'person_arm', (0.0, -0.25, 1.42),
            (0, -1.65, 0), axis=(1, 0, 0), lower=-1.2, upper=1.2, velocity=1.0, effort=10)
    w.link('person_hand', [('sphere', (0.07,), (0, 0, 0), (0, 0, 0), 'hand_green')],
           mass=0.4, inertia=sphere_inertia(0.4, 0.07))
    w.joint('person_hand_joint', 'fixed', 'person_arm', 'person_hand', (0, 0, -0.6))


def _world_materials(w: UrdfWriter) -> None:
    w.material('floor', (0.55, 0.55, 0.52, 1))
    w.material('wall', (0.85, 0.83, 0.78, 1))
    w.material('wood', (0.6, 0.42, 0.25, 1))
    w.material('metal', (0.4, 0.4, 0.45, 1))
    w.material('drum_red', (0.75, 0.12, 0.1, 1))
    w.material('drum_blue', (0.1, 0.25, 0.7, 1))
    w.material('shelf_blue', (0.2, 0.35, 0.6, 1))
    w.material('cardboard', (0.7, 0.55, 0.35, 1))
    w.material('trousers', (0.15, 0.15, 0.3, 1))
    w.material('shirt', (0.85, 0.35, 0.1, 1))
    w.material('skin', (0.9, 0.72, 0.6, 1))
    w.material('hand_green', (0.0, 1.0, 0.0, 1))


def lab_world_urdf() -> str:
    """The lab room: 8 x 7 m, walls, two tables, drums, two shelves, a crate and a person."""
    w = UrdfWriter('lab_world')
    _world_materials(w)
    w.link('world', [], mass=0.0, inertia=(0, 0, 0))
    lx, ly, h, t = 8.0, 7.0, 2.6, 0.15
    _static(w, 'floor', [('box', (lx, ly, 0.05), (0, 0, -0.025), (0, 0, 0), 'floor')], (1.0, 0, 0))
    _static(w, 'walls', [
        ('box', (t, ly, h), (lx / 2 + t / 2, 0, h / 2), (0, 0, 0), 'wall'),
        ('box', (t, ly, h), (-lx / 2 - t / 2, 0, h / 2), (0, 0, 0), 'wall'),
        ('box', (lx, t, h), (0, ly / 2 + t / 2, h / 2), (0, 0, 0), 'wall'),
        ('box', (lx, t, h), (0, -ly / 2 - t / 2, h / 2), (0, 0, 0), 'wall'),
    ], (1.0, 0, 0))
    _table(w, 'table_left', (2.2, 2.2, 0), 0.0)
    _table(w, 'table_right', (3.0, -1.8, 0), PI / 2)
    _static(w, 'drums', [
        ('cylinder', (0.29, 0.88), (0, 0, 0.44), (0, 0, 0), 'drum_red'),
        ('cylinder', (0.29, 0.88), (0.65, 0.1, 0.44), (0, 0, 0), 'drum_blue'),
        ('cylinder', (0.29, 0.88), (0.3, -0.55, 0.44), (0, 0, 0), 'drum_red'),
    ], (3.5, -0.9, 0))
    _shelf(w, 'shelf_front', (4.7, 2.0, 0), 0.0)
    _shelf(w, 'shelf_left', (0.5, 3.2, 0), PI / 2)
    _static(w, 'crate', [('box', (0.6, 0.6, 0.6), (0, 0, 0.3), (0, 0, 0), 'cardboard')],
            (1.8, -1.2, 0), 0.3)
    _person(w, (3.0, 1.0, 0), PI)
    return w.text()


TEST_WALL_X = 3.0
TEST_POLE_XY = (0.0, -6.0)
TEST_POLE_RADIUS = 0.025


def test_world_urdf() -> str:
    """Known geometry for tests: a floor at z=0 and one wall whose face is the plane x=TEST_WALL_X."""
    w = UrdfWriter('test_world')
    _world_materials(w)
    w.link('world', [], mass=0.0, inertia=(0, 0, 0))
    _static(w, 'floor', [('box', (20, 20, 0.05), (0, 0, -0.025), (0, 0, 0), 'floor')], (0, 0, 0))
    _static(w, 'wall', [('box', (0.2, 20, 6), (0.1, 0, 3), (0, 0, 0), 'wall')], (TEST_WALL_X, 0, 0))
    # a pole for the gripper to close on (tests put the robot where the fingers straddle it: ``~base_pose``)
    _static(w, 'pole', [('cylinder', (TEST_POLE_RADIUS, 1.6), (0, 0, 0.8), (0, 0, 0), 'metal')], TEST_POLE_XY + (0,))
    # the person must exist in every world: the sim and drivers animate person_shoulder_joint.
    _person(w, (-6.0, 0, 0), 0.0)
    return w.text()


def write_all(urdf_dir: str) -> list[str]:
    os.makedirs(urdf_dir, exist_ok=True)
    out = []
    for name, text in (('vaultbot.urdf', robot_urdf()), ('lab_world.urdf', lab_world_urdf()),
                       ('test_world.urdf', test_world_urdf())):
        path = os.path.join(urdf_dir, name)
        with open(path, 'w') as f:
            f.write(text)
        out.append(path)
    return out


if __name__ == '__main__':
    here = os.path.dirname(os.path.abspath(__file__))
    for p in write_all(os.path.join(here, 'urdf')):
        print('wrote', p)
