"""The navigator's logic: one goal at a time, from its checks to its end, with a stop for every reason. No ROS.

``navigator_node.py`` is the ROS side (move_base's action, ``/move_base_simple/goal``, the topics);
this class decides. A goal is:
- **checked** before anything moves (:meth:`Navigator.check`): finite numbers, a known frame (the
  node's), a unit quaternion, inside the map, and the robot's whole outline clear of the map's obstacles there.
  A goal that fails a check raises :class:`BadGoal` naming the field; the robot is not touched;
- **planned** on the costmap (``global_planner.py``) and replanned every ``REPLAN_PERIOD_S`` against
  the live obstacles;
- **driven** (``path_follower.py``), every command passed through the collision monitor
  (``collision_monitor.py``);
- **paused** while the obstacle source is stale (``freshness.py``): the command is zero until a fresh
  frame comes, from the same source or from the one the Robot Manager fails over to; and while a guard
  (``guards.py``: the odometry fresh, the arms inside the outline) holds it, until it passes again, for
  ``BLOCKED_PATIENCE_S`` at most;
- **ended**: arrived, cancelled, or aborted with the reason (no path, blocked, no fresh obstacles for
  the description's ``obstacle_patience``, no odometry for the description's ``odom_patience``, or a guard's final reason:
  :meth:`Navigator.abort`).

Every state is one of :class:`State`; :meth:`tick` moves between them and returns the command.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np

from temoto_robot_manager.navigation import global_planner
from temoto_robot_manager.navigation.collision_monitor import CollisionMonitor, MonitorSettings, Verdict, Zone
from temoto_robot_manager.navigation.costmap import Costmap, Footprint
from temoto_robot_manager.description import Navigation
from temoto_robot_manager.navigation.freshness import Freshness
from temoto_robot_manager.guards import OdometryFresh, StopCode, StopReason
from temoto_robot_manager.navigation.path_follower import FollowerLimits, PathFollower, Phase, wrap

REPLAN_PERIOD_S = 1.0
BLOCKED_PATIENCE_S = 10.0          # stopped by an obstacle this long: the goal is aborted, not held forever
OBSTACLE_PATIENCE_S = 10.0         # no fresh obstacle source this long: aborted (the description's default)
NO_PATH_PATIENCE_S = 3.0           # replans that find no path, this long: aborted
MONITOR_RADIUS = 2.5               # m around the robot of the map's obstacles the monitor checks
APPROACH = 0.8                     # m: the last stretch, driven straight along the goal's heading
ON_STRETCH = 0.15                  # m aside of the last stretch that still counts as on it, when replanning
ON_STRETCH_YAW = math.radians(15.0)  # and how far off its heading
DEPART_SPEED = 0.15                # m/s, backing out of a place with no room to turn
DEPART_LIMIT = 1.2                 # m backed out at most before following a plan regardless
CREEP = (0.3, 0.1)                 # a command the stop zone refuses is tried again at these fractions
YAW_LIMIT = math.radians(5.0)      # the heading tolerance: a last turn blocked within it has arrived

Pose = Tuple[float, float, float]


class State(enum.Enum):
    IDLE = 'idle'
    DRIVING = 'driving'
    WAITING = 'waiting for a fresh obstacle source'
    HELD = 'held by a guard'
    BLOCKED = 'stopped by an obstacle'


class Outcome(enum.Enum):
    SUCCEEDED = 'succeeded'
    ABORTED = 'aborted'
    CANCELED = 'canceled'


class BadGoal(ValueError):
    """A goal refused before anything moved: ``field`` is the goal's field at fault."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__('%s: %s' % (field, message))
        self.field = field


@dataclass(frozen=True)
class Ending:
    outcome: Outcome
    text: str
    code: StopCode = StopCode.ENDED          # why it ended, typed


@dataclass(frozen=True)
class Tick:
    linear: float
    angular: float
    state: State
    remaining: float                   # m left along the plan
    ending: Optional[Ending] = None    # set once, on the tick the goal ends
    verdict: Optional[Verdict] = None


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float:
    return math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))


