"""The robot description file: which robots there are, and the parts of each feature, checked line by line.

Modelled on the original's ``robot_description.yaml`` (a list of robots, each with its reliability
and the features ``navigation``, ``manipulation`` and ``gripper``); its keys are this project's.
One file holds a list under ``robots``::

    robots:
      - name: vaultbot                       # a ROS base name, unique in the file
        description: Husky A200 with two UR5s
        reliability: 0.9                     # optional prior, 0 to 1 (default 0.8): the best robot is chosen
        navigation:
          driver:                            # the base's controller (cmd_vel in, odom out), through the ER Manager
            package: vaultbot_sim
            executable: base.launch
            running: true                    # optional: it runs with the robot already; checked, not started
          cmd_vel_topic: cmd_vel
          odom_topic: odom
          odom_rate: 50                      # Hz the driver publishes odometry at: 3 periods without, and the base
                                             # is commanded zero (optional, default 50)
          odom_patience: 0.5                 # s without odometry, or its publisher's connection gone: the goal is
                                             # aborted, and nothing drives until a new goal (optional, default 0.5)
          odom_frame: odom
          base_frame: base_link
          footprint: [-0.50, 0.64, -0.69, 0.67]   # x_min, x_max, y_min, y_max (m) in base_frame, arms included
                                             # (or [length, width], centred): the costmap's and the monitor's
          arm_inset: 0.04                    # m the arms' axes stay inside the footprint while the base drives (the
                                             # links' thickness); an arm out holds the base (optional, default 0.04)
          max_speed: 0.8                     # m/s and rad/s the navigator commands at most, a goal's or a stream's
          max_turn: 1.2                      # (optional, defaults 0.8 and 1.2)
          stop_margin: 0.05                  # m around the outline the collision monitor keeps clear: a command
          slow_margin: 0.20                  # that would enter it is zero, one entering the slow margin slowed
          braking: 2.0                       # m/s^2 the base brakes at: how far ahead the monitor looks
          stale_periods: 3                   # an obstacle source silent this many of its periods: zero
          teleop_timeout: 0.1                # s a teleop stream's command lasts (its deadman)
          teleop_max_age: 0.1                # s old a teleop command may be on arrival; older: refused
          obstacle_patience: 10.0            # s a goal waits, at zero, for a fresh obstacle source (the Robot
                                             # Manager failing over, a stall taken back); then it is aborted
          obstacle_sources:                  # ranked: the Sensor Manager's sensors, flattened into the costmap
            - {label: base LIDAR scan, sensor_type: lidar, output_topic: lidar_data,
               package: vaultbot_sim, executable: sick_driver}     # optional: that device, not the best of the type
          places:                            # named places: [x, y, yaw] in odom_frame (m, m, rad)
            home: [0.0, 0.0, 0.0]
        manipulation:
          left_arm:                          # one entry per arm
            controller: {package: vaultbot_sim, executable: arm_controller, args: _arm:=left_arm}
            manipulator: {package: temoto_robot_manager, executable: manipulator}   # goals and servoing
            action: left_arm/follow_joint_trajectory
            servo_topic: left_arm/servo_command
            servo_timeout: 0.1               # s: a servo target this old is not followed; the arm holds (optional)
            world_margin: 0.05               # m the arm's axes keep from the map's obstacles (optional)
            joints: [left_shoulder_pan_joint, ...]
            base_frame: left_base_link
            tool_frame: left_tool0
            named_poses:                     # one position per joint, in the order of joints
              stow: [-0.121, -1.694, -1.673, -3.018, -1.789, -0.802]
        gripper:
          controller: {package: vaultbot_sim, executable: gripper_controller}
          node: {package: temoto_robot_manager, executable: gripper}   # its command gate: goals on gripper/command
          action: gripper/gripper_command    # the controller's
          arm: left_arm                      # the arm that carries it
          positions: {open: 0.085, closed: 0.0}   # named gaps between the pads (m)

Every problem is reported with its file and line (``temoto robots check FILE``); a robot with a
problem is left out, the others load.
"""
from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Tuple

import rosgraph.names
import yaml

