"""The sensor catalogue: YAML files of sensor descriptions, checked entry by entry.

Format (one file holds a list under ``sensors``)::

    sensors:
      - name: realsense_d435            # unique in the catalogue
        type: depth camera
        package: vaultbot_sim
        executable: d435.launch         # a node, or a *.launch file (roslaunch)
        args: ''                        # optional extra arguments (shlex-split by the ER Manager)
        reliability: 0.8                # optional prior of the moving average (default 0.8)
        rate: 30                        # optional expected rate of every topic, Hz
        stall_timeout: 1.0              # optional silence limit of every topic, s (the most, when adaptive)
        stall_detection: adaptive       # optional: adaptive (default) or fixed
        description: ...                # optional
        output_topics:                  # topic type -> topic, or a mapping:
          camera_info: d435/color/camera_info
          camera_data:
            topic: d435/depth_registered/points
            arg: points_topic           # launch file: the <arg> that sets it (default: the type key)
            remap: ''                   # node: the name to remap (default: the topic)
            rate: 30                    # overrides the entry's rate
            stall_timeout: 1.0          # overrides the entry's limit
            stall_detection: fixed      # overrides the entry's

A relative topic is resolved in the namespace of the manager that loads the
catalogue, as ROS resolves a node's relative names: one catalogue serves every
robot, and the Sensor Manager of robot ``vaultbot_2`` (in ROS namespace
``/vaultbot_2``) starts its drivers on ``/vaultbot_2/d435/...``. An absolute
topic stays as written.

A malformed entry is reported with its file and line and skipped; the rest of
the catalogue loads. The stall limit of a topic is its ``stall_timeout``, or
``max(3 expected periods, 100 ms)``; a topic with no rate and no limit is not
watched for stalls (only for its first message). With ``stall_detection:
adaptive`` (the default) that limit is the most: the limit in use follows the
topic's measured rhythm (``arrivals.py``), down to 2.5 expected periods.
"""
import dataclasses
import os
from typing import Dict, List, Optional, Tuple

import rosgraph.names
import yaml

from temoto_core.reliability import DEFAULT_PRIOR, Reliability

STALL_PERIODS = 3.0
MIN_STALL_TIMEOUT = 0.1
# A started driver's first message: its start-up (the allowance) plus this many of its periods.
FIRST_DATA_PERIODS = 10.0
_ENTRY_KEYS = {'name', 'type', 'package', 'executable', 'args', 'reliability', 'rate', 'stall_timeout',
               'stall_detection', 'description', 'output_topics', 'input_topics'}
_TOPIC_KEYS = {'topic', 'arg', 'remap', 'rate', 'stall_timeout', 'stall_detection'}
STALL_DETECTIONS = ('adaptive', 'fixed')


class CatalogueError(ValueError):
    """One malformed entry (or file); ``where`` is ``file:line``."""

    def __init__(self, where: str, message: str) -> None:
        super().__init__('%s: %s' % (where, message))
        self.where = where


@dataclasses.dataclass
class TopicSpec:
    key: str                    # the topic type, e.g. camera_data
    topic: str                  # default topic, absolute (resolved in the manager's namespace)
    arg: str = ''               # launch files: the arg that sets this topic
    remap: str = ''             # nodes: the name inside the node that is remapped
    rate: float = 0.0           # expected Hz; 0: unknown
    stall_timeout: float = 0.0  # s; 0: derived from the rate
    stall_detection: str = 'adaptive'   # or 'fixed': the limit is silence_limit() whatever the rhythm

    @property
    def adaptive(self) -> bool:
        return self.stall_detection == 'adaptive'

    def silence_limit(self) -> float:
        """Seconds of silence that count as a stall; 0 means not watched."""
        if self.stall_timeout > 0:
            return self.stall_timeout
        if self.rate > 0:
            return max(STALL_PERIODS / self.rate, MIN_STALL_TIMEOUT)
        return 0.0

    def first_data_limit(self, allowance: float, cap: float) -> float:
        """Seconds a driver that has just registered has to send its first message here.

        From the nominal rate: ``allowance`` (the driver's own start-up) plus ten periods, never
        more than ``cap``. A device that is silent from its start then costs a few seconds, not
        the cap (which is what a topic of unknown rate gets).
        """
        if self.rate > 0:
            return min(cap, allowance + FIRST_DATA_PERIODS / self.rate)
        return cap


