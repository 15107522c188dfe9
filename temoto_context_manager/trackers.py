"""The tracker catalogue: pipes of filters, and the objects that trackers can follow.

Format (``config/trackers.yaml``)::

    trackers:
      - name: green_hand_rgbd            # unique
        category: hand                   # what it tracks (the original's detection method)
        reliability: 0.8                 # optional prior (default 0.8)
        filters:                         # run in order; each adds its outputs to the pipe
          - sensor: depth camera         # a nested start_sensor of this type ...
            outputs: [camera_data]       # ... giving these topic types
          - algorithm: color_blob_tracker
            package: temoto_context_manager
            executable: color_blob_tracker
            args: ''                     # extra arguments
            inputs: {camera_data: points}   # type (from an earlier filter) -> the node's name to remap
            outputs: {pose: pose}           # type -> the node's name; published at
                                            # /<ns>/<pipe_id>/filter_<i>/<type>
            first_data_timeout: 15          # optional, seconds
    objects:
      - name: hand
        detection_methods: [hand]        # tracker categories, tried by reliability

Malformed entries are reported with file and line and skipped.
"""
import dataclasses
from typing import Dict, List

import rosgraph.names
import yaml

from temoto_core.reliability import DEFAULT_PRIOR, Reliability


@dataclasses.dataclass
class Filter:
    kind: str                              # 'sensor' | 'algorithm'
    type: str                              # sensor type, or algorithm name
    outputs: Dict[str, str]                # type -> node-side name ('' for sensors)
    inputs: Dict[str, str] = dataclasses.field(default_factory=dict)
    package: str = ''
    executable: str = ''
    args: str = ''
    first_data_timeout: float = 15.0


@dataclasses.dataclass
class Tracker:
    name: str
    category: str
    filters: List[Filter]
    prior: float = DEFAULT_PRIOR
    source: str = ''
    reliability: Reliability = dataclasses.field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.reliability is None:
            self.reliability = Reliability(self.prior)

    @property
    def output_types(self) -> List[str]:
        return list(self.filters[-1].outputs)


@dataclasses.dataclass
class TrackedObjectSpec:
    name: str
    detection_methods: List[str]
    source: str = ''


