"""The sources an operator's view can show, in the order of preference: parsed and checked once.

A view's priority list comes from configuration (``~actions/<action>/sensor_priority``), so every
field is checked here and a bad one is named (``sensor_priority[2].display_key ...``) before any
sensor is asked for. :class:`SensorChoice` is what the rest of the failover code reads.
"""
from __future__ import annotations

from dataclasses import dataclass

import yaml

from temoto_action_engine.action_base import ActionError

# where an entry's sensor is asked for: the robot's Sensor Manager (the action's robot, or the engine's own when
# there is none), or the station's (the engine's own namespace: a sensor wired to the operator's station)
SENSOR_MANAGERS = ('robot', 'station')

# the VaultBot's, from the paper's section 4: the RGB-D cloud, then the arm LIDARs' stitched cloud, then the base scan
DEFAULT_PRIORITY = [
    {'label': 'RGB-D camera cloud', 'sensor_type': 'depth camera', 'output_topics': ['camera_data'],
     'display_type': 'point cloud', 'display_key': 'camera_data'},
    {'label': 'arm LIDAR stitched cloud', 'sensor_type': 'lidar', 'output_topics': ['lidar_data', 'cloud_data'],
     'display_type': 'point cloud', 'display_key': 'cloud_data'},
    {'label': 'base LIDAR scan', 'sensor_type': 'lidar', 'output_topics': ['lidar_data'],
     'display_type': 'laser scan', 'display_key': 'lidar_data',
     'display_config': {'Style': 'Flat Squares', 'Size (m)': 0.05, 'Color Transformer': 'FlatColor',
                        'Color': '255; 120; 0'}},
]


@dataclass(frozen=True)
class SensorChoice:
    """One entry of the priority list: what kind of sensor to ask for, and how to show it."""
    label: str
    sensor_type: str
    output_topics: tuple
    display_type: str
    display_key: str
    display_config: str = ''     # RViz properties (YAML) for the display, e.g. point size and colour
    station: bool = False        # served by the operator's station's Sensor Manager, not the robot's


def parse_priority(raw: object) -> list[SensorChoice]:
    """Validate the priority list parameter; raise ActionError naming the bad entry."""
    if not isinstance(raw, list) or not raw:
        raise ActionError('sensor_priority must be a non-empty list, got %r' % (raw,))
    out = []
    for i, e in enumerate(raw):
        if not isinstance(e, dict):
            raise ActionError('sensor_priority[%d] must be a mapping, got %r' % (i, e))
        keys = e.get('output_topics')
        if not isinstance(keys, list) or not keys or not all(isinstance(k, str) and k for k in keys):
            raise ActionError('sensor_priority[%d].output_topics must be a non-empty list of keys' % i)
        for f in ('sensor_type', 'display_type'):
            if not isinstance(e.get(f), str) or not e[f]:
                raise ActionError('sensor_priority[%d].%s must be a non-empty string' % (i, f))
        key = e.get('display_key', keys[0])
        if key not in keys:
            raise ActionError('sensor_priority[%d].display_key %r is not one of its output_topics %s'
                              % (i, key, keys))
        config = e.get('display_config', '')
        if isinstance(config, dict):
            config = yaml.safe_dump(config, default_flow_style=True).strip()
        elif not isinstance(config, str):
            raise ActionError('sensor_priority[%d].display_config must be a mapping of RViz properties or YAML, '
                              'got %r' % (i, config))
        where = e.get('sensor_manager', 'robot')
        if where not in SENSOR_MANAGERS:
            raise ActionError('sensor_priority[%d].sensor_manager must be one of %s, got %r'
                              % (i, ', '.join(SENSOR_MANAGERS), where))
        out.append(SensorChoice(str(e.get('label', e['sensor_type'])), e['sensor_type'], tuple(keys),
                                e['display_type'], key, config, where == 'station'))
    return out
