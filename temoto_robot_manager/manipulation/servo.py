"""Servoing: one step of joint velocities that brings an arm's tool towards a target pose, safely. No ROS.

The tool follows a stream of target poses (a hand, a marker) as MoveIt Servo follows twists:

1. the pose error becomes a twist, proportional (``GAIN``), capped at ``MAX_LINEAR`` and ``MAX_ANGULAR``;
2. the twist becomes joint velocities by damped least squares, ``J^T (J J^T + lambda^2 I)^-1 v``: near a
   singularity the damping trades accuracy for bounded speeds instead of the pseudo-inverse's blow-up;
3. near a singularity, moving towards it, the step slows: the Jacobian's condition number scales it from
   1 at ``SINGULARITY_SLOW`` (17) down to 0 at ``SINGULARITY_STOP`` (30), MoveIt Servo's UR thresholds, and
   halts beyond. Moving away is never slowed, so the operator can always back out;
4. a joint within ``JOINT_MARGIN`` (0.1 rad, MoveIt Servo's) of its range's end, moving towards it, halts
   the step;
5. the whole step is scaled down so no joint exceeds its speed limit (the direction is kept);
6. the arm where the step leads (``LOOKAHEAD_S`` ahead) is checked against the robot's own body
   (``self_collision.py``): slowed within ``COLLISION_SLOW`` of it, halted at contact;
7. and against the world (``world_clearance.py``): moving towards it, slowed within ``WORLD_SLOW`` of its margin,
   halted ``WORLD_HALT`` short of the margin. A halt at full speed would leave the arm's braking, and every delay between here and the
   motors (a starved controller, a late joint state), to the margin: on a loaded machine an arm servoed at the
   box touched it (CI at ed0d926). Slowed, the arm nears the margin at a speed that stops in no distance.

The checks of 6 and 7 cost more than a step (the node runs them at 25 Hz, the steps at 125 Hz): a step that does
not run them keeps the slowing of the last one that did, so that it is not lost four steps in five.

A halted step commands zero and says why; the next step may move again (a target that leads away).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics

GAIN = 8.0                  # 1/s: the twist per metre (and per radian) of error
MAX_LINEAR = 0.5            # m/s of the tool
MAX_ANGULAR = 1.5           # rad/s of the tool
DAMPING = 0.05              # lambda of the damped least squares
SINGULARITY_SLOW = 17.0     # condition number: slow from here (MoveIt Servo's UR figures)
SINGULARITY_STOP = 30.0     # and halt here
JOINT_MARGIN = 0.1          # rad from a range's end
COLLISION_SLOW = 0.01       # m from the robot's own body: slow within, halt at contact
LOOKAHEAD_S = 0.05          # s ahead: where the self-collision check looks
WORLD_SLOW = 0.10           # m beyond the world margin: slow from here, towards it (MoveIt Servo slows from 0.3 m)
WORLD_HALT = 0.005          # m: and halt here, where the slowing would otherwise creep on without end

# the distance (m) from the arm to the robot's own body with the arm's joints at q, within a margin; None if
# farther (self_collision.SelfCollision.nearest, adapted)
BodyDistance = Callable[[Sequence[float], float], Optional[float]]
# how far the arm at q is beyond its margin from the world (m; at or below 0 it touches) and a text naming where,
# when within WORLD_SLOW; None if farther (``world_clearance.WorldClearance.free``, adapted)
WorldFree = Callable[[Sequence[float]], Optional[Tuple[float, str]]]


@dataclass
class Step:
    velocities: List[float]
    positions: List[float]          # where the velocities lead after the period: the setpoint to send
    scale: float                    # 1: as asked; 0: halted
    condition: float
    why: str = ''                   # what slowed or halted it ('' when nothing did)

    @property
    def halted(self) -> bool:
        return self.scale == 0.0


def rotation_error(current: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rotation vector (axis x angle, in the base frame) that turns ``current`` onto ``target``."""
    r = target @ current.T
    angle = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))
    if angle < 1e-9:
        return np.zeros(3)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    norm = np.linalg.norm(axis)
    if norm < 1e-9:                          # a half turn: the axis from the symmetric part
        w, v = np.linalg.eigh((r + np.eye(3)) / 2)
        axis = v[:, int(np.argmax(w))]
        norm = 1.0
    return axis / norm * angle


