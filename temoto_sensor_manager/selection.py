"""Choosing sensors for a request, and the arguments that give them the requested topic names.

Selection follows the original ``findSensors``: filter by type, then by package
and executable when given, then keep sensors that provide every requested topic
type; sort by reliability, highest first (a stable sort: catalogue order breaks
ties). Unlike the original, the filtered-out entries are really gone.
"""
import dataclasses
import shlex
from typing import Dict, List, Optional, Sequence, Tuple

import rosgraph.names

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_sensor_manager.catalogue import Catalogue, SensorEntry

SUB = Subsystem.SENSOR_MANAGER


def _bad(message: str) -> TemotoError:
    return TemotoError(ErrorCode.BAD_REQUEST, SUB, message)


@dataclasses.dataclass(frozen=True)
class SensorQuery:
    """A validated ``LoadSensor`` request."""
    sensor_type: str
    package_name: str
    executable: str
    topics: Tuple[Tuple[str, str], ...]     # (type, wanted absolute name or '') in request order

    @property
    def topic_types(self) -> List[str]:
        return [k for k, _ in self.topics]


def validate(sensor_type: str, package_name: str, executable: str,
             output_topics: Sequence[Tuple[str, str]]) -> SensorQuery:
    """Check every field arriving over the wire; raise BAD_REQUEST naming the field."""
    if not isinstance(sensor_type, str) or not sensor_type.strip():
        raise _bad('sensor_type is empty: name a sensor type, e.g. "depth camera" or "lidar"')
    for label, value in (('package_name', package_name), ('executable', executable)):
        if len(value) > 256 or '\x00' in value:
            raise _bad('%s %r is not a plausible name' % (label, value[:40]))
    seen = set()
    topics = []
    for key, value in output_topics:
        if not key or not rosgraph.names.is_legal_base_name(key):
            raise _bad('output topic type %r is not a plain name (e.g. camera_data)' % key)
        if key in seen:
            raise _bad('output topic type %r is requested twice' % key)
        seen.add(key)
        if value:
            if not rosgraph.names.is_legal_name(value) or value.startswith('~'):
                raise _bad('output topic %s: %r is not a legal ROS topic name' % (key, value))
            value = value if value.startswith('/') else '/' + value
            value = rosgraph.names.canonicalize_name(value)
        topics.append((key, value))
    return SensorQuery(sensor_type.strip(), package_name.strip(), executable.strip(), tuple(topics))


def candidates(catalogue: Catalogue, query: SensorQuery) -> List[SensorEntry]:
    """Matching entries, best first; raises SENSOR_NOT_FOUND explaining what did not match."""
    of_type = [e for e in catalogue.entries if e.type == query.sensor_type]
    if not of_type:
        raise TemotoError(ErrorCode.SENSOR_NOT_FOUND, SUB, 'unknown sensor type %r (known types: %s)'
                          % (query.sensor_type, ', '.join(repr(t) for t in catalogue.types()) or 'none: the '
                             'catalogue is empty'))
    found = of_type
    if query.package_name:
        found = [e for e in found if e.package == query.package_name]
    if query.executable:
        found = [e for e in found if e.executable == query.executable]
    wanted = set(query.topic_types)
    found = [e for e in found if wanted <= set(e.output_topics)]
    if not found:
        described = '; '.join('%s (%s/%s: %s)' % (e.name, e.package, e.executable, ', '.join(e.output_topics))
                              for e in of_type)
        asked = []
        if query.package_name:
            asked.append('package %r' % query.package_name)
        if query.executable:
            asked.append('executable %r' % query.executable)
        if wanted:
            asked.append('topic types %s' % ', '.join(query.topic_types))
        raise TemotoError(ErrorCode.SENSOR_NOT_FOUND, SUB, 'no %r sensor matches %s; the %r sensors are: %s'
                          % (query.sensor_type, ' and '.join(asked), query.sensor_type, described))
    return sorted(found, key=lambda e: -e.reliability.value)


@dataclasses.dataclass
class LaunchPlan:
    """What to ask the ER Manager for, and which topics will carry data."""
    args: str                       # LoadProcess.args
    topics: Dict[str, str]          # type -> absolute topic, in response order


def plan(entry: SensorEntry, query: SensorQuery) -> LaunchPlan:
    """Remapping for the requested names: launch files get ``arg:=name``, nodes ``default:=name``.

    Every catalogued topic of the entry is set, not only the requested ones: a topic left at the
    driver's default would collide with another device run by the same driver (a second camera
    would publish its image on the first camera's name). The response lists the requested
    topics, or every topic of the sensor when none was requested.
    """
    requested = dict(query.topics)
    keys = query.topic_types or list(entry.output_topics)
    args = shlex.split(entry.args)
    topics = {key: requested.get(key) or entry.output_topics[key].topic for key in keys}
    # the arguments in the catalogue's order, whatever outputs are asked for and in whatever order: two requests
    # for different outputs of one device are then one request of the ER Manager, which shares the running
    # driver. In the request's order, the view's arm LIDAR cloud and navigation's arm LIDAR scan were two
    # launches of one device, and the second was refused ("node name /hokuyo_driver ... is already in use")
    for key, spec in entry.output_topics.items():
        name = requested.get(key) or spec.topic
        if entry.is_launch_file:
            if spec.arg:
                args.append('%s:=%s' % (spec.arg, name))
            elif name != spec.topic:
                args.append('%s:=%s' % (key, name))      # the original's rule: an arg named after the type
        elif name != spec.topic or spec.remap:
            args.append('%s:=%s' % (spec.remap or spec.topic, name))
    return LaunchPlan(' '.join(shlex.quote(a) for a in args), topics)


def ranked_rows(rows: Sequence[dict], sensor_type: str, keys: Sequence[str]) -> List[dict]:
    """The catalogue rows that could answer a ``start_sensor`` of ``sensor_type`` with topic types ``keys``,
    best first: the ranking ``candidates`` applies (reliability, then catalogue order)."""
    wanted = set(keys)
    found = [r for r in rows if isinstance(r, dict) and r.get('type') == sensor_type
             and isinstance(r.get('output_topics'), dict) and wanted <= set(r['output_topics'])]
    return sorted(found, key=lambda r: -float(r.get('reliability', 0.0)))


def likely_topics(rows: Sequence[dict], sensor_type: str, keys: Sequence[str]) -> Optional[Dict[str, str]]:
    """The topics a ``start_sensor`` request with no names would most likely be answered with.

    ``rows`` are the ``sensors`` of the manager's catalogue JSON. The ranking is the one
    ``candidates`` applies (type, topic types, reliability, catalogue order), so a client
    can get ready for the data (e.g. subscribe a display) while the driver starts. Only a
    guess: the best candidate may fail and a lower one answer. None when nothing matches.
    """
    found = ranked_rows(rows, sensor_type, keys)
    if not found:
        return None
    try:
        return {k: str(found[0]['output_topics'][k]['topic']) for k in keys}
    except (KeyError, TypeError):
        return None