from temoto_core import yaml_lines
from temoto_core.reliability import DEFAULT_PRIOR

FEATURES = ('navigation', 'manipulation', 'gripper')
GRIPPER_GATE_ACTION = 'gripper/command'     # where a gripper node serves its goals
_ROBOT_KEYS = {'name', 'description', 'reliability', 'temoto_namespace'} | set(FEATURES)
_PART_KEYS = {'package', 'executable', 'args', 'running'}
_NAVIGATION_KEYS = {'driver', 'controller', 'cmd_vel_topic', 'odom_topic', 'odom_rate', 'odom_patience', 'odom_frame',
                    'base_frame', 'footprint', 'protrusions', 'arm_inset', 'max_speed', 'max_turn', 'stop_margin',
                    'slow_margin', 'braking', 'stale_periods', 'teleop_timeout', 'teleop_max_age', 'obstacle_patience',
                    'obstacle_sources', 'places'}
_SOURCE_KEYS = {'label', 'sensor_type', 'output_topic', 'package', 'executable'}
_ARM_KEYS = {'controller', 'manipulator', 'action', 'servo_topic', 'servo_timeout', 'world_margin', 'joints',
             'base_frame', 'tool_frame', 'named_poses'}
_GRIPPER_KEYS = {'controller', 'node', 'action', 'arm', 'positions'}


class DescriptionError(ValueError):
    """One problem of a description file; ``where`` is ``file:line``."""

    def __init__(self, where: str, message: str) -> None:
        super().__init__('%s: %s' % (where, message))
        self.where, self.message = where, message


@dataclass(frozen=True)
class Part:
    """A process a feature needs: started through the ER Manager, unless it runs with the robot already."""
    package: str
    executable: str
    args: str = ''
    running: bool = False

    @property
    def node_name(self) -> str:
        """The name its node runs as: a ``__name:=`` remapping in its args, else its executable's (as the
        node scripts here name themselves)."""
        renamed = [a.split(':=', 1)[1] for a in self.args.split() if a.startswith('__name:=')]
        return renamed[-1] if renamed else self.executable


@dataclass(frozen=True)
class ObstacleSource:
    """A source of obstacles, asked of the Sensor Manager: its best sensor of the type, or the one named by its
    package and executable (the base's own scanner, when an arm carries another of the same type)."""
    label: str
    sensor_type: str
    output_topic: str
    package: str = ''
    executable: str = ''


@dataclass(frozen=True)
class Navigation:
    driver: Part
    controller: Optional[Part]
    cmd_vel_topic: str
    odom_topic: str
    odom_frame: str
    base_frame: str
    footprint: Tuple[float, ...]          # [length, width] (centred) or [x_min, x_max, y_min, y_max] (m)
    obstacle_sources: Tuple[ObstacleSource, ...]
    places: Dict[str, Tuple[float, float, float]]
    # what sticks out of the footprint's rectangle (a gripper ahead of the bumper), each [x_min, x_max, y_min,
    # y_max] (m): part of the outline that is kept clear, without widening it all round
    protrusions: Tuple[Tuple[float, float, float, float], ...] = ()
    odom_rate: float = 50.0               # Hz: the odometry is stale after 3 of its periods (``guards.OdometryFresh``)
    odom_patience: float = 0.5            # s of stale odometry before a goal is aborted
    arm_inset: float = 0.04               # m the arms' axes stay inside the footprint while the base drives
    place_sources: Dict[str, str] = field(default_factory=dict)    # each place's file:line, for what is said of it
    # the safety numbers (docs/robots.md, "Safety numbers"); the defaults are the VaultBot's
    max_speed: float = 0.8                # m/s a command may ask at most
    max_turn: float = 1.2                 # rad/s
    stop_margin: float = 0.05             # m around the outline: a command that would enter it is zero
    slow_margin: float = 0.20             # m: one entering it is slowed
    braking: float = 2.0                  # m/s^2 the base brakes at
    stale_periods: int = 3                # periods of an obstacle source's without a frame: stale
    teleop_timeout: float = 0.1           # s a teleop command lasts
    teleop_max_age: float = 0.1           # s old a teleop command may arrive
    obstacle_patience: float = 10.0       # s a goal waits at zero for a fresh obstacle source, then ends ABORTED