class Navigator:
    def __init__(self, footprint: Footprint, freshness: Freshness,
                 follower: Optional[PathFollower] = None, monitor: Optional[CollisionMonitor] = None,
                 odometry: Optional[OdometryFresh] = None, guards: Sequence = (),
                 obstacle_patience: float = OBSTACLE_PATIENCE_S) -> None:
        """``guards``: more rules a command must pass (each with ``check(now) -> Optional[StopReason]``);
        ``obstacle_patience``: seconds a goal waits at zero for a fresh obstacle source before it ends. It was 45 s:
        a goal whose source had stalled waited that long, its holder told "0.1 m to go" again and again."""
        self.footprint = footprint
        self.freshness = freshness
        self.obstacle_patience = obstacle_patience
        self.odometry = odometry                   # None: the pose is trusted as it is (the rules' own tests)
        self.guards = ([odometry] if odometry is not None else []) + list(guards)
        self.held_by: Optional[StopReason] = None  # why a guard holds the goal now
        self.follower = follower or PathFollower()
        self.monitor = monitor or CollisionMonitor(footprint)
        self.costmap: Optional[Costmap] = None
        self.pose: Optional[Pose] = None
        self.obstacles_base = np.zeros((0, 2))     # the source's latest frame, in the base's frame
        self.state = State.IDLE
        self.goal: Optional[Pose] = None
        self.target: Optional[Pose] = None         # where the current plan ends: the goal, or its staging pose
        self.path: Optional[np.ndarray] = None
        self._since: float = 0.0                   # when the current state began
        self._planned: float = 0.0
        self._no_path_since: Optional[float] = None
        self._departing = False                    # backing out of a place with no room to turn
        self._backed = 0.0                         # m backed out so far
        self._last_tick: Optional[float] = None

    # -- what the node feeds in -----------------------------------------------------------------------------
    def set_map(self, costmap: Costmap) -> None:
        self.costmap = costmap

    def set_pose(self, pose: Pose, now: Optional[float] = None) -> None:
        """The base's pose from odometry that arrived at ``now`` (monotonic; None: not timed)."""
        self.pose = pose
        if now is not None and self.odometry is not None:
            self.odometry.heard(now)

    def guard_stop(self, now: float) -> Optional[StopReason]:
        """Why a guard forbids driving now (a final reason first), or None."""
        reasons = [r for r in (g.check(now) for g in self.guards) if r is not None]
        return next((r for r in reasons if r.final), reasons[0] if reasons else None)

    def stop_deadline(self) -> Optional[float]:
        """The earliest moment the obstacle source or the odometry goes stale, if nothing comes; None when
        neither can (nothing proven fresh yet)."""
        deadlines = [d for d in (self.freshness.deadline(),
                                 self.odometry.deadline() if self.odometry is not None else None) if d is not None]
        return min(deadlines) if deadlines else None

    def set_obstacles(self, points_base: np.ndarray, now: float) -> None:
        """A frame of the obstacle source (N x 2, base frame, at ``self.pose``): marked and fresh."""
        self.obstacles_base = points_base
        self.freshness.heard(now)
        if self.costmap is not None and self.pose is not None:
            self.costmap.mark(self.to_map(points_base))

    def monitor_points(self) -> np.ndarray:
        """What the collision monitor checks a command against (N x 2, base frame): the source's latest frame
        and the map's obstacles within ``MONITOR_RADIUS``."""
        points = self.obstacles_base
        if self.costmap is not None and self.pose is not None:
            near = self.costmap.static_points(self.pose[0], self.pose[1], MONITOR_RADIUS)
            points = np.vstack([points, self.to_base(near)]) if len(near) else points
        return points

    def to_map(self, points_base: np.ndarray) -> np.ndarray:
        x, y, yaw = self.pose
        c, s = math.cos(yaw), math.sin(yaw)
        return np.stack([x + c * points_base[:, 0] - s * points_base[:, 1],
                         y + s * points_base[:, 0] + c * points_base[:, 1]], axis=1)

    def to_base(self, points_map: np.ndarray) -> np.ndarray:
        x, y, yaw = self.pose
        c, s = math.cos(yaw), math.sin(yaw)
        rel = points_map - (x, y)
        return np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)

    # -- goals ----------------------------------------------------------------------------------------------
    def check(self, x: float, y: float, quaternion: Tuple[float, float, float, float],
              field: str = 'target_pose.pose') -> Pose:
        """The goal as (x, y, yaw) in the map's frame; raises :class:`BadGoal` naming the field at fault."""
        for name, value in (('position.x', x), ('position.y', y)) + tuple(
                ('orientation.' + k, v) for k, v in zip('xyzw', quaternion)):
            if not math.isfinite(value):
                raise BadGoal('%s.%s' % (field, name), 'must be a finite number, not %r' % value)
        norm = math.sqrt(sum(v * v for v in quaternion))
        if abs(norm - 1.0) > 0.01:
            raise BadGoal('%s.orientation' % field, 'must be a unit quaternion (its norm is %.3f)' % norm)
        qx, qy, qz, qw = (v / norm for v in quaternion)
        if abs(qx) > 0.01 or abs(qy) > 0.01:
            raise BadGoal('%s.orientation' % field, 'must turn about z only: a base stands on the floor')
        if self.costmap is None:
            raise BadGoal('target_pose.header.frame_id', 'no map has come yet: no goal can be checked')
        cm = self.costmap
        if not cm.inside(x, y):
            raise BadGoal('%s.position' % field, '(%.2f, %.2f) is outside the map (x %.2f to %.2f, y %.2f to %.2f)'
                          % (x, y, cm.bounds[0], cm.bounds[2], cm.bounds[1], cm.bounds[3]))
        if cm.occupied(x, y):
            raise BadGoal('%s.position' % field, '(%.2f, %.2f) is inside an obstacle' % (x, y))
        yaw = yaw_of(qx, qy, qz, qw)
        gap = self.gap_at((x, y, yaw))
        margin = self.monitor.settings.stop_margin
        if gap < margin:
            raise BadGoal('%s.position' % field, 'the robot at (%.2f, %.2f, %.0f deg) would be %.2f m from an '
                          'obstacle; its outline needs %.2f m clear' % (x, y, math.degrees(yaw), gap, margin))
        return x, y, yaw

    def gap_at(self, pose: Pose) -> float:
        """Metres between the footprint at ``pose`` and the nearest obstacle, the map's or the source's."""
        near = self.costmap.points_near(pose[0], pose[1], self.footprint.circumscribed + 0.5)
        if not len(near):
            return math.inf
        return float(self.footprint.distance(self._into(near, pose)).min())

    @staticmethod
    def _into(points: np.ndarray, pose: Pose) -> np.ndarray:
        x, y, yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)
        rel = points - (x, y)
        return np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)

    @staticmethod
    def _on_stretch(pose: Pose, goal: Pose) -> bool:
        """Whether the robot at ``pose`` is on the goal's last stretch (``APPROACH`` long, ending at the goal),
        facing the goal's way."""
        gx, gy, yaw = goal
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = pose[0] - gx, pose[1] - gy
        along, aside = dx * c + dy * s, -dx * s + dy * c
        return (-APPROACH - ON_STRETCH <= along <= 0.0 and abs(aside) <= ON_STRETCH
                and abs(wrap(pose[2] - yaw)) <= ON_STRETCH_YAW)

    @staticmethod
    def _stretch(start: Tuple[float, float], goal: Pose) -> np.ndarray:
        """The straight way in from ``start`` (on the goal's line) to the goal."""
        gx, gy, yaw = goal
        c, s = math.cos(yaw), math.sin(yaw)
        along = max(0.0, -((start[0] - gx) * c + (start[1] - gy) * s))
        steps = np.linspace(along, 0.0, max(2, int(round(along / global_planner.SPACING)) + 1))
        return np.vstack([[start], np.stack([gx - steps * c, gy - steps * s], axis=1)])

    def route(self, start: Pose, goal: Pose) -> Tuple[np.ndarray, Pose]:
        """(the plan, the pose it ends at) toward ``goal``. When the goal is too close to something to turn
        there (at a table, say), the plan ends at a *staging* pose ``APPROACH`` behind it, facing its way,
        and the robot then drives the last stretch straight in; the stretch must be free for the whole
        outline. A robot already on that stretch just finishes it."""
        gx, gy, yaw = goal
        c, s = math.cos(yaw), math.sin(yaw)
        sx, sy = gx - APPROACH * c, gy - APPROACH * s
        cm = self.costmap
        if self._on_stretch(start, goal):
            return self._stretch(start[:2], goal), goal
        if not cm.lethal(gx, gy):
            return global_planner.plan(cm, start[:2], (gx, gy)), goal
        if cm.inside(sx, sy) and not cm.lethal(sx, sy):
            near = cm.points_near(sx, sy, self.footprint.circumscribed + APPROACH + 0.5)
            stretch = self._into(near, (sx, sy, yaw)) if len(near) else np.zeros((0, 2))
            if not self.monitor.swept_hit(stretch, 1.0, 0.0, APPROACH, self.monitor.settings.stop_margin):
                return global_planner.plan(cm, start[:2], (sx, sy)), (sx, sy, yaw)
        raise global_planner.NoPath('the goal (%.2f, %.2f) is %.2f m from an obstacle, too close to turn there, '
                                    'and no straight way in along its heading is free' % (gx, gy,
                                                                                        cm.clearance(gx, gy)))

    def start(self, goal: Pose, now: float) -> None:
        """Drive to a checked ``goal`` (replacing any other); raises NoPath when none is found now."""
        if self.pose is None:
            raise BadGoal('target_pose', 'the robot\'s pose is not known yet (no odometry)')
        stop = self.guard_stop(now)
        if stop is not None:
            raise BadGoal('target_pose', 'the robot may not drive now: %s' % stop.text)
        self.path, self.target = self.route(self.pose, goal)
        self.goal = goal
        self.follower.reset()
        # no room to turn where it stands (it is at a table, say) and not already on the way in: back out
        # first, straight, as it came in, until it has room (``DEPART_LIMIT`` at most)
        self._departing = self.costmap.lethal(*self.pose[:2]) and not self._on_stretch(self.pose, goal)
        self._backed, self._last_tick = 0.0, None
        self._planned = now
        self._no_path_since = None
        self._enter(State.DRIVING, now)

    def cancel(self) -> None:
        self._finish()

    def abort(self, reason: StopReason) -> Tick:
        """End the goal ABORTED for a guard's final ``reason`` (its controller is gone): zero, and nothing resumes
        without a new goal."""
        return self._end(Outcome.ABORTED, '%s: the robot stopped' % reason.text, reason.code)

    def _finish(self) -> None:
        self.goal, self.path, self.target = None, None, None
        self.state = State.IDLE

    def _enter(self, state: State, now: float) -> None:
        if state is not self.state:
            self.state, self._since = state, now

    def _end(self, outcome: Outcome, text: str, code: StopCode = StopCode.ENDED) -> Tick:
        remaining = self.remaining()
        self._finish()
        return Tick(0.0, 0.0, State.IDLE, remaining, Ending(outcome, text, code))

    def remaining(self) -> float:
        if self.path is None or self.pose is None:
            return 0.0
        left, _ = global_planner.remaining(self.path, self.pose[0], self.pose[1])
        if self.goal is not None:
            left = max(left, math.hypot(self.goal[0] - self.pose[0], self.goal[1] - self.pose[1]))
        return left

    # -- the loop ------------------------------------------------------------------------------------------
    def must_stop(self, now: float) -> bool:
        """Whether a goal is held and its obstacle source is stale, or a guard holds it: the command must be zero
        now."""
        return self.goal is not None and (not self.freshness.fresh(now) or self.guard_stop(now) is not None)

    def tick(self, now: float) -> Tick:
        if self.goal is None:
            return Tick(0.0, 0.0, State.IDLE, 0.0)
        stop = self.held_by = self.guard_stop(now)
        if stop is not None:
            if stop.final:
                return self.abort(stop)
            if self.state is not State.HELD:
                self._enter(State.HELD, now)
            elif now - self._since > BLOCKED_PATIENCE_S:
                return self._end(Outcome.ABORTED, 'held for %.0f s: %s' % (BLOCKED_PATIENCE_S, stop.text), stop.code)
            return Tick(0.0, 0.0, State.HELD, self.remaining())
        if not self.freshness.fresh(now):
            if self.state is not State.WAITING:
                self._enter(State.WAITING, now)
            elif now - self._since > self.obstacle_patience:
                return self._end(Outcome.ABORTED, 'no fresh obstacle source for %.0f s: the robot will not drive '
                                 'blind' % self.obstacle_patience, StopCode.OBSTACLES_STALE)
            return Tick(0.0, 0.0, State.WAITING, self.remaining())
        if self.state in (State.WAITING, State.HELD):
            self._enter(State.DRIVING, now)
            self._planned = -math.inf                  # the world may have changed while waiting: plan again
        if now - self._planned >= REPLAN_PERIOD_S:
            self._planned = now
            try:
                path, target = self.route(self.pose, self.goal)
                if target != self.target:
                    self.follower.reset()
                self.path, self.target = path, target
                self._no_path_since = None
            except global_planner.NoPath as err:
                if self._no_path_since is None:
                    self._no_path_since = now
                elif now - self._no_path_since > NO_PATH_PATIENCE_S:
                    return self._end(Outcome.ABORTED, 'no path any more: %s' % err)
        if self._departing and (not self.costmap.lethal(*self.pose[:2]) or self._backed >= DEPART_LIMIT):
            self._departing = False                    # room to turn: follow a plan from here
            self._planned = -math.inf
            return Tick(0.0, 0.0, self.state, self.remaining())
        dt = now - self._last_tick if self._last_tick is not None else 0.0
        self._last_tick = now
        if self._departing:
            linear, angular = -DEPART_SPEED, 0.0
        else:
            linear, angular = self.follower.command(self.pose, self.path, self.target[2])
        if self.follower.phase is Phase.ARRIVED and self.target != self.goal:
            # at the staging pose, facing the goal's way: the last stretch, straight in
            self.path, self.target = self._stretch(self.pose[:2], self.goal), self.goal
            self.follower.reset()
            return Tick(0.0, 0.0, self.state, self.remaining())
        if self.follower.phase is Phase.ARRIVED:
            x, y, yaw = self.pose
            return self._end(Outcome.SUCCEEDED, 'arrived %.3f m and %.1f deg from the goal' % (
                math.hypot(self.goal[0] - x, self.goal[1] - y), math.degrees(abs(wrap(self.goal[2] - yaw)))))
        points = self.monitor_points()
        verdict = self.monitor.check(points, linear, angular)
        for scale in CREEP:                            # too fast for where it is: slower may be safe (a creep)
            if verdict.zone is not Zone.STOP:
                break
            verdict = self.monitor.check(points, linear * scale, angular * scale)
        if self._departing:
            self._backed += abs(verdict.linear) * dt          # what it was told, slowed or not
        if verdict.zone is Zone.STOP and self._departing:
            # backing out is blocked (it did not come in this way): follow the plan from here instead, still
            # under the monitor; the planner lets a plan start where the robot stands
            self._departing = False
            self._planned = -math.inf
            return Tick(0.0, 0.0, self.state, self.remaining(), verdict=verdict)
        if verdict.zone is Zone.STOP and self.follower.phase is Phase.ALIGN:
            x, y, yaw = self.pose
            error = abs(wrap(self.goal[2] - yaw))
            if error <= YAW_LIMIT:
                return self._end(Outcome.SUCCEEDED, 'arrived %.3f m and %.1f deg from the goal (turning further would '
                                 'touch an obstacle %.2f m away)' % (math.hypot(self.goal[0] - x, self.goal[1] - y),
                                                                      math.degrees(error), verdict.nearest))
        if verdict.zone is Zone.STOP:
            if self.state is not State.BLOCKED:
                self._enter(State.BLOCKED, now)
            elif now - self._since > BLOCKED_PATIENCE_S:
                return self._end(Outcome.ABORTED, 'blocked for %.0f s by an obstacle %.2f m from the robot'
                                 % (BLOCKED_PATIENCE_S, verdict.nearest), StopCode.BLOCKED)
        else:
            self._enter(State.DRIVING, now)
        return Tick(verdict.linear, verdict.angular, self.state, self.remaining(), verdict=verdict)


def described(navigation: Navigation, odometry: Optional[OdometryFresh] = None, guards: Sequence = ()) -> Navigator:
    """A navigator with the outline and the safety numbers of a robot description's ``navigation``."""
    footprint = Footprint.of(navigation.footprint, navigation.protrusions)
    monitor = CollisionMonitor(footprint, MonitorSettings(stop_margin=navigation.stop_margin,
                                                          slow_margin=navigation.slow_margin, decel=navigation.braking))
    follower = PathFollower(FollowerLimits(max_speed=navigation.max_speed, max_turn=navigation.max_turn))
    return Navigator(footprint, Freshness(periods=navigation.stale_periods), follower, monitor, odometry, guards,
                     navigation.obstacle_patience)
