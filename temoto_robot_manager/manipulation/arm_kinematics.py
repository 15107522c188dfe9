"""An arm's kinematics from its URDF, through Orocos KDL (Debian's ``python3-pykdl``): forward kinematics, the
Jacobian, its condition number, and inverse kinematics. No ROS.

Why KDL: it ships its own IK solver (Levenberg-Marquardt, ``ChainIkSolverPos_LMA``), solves the UR5 as
fast as Pinocchio (0.11 ms p95 against 0.11 ms), and installs 1.9 MB from Debian against Pinocchio's
380 MB (BENCHMARKS.md, "bench_ik.py"). Debian has no ``kdl_parser_py``, so the chain is built here from
the URDF's joints between the two frames (yourdfpy reads the file), one KDL segment per URDF joint: its
fixed origin, then its motion.

Poses are 4 x 4 homogeneous matrices (numpy) of the tool frame in the arm's base frame.
"""
from __future__ import annotations

import io
import math
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np
import PyKDL
import yourdfpy

IK_TOLERANCE_M = 1e-4        # a solution's position error at most
IK_TOLERANCE_RAD = 1e-3      # and its rotation error
IK_RESTARTS = 8              # seeds tried beyond the given one (deterministic: the same target, the same answer)


class KinematicsError(ValueError):
    """A chain that cannot be built, or a target that cannot be reached; the message says which and why."""


@dataclass(frozen=True)
class JointLimit:
    lower: float
    upper: float
    velocity: float


def _frame(m: np.ndarray) -> PyKDL.Frame:
    return PyKDL.Frame(PyKDL.Rotation(*m[:3, :3].ravel()), PyKDL.Vector(*m[:3, 3]))


def _matrix(f: PyKDL.Frame) -> np.ndarray:
    m = np.eye(4)
    for i in range(3):
        for j in range(3):
            m[i, j] = f.M[i, j]
        m[i, 3] = f.p[i]
    return m


def pose_error(a: np.ndarray, b: np.ndarray) -> Tuple[float, float]:
    """(metres, radians) between two poses."""
    r = a[:3, :3].T @ b[:3, :3]
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])), math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))