@dataclasses.dataclass
class SensorEntry:
    name: str
    type: str
    package: str
    executable: str
    output_topics: Dict[str, TopicSpec]
    input_topics: Dict[str, str] = dataclasses.field(default_factory=dict)
    args: str = ''
    description: str = ''
    prior: float = DEFAULT_PRIOR
    source: str = ''            # file:line
    reliability: Reliability = dataclasses.field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.reliability is None:
            self.reliability = Reliability(self.prior)

    @property
    def is_launch_file(self) -> bool:
        return self.executable.endswith('.launch')


def _number(value, what: str, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError('%s must be a number, got %r' % (what, value))
    if positive and value <= 0:
        raise ValueError('%s must be > 0, got %r' % (what, value))
    return float(value)


def _text(entry: dict, key: str, required: bool = True) -> str:
    value = entry.get(key, '')
    if value is None:
        value = ''
    if not isinstance(value, str):
        raise ValueError('%s must be a string, got %r' % (key, value))
    value = value.strip()
    if required and not value:
        raise ValueError('%s is missing or empty' % key)
    return value


def _absolute(topic: str, what: str, namespace: str) -> str:
    if not isinstance(topic, str) or not topic or not rosgraph.names.is_legal_name(topic) or topic.startswith('~'):
        raise ValueError('%s: %r is not a legal ROS topic name' % (what, topic))
    return rosgraph.names.ns_join(namespace, topic) if not topic.startswith('/') else topic


def parse_entry(raw, source: str = '', namespace: str = '/') -> SensorEntry:
    """One catalogue entry from its YAML value; raises ValueError naming the bad field."""
    if not isinstance(raw, dict):
        raise ValueError('an entry must be a mapping, got %s' % type(raw).__name__)
    unknown = sorted(set(map(str, raw)) - _ENTRY_KEYS)
    if unknown:
        raise ValueError('unknown field(s) %s (known: %s)' % (', '.join(unknown), ', '.join(sorted(_ENTRY_KEYS))))
    name = _text(raw, 'name')
    kind = _text(raw, 'type')
    package = _text(raw, 'package')
    executable = _text(raw, 'executable')
    if '/' in executable or executable.startswith('.'):
        raise ValueError('executable %r must be a file name inside the package' % executable)
    prior = raw.get('reliability', DEFAULT_PRIOR)
    prior = _number(prior, 'reliability', positive=False)
    if not 0.0 <= prior <= 1.0:
        raise ValueError('reliability must be in [0, 1], got %r' % prior)
    rate = _number(raw['rate'], 'rate') if 'rate' in raw else 0.0
    stall = _number(raw['stall_timeout'], 'stall_timeout') if 'stall_timeout' in raw else 0.0
    detection = _detection(raw, 'stall_detection', 'adaptive')
    outputs = raw.get('output_topics')
    if not isinstance(outputs, dict) or not outputs:
        raise ValueError('output_topics must be a non-empty mapping of topic type -> topic')
    topics = {}
    for key, value in outputs.items():
        if not isinstance(key, str) or not rosgraph.names.is_legal_base_name(key):
            raise ValueError('output topic type %r is not a plain name' % (key,))
        if isinstance(value, str):
            value = {'topic': value}
        if not isinstance(value, dict):
            raise ValueError('output_topics.%s must be a topic name or a mapping' % key)
        bad = sorted(set(map(str, value)) - _TOPIC_KEYS)
        if bad:
            raise ValueError('output_topics.%s: unknown field(s) %s (known: %s)'
                             % (key, ', '.join(bad), ', '.join(sorted(_TOPIC_KEYS))))
        spec = TopicSpec(key=key, topic=_absolute(value.get('topic'), 'output_topics.%s.topic' % key, namespace),
                         arg=_text(value, 'arg', required=False), remap=_text(value, 'remap', required=False),
                         rate=_number(value['rate'], 'output_topics.%s.rate' % key) if 'rate' in value else rate,
                         stall_timeout=_number(value['stall_timeout'], 'output_topics.%s.stall_timeout' % key)
                         if 'stall_timeout' in value else stall,
                         stall_detection=_detection(value, 'output_topics.%s.stall_detection' % key, detection,
                                                    field='stall_detection'))
        if spec.arg and not rosgraph.names.is_legal_base_name(spec.arg):
            raise ValueError('output_topics.%s.arg %r is not a legal launch arg name' % (key, spec.arg))
        if spec.remap and not rosgraph.names.is_legal_name(spec.remap):
            raise ValueError('output_topics.%s.remap %r is not a legal ROS name' % (key, spec.remap))
        topics[key] = spec
    inputs = raw.get('input_topics') or {}
    if not isinstance(inputs, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in inputs.items()):
        raise ValueError('input_topics must be a mapping of topic type -> topic name')
    return SensorEntry(name=name, type=kind, package=package, executable=executable, output_topics=topics,
                       input_topics=dict(inputs), args=_text(raw, 'args', required=False),
                       description=_text(raw, 'description', required=False), prior=prior, source=source)


def _detection(raw: dict, where: str, default: str, field: str = '') -> str:
    """The ``stall_detection`` of ``raw`` (``field``, or the last part of ``where``), one of STALL_DETECTIONS."""
    value = raw.get(field or where, default)
    if value not in STALL_DETECTIONS:
        raise ValueError('%s must be one of %s, got %r' % (where, ', '.join(STALL_DETECTIONS), value))
    return value


def load_file(path: str, namespace: str = '/') -> Tuple[List[SensorEntry], List[CatalogueError]]:
    """Entries of one file and the problems found (each with file and line); relative topics are resolved in
    ``namespace``."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError as err:
        return [], [CatalogueError(path, 'cannot read the catalogue: %s' % err.strerror)]
    try:
        data = yaml.safe_load(text)
        root = yaml.compose(text)       # the same document as nodes, for line numbers
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        where = '%s:%d' % (path, mark.line + 1) if mark else path
        return [], [CatalogueError(where, 'not valid YAML: %s' % getattr(err, 'problem', err))]
    if not isinstance(data, dict) or not isinstance(data.get('sensors'), list):
        return [], [CatalogueError('%s:1' % path, "the file must hold a list under the key 'sensors'")]
    items_node = next(v for k, v in root.value if k.value == 'sensors')
    entries, problems = [], []
    for raw, node in zip(data['sensors'], items_node.value):
        where = '%s:%d' % (path, node.start_mark.line + 1)
        try:
            entries.append(parse_entry(raw, where, namespace))
        except ValueError as err:
            label = raw.get('name') if isinstance(raw, dict) and isinstance(raw.get('name'), str) else None
            problems.append(CatalogueError(where, '%s%s; entry skipped' % (
                'sensor %r: ' % label if label else '', err)))
    return entries, problems


class Catalogue:
    """Every loaded sensor, by name, in file order (the tie-break of the ranking)."""

    def __init__(self, entries: Optional[List[SensorEntry]] = None) -> None:
        self.entries: List[SensorEntry] = []
        self.problems: List[CatalogueError] = []
        for entry in entries or []:
            self.add(entry)

    def add(self, entry: SensorEntry) -> None:
        for known in self.entries:
            if known.name == entry.name:
                self.problems.append(CatalogueError(entry.source or '?', 'sensor %r is already defined at %s; '
                                                    'entry skipped' % (entry.name, known.source)))
                return
        self.entries.append(entry)

    @classmethod
    def from_files(cls, paths: List[str], namespace: str = '/') -> 'Catalogue':
        """``namespace``: the ROS namespace relative topics are resolved in (the manager's own)."""
        if not rosgraph.names.is_global(namespace) or not rosgraph.names.is_legal_name(namespace):
            raise ValueError('catalogue namespace %r: a global ROS namespace such as /vaultbot_2/' % (namespace,))
        cat = cls()
        for path in paths:
            entries, problems = load_file(os.path.expanduser(path), namespace)
            cat.problems.extend(problems)
            for entry in entries:
                cat.add(entry)
        return cat

    def types(self) -> List[str]:
        return sorted({e.type for e in self.entries})

    def get(self, name: str) -> Optional[SensorEntry]:
        return next((e for e in self.entries if e.name == name), None)
