"""SensorManagerInterface: how actions (and other managers) ask for sensors.

The default failure policy is the original's reload: on FAILED, unload the
failed sensor and ask for the same type again *with its topics pinned* to the
names it had, so the ranking (where the failed device has dropped) picks
another device and the consumer keeps listening on the same topics.
``register_update_callback(cb)`` replaces that policy.
"""
import copy
import dataclasses
import json
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Union

from diagnostic_msgs.msg import KeyValue

from temoto_core.errors import Subsystem, TemotoError
from temoto_core.interface import ManagerInterface
from temoto_core.rr import StatusEvent
from temoto_core.rr.deadlines import call_once
from temoto_core.srv import GetRegistry
from temoto_sensor_manager.contract import CATALOGUE, RR_NAME, START_SENSOR, START_SENSOR_TYPE
from temoto_sensor_manager.selection import likely_topics, ranked_rows

TopicsArg = Union[None, Mapping[str, str], Sequence[str]]


@dataclasses.dataclass(frozen=True)
class SensorResult:
    resource_id: int              # this interface's id: pass it to stop_sensor
    sensor_name: str
    package_name: str
    executable: str
    output_topics: Dict[str, str]  # topic type -> absolute topic name

    def topic(self, key: str) -> str:
        """The topic of type ``key`` (the original's ``getOutputTopic``)."""
        try:
            return self.output_topics[key]
        except KeyError:
            raise KeyError('sensor %s has no output topic of type %r (it has %s)'
                           % (self.sensor_name, key, ', '.join(self.output_topics))) from None


def fetch_catalogue(namespace: str = 'temoto', timeout: float = 1.0) -> List[dict]:
    """The running manager's catalogue rows (type, reliability, topics), through its service, within
    ``timeout`` (look-up, connection and answer: a failover asks it, and must not hang on a stopped manager).
    Raises ``rospy.ServiceException`` if the manager does not answer in time."""
    name = '/%s/%s/%s' % (namespace.strip('/'), RR_NAME, CATALOGUE)
    return json.loads(call_once(name, GetRegistry, GetRegistry._request_class(), timeout).json)['sensors']


def _key_values(topics: TopicsArg, what: str) -> List[KeyValue]:
    if topics is None:
        return []
    if isinstance(topics, str):
        raise TypeError('%s must be a dict of type -> name or a list of types, not a string' % what)
    if isinstance(topics, Mapping):
        return [KeyValue(str(k), str(v or '')) for k, v in topics.items()]
    return [KeyValue(str(k), '') for k in topics]


def _result(response) -> SensorResult:
    return SensorResult(response.trr.resource_id, response.sensor_name, response.package_name, response.executable,
                        {kv.key: kv.value for kv in response.output_topics})


class SensorManagerInterface(ManagerInterface):
    """Client of ``/<ns>/temoto_sensor_manager/start_sensor``."""

    MANAGER = RR_NAME
    SUBSYSTEM = Subsystem.SENSOR_MANAGER

    def __init__(self, rr=None, namespace: Optional[str] = None) -> None:
        super().__init__(rr=rr, namespace=namespace)
        # request object (alive while remembered) -> topics it was granted, for pinning on reload
        self._granted: Dict[int, Dict[str, str]] = {}
        self.reload_errors: Dict[int, TemotoError] = {}   # failed id -> why its reload gave up
        self._results: Dict[int, SensorResult] = {}

    def start_sensor(self, sensor_type: str, output_topics: TopicsArg = None, package_name: str = '',
                     executable: str = '', input_topics: TopicsArg = None,
                     on_status: Optional[Callable[[StatusEvent], None]] = None) -> SensorResult:
        """Start the best sensor of ``sensor_type``; return once its data flows.

        ``output_topics``: a list of topic types (any names), or a dict type -> wanted name ('' for any).
        ``on_status``: this request's failure policy (every status of the sensor goes to it); without it,
        the interface's default applies (reload the same request, with its topics pinned).
        Raises TemotoError (e.g. SENSOR_NOT_FOUND with the known types) on failure.
        """
        request = START_SENSOR_TYPE._request_class(sensor_type=sensor_type, package_name=package_name,
                                                   executable=executable,
                                                   output_topics=_key_values(output_topics, 'output_topics'),
                                                   input_topics=_key_values(input_topics, 'input_topics'))
        return _result(self._load(START_SENSOR, request, on_status))

    def catalogue(self, timeout: float = 1.0) -> List[dict]:
        """The manager's catalogue rows now (type, topics, package, executable, reliability)."""
        return fetch_catalogue(self.namespace or self.rr.namespace, timeout)

    def ranked_sensors(self, sensor_type: str, keys: Sequence[str], timeout: float = 1.0) -> List[dict]:
        """The rows that could answer ``start_sensor(sensor_type, keys)``, in the manager's order, best first."""
        return ranked_rows(self.catalogue(timeout), sensor_type, keys)

    def likely_topics(self, sensor_type: str, keys: Sequence[str], timeout: float = 1.0) -> Optional[Dict[str, str]]:
        """The topics ``start_sensor(sensor_type, keys)`` will most likely give (None: no candidate)."""
        return likely_topics(self.catalogue(timeout), sensor_type, keys)

    def stop_sensor(self, resource_id: int) -> None:
        """Release a sensor started by this interface (its driver stops when nobody else holds it)."""
        with self._lock:
            entry = self._requests.get(resource_id)
            if entry is not None:
                self._granted.pop(id(entry[1]), None)
        self._unload(resource_id)

    def _load(self, server: str, request, on_status=None):
        response = super()._load(server, request, on_status)
        with self._lock:
            self._granted[id(request)] = {kv.key: kv.value for kv in response.output_topics}
            self._results[response.trr.resource_id] = _result(response)
        return response

    def _unload(self, resource_id: int) -> None:
        super()._unload(resource_id)
        with self._lock:
            self._results.pop(resource_id, None)

    def pinned_request(self, request):
        """The same request, every topic pinned to the name the failed sensor had."""
        with self._lock:
            granted = self._granted.pop(id(request), None)
        if not granted:
            return request
        pinned = copy.deepcopy(request)
        pinned.output_topics = [KeyValue(k, v) for k, v in granted.items()]
        return pinned

    def reload(self, resource_id: int):
        try:
            return super().reload(resource_id)
        except TemotoError as err:
            with self._lock:
                self.reload_errors[resource_id] = err
            raise

    def result_of(self, resource_id: int) -> Optional[SensorResult]:
        """What a sensor id held by this interface serves (e.g. the replacement after a reload)."""
        with self._lock:
            return self._results.get(resource_id)