@dataclass(frozen=True)
class Arm:
    name: str
    controller: Part
    action: str
    servo_topic: str
    joints: Tuple[str, ...]
    base_frame: str
    tool_frame: str
    named_poses: Dict[str, Tuple[float, ...]]
    manipulator: Optional[Part] = None      # the node that serves the arm's goals and servoing (manipulator_node)
    servo_timeout: float = 0.1              # s: a servo target this old is not followed (MoveIt Servo's)
    world_margin: float = 0.05              # m each arm's axes keep from the map's obstacles (the links' thickness)


@dataclass(frozen=True)
class Gripper:
    controller: Part
    action: str
    arm: str
    positions: Dict[str, float] = field(default_factory=dict)   # named gaps between the pads (m): open, closed
    node: Optional[Part] = None             # its command gate (gripper_node), whose goals clients send

    @property
    def command_action(self) -> str:
        """The action clients send goals to: the gate's when one is described, else the controller's."""
        return GRIPPER_GATE_ACTION if self.node is not None else self.action


@dataclass(frozen=True)
class RobotDescription:
    name: str
    description: str = ''
    reliability: float = DEFAULT_PRIOR
    temoto_namespace: str = ''
    navigation: Optional[Navigation] = None
    manipulation: Dict[str, Arm] = field(default_factory=dict)
    gripper: Optional[Gripper] = None
    source: str = ''               # file:line

    @property
    def path(self) -> str:
        """The description file this robot was read from."""
        return os.path.abspath(self.source.rsplit(':', 1)[0])

    @property
    def features(self) -> List[str]:
        return [f for f, on in (('navigation', self.navigation), ('manipulation', self.manipulation),
                                ('gripper', self.gripper)) if on]