class Servo:
    def __init__(self, kinematics: ArmKinematics, period: float, body_distance: Optional[BodyDistance] = None,
                 world: Optional[WorldFree] = None) -> None:
        self.kin = kinematics
        self.period = period
        self.body_distance = body_distance
        self.world = world
        self._slowed = (1.0, '')          # the last check's slowing (6, 7): kept by the steps that do not check

    def twist(self, q: Sequence[float], target: np.ndarray) -> np.ndarray:
        here = self.kin.fk(q)
        linear = GAIN * (target[:3, 3] - here[:3, 3])
        angular = GAIN * rotation_error(here[:3, :3], target[:3, :3])
        n = np.linalg.norm(linear)
        if n > MAX_LINEAR:
            linear *= MAX_LINEAR / n
        n = np.linalg.norm(angular)
        if n > MAX_ANGULAR:
            angular *= MAX_ANGULAR / n
        return np.concatenate([linear, angular])

    def step(self, q: Sequence[float], target: np.ndarray, check: bool = True) -> Step:
        """One step from ``q`` towards ``target``; ``check``: run the body's and the world's checks (6, 7), else
        keep the last check's slowing."""
        q = np.asarray(q, dtype=float)
        jac = self.kin.jacobian(q)
        dq = jac.T @ np.linalg.solve(jac @ jac.T + DAMPING ** 2 * np.eye(6), self.twist(q, target))
        condition = self.kin.condition_number(q)
        scale, why = 1.0, ''
        # 3. the singularity, when moving towards it
        if condition >= SINGULARITY_SLOW and np.any(dq):
            ahead = self.kin.condition_number(q + dq * self.period)
            if ahead > condition:
                if condition >= SINGULARITY_STOP:
                    return self._halt(q, condition, 'near a singularity (condition number %.1f, stop at %.0f)'
                                      % (condition, SINGULARITY_STOP))
                scale = (SINGULARITY_STOP - condition) / (SINGULARITY_STOP - SINGULARITY_SLOW)
                why = 'slowed near a singularity (condition number %.1f)' % condition
        # 4. the joints' ranges, with their margin
        for name, v, lim, dv in zip(self.kin.joints, q, self.kin.limits, dq):
            if (dv > 0 and v >= lim.upper - JOINT_MARGIN) or (dv < 0 and v <= lim.lower + JOINT_MARGIN):
                return self._halt(q, condition, '%s at %.3f rad is within %.1f rad of its range\'s end'
                                  % (name, v, JOINT_MARGIN))
        # 5. each joint within its speed
        worst = max((abs(dv * scale) / lim.velocity for dv, lim in zip(dq, self.kin.limits)), default=0.0)
        if worst > 1.0:
            scale /= worst
        if check:
            slowed = self._checks(q, dq * scale)
            if isinstance(slowed, str):
                # the steps until the next check halt too: before, four steps in five went on at full speed
                # towards what the fifth had halted for
                self._slowed = (0.0, slowed)
                return self._halt(q, condition, slowed)
            self._slowed = slowed
        if self._slowed[0] == 0.0:
            return self._halt(q, condition, self._slowed[1])
        scale *= self._slowed[0]
        why = why or self._slowed[1]
        velocities = list(dq * scale)
        return Step(velocities, list(q + dq * scale * self.period), scale, condition, why)

    def _checks(self, q: np.ndarray, dq: np.ndarray):
        """6 and 7 for the step ``dq``: (the factor it is slowed by, why) or, to halt, why (a str)."""
        factor, why = 1.0, ''
        if not np.any(dq):
            return factor, why
        ahead = q + dq * LOOKAHEAD_S
        if self.body_distance is not None:
            distance = self.body_distance(ahead, COLLISION_SLOW)
            if distance is not None:
                if distance <= 0.0:
                    return 'the arm would touch the robot\'s own body'
                factor *= distance / COLLISION_SLOW
                why = 'slowed %.1f mm from the robot\'s own body' % (1000 * distance)
        if self.world is not None:
            near = self.world(ahead)
            if near is not None:
                free, where = near
                if free <= WORLD_HALT:
                    return 'the arm would touch the world: it would come %s' % where
                now = self.world(q)
                if now is None or free < now[0]:          # towards it; moving away is never slowed
                    factor *= free / WORLD_SLOW
                    why = why or 'slowed within %.2f m of the world\'s margin' % WORLD_SLOW
        return factor, why

    def _halt(self, q: np.ndarray, condition: float, why: str) -> Step:
        return Step([0.0] * len(q), list(q), 0.0, condition, why)
