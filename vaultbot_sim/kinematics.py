"""Forward kinematics of a URDF tree, for TF and for placing sensors.

yourdfpy parses the file; the per-joint transforms are computed here with numpy
so that the sim can publish every joint's parent->child transform (what
robot_state_publisher would) without building a scene graph per update.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Mapping

import numpy as np

PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__))
URDF_DIR = os.path.join(PACKAGE_DIR, 'urdf')     # inside the package: it installs with it
ROBOT_URDF = os.path.join(URDF_DIR, 'vaultbot.urdf')
WORLDS = {'lab': os.path.join(URDF_DIR, 'lab_world.urdf'),
          'test_wall': os.path.join(URDF_DIR, 'test_world.urdf')}


def resolve_world(name_or_path: str) -> str:
    """A world name from WORLDS or a path to a world URDF; raises ValueError naming the choices."""
    if name_or_path in WORLDS:
        return WORLDS[name_or_path]
    if name_or_path.endswith('.urdf') and os.path.isfile(name_or_path):
        return os.path.abspath(name_or_path)
    raise ValueError(f'unknown world {name_or_path!r}: use one of {sorted(WORLDS)} or a .urdf path')


def axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis / np.linalg.norm(axis)
    c, s = math.cos(angle), math.sin(angle)
    C = 1 - c
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


def quat_from_matrix(m: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix (3x3 or 4x4) to quaternion (x, y, z, w)."""
    r = m[:3, :3]
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        w, x, y, z = (r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s
    elif r[1, 1] > r[2, 2]:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        w, x, y, z = (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s
    else:
        s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        w, x, y, z = (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s
    return (x, y, z, w)


def matrix_from_quat(q) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def planar_matrix(x: float, y: float, yaw: float) -> np.ndarray:
    """A pose in the plane (metres, radians) as a homogeneous transform."""
    m = np.eye(4)
    m[0, 0], m[0, 1], m[1, 0], m[1, 1] = math.cos(yaw), -math.sin(yaw), math.sin(yaw), math.cos(yaw)
    m[0, 3], m[1, 3] = x, y
    return m


@dataclass
class Joint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float
    upper: float
    velocity: float


class TreeModel:
    """The kinematic tree of one URDF: joint list, FK, and per-joint transforms for TF."""

    def __init__(self, urdf_path: str):
        import yourdfpy  # slow import (trimesh); only paid by processes that need kinematics
        self.path = urdf_path
        self.urdf = yourdfpy.URDF.load(urdf_path, build_scene_graph=False,
                                       build_collision_scene_graph=False, load_meshes=False)
        self.joints: list[Joint] = []
        for j in self.urdf.robot.joints:
            origin = j.origin if j.origin is not None else np.eye(4)
            axis = np.asarray(j.axis if j.axis is not None else (1, 0, 0), dtype=float)
            lim = j.limit
            self.joints.append(Joint(j.name, j.type, j.parent, j.child, np.asarray(origin, float), axis,
                                     float(lim.lower) if lim is not None and lim.lower is not None else -math.inf,
                                     float(lim.upper) if lim is not None and lim.upper is not None else math.inf,
                                     float(lim.velocity) if lim is not None and lim.velocity is not None else 0.0))
        children = {j.child for j in self.joints}
        roots = [l.name for l in self.urdf.robot.links if l.name not in children]
        if len(roots) != 1:
            raise ValueError(f'{urdf_path}: expected one root link, found {roots}')
        self.root = roots[0]
        self._by_child = {j.child: j for j in self.joints}
        self.movable = [j.name for j in self.joints if j.type in ('revolute', 'continuous', 'prismatic')]
        self.joint = {j.name: j for j in self.joints}

    def links(self) -> list[str]:
        return [l.name for l in self.urdf.robot.links]

    def joint_transform(self, j: Joint, q: float) -> np.ndarray:
        t = j.origin.copy()
        if j.type in ('revolute', 'continuous'):
            m = np.eye(4)
            m[:3, :3] = axis_angle(j.axis, q)
            t = t @ m
        elif j.type == 'prismatic':
            m = np.eye(4)
            m[:3, 3] = j.axis / np.linalg.norm(j.axis) * q
            t = t @ m
        return t

    def link_pose(self, link: str, cfg: Mapping[str, float]) -> np.ndarray:
        """Pose of `link` in the root frame as a 4x4 matrix (missing joints count as 0)."""
        t = np.eye(4)
        while link != self.root:
            j = self._by_child[link]
            t = self.joint_transform(j, cfg.get(j.name, 0.0)) @ t
            link = j.parent
        return t

    def transform(self, target: str, source: str, cfg: Mapping[str, float]) -> np.ndarray:
        """Pose of `target` expressed in `source`."""
        return np.linalg.inv(self.link_pose(source, cfg)) @ self.link_pose(target, cfg)

    def fixed_transforms(self) -> list[tuple[str, str, np.ndarray]]:
        return [(j.parent, j.child, j.origin) for j in self.joints if j.name not in self.movable]

    def moving_transforms(self, cfg: Mapping[str, float]) -> list[tuple[str, str, np.ndarray]]:
        return [(j.parent, j.child, self.joint_transform(j, cfg.get(j.name, 0.0)))
                for j in self.joints if j.name in self.movable]


def solve_tool_pose(model: TreeModel, joints: list[str], tool: str, target_pos: np.ndarray,
                    target_rot: np.ndarray, q0: np.ndarray, iters: int = 200) -> np.ndarray:
    """Damped least-squares IK (numerical Jacobian); used offline to choose the stowed pose."""
    q = np.array(q0, float)

    def err(qv):
        t = model.link_pose(tool, dict(zip(joints, qv)))
        dp = target_pos - t[:3, 3]
        r = t[:3, :3]
        dr = 0.5 * sum(np.cross(r[:, i], target_rot[:, i]) for i in range(3))
        return np.concatenate([dp, dr])

    for _ in range(iters):
        e = err(q)
        if np.linalg.norm(e) < 1e-9:
            break
        jac = np.zeros((6, len(q)))
        for i in range(len(q)):
            dq = q.copy()
            dq[i] += 1e-6
            jac[:, i] = (err(q) - err(dq)) / 1e-6
        q = q + np.linalg.solve(jac.T @ jac + 1e-4 * np.eye(len(q)), jac.T @ e)
    return q
