"""A seeded history of steps: client operations and faults, drawn from the seed alone.

Each step is drawn from ``random.Random(seed)`` and the step's number, never from what happened before,
so ``--seed S --until N`` replays the same first N steps. A step that names something (a client, a held
resource, a driver) names it by a draw the runner resolves against the system at that moment ("the k-th
held resource, modulo how many there are"), which is as far as a real system allows a replay to go.
"""
from __future__ import annotations

import dataclasses
import math
import random
from typing import Dict, Iterator, List, Tuple

VERSION = 5
# (kind, weight) by history version: client operations are the bulk of a history, faults the rest. A new
# version draws other steps from the same seed; the older ones stay, so that every seed ever reported
# replays (version 1: sensors only, no consumer processes and no power loss of the robot; version 2: no
# tracked objects, no displays, and only the robot's Sensor and ER Managers).
CLIENT_OPS: Dict[int, List[Tuple[str, float]]] = {
    1: [('load_sensor', 6), ('unload', 5)],
    2: [('load_sensor', 5), ('load_process', 2), ('unload', 6)],
    3: [('load_sensor', 4), ('load_process', 1.5), ('track_object', 1.5), ('show_display', 2), ('unload', 8)],
}
NEMESIS: Dict[int, List[Tuple[str, float]]] = {
    1: [('kill_driver', 1), ('kill_client', 1), ('kill_manager', 1), ('stop_manager', 1), ('unplug', 1),
        ('replug', 2), ('partition', 1)],                                               # partition: two hosts only
    2: [('kill_driver', 1), ('kill_consumer', 1), ('kill_client', 1), ('kill_manager', 1), ('stop_manager', 1),
        ('unplug', 1), ('replug', 2), ('partition', 1),
        ('kill_robot', 0.25)],                         # the slowest fault (the robot boots again): the rarest
}
NEMESIS[3] = NEMESIS[4] = NEMESIS[2]
CLIENT_OPS[4] = CLIENT_OPS[3]
# version 5: the clients also hold motion (a drive to a point of the lab, a servo stream, a gripper goal, a
# cancel), and the nemesis hits what moves (a controller killed or stalled, the obstacle source the base
# drives on, the hand an arm follows; the Robot Manager among the managers)
CLIENT_OPS[5] = [(k, 6 if k == 'unload' else w) for k, w in CLIENT_OPS[3]] + [
    ('navigate', 3.0), ('servo', 2.5), ('grip', 1.0), ('cancel_motion', 1.0)]
NEMESIS[5] = [(k, 3 if k == 'replug' else w) for k, w in NEMESIS[2]] + [
    ('kill_controller', 1), ('stop_controller', 1), ('unplug_obstacle', 0.75), ('unplug_hand', 0.5)]
# (a replug is as frequent as the three ways of pulling a cable: a device does not stay unplugged for good)
# version 6 (issue 51): the clients also send arm trajectory goals (the camera's arm), and the nemesis hits what
# holds motion: the operator's stop under whatever moves (the gripper's included), and a manipulator SIGKILLed
# (the client of its arm's trajectory). The motors keep their command timeout here: a controller killed is a
# stop only hardware makes (``bench_safety.py`` measures the stack's side of it, the motors' timeout off); every
# other stop case is the stack's own, since a live commander's stream keeps the motors' timeout from firing.
CLIENT_OPS[6] = CLIENT_OPS[5] + [('arm_goal', 1.5)]
NEMESIS[6] = NEMESIS[5] + [('halt', 0.75), ('kill_manipulator', 0.75)]
# version 7 (issue 51): the stop cases measured often enough (at least 50 of each in 10,000 steps): more drives and
# servo streams, the hand followed in half of them, and the faults that stop them drawn four times as often; the
# gripper's goals go through its command gate (a goal with a negative force is the gate's to refuse)
CLIENT_OPS[7] = [(k, {'navigate': 5.0, 'servo': 4.0}.get(k, w)) for k, w in CLIENT_OPS[6]]
NEMESIS[7] = [(k, {'unplug_obstacle': 3.0, 'unplug_hand': 3.0, 'halt': 1.5, 'kill_manipulator': 1.5}.get(k, w))
              for k, w in NEMESIS[6]]
HAND_SHARE = {7: 0.5}          # of the servo streams, those that follow the hand (0.25 before version 7)
FAULT_SHARE = 0.2
# what a client asks for: a type and the topic types it needs (equal requests are shared by the manager)
SENSOR_REQUESTS: List[Tuple[str, Tuple[str, ...]]] = [('depth camera', ('camera_data',)), ('lidar', ('lidar_data',)),
                                                       ('lidar', ('lidar_data', 'cloud_data'))]
