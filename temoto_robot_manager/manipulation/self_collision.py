"""An arm against the robot's own body: the distance from each of the arm's links to every other link, in a
private pybullet copy of the robot (posed, never stepped). No ROS.

Which pairs count is decided as MoveIt's setup assistant decides it: pairs that touch in the reference
configuration (a link and its neighbours, the shoulder on its mount) are in contact by design, and
pairs that no arm joint moves apart (the gripper, its fingers and the camera on the flange) cannot
collide through the arm's motion: neither is checked. Every other pair of an arm link and any link is.
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from typing import Dict, List, Mapping, Optional, Sequence, Set, Tuple

import pybullet

REFERENCE_MARGIN = 0.005     # m: pairs this close in the reference configuration are touching by design


@dataclass(frozen=True)
class Nearest:
    link: str                 # of the arm
    other: str                # of the robot
    distance: float           # m; negative: they overlap


class SelfCollision:
    def __init__(self, urdf_xml: str, arm_joints: Sequence[str], reference: Mapping[str, float]) -> None:
        """``arm_joints``: the joints whose links (and everything they carry) move; ``reference``: a
        configuration in which the robot touches itself only by design (its stowed pose)."""
        self._cid = pybullet.connect(pybullet.DIRECT)
        handle, path = tempfile.mkstemp(suffix='.urdf')
        try:
            with os.fdopen(handle, 'w') as f:
                f.write(urdf_xml)
            self._body = pybullet.loadURDF(path, useFixedBase=True, physicsClientId=self._cid)
        finally:
            os.unlink(path)
        p, cid, body = pybullet, self._cid, self._body
        info = [p.getJointInfo(body, i, physicsClientId=cid) for i in range(p.getNumJoints(body, physicsClientId=cid))]
        self._joint_index = {row[1].decode(): row[0] for row in info}
        self._link_name = {-1: p.getBodyInfo(body, physicsClientId=cid)[0].decode()}
        self._link_name.update({row[0]: row[12].decode() for row in info})
        parent = {row[0]: row[16] for row in info}
        missing = [j for j in arm_joints if j not in self._joint_index]
        if missing:
            raise ValueError('not joints of the robot description: %s' % ', '.join(missing))
        first = min(self._joint_index[j] for j in arm_joints)
        # the arm's links: the first joint's child and every link below it
        moving: Set[int] = set()
        for i in sorted(parent):
            if i == first or parent[i] in moving:
                moving.add(i)
        self.moving = sorted(moving)
        # each arm link's group: the last arm joint above it; two links of one group move as one
        arm = {self._joint_index[j] for j in arm_joints}
        self._group: Dict[int, int] = {}
        for i in self.moving:
            self._group[i] = i if i in arm else self._group.get(parent[i], i)
        self._allowed: Set[Tuple[int, int]] = set()
        self.set(reference)
        for a, b, _ in self._pairs(REFERENCE_MARGIN):
            self._allowed.add((a, b))

    def close(self) -> None:
        if self._cid is not None:
            pybullet.disconnect(physicsClientId=self._cid)
            self._cid = None

    def set(self, cfg: Mapping[str, float]) -> None:
        for name, q in cfg.items():
            index = self._joint_index.get(name)
            if index is not None:
                pybullet.resetJointState(self._body, index, q, physicsClientId=self._cid)

    def _pairs(self, margin: float) -> List[Tuple[int, int, float]]:
        out: Dict[Tuple[int, int], float] = {}
        for link in self.moving:
            for c in pybullet.getClosestPoints(self._body, self._body, margin, linkIndexA=link,
                                               physicsClientId=self._cid):
                other = c[4]
                if other == link or self._group.get(other) == self._group[link]:
                    continue
                key = (link, other)
                out[key] = min(c[8], out.get(key, c[8]))
        return [(a, b, d) for (a, b), d in out.items()]

    def nearest(self, cfg: Mapping[str, float], margin: float) -> Optional[Nearest]:
        """The closest pair of an arm link and another link within ``margin`` in ``cfg``, if any (pairs touching
        by design left out)."""
        self.set(cfg)
        found = [(d, a, b) for a, b, d in self._pairs(margin) if (a, b) not in self._allowed]
        if not found:
            return None
        d, a, b = min(found)
        return Nearest(self._link_name[a], self._link_name[b], d)
