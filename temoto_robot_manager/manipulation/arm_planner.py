"""An arm goal, from its target to a trajectory the arm's controller can run, or a refusal naming why. No ROS.

A goal names exactly one target: a pose of the tool (in the arm's base frame by now: the node transforms
it), a named pose of the description, or one position per joint. A pose is solved by inverse kinematics
from where the arm is, so the arm takes the nearest way there. The joint-space line from the start to
the goal is checked against the robot's own body and against the world (the map: ``world_clearance.py``)
every ``CHECK_STEP_RAD`` of the joint that moves most, and only then time-parameterised (``joint_motion.py``).
Nothing moves before all of this has passed.
"""
from __future__ import annotations

import math
from typing import Callable, List, Mapping, Optional, Sequence

import numpy as np

from temoto_robot_manager.manipulation.arm_kinematics import ArmKinematics, KinematicsError
from temoto_robot_manager.manipulation.joint_motion import Point, time_parameterise
from temoto_robot_manager.manipulation.world_clearance import way_touch

ACCEL = 4.0                   # rad/s^2 per joint: half what the UR5's motors give, for smooth goals
DEFAULT_SPEED_SCALE = 0.5     # of each joint's speed limit
CHECK_STEP_RAD = 0.05         # the self-collision check's sampling along the way
GOAL_MARGIN = 0.05            # rad: a goal keeps this far inside each joint's range

# the joint the arm would touch its own body with at q, named with the link it touches; None when clear
Touches = Callable[[Sequence[float]], Optional[str]]

INVALID_GOAL, NO_SOLUTION, SELF_COLLISION, WORLD_COLLISION = -1, -2, -3, -7     # MoveArm's result codes


class GoalRefused(ValueError):
    def __init__(self, code: int, text: str) -> None:
        super().__init__(text)
        self.code = code


class ArmPlanner:
    def __init__(self, kinematics: ArmKinematics, named: Mapping[str, Sequence[float]],
                 touches: Optional[Touches] = None, world: Optional[Touches] = None) -> None:
        """``touches``: the robot's own body at q; ``world``: the world at q (both: why, or None)."""
        self.kin = kinematics
        self.named = {k: list(v) for k, v in named.items()}
        self.touches = touches
        self.world = world

    def target(self, start: Sequence[float], pose: Optional[np.ndarray], named_pose: str,
               joint_positions: Sequence[float]) -> List[float]:
        """The goal's joint positions; raises GoalRefused naming the field."""
        given = [name for name, set_ in (('pose', pose is not None), ('named_pose', bool(named_pose)),
                                         ('joint_positions', len(joint_positions) > 0)) if set_]
        if len(given) != 1:
            raise GoalRefused(INVALID_GOAL, 'give exactly one of pose, named_pose and joint_positions (given: %s)'
                              % (', '.join(given) or 'none'))
        if named_pose:
            if named_pose not in self.named:
                raise GoalRefused(INVALID_GOAL, 'named_pose %r is not a pose of this arm (its poses: %s)'
                                  % (named_pose, ', '.join(sorted(self.named)) or 'none'))
            goal = self.named[named_pose]
        elif len(joint_positions):
            if len(joint_positions) != self.kin.n:
                raise GoalRefused(INVALID_GOAL, 'joint_positions has %d values for the %d joints %s'
                                  % (len(joint_positions), self.kin.n, ', '.join(self.kin.joints)))
            goal = [float(v) for v in joint_positions]
            for name, v in zip(self.kin.joints, goal):
                if not math.isfinite(v):
                    raise GoalRefused(INVALID_GOAL, 'joint_positions: %s is %r, not a finite angle' % (name, v))
        else:
            if not np.all(np.isfinite(pose)):
                raise GoalRefused(INVALID_GOAL, 'pose: every value must be finite')
            try:
                goal = self.kin.ik(pose, start, margin=GOAL_MARGIN)
            except KinematicsError as err:
                raise GoalRefused(NO_SOLUTION, 'pose: %s' % err) from None
        beyond = self.kin.within_limits(goal, GOAL_MARGIN)
        if beyond:
            raise GoalRefused(INVALID_GOAL, '%s: %s' % ('named_pose' if named_pose else 'joint_positions', beyond))
        return goal

    def check_way(self, start: Sequence[float], goal: Sequence[float]) -> None:
        """Raises GoalRefused where the straight joint-space way touches the robot's own body (SELF_COLLISION) or
        the world (WORLD_COLLISION)."""
        if self.touches is not None:
            found = way_touch(self.touches, start, goal, CHECK_STEP_RAD)
            if found:
                raise GoalRefused(SELF_COLLISION, 'the way there touches the robot\'s own body %.0f%% of the way: %s'
                                  % (100 * found[0], found[1]))
        if self.world is not None:
            found = way_touch(self.world, start, goal, CHECK_STEP_RAD)
            if found:
                raise GoalRefused(WORLD_COLLISION, 'the way there touches the world %.0f%% of the way: %s'
                                  % (100 * found[0], found[1]))

    def plan(self, start: Sequence[float], pose: Optional[np.ndarray] = None, named_pose: str = '',
             joint_positions: Sequence[float] = (), speed_scale: float = 0.0) -> List[Point]:
        """The trajectory from ``start`` to the goal; raises GoalRefused naming why there is none."""
        if not (math.isfinite(speed_scale) and 0.0 <= speed_scale <= 1.0):
            raise GoalRefused(INVALID_GOAL, 'speed_scale %r must be in (0, 1], or 0 for %.1f'
                              % (speed_scale, DEFAULT_SPEED_SCALE))
        scale = speed_scale or DEFAULT_SPEED_SCALE
        goal = self.target(start, pose, named_pose, joint_positions)
        self.check_way(start, goal)
        speeds = [lim.velocity * scale for lim in self.kin.limits]
        return time_parameterise(start, goal, speeds, [ACCEL] * self.kin.n)