class ArmKinematics:
    def __init__(self, urdf_xml: str, base: str, tip: str, joints: Sequence[str]) -> None:
        """The chain from ``base`` to ``tip``; its movable joints must be ``joints``, in that order."""
        try:
            robot = yourdfpy.URDF.load(io.StringIO(urdf_xml), build_scene_graph=False, load_meshes=False,
                                       build_collision_scene_graph=False, load_collision_meshes=False).robot
        except Exception as err:          # yourdfpy raises what lxml and its own checks raise
            raise KinematicsError('the robot description does not parse: %s' % err) from None
        by_child = {j.child: j for j in robot.joints}
        path, link = [], tip
        while link != base:
            if link not in by_child:
                raise KinematicsError('no chain from %s to %s in the robot description (%s has no parent '
                                      'joint on the way)' % (base, tip, link))
            path.append(by_child[link])
            link = by_child[link].parent
        path.reverse()
        movable = [j for j in path if j.type in ('revolute', 'continuous', 'prismatic')]
        if [j.name for j in movable] != list(joints):
            raise KinematicsError('the chain from %s to %s moves %s, not %s' % (
                base, tip, ', '.join(j.name for j in movable) or 'nothing', ', '.join(joints)))
        self.base, self.tip, self.joints = base, tip, list(joints)
        self.limits: List[JointLimit] = []
        chain = PyKDL.Chain()
        for j in path:
            origin = j.origin if j.origin is not None else np.eye(4)
            chain.addSegment(PyKDL.Segment(j.name + '_origin', PyKDL.Joint(j.name + '_fixed'), _frame(origin)))
            if j.type in ('revolute', 'continuous', 'prismatic'):
                axis = PyKDL.Vector(*(j.axis if j.axis is not None else (1.0, 0.0, 0.0)))
                kind = PyKDL.Joint.TransAxis if j.type == 'prismatic' else PyKDL.Joint.RotAxis
                chain.addSegment(PyKDL.Segment(j.child, PyKDL.Joint(j.name, PyKDL.Vector(), axis, kind), PyKDL.Frame()))
                lim = j.limit
                if j.type == 'continuous' or lim is None:
                    self.limits.append(JointLimit(-math.inf, math.inf, lim.velocity if lim is not None else math.inf))
                else:
                    self.limits.append(JointLimit(float(lim.lower), float(lim.upper), float(lim.velocity)))
        self.chain = chain
        self.n = chain.getNrOfJoints()
        self._fk = PyKDL.ChainFkSolverPos_recursive(chain)
        self._jac = PyKDL.ChainJntToJacSolver(chain)
        self._ik = PyKDL.ChainIkSolverPos_LMA(chain)

    def _array(self, q: Sequence[float]) -> PyKDL.JntArray:
        if len(q) != self.n:
            raise KinematicsError('%d joint positions for %d joints' % (len(q), self.n))
        out = PyKDL.JntArray(self.n)
        for i, v in enumerate(q):
            out[i] = float(v)
        return out

    def fk(self, q: Sequence[float]) -> np.ndarray:
        """The tip's pose in the base frame."""
        f = PyKDL.Frame()
        self._fk.JntToCart(self._array(q), f)
        return _matrix(f)

    def skeleton(self, q: Sequence[float], spacing: float = 0.05) -> np.ndarray:
        """Points along the chain (K x 3, in the base frame): each segment's frame origin, and points every
        ``spacing`` m on the straight line between two of them, so that a long link's middle is there too."""
        joints = self._array(q)
        origins = []
        for segment in range(1, self.chain.getNrOfSegments() + 1):
            f = PyKDL.Frame()
            self._fk.JntToCart(joints, f, segment)
            origins.append((f.p[0], f.p[1], f.p[2]))
        points = [np.array(origins[:1])]
        for a, b in zip(origins, origins[1:]):
            a, b = np.array(a), np.array(b)
            steps = max(1, int(math.ceil(np.linalg.norm(b - a) / spacing)))
            points.append(a + np.outer(np.arange(1, steps + 1) / steps, b - a))
        return np.vstack(points)

    def jacobian(self, q: Sequence[float]) -> np.ndarray:
        """6 x n: the tip's twist (linear, then angular, in the base frame, at the tip) per joint velocity."""
        jac = PyKDL.Jacobian(self.n)
        self._jac.JntToJac(self._array(q), jac)
        return np.array([[jac[r, c] for c in range(self.n)] for r in range(6)])

    def condition_number(self, q: Sequence[float]) -> float:
        """The Jacobian's largest singular value over its smallest: near a singularity it grows without bound."""
        s = np.linalg.svd(self.jacobian(q), compute_uv=False)
        return float(s[0] / s[-1]) if s[-1] > 1e-12 else math.inf

    def within_limits(self, q: Sequence[float], margin: float = 0.0) -> Optional[str]:
        """None, or the first joint beyond its range less ``margin``, named."""
        for name, v, lim in zip(self.joints, q, self.limits):
            if not lim.lower + margin <= v <= lim.upper - margin:
                return '%s at %.3f rad is beyond [%.3f, %.3f]%s' % (
                    name, v, lim.lower, lim.upper, ' less its %.2f rad margin' % margin if margin else '')
        return None

    def ik(self, target: np.ndarray, seed: Sequence[float], margin: float = 0.0) -> List[float]:
        """Joint positions that put the tip at ``target``, the closest found to ``seed`` (the solver starts from
        it, then from seeds around it); raises KinematicsError when none is within tolerance and limits."""
        goal = _frame(np.asarray(target, dtype=float))
        seed = [float(v) for v in seed]
        rng = np.random.default_rng(0)
        best, why = None, 'no seed converged'
        for attempt in range(IK_RESTARTS + 1):
            start = seed if attempt == 0 else [
                min(l.upper, max(l.lower, s + d)) for s, d, l in zip(seed, rng.uniform(-1.0, 1.0, self.n), self.limits)]
            out = PyKDL.JntArray(self.n)
            self._ik.CartToJnt(self._array(start), goal, out)
            q = [out[i] for i in range(self.n)]
            dp, da = pose_error(self.fk(q), target)
            if dp > IK_TOLERANCE_M or da > IK_TOLERANCE_RAD:
                why = 'the closest reached is %.1f mm and %.1f mrad away' % (1000 * dp, 1000 * da)
                continue
            beyond = self.within_limits(q, margin)
            if beyond:
                why = beyond
                continue
            distance = sum((a - b) ** 2 for a, b in zip(q, seed))
            if best is None or distance < best[0]:
                best = (distance, q)
            if attempt == 0:
                break                     # from the seed itself: the nearest branch, no need to look further
        if best is None:
            raise KinematicsError('no joint positions reach the target: %s' % why)
        return best[1]
