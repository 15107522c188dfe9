"""A joint trajectory as an arm's controller follows it: checked against the arm, then sampled. No ROS.

``Trajectory.check`` refuses a goal that the arm cannot follow, naming what is wrong (the
``FollowJointTrajectoryResult`` code with it), before anything moves: unknown or missing
joints, a value that is not finite, a position beyond a joint's range, times that do not
increase, or a speed beyond the UR5's pi rad/s between two points (or from where the arm is
to the first point). Sampling is piecewise cubic (Hermite) through the points, with the
velocities the goal gives, or, where it gives none, the mean of the neighbouring slopes (zero
at a turn and at the ends), as joint_trajectory_controller does.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Mapping, Sequence, Tuple

from vaultbot_sim.arm import SPEED, JointRange

# FollowJointTrajectoryResult's codes (control_msgs 1.5)
SUCCESSFUL, INVALID_GOAL, INVALID_JOINTS, OLD_HEADER_TIMESTAMP = 0, -1, -2, -3
PATH_TOLERANCE_VIOLATED, GOAL_TOLERANCE_VIOLATED = -4, -5
SPEED_SLACK = 1.01          # a speed within 1 % of the limit is the limit (rounding in a planner's timing)
START_TOLERANCE = 0.01      # rad: a first point at time 0 must be where the arm is


class Refused(ValueError):
    """A goal the arm cannot follow: ``code`` is the FollowJointTrajectoryResult error code."""

    def __init__(self, code: int, text: str) -> None:
        super().__init__(text)
        self.code = code


@dataclass(frozen=True)
class Point:
    t: float
    positions: Tuple[float, ...]
    velocities: Tuple[float, ...]


class Trajectory:
    """Points in the arm's own joint order, starting from where the arm is at ``t = 0``."""

    def __init__(self, joints: Sequence[str], points: List[Point]) -> None:
        self.joints = list(joints)
        self.points = points

    @property
    def duration(self) -> float:
        return self.points[-1].t

    @classmethod
    def check(cls, joints: Sequence[str], ranges: Mapping[str, JointRange], names: Sequence[str],
              points: Sequence[Tuple[float, Sequence[float], Sequence[float]]],
              start: Mapping[str, float]) -> 'Trajectory':
        """``points``: (time from start, positions, velocities) in the order of ``names``. Raises Refused."""
        missing = [j for j in joints if j not in names]
        unknown = [n for n in names if n not in joints]
        if missing or unknown or len(set(names)) != len(names):
            raise Refused(INVALID_JOINTS, 'joint_names must name each joint of the arm once (%s): %s'
                          % (', '.join(joints), '; '.join(filter(None, [
                              'missing ' + ', '.join(missing) if missing else '',
                              'unknown ' + ', '.join(unknown) if unknown else '',
                              'repeated' if len(set(names)) != len(names) else '']))))
        if not points:
            raise Refused(INVALID_GOAL, 'the trajectory has no points')
        order = [names.index(j) for j in joints]
        out = [Point(0.0, tuple(start[j] for j in joints), tuple(0.0 for _ in joints))]
        for i, (t, q, v) in enumerate(points):
            where = 'points[%d]' % i
            if len(q) != len(names) or (v and len(v) != len(names)):
                raise Refused(INVALID_GOAL, '%s: %d positions and %d velocities for %d joints'
                              % (where, len(q), len(v), len(names)))
            if not all(math.isfinite(x) for x in list(q) + list(v) + [t]):
                raise Refused(INVALID_GOAL, '%s: every value must be finite' % where)
            if t < out[-1].t or (t == out[-1].t and i > 0):
                raise Refused(INVALID_GOAL, '%s: time_from_start %.3f s does not come after %.3f s'
                              % (where, t, out[-1].t))
            qq = tuple(q[k] for k in order)
            vv = tuple(v[k] for k in order) if v else None
            for j, x in zip(joints, qq):
                r = ranges[j]
                if not r.lower <= x <= r.upper:
                    raise Refused(INVALID_GOAL, '%s: %s at %.3f rad is beyond its range [%.3f, %.3f]'
                                  % (where, j, x, r.lower, r.upper))
            if vv is not None:
                for j, x in zip(joints, vv):
                    if abs(x) > SPEED * SPEED_SLACK:
                        raise Refused(INVALID_GOAL, '%s: %s at %.2f rad/s; the UR5 turns at most %.2f'
                                      % (where, j, x, SPEED))
            prev = out[-1]
            dt = t - prev.t
            for j, a, b in zip(joints, prev.positions, qq):
                if dt == 0.0:
                    if abs(b - a) > START_TOLERANCE:
                        raise Refused(INVALID_GOAL, '%s: at time 0, %s is %.3f rad from where the arm is'
                                      % (where, j, abs(b - a)))
                elif abs(b - a) / dt > SPEED * SPEED_SLACK:
                    raise Refused(INVALID_GOAL, '%s: %s would turn at %.2f rad/s to reach it; the UR5 turns '
                                  'at most %.2f' % (where, j, abs(b - a) / dt, SPEED))
            if dt == 0.0:
                out[-1] = Point(0.0, qq, vv or prev.velocities)
            else:
                out.append(Point(t, qq, vv if vv is not None else ()))
        return cls(joints, _with_velocities(out))

    def sample(self, t: float) -> Dict[str, Tuple[float, float]]:
        """(position, velocity) of every joint at ``t`` seconds from the start (held at the ends)."""
        pts = self.points
        if t >= pts[-1].t:
            return {j: (q, 0.0) for j, q in zip(self.joints, pts[-1].positions)}
        t = max(0.0, t)
        k = next(i for i in range(1, len(pts)) if pts[i].t > t)
        a, b = pts[k - 1], pts[k]
        h = b.t - a.t
        s = (t - a.t) / h
        h00, h10, h01, h11 = 2 * s ** 3 - 3 * s ** 2 + 1, s ** 3 - 2 * s ** 2 + s, -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
        d00, d10, d01, d11 = 6 * s ** 2 - 6 * s, 3 * s ** 2 - 4 * s + 1, -6 * s ** 2 + 6 * s, 3 * s ** 2 - 2 * s
        out = {}
        for j, q0, q1, v0, v1 in zip(self.joints, a.positions, b.positions, a.velocities, b.velocities):
            q = h00 * q0 + h10 * h * v0 + h01 * q1 + h11 * h * v1
            v = (d00 * q0 + d10 * h * v0 + d01 * q1 + d11 * h * v1) / h
            out[j] = (q, max(-SPEED, min(SPEED, v)))
        return out

    def goal(self) -> Dict[str, float]:
        return dict(zip(self.joints, self.points[-1].positions))


def _with_velocities(points: List[Point]) -> List[Point]:
    """Velocities where the goal gave none: the mean of the slopes on either side, zero at a turn and at the ends."""
    out = []
    for i, p in enumerate(points):
        if p.velocities:
            out.append(p)
            continue
        if i == 0 or i == len(points) - 1:
            out.append(Point(p.t, p.positions, tuple(0.0 for _ in p.positions)))
            continue
        a, b = points[i - 1], points[i + 1]
        vel = []
        for qa, q, qb in zip(a.positions, p.positions, b.positions):
            left, right = (q - qa) / (p.t - a.t), (qb - q) / (b.t - p.t)
            vel.append(0.0 if left * right <= 0 else (left + right) / 2)
        out.append(Point(p.t, p.positions, tuple(vel)))
    return out