# the process a client runs: a sensor topic (relative to the robot's namespace) throttled to a rate, in Hz
THROTTLE_REQUESTS: List[Tuple[str, float]] = [('sick/scan', 2.0), ('hokuyo/scan', 2.0), ('d435/color/camera_info', 1.0)]
# what a client shows on the station's screen: a display type and a topic of the robot's (relative)
DISPLAY_REQUESTS: List[Tuple[str, str]] = [('laser scan', 'hokuyo/scan'), ('laser scan', 'sick/scan'),
                                           ('image', 'd435/color/image_raw')]
OBJECTS = ('hand',)            # what a client asks the Context Manager to track (trackers.yaml)
# the managers a fault may kill or stop, by history version: relative to the robot's namespace, or to the
# station's ('station/...')
MANAGERS: Dict[int, Tuple[str, ...]] = {
    1: ('/temoto_sensor_manager', '/temoto_er_manager'),
    3: ('/temoto_sensor_manager', '/temoto_er_manager', '/temoto_context_manager', 'station/temoto_output_manager',
        'station/temoto_er_manager'),
}
MANAGERS[2] = MANAGERS[1]
MANAGERS[4] = MANAGERS[3]
MANAGERS[5] = MANAGERS[3] + ('/temoto_robot_manager',)
MANAGERS[6] = MANAGERS[7] = MANAGERS[5]
# how many clients a history has unless told (``step`` draws the client from them); from version 4 the
# clients work concurrently (runner.py), and the draws are version 3's over twice as many clients
CLIENTS: Dict[int, int] = {1: 3, 2: 3, 3: 3, 4: 6, 5: 6, 6: 6, 7: 6}
CONCURRENT_FROM = 4
MOTION_FROM = 5
DEVICES = ('d435', 'hokuyo', 'sick')
DEVICES_WITH_HAND = DEVICES + ('hand_tracker',)      # version 5: the operator's hand tracker has a cable too
MODES = ('crash', 'stall')
# version 5's motion: the lab's floor to draw goals from (m, the world frame; a point in an obstacle, or too
# near one for the robot's outline, is refused), its named places, and goals that are wrong on purpose
LAB_X, LAB_Y = (-1.5, 3.5), (-1.5, 3.0)
PLACES = ((0.0, 0.0, 0.0), (1.7, 1.06, 1.571), (0.5, 2.1, 1.571), (2.3, 0.0, -0.3))
BAD_GOALS = (('world', 25.0, 0.0), ('nowhere', 1.0, 0.0), ('world', float('nan'), 0.0))
ARMS = ('left_arm', 'left_arm', 'right_arm')          # the camera's arm carries the gripper: servoed more
SCALES = (0.1, 0.25, 0.5, 1.0)                        # the dial, for a servo that follows the hand
ARM_GOAL_ARMS = ('left_arm',)     # trajectory goals: the camera's arm (the Hokuyo's sweeps between its holds)
GRIPPER_STROKE = 0.085



@dataclasses.dataclass(frozen=True)
class Step:
    index: int
    kind: str
    args: Dict[str, object]

    def describe(self) -> str:
        return '%d %s %s' % (self.index, self.kind, ' '.join('%s=%s' % kv for kv in sorted(self.args.items())))


def _weighted(rng: random.Random, table: List[Tuple[str, float]]) -> str:
    return rng.choices([k for k, _ in table], [w for _, w in table])[0]


