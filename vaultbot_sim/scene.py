"""A kinematic pybullet copy of the world, used by each driver to render its sensor.

Every driver process builds its own Scene (pybullet DIRECT, no stepping: the
world is posed, never simulated) and copies the joint positions that the sim
publishes into it, so all drivers see the same world the sim owns.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from vaultbot_sim.kinematics import matrix_from_quat
from vaultbot_sim.spec import BASE_JOINTS


@dataclass(frozen=True)
class Intrinsics:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> 'Intrinsics':
        """Square pixels, principal point at the image centre (pixel centres at integers)."""
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width, height, f, f, width / 2.0 - 0.5, height / 2.0 - 0.5)

    @property
    def vfov_deg(self) -> float:
        return math.degrees(2 * math.atan((self.height / 2.0) / self.fy))

    def k(self) -> list[float]:
        return [self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0]


RENDERERS = ('tiny', 'egl')     # pybullet's software renderer; its EGL plugin (a GPU)


class Scene:
    """Robot + world loaded into a private pybullet DIRECT client."""

    def __init__(self, robot_urdf: str, world_urdf: str, renderer: str = 'tiny'):
        import pybullet as p  # imported here: it prints its build time on import
        self.p = p
        self.cid = p.connect(p.DIRECT)
        self.robot = p.loadURDF(robot_urdf, useFixedBase=True, physicsClientId=self.cid)
        self.world = p.loadURDF(world_urdf, useFixedBase=True, physicsClientId=self.cid)
        self._joints: dict[int, dict[str, int]] = {}
        self._links: dict[int, dict[str, int]] = {}
        for body in (self.robot, self.world):
            jmap, lmap = {}, {p.getBodyInfo(body, physicsClientId=self.cid)[0].decode(): -1}
            for i in range(p.getNumJoints(body, physicsClientId=self.cid)):
                info = p.getJointInfo(body, i, physicsClientId=self.cid)
                jmap[info[1].decode()] = i
                lmap[info[12].decode()] = i
            self._joints[body], self._links[body] = jmap, lmap
        self.renderer = p.ER_TINY_RENDERER
        if renderer == 'egl':
            import pkgutil     # lazy: only for the EGL plugin
            egl = pkgutil.get_loader('eglRenderer')
            p.loadPlugin(egl.get_filename(), '_eglRendererPlugin', physicsClientId=self.cid)
            self.renderer = p.ER_BULLET_HARDWARE_OPENGL
        elif renderer not in RENDERERS:
            raise ValueError(f'unknown renderer {renderer!r}: use one of {", ".join(RENDERERS)}')

    def close(self) -> None:
        self.p.disconnect(self.cid)

    # --- state ------------------------------------------------------------------
    def _set(self, body: int, cfg: Mapping[str, float]) -> None:
        jmap = self._joints[body]
        for name, q in cfg.items():
            i = jmap.get(name)
            if i is not None:
                self.p.resetJointState(body, i, q, physicsClientId=self.cid)

    def set_robot(self, cfg: Mapping[str, float]) -> None:
        """The robot's joints, and its base's place in the world (``BASE_JOINTS``, when ``cfg`` has them)."""
        self._set(self.robot, cfg)
        if BASE_JOINTS[0] in cfg:
            x, y, yaw = (cfg.get(n, 0.0) for n in BASE_JOINTS)
            self.p.resetBasePositionAndOrientation(self.robot, (x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2),
                                                                              math.cos(yaw / 2)),
                                                   physicsClientId=self.cid)

    def contacts(self, margin: float = 0.0, ignore: frozenset = frozenset({'floor'})) -> list[tuple[str, str, float]]:
        """(robot link, world link, distance) of every pair of the robot and the world, as posed, that is closer
        than ``margin`` metres (a negative distance: they overlap), but for the world's links in ``ignore`` (the
        floor the wheels stand on). Sorted by distance."""
        p = self.p
        names = {body: {i: n for n, i in links.items()} for body, links in self._links.items()}
        closest: dict = {}
        for c in p.getClosestPoints(self.robot, self.world, margin, physicsClientId=self.cid):
            pair = (names[self.robot][c[3]], names[self.world][c[4]])
            if pair[1] not in ignore and c[8] <= margin:
                closest[pair] = min(c[8], closest.get(pair, c[8]))
        return sorted(((a, b, d) for (a, b), d in closest.items()), key=lambda t: t[2])

    def set_world(self, cfg: Mapping[str, float]) -> None:
        self._set(self.world, cfg)

    def robot_link_pose(self, link: str) -> np.ndarray:
        """World pose (4x4) of a robot link's URDF frame."""
        i = self._links[self.robot][link]
        p = self.p
        if i == -1:
            pos, orn = p.getBasePositionAndOrientation(self.robot, physicsClientId=self.cid)
        else:
            st = p.getLinkState(self.robot, i, computeForwardKinematics=True, physicsClientId=self.cid)
            pos, orn = st[4], st[5]
        t = np.eye(4)
        t[:3, :3] = matrix_from_quat(orn)
        t[:3, 3] = pos
        return t

    # --- sensors ------------------------------------------------------------------
    def render(self, optical: np.ndarray, intr: Intrinsics, near: float, far: float):
        """Render from an optical frame (z forward, y down). Returns rgb (h,w,3 uint8), depth z (h,w) m."""
        p = self.p
        eye = optical[:3, 3]
        view = p.computeViewMatrix(eye.tolist(), (eye + optical[:3, 2]).tolist(), (-optical[:3, 1]).tolist(),
                                   physicsClientId=self.cid)
        proj = p.computeProjectionMatrixFOV(intr.vfov_deg, intr.width / intr.height, near, far,
                                            physicsClientId=self.cid)
        _, _, rgba, depth, _ = p.getCameraImage(intr.width, intr.height, view, proj, shadow=0,
                                                renderer=self.renderer,
                                                flags=p.ER_NO_SEGMENTATION_MASK, physicsClientId=self.cid)
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(intr.height, intr.width, 4)
        d = np.asarray(depth, dtype=np.float32).reshape(intr.height, intr.width)
        z = far * near / (far - (far - near) * d)
        return rgba[:, :, :3], z, d

    def laser(self, sensor: np.ndarray, angles: np.ndarray, range_min: float, range_max: float,
              threads: int = 1) -> np.ndarray:
        """Planar scan in the sensor's x-y plane; ranges in metres, +inf where nothing is hit."""
        local = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
        dirs = local @ sensor[:3, :3].T
        origin = sensor[:3, 3]
        ranges = np.empty(len(angles), dtype=np.float64)
        step = 16000  # pybullet caps a batch at 16384 rays
        for s in range(0, len(angles), step):
            d = dirs[s:s + step]
            res = self.p.rayTestBatch((origin + d * range_min).tolist(), (origin + d * range_max).tolist(),
                                      numThreads=threads, physicsClientId=self.cid)
            frac = np.fromiter((r[2] if r[0] >= 0 else 2.0 for r in res), dtype=np.float64, count=len(res))
            ranges[s:s + step] = range_min + frac * (range_max - range_min)
        ranges[ranges > range_max] = np.inf
        return ranges