def _name(value, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError('%s is missing or empty' % what)
    return value.strip()


def _base(value, what: str) -> str:
    if not isinstance(value, str) or not rosgraph.names.is_legal_base_name(value):
        raise ValueError('%s %r is not a plain name' % (what, value))
    return value


def parse_filter(raw, index: int, available: List[str]) -> Filter:
    where = 'filters[%d]' % index
    if not isinstance(raw, dict):
        raise ValueError('%s must be a mapping' % where)
    if ('sensor' in raw) == ('algorithm' in raw):
        raise ValueError("%s must have exactly one of 'sensor' or 'algorithm'" % where)
    if 'sensor' in raw:
        unknown = sorted(set(raw) - {'sensor', 'outputs'})
        if unknown:
            raise ValueError('%s: unknown field(s) %s' % (where, ', '.join(map(str, unknown))))
        outputs = raw.get('outputs') or []
        if not isinstance(outputs, list) or not outputs:
            raise ValueError('%s.outputs must be a non-empty list of topic types' % where)
        return Filter('sensor', _name(raw['sensor'], where + '.sensor'),
                      {_base(t, where + '.outputs type'): '' for t in outputs})
    unknown = sorted(set(raw) - {'algorithm', 'package', 'executable', 'args', 'inputs', 'outputs',
                                 'first_data_timeout'})
    if unknown:
        raise ValueError('%s: unknown field(s) %s' % (where, ', '.join(map(str, unknown))))
    inputs, outputs = raw.get('inputs') or {}, raw.get('outputs') or {}
    if not isinstance(inputs, dict) or not isinstance(outputs, dict) or not outputs:
        raise ValueError('%s: inputs must be a mapping and outputs a non-empty mapping (type -> node topic)' % where)
    for t in inputs:
        if t not in available:
            raise ValueError('%s: input type %r is produced by no earlier filter (available: %s)'
                             % (where, t, ', '.join(available) or 'none'))
    for mapping in (inputs, outputs):
        for t, n in mapping.items():
            _base(t, where + ' topic type')
            if not isinstance(n, str) or not rosgraph.names.is_legal_name(n) or not n:
                raise ValueError('%s: %r is not a legal topic name' % (where, n))
    timeout = raw.get('first_data_timeout', 15.0)
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or timeout <= 0:
        raise ValueError('%s.first_data_timeout must be a number > 0' % where)
    return Filter('algorithm', _name(raw['algorithm'], where + '.algorithm'), dict(outputs), dict(inputs),
                  _base(_name(raw.get('package'), where + '.package'), where + '.package'),
                  _name(raw.get('executable'), where + '.executable'), str(raw.get('args') or ''), float(timeout))


def parse_tracker(raw, source: str = '') -> Tracker:
    if not isinstance(raw, dict):
        raise ValueError('a tracker must be a mapping')
    unknown = sorted(set(map(str, raw)) - {'name', 'category', 'reliability', 'filters', 'description'})
    if unknown:
        raise ValueError('unknown field(s) %s' % ', '.join(unknown))
    prior = raw.get('reliability', DEFAULT_PRIOR)
    if isinstance(prior, bool) or not isinstance(prior, (int, float)) or not 0 <= prior <= 1:
        raise ValueError('reliability must be a number in [0, 1], got %r' % (prior,))
    filters_raw = raw.get('filters')
    if not isinstance(filters_raw, list) or not filters_raw:
        raise ValueError('filters must be a non-empty list')
    filters, available = [], []
    for i, f in enumerate(filters_raw):
        parsed = parse_filter(f, i, available)
        filters.append(parsed)
        available.extend(parsed.outputs)
    return Tracker(_name(raw.get('name'), 'name'), _name(raw.get('category'), 'category'), filters, float(prior),
                   source)


def parse_object(raw, source: str = '') -> TrackedObjectSpec:
    if not isinstance(raw, dict):
        raise ValueError('an object must be a mapping')
    methods = raw.get('detection_methods')
    if not isinstance(methods, list) or not methods or not all(isinstance(m, str) and m for m in methods):
        raise ValueError('detection_methods must be a non-empty list of tracker categories')
    return TrackedObjectSpec(_name(raw.get('name'), 'name'), list(methods), source)


class TrackerCatalogue:
    def __init__(self) -> None:
        self.trackers: List[Tracker] = []
        self.objects: Dict[str, TrackedObjectSpec] = {}
        self.problems: List[str] = []

    @classmethod
    def from_files(cls, paths: List[str]) -> 'TrackerCatalogue':
        cat = cls()
        for path in paths:
            cat._load(path)
        return cat

    def _load(self, path: str) -> None:
        try:
            with open(path) as f:
                text = f.read()
            data = yaml.safe_load(text) or {}
            root = yaml.compose(text)
        except OSError as err:
            self.problems.append('%s: cannot read: %s' % (path, err.strerror))
            return
        except yaml.YAMLError as err:
            mark = getattr(err, 'problem_mark', None)
            self.problems.append('%s:%s: not valid YAML: %s' % (path, mark.line + 1 if mark else '?', err))
            return
        if not isinstance(data, dict):
            self.problems.append('%s:1: expected a mapping with trackers and objects' % path)
            return
        nodes = {k.value: v for k, v in root.value} if root is not None else {}
        for key, parse, add in (('trackers', parse_tracker, self._add_tracker),
                                ('objects', parse_object, self._add_object)):
            items = data.get(key) or []
            if not isinstance(items, list):
                self.problems.append('%s: %s must be a list' % (path, key))
                continue
            for raw, node in zip(items, nodes[key].value if key in nodes else []):
                where = '%s:%d' % (path, node.start_mark.line + 1)
                try:
                    add(parse(raw, where))
                except ValueError as err:
                    self.problems.append('%s: %s entry skipped: %s' % (where, key[:-1], err))

    def _add_tracker(self, tracker: Tracker) -> None:
        if any(t.name == tracker.name for t in self.trackers):
            raise ValueError('tracker %r is defined twice' % tracker.name)
        self.trackers.append(tracker)

    def _add_object(self, obj: TrackedObjectSpec) -> None:
        if obj.name in self.objects:
            raise ValueError('object %r is defined twice' % obj.name)
        self.objects[obj.name] = obj

    def categories(self) -> List[str]:
        return sorted({t.category for t in self.trackers})

    def ranked(self, category: str) -> List[Tracker]:
        return sorted((t for t in self.trackers if t.category == category), key=lambda t: -t.reliability.value)