def step(seed: int, index: int, clients: int, version: int = VERSION) -> Step:
    """Step ``index`` of the history of ``seed`` (drawn as history ``version`` draws): the same in every run."""
    if version not in CLIENT_OPS:
        raise ValueError('history version %r does not exist (%s)' % (version, ', '.join(map(str, sorted(CLIENT_OPS)))))
    rng = random.Random('%d/%d' % (seed, index))
    if rng.random() >= FAULT_SHARE:
        kind = _weighted(rng, CLIENT_OPS[version])
        args: Dict[str, object] = {'client': rng.randrange(clients)}
        if kind == 'load_sensor':
            sensor_type, keys = rng.choice(SENSOR_REQUESTS)
            args.update(type=sensor_type, keys=list(keys))
        elif kind == 'load_process':
            topic, rate = rng.choice(THROTTLE_REQUESTS)
            args.update(topic=topic, rate=rate)
        elif kind == 'track_object':
            args['object'] = rng.choice(OBJECTS)
        elif kind == 'show_display':
            display_type, topic = rng.choice(DISPLAY_REQUESTS)
            args.update(type=display_type, topic=topic)
        elif kind == 'navigate':
            args.update(_goal(rng))
        elif kind == 'servo':
            args.update(_servo(rng, HAND_SHARE.get(version, 0.25)))
        elif kind == 'arm_goal':
            args.update(arm=rng.choice(ARM_GOAL_ARMS), speed=rng.choice((0.2, 0.5, 1.0)),
                        offsets=[round(rng.uniform(-0.3, 0.3), 3) if rng.random() < 0.5 else 0.0 for _ in range(6)])
        elif kind == 'grip':
            draw = rng.random()
            gap = GRIPPER_STROKE if draw < 0.35 else 0.0 if draw < 0.7 else 0.2 if draw < 0.8 else \
                round(rng.uniform(0.0, GRIPPER_STROKE), 4)        # 0.2: beyond the stroke, refused
            args.update(gap=gap, effort=round(rng.uniform(10.0, 100.0), 1) if rng.random() > 0.05 else -1.0)
        else:
            args['pick'] = rng.randrange(1 << 30)      # unload, cancel_motion: which of what it holds
        return Step(index, kind, args)
    kind = _weighted(rng, NEMESIS[version])
    if kind in ('kill_driver', 'kill_consumer'):
        return Step(index, kind, {'pick': rng.randrange(1 << 30)})
    if kind == 'kill_client':
        return Step(index, kind, {'client': rng.randrange(clients)})
    if kind == 'kill_manager':
        return Step(index, kind, {'manager': rng.choice(MANAGERS[version])})
    if kind == 'stop_manager':
        return Step(index, kind, {'manager': rng.choice(MANAGERS[version]),
                                  'seconds': round(rng.uniform(0.2, 2.0), 2)})
    if kind == 'partition':
        return Step(index, kind, {'seconds': round(rng.uniform(1.0, 3.0), 2)})
    if kind == 'kill_robot':
        return Step(index, kind, {})
    if kind == 'kill_controller':          # which: of the controllers of the parts moving then, if any move
        return Step(index, kind, {'pick': rng.randrange(1 << 30)})
    if kind == 'stop_controller':
        return Step(index, kind, {'pick': rng.randrange(1 << 30), 'seconds': round(rng.uniform(0.2, 1.5), 2)})
    if kind == 'halt':
        return Step(index, kind, {})
    if kind == 'kill_manipulator':
        return Step(index, kind, {'pick': rng.randrange(1 << 30)})
    if kind in ('unplug_obstacle', 'unplug_hand'):
        return Step(index, kind, {'mode': rng.choice(MODES)})
    devices = DEVICES_WITH_HAND if version >= MOTION_FROM else DEVICES
    if kind == 'unplug':
        return Step(index, kind, {'device': rng.choice(devices), 'mode': rng.choice(MODES)})
    return Step(index, 'replug', {'device': rng.choice(devices)})


def _goal(rng: random.Random) -> Dict[str, object]:
    """A drive's goal: a point of the lab's floor (most), a named place, or a goal wrong on purpose."""
    draw = rng.random()
    if draw < 0.6:
        x, y, yaw = rng.uniform(*LAB_X), rng.uniform(*LAB_Y), rng.uniform(-math.pi, math.pi)
        return {'frame': 'world', 'x': round(x, 2), 'y': round(y, 2), 'yaw': round(yaw, 2)}
    if draw < 0.9:
        x, y, yaw = rng.choice(PLACES)
        return {'frame': 'world', 'x': x, 'y': y, 'yaw': yaw}
    frame, x, y = rng.choice(BAD_GOALS)
    return {'frame': frame, 'x': x, 'y': y, 'yaw': 0.0}


def _servo(rng: random.Random, hand_share: float) -> Dict[str, object]:
    """A servo stream: a short path from where the tool is (a direction, 2 to 8 cm, there and back), or (that
    share of them) the hand tracker followed at a dial's scale; 1 to 4 s."""
    v = [rng.gauss(0.0, 1.0) for _ in range(3)]
    norm = math.sqrt(sum(c * c for c in v)) or 1.0
    length = rng.uniform(0.02, 0.08)
    return {'arm': rng.choice(ARMS), 'source': 'hand' if rng.random() < hand_share else 'path',
            'offset': [round(c / norm * length, 4) for c in v], 'scale': rng.choice(SCALES),
            'seconds': round(rng.uniform(1.0, 4.0), 2)}


def history(seed: int, steps: int, clients: int, version: int = VERSION) -> Iterator[Step]:
    for index in range(steps):
        yield step(seed, index, clients, version)