class _Reader:
    """Reads one robot's mapping, naming the file and line of whatever is wrong."""

    def __init__(self, path: str, lines: yaml_lines.Lines) -> None:
        self.path, self.lines = path, lines

    def error(self, at: Sequence, message: str) -> DescriptionError:
        return DescriptionError('%s:%d' % (self.path, self.lines.of(tuple(at))), message)

    @staticmethod
    def label(at: Sequence) -> str:
        out = ''
        for p in at:
            out += '[%d]' % p if isinstance(p, int) else ('.' if out else '') + str(p)
        return out

    def mapping(self, value: Any, at: Sequence, keys: set, required: Sequence[str] = ()) -> dict:
        if not isinstance(value, dict):
            raise self.error(at, '%s must be a mapping, got %r' % (self.label(at), value))
        for key in value:
            if key not in keys:
                close = difflib.get_close_matches(str(key), sorted(keys), n=1)
                raise self.error(list(at) + [key], 'unknown key %s.%s%s (known: %s)' % (
                    self.label(at), key, ' (did you mean %r?)' % close[0] if close else '', ', '.join(sorted(keys))))
        for key in required:
            if key not in value:
                raise self.error(at, '%s needs %r' % (self.label(at), key))
        return value

    def text(self, parent: dict, key: str, at: Sequence, default: Optional[str] = None, name: bool = False) -> str:
        if key not in parent and default is not None:
            return default
        value = parent.get(key)
        where = list(at) + [key]
        if not isinstance(value, str) or not value.strip():
            raise self.error(where, '%s must be a non-empty string, got %r' % (self.label(where), value))
        if name and not rosgraph.names.is_legal_name(value):
            raise self.error(where, '%s %r is not a legal ROS name' % (self.label(where), value))
        return value.strip()

    def number(self, parent: dict, key: str, at: Sequence, default: float, above: float, maximum: float) -> float:
        """``parent[key]``, a finite number in (``above``, ``maximum``], or ``default`` when it is not given."""
        if key not in parent:
            return default
        value, where = parent[key], list(at) + [key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or not above < value <= maximum:
            raise self.error(where, '%s must be a number above %g and at most %g, got %r'
                             % (self.label(where), above, maximum, value))
        return float(value)

    def count(self, parent: dict, key: str, at: Sequence, default: int, least: int, most: int) -> int:
        """``parent[key]``, a whole number from ``least`` to ``most``, or ``default`` when it is not given."""
        value, where = parent.get(key, default), list(at) + [key]
        if isinstance(value, bool) or not isinstance(value, int) or not least <= value <= most:
            raise self.error(where, '%s must be a whole number from %d to %d, got %r'
                             % (self.label(where), least, most, value))
        return value

    def numbers(self, value: Any, at: Sequence, count: int, what: str) -> Tuple[float, ...]:
        if not isinstance(value, list) or len(value) != count or \
                not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value):
            raise self.error(at, '%s must be %s: %d finite numbers, got %r' % (self.label(at), what, count, value))
        return tuple(float(v) for v in value)

    def part(self, value: Any, at: Sequence) -> Part:
        raw = self.mapping(value, at, _PART_KEYS, ('package', 'executable'))
        running = raw.get('running', False)
        if not isinstance(running, bool):
            raise self.error(list(at) + ['running'], '%s.running must be true or false' % self.label(at))
        args = raw.get('args', '')
        if not isinstance(args, str):
            raise self.error(list(at) + ['args'], '%s.args must be a string' % self.label(at))
        return Part(self.text(raw, 'package', at), self.text(raw, 'executable', at), args, running)

    def navigation(self, value: Any, at: Sequence) -> Navigation:
        raw = self.mapping(value, at, _NAVIGATION_KEYS, ('driver', 'obstacle_sources'))
        sources_at = list(at) + ['obstacle_sources']
        sources = raw['obstacle_sources']
        if not isinstance(sources, list) or not sources:
            raise self.error(sources_at, '%s must be a non-empty list, ranked' % self.label(sources_at))
        ranked = []
        for i, s in enumerate(sources):
            s_at = sources_at + [i]
            s_raw = self.mapping(s, s_at, _SOURCE_KEYS, ('sensor_type', 'output_topic'))
            ranked.append(ObstacleSource(self.text(s_raw, 'label', s_at, default=str(s_raw.get('sensor_type'))),
                                         self.text(s_raw, 'sensor_type', s_at), self.text(s_raw, 'output_topic', s_at),
                                         self.text(s_raw, 'package', s_at, default=''),
                                         self.text(s_raw, 'executable', s_at, default='')))
        places = {}
        places_raw = raw.get('places', {})
        if not isinstance(places_raw, dict):
            raise self.error(list(at) + ['places'], '%s.places must be a mapping of names to [x, y, yaw]'
                             % self.label(at))
        place_sources = {}
        for place, pose in places_raw.items():
            places[str(place)] = self.numbers(pose, list(at) + ['places', place], 3, '[x, y, yaw]')
            place_sources[str(place)] = '%s:%d' % (self.path, self.lines.of(tuple(at) + ('places', place)))
        fp_at, fp_raw = list(at) + ['footprint'], raw.get('footprint', [0.99, 0.67])
        if isinstance(fp_raw, list) and len(fp_raw) == 4:
            footprint = self.numbers(fp_raw, fp_at, 4, '[x_min, x_max, y_min, y_max]')
            if not (footprint[0] < 0 < footprint[1] and footprint[2] < 0 < footprint[3]):
                raise self.error(fp_at, '%s.footprint [x_min, x_max, y_min, y_max] must hold the base\'s origin: '
                                 'each min below 0, each max above' % self.label(at))
        else:
            footprint = self.numbers(fp_raw, fp_at, 2, '[length, width] or [x_min, x_max, y_min, y_max]')
            if min(footprint) <= 0:
                raise self.error(fp_at, '%s.footprint must be positive' % self.label(at))
        pr_at, pr_raw = list(at) + ['protrusions'], raw.get('protrusions', [])
        if not isinstance(pr_raw, list):
            raise self.error(pr_at, '%s.protrusions must be a list of [x_min, x_max, y_min, y_max]' % self.label(at))
        protrusions = []
        for k, box in enumerate(pr_raw):
            box = self.numbers(box, pr_at + [k], 4, '[x_min, x_max, y_min, y_max]')
            if not (box[0] < box[1] and box[2] < box[3]):
                raise self.error(pr_at + [k], '%s.protrusions[%d]: each min must be below its max'
                                 % (self.label(at), k))
            protrusions.append(box)
        stop = self.number(raw, 'stop_margin', at, 0.05, above=0.0, maximum=1.0)
        slow = self.number(raw, 'slow_margin', at, 0.20, above=0.0, maximum=3.0)
        if slow < stop:
            raise self.error(list(at) + ['slow_margin'], '%s.slow_margin %.2f must be at least its stop_margin %.2f'
                             % (self.label(at), slow, stop))
        return Navigation(
            self.part(raw['driver'], list(at) + ['driver']),
            self.part(raw['controller'], list(at) + ['controller']) if 'controller' in raw else None,
            self.text(raw, 'cmd_vel_topic', at, default='cmd_vel', name=True),
            self.text(raw, 'odom_topic', at, default='odom', name=True),
            self.text(raw, 'odom_frame', at, default='odom'), self.text(raw, 'base_frame', at, default='base_link'),
            footprint, tuple(ranked), places, tuple(protrusions),
            self.number(raw, 'odom_rate', at, 50.0, above=0.0, maximum=1000.0),
            self.number(raw, 'odom_patience', at, 0.5, above=0.0, maximum=10.0),
            self.number(raw, 'arm_inset', at, 0.04, above=-1e-9, maximum=1.0), place_sources,
            self.number(raw, 'max_speed', at, 0.8, above=0.0, maximum=5.0),
            self.number(raw, 'max_turn', at, 1.2, above=0.0, maximum=10.0),
            stop, slow,
            self.number(raw, 'braking', at, 2.0, above=0.0, maximum=20.0),
            self.count(raw, 'stale_periods', at, 3, 1, 20),
            self.number(raw, 'teleop_timeout', at, 0.1, above=0.0, maximum=2.0),
            self.number(raw, 'teleop_max_age', at, 0.1, above=0.0, maximum=2.0),
            self.number(raw, 'obstacle_patience', at, 10.0, above=0.0, maximum=120.0))

    def arm(self, name: str, value: Any, at: Sequence) -> Arm:
        raw = self.mapping(value, at, _ARM_KEYS, ('controller', 'action', 'joints', 'tool_frame'))
        joints = raw['joints']
        if not isinstance(joints, list) or not joints or not all(isinstance(j, str) and j for j in joints) \
                or len(set(joints)) != len(joints):
            raise self.error(list(at) + ['joints'], '%s.joints must list each joint once, got %r'
                             % (self.label(at), joints))
        poses = {}
        poses_raw = raw.get('named_poses', {})
        if not isinstance(poses_raw, dict):
            raise self.error(list(at) + ['named_poses'], '%s.named_poses must be a mapping' % self.label(at))
        for pose, q in poses_raw.items():
            poses[str(pose)] = self.numbers(q, list(at) + ['named_poses', pose], len(joints),
                                            'one position per joint (%s)' % ', '.join(joints))
        return Arm(name, self.part(raw['controller'], list(at) + ['controller']),
                   self.text(raw, 'action', at, name=True),
                   self.text(raw, 'servo_topic', at, default='%s/servo_command' % name, name=True),
                   tuple(joints), self.text(raw, 'base_frame', at, default='base_link'),
                   self.text(raw, 'tool_frame', at), poses,
                   self.part(raw['manipulator'], list(at) + ['manipulator']) if 'manipulator' in raw else None,
                   self.number(raw, 'servo_timeout', at, 0.1, above=0.0, maximum=2.0),
                   self.number(raw, 'world_margin', at, 0.05, above=0.0, maximum=1.0))

    def robot(self, value: Any, at: Sequence) -> RobotDescription:
        raw = self.mapping(value, at, _ROBOT_KEYS, ('name',))
        name = self.text(raw, 'name', at)
        if not rosgraph.names.is_legal_base_name(name):
            raise self.error(list(at) + ['name'], 'robot name %r is not a legal ROS base name' % name)
        reliability = raw.get('reliability', DEFAULT_PRIOR)
        if isinstance(reliability, bool) or not isinstance(reliability, (int, float)) or not 0 <= reliability <= 1:
            raise self.error(list(at) + ['reliability'], 'reliability must be a number from 0 to 1, got %r'
                             % (reliability,))
        if not any(f in raw for f in FEATURES):
            raise self.error(at, 'robot %r has no feature: give navigation, manipulation or gripper' % name)
        arms = {}
        if 'manipulation' in raw:
            m_at = list(at) + ['manipulation']
            m_raw = raw['manipulation']
            if not isinstance(m_raw, dict) or not m_raw:
                raise self.error(m_at, 'manipulation must map each arm\'s name to its description')
            for arm_name, arm in m_raw.items():
                arms[str(arm_name)] = self.arm(str(arm_name), arm, m_at + [arm_name])
        gripper = None
        if 'gripper' in raw:
            g_at = list(at) + ['gripper']
            g_raw = self.mapping(raw['gripper'], g_at, _GRIPPER_KEYS, ('controller', 'action', 'arm'))
            carrier = self.text(g_raw, 'arm', g_at)
            if carrier not in arms:
                raise self.error(g_at + ['arm'], 'gripper.arm %r is not an arm of manipulation (%s)'
                                 % (carrier, ', '.join(arms) or 'none'))
            positions_raw = g_raw.get('positions', {})
            if not isinstance(positions_raw, dict):
                raise self.error(g_at + ['positions'], 'gripper.positions must map names to gaps in metres')
            positions = {}
            for label, gap in positions_raw.items():
                p_at = g_at + ['positions', label]
                if isinstance(gap, bool) or not isinstance(gap, (int, float)) or not 0 <= gap < 1:
                    raise self.error(p_at, 'gripper.positions.%s must be a gap from 0 to 1 m, got %r' % (label, gap))
                positions[str(label)] = float(gap)
            gripper = Gripper(self.part(g_raw['controller'], g_at + ['controller']),
                              self.text(g_raw, 'action', g_at, name=True), carrier, positions,
                              self.part(g_raw['node'], g_at + ['node']) if 'node' in g_raw else None)
        return RobotDescription(
            name, str(raw.get('description', '')), float(reliability),
            self.text(raw, 'temoto_namespace', at, default=''),
            self.navigation(raw['navigation'], list(at) + ['navigation']) if 'navigation' in raw else None,
            arms, gripper, '%s:%d' % (self.path, self.lines.of(tuple(at))))


