"""Which described robot serves a ``load_robot`` request: the one named, or the most reliable one with every
feature asked for. Plain logic, so that each refusal is tested without a manager."""
from __future__ import annotations

from typing import Callable, Mapping, Sequence

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_robot_manager.description import FEATURES, RobotDescription

SUB = Subsystem.ROBOT_MANAGER


def choose_robot(robots: Mapping[str, RobotDescription], reliability: Callable[[str], float], robot_name: str,
                 features: Sequence[str]) -> RobotDescription:
    """The robot asked for by name, or the most reliable one with every feature; raises naming why none."""
    unknown = [f for f in features if f not in FEATURES]
    if unknown:
        raise TemotoError(ErrorCode.BAD_REQUEST, SUB, 'unknown feature %s (features: %s)'
                          % (', '.join(repr(f) for f in unknown), ', '.join(FEATURES)))
    if robot_name:
        robot = robots.get(robot_name)
        if robot is None:
            raise TemotoError(ErrorCode.ROBOT_NOT_FOUND, SUB, 'no robot %r is described (described: %s)'
                              % (robot_name, ', '.join(sorted(robots)) or 'none'))
        missing = [f for f in features if f not in robot.features]
        if missing:
            raise TemotoError(ErrorCode.ROBOT_NOT_FOUND, SUB, 'robot %s has no %s (it has: %s)'
                              % (robot_name, ', '.join(missing), ', '.join(robot.features)))
        return robot
    able = [r for r in robots.values() if all(f in r.features for f in features)]
    if not able:
        raise TemotoError(ErrorCode.ROBOT_NOT_FOUND, SUB, 'no described robot has %s (described: %s)' % (
            ', '.join(features) or 'a feature', '; '.join('%s: %s' % (r.name, ', '.join(r.features))
                                                          for r in robots.values()) or 'none'))
    return max(able, key=lambda r: reliability(r.name))
