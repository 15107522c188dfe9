"""A seeded history of steps: client operations and faults, drawn from the seed alone.

Each step is drawn from ``random.Random(seed)`` and the step's number, never from what happened before,
so ``--seed S --until N`` replays the same first N steps. A step that names something (a client, a held
resource, a driver) names it by a draw the runner resolves against the system at that moment ("the k-th
held resource, modulo how many there are"), which is as far as a real system allows a replay to go.
"""
from __future__ import annotations

import dataclasses
import random
from typing import Dict, Iterator, List, Tuple

# (kind, weight): client operations are the bulk of a history, faults the rest
CLIENT_OPS: List[Tuple[str, int]] = [('load_sensor', 6), ('unload', 5)]
NEMESIS: List[Tuple[str, int]] = [('kill_driver', 1), ('kill_client', 1), ('kill_manager', 1), ('stop_manager', 1),
                                  ('unplug', 1), ('replug', 2), ('partition', 1)]   # partition: two hosts only
FAULT_SHARE = 0.2
# what a client asks for: a type and the topic types it needs (equal requests are shared by the manager)
SENSOR_REQUESTS: List[Tuple[str, Tuple[str, ...]]] = [('depth camera', ('camera_data',)), ('lidar', ('lidar_data',)),
                                                       ('lidar', ('lidar_data', 'cloud_data'))]
MANAGERS = ('/temoto_sensor_manager', '/temoto_er_manager')
DEVICES = ('d435', 'hokuyo', 'sick')
MODES = ('crash', 'stall')


@dataclasses.dataclass(frozen=True)
class Step:
    index: int
    kind: str
    args: Dict[str, object]

    def describe(self) -> str:
        return '%d %s %s' % (self.index, self.kind, ' '.join('%s=%s' % kv for kv in sorted(self.args.items())))


def _weighted(rng: random.Random, table: List[Tuple[str, int]]) -> str:
    return rng.choices([k for k, _ in table], [w for _, w in table])[0]


def step(seed: int, index: int, clients: int) -> Step:
    """Step ``index`` of the history of ``seed``: the same for every run."""
    rng = random.Random('%d/%d' % (seed, index))
    if rng.random() >= FAULT_SHARE:
        kind = _weighted(rng, CLIENT_OPS)
        args: Dict[str, object] = {'client': rng.randrange(clients)}
        if kind == 'load_sensor':
            sensor_type, keys = rng.choice(SENSOR_REQUESTS)
            args.update(type=sensor_type, keys=list(keys))
        else:
            args['pick'] = rng.randrange(1 << 30)
        return Step(index, kind, args)
    kind = _weighted(rng, NEMESIS)
    if kind == 'kill_driver':
        return Step(index, kind, {'pick': rng.randrange(1 << 30)})
    if kind == 'kill_client':
        return Step(index, kind, {'client': rng.randrange(clients)})
    if kind == 'kill_manager':
        return Step(index, kind, {'manager': rng.choice(MANAGERS)})
    if kind == 'stop_manager':
        return Step(index, kind, {'manager': rng.choice(MANAGERS), 'seconds': round(rng.uniform(0.2, 2.0), 2)})
    if kind == 'unplug':
        return Step(index, kind, {'device': rng.choice(DEVICES), 'mode': rng.choice(MODES)})
    if kind == 'partition':
        return Step(index, kind, {'seconds': round(rng.uniform(1.0, 3.0), 2)})
    return Step(index, 'replug', {'device': rng.choice(DEVICES)})


def history(seed: int, steps: int, clients: int) -> Iterator[Step]:
    for index in range(steps):
        yield step(seed, index, clients)