def load_file(path: str) -> Tuple[List[RobotDescription], List[DescriptionError]]:
    """The robots of one file and the problems found, each with its file and line."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError as err:
        return [], [DescriptionError(path, 'cannot read the description: %s' % err.strerror)]
    try:
        data, lines = yaml_lines.load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        where = '%s:%d' % (path, mark.line + 1) if mark else path
        return [], [DescriptionError(where, 'not valid YAML: %s' % getattr(err, 'problem', err))]
    if not isinstance(data, dict) or not isinstance(data.get('robots'), list) or not data['robots']:
        return [], [DescriptionError('%s:1' % path, "the file must hold a non-empty list under the key 'robots'")]
    reader = _Reader(path, lines)
    robots: List[RobotDescription] = []
    problems: List[DescriptionError] = []
    for i, raw in enumerate(data['robots']):
        try:
            robot = reader.robot(raw, ['robots', i])
        except DescriptionError as err:
            problems.append(err)
            continue
        if any(r.name == robot.name for r in robots):
            problems.append(reader.error(['robots', i, 'name'], 'robot %r is described twice' % robot.name))
            continue
        robots.append(robot)
    return robots, problems


def described_robot(path: str, name: str, feature: str) -> RobotDescription:
    """Robot ``name`` of the file ``path``, which must have ``feature``; raises ValueError naming why not (a node
    started by the Robot Manager reads its robot so)."""
    robots, problems = load_file(path)
    for robot in robots:
        if robot.name == name and feature in robot.features:
            return robot
    raise ValueError('%s describes no robot %r with %s%s' % (path, name, feature,
                                                             ''.join('; ' + str(p) for p in problems)))
