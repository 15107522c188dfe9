"""The Context Manager's logic: trackers as pipes of filters, and objects tracked through them.

Two registrars, as in the original (``context_manager`` and ``context_manager_2``),
because a registrar never asks itself for a resource:

* ``temoto_context_manager`` serves ``track_object`` and ``load_tracker``;
* ``temoto_context_manager_trackers`` serves ``load_tracker`` too, and is what
  ``track_object`` calls, so an object's tracker is a linked sub-resource
  (action -> track_object -> load_tracker -> start_sensor -> load_process).

``load_tracker`` tries the trackers of a category by reliability. Each filter of
a pipe is a nested, linked call: a sensor filter asks the Sensor Manager (whose
response means data flows), an algorithm filter asks the ER Manager for the
node with its inputs and outputs remapped, and waits for its first output.
A failure of any sub-resource lowers the tracker's reliability (the owner
status callback); the registrar forwards the FAILED up the chain.

With a journal (``~journal``; the tracker registrar keeps its own beside it,
``<name>.trackers.sqlite``) the manager survives its own restart: the pipes (which
tracker, which sub-resources), the tracked objects and the reliabilities are kept
in the journals; the registrars bring back the resources and their links, and
``resume()`` asks the Sensor and ER Managers whether each filter still runs (one
that died meanwhile reaches the action as FAILED).
"""
import collections
import itertools
import json
import os
import shlex
import threading
import time
from typing import Dict, List, Optional

import rospy
from diagnostic_msgs.msg import KeyValue

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_core.fallback import first_that_works
from temoto_core.msg import ResourceStatus
from temoto_core.rr import ResourceRegistrar, StatusEvent
from temoto_core.rr.settings import journal_param
from temoto_core.srv import GetRegistry, GetRegistryResponse
from temoto_context_manager.contract import (LOAD_TRACKER, LOAD_TRACKER_TYPE, RR_NAME as NAME, TRACK_OBJECT,
                                             TRACK_OBJECT_TYPE, TRACKER_RR_NAME as TRACKER_RR)
from temoto_context_manager.trackers import Filter, Tracker, TrackerCatalogue
from temoto_core.reliability import Reliability
from temoto_er_manager.contract import LOAD_PROCESS, LOAD_PROCESS_TYPE, RR_NAME as ER_MANAGER
from temoto_sensor_manager.contract import RR_NAME as SENSOR_MANAGER, START_SENSOR, START_SENSOR_TYPE
from temoto_core.stall.detector import TopicProbe

SUB = Subsystem.CONTEXT_MANAGER
PIPE_KEY = 'pipe/%d'                  # owner state of either registrar: a loaded tracker's pipe, by internal id
OBJECT_KEY = 'object/%d'              # owner state: a tracked object, by internal id
RELIABILITIES_KEY = 'reliabilities'   # owner state: trackers' and detection methods' reliability windows


def tracker_journal(journal: str) -> str:
    """The tracker registrar's journal, beside the manager's: ``x.sqlite`` -> ``x.trackers.sqlite``."""
    base, ext = os.path.splitext(journal)
    return base + '.trackers' + ext if journal else ''
_pipe_numbers = itertools.count(1)


class _Pipe:
    """A loaded tracker: its sub-resources (local ids of the serving registrar)."""

    def __init__(self, tracker: Tracker, rr: ResourceRegistrar, pipe_id: str) -> None:
        self.tracker = tracker
        self.rr = rr
        self.pipe_id = pipe_id
        self.sub_ids: List[int] = []


class ContextManager:
    def __init__(self, catalogue: TrackerCatalogue, namespace: Optional[str] = None) -> None:
        self.catalogue = catalogue
        journal = journal_param()
        self.rr = ResourceRegistrar(NAME, namespace=namespace, subsystem=SUB, journal=journal)
        self.tracker_rr = ResourceRegistrar(TRACKER_RR, namespace=namespace, subsystem=SUB,
                                            journal=tracker_journal(journal))
        self.namespace = self.rr.namespace
        self._lock = threading.Lock()
        self._pipes: Dict[tuple, _Pipe] = {}                 # (rr name, internal id) -> pipe
        self._pipe_of_sub: Dict[tuple, _Pipe] = {}           # (rr name, sub local id) -> pipe
        self._objects: Dict[int, tuple] = {}                 # track_object internal id -> (object, method, id)
        self._object_of_tracker: Dict[int, tuple] = {}       # tracker local id (at self.rr) -> (object, method)
        self._methods: Dict[tuple, Reliability] = {}         # (object, method) -> reliability
        self.status_log = collections.deque(maxlen=100)      # owner callbacks that ran (introspection)
        for problem in catalogue.problems:
            rospy.logerr('%s: catalogue: %s', NAME, problem)
        kept = {rr.name: rr.owner_state() for rr in (self.rr, self.tracker_rr)}
        self._restore_reliabilities(kept[NAME].get(RELIABILITIES_KEY))
        # one callback per registrar for everything it holds, also what a restart brings back
        self.rr.register_status_callback(self._on_held_status)
        self.tracker_rr.register_status_callback(self._on_pipe_status)
        for rr in (self.rr, self.tracker_rr):
            rr.add_server(LOAD_TRACKER, LOAD_TRACKER_TYPE, lambda q, s, rr=rr: self._load_tracker(rr, q, s),
                          lambda q, s, rr=rr: self._unload_tracker(rr, q, s),
                          recover=lambda q, s, rr=rr: self._recover_tracker(rr, kept[rr.name], s))
        self.rr.add_server(TRACK_OBJECT, TRACK_OBJECT_TYPE, self._track_object, self._untrack_object,
                           recover=lambda q, s: self._recover_object(kept[NAME], s))
        self._info_srv = rospy.Service('/%s/%s/trackers' % (self.namespace, NAME), GetRegistry,
                                       lambda _req: GetRegistryResponse(json=self.info_json()))
        for rr in (self.rr, self.tracker_rr):
            for key in kept[rr.name]:
                if key != RELIABILITIES_KEY and not self._recovered(rr, key):
                    rr.drop_owner_state(key)
        for rr in (self.tracker_rr, self.rr):     # the filters' owners first: an object's tracker is local
            rr.resume()
        rospy.loginfo('%s: ready with tracker categories %s and objects %s', NAME,
                      ', '.join(catalogue.categories()) or 'none', ', '.join(sorted(catalogue.objects)) or 'none')

    # -- load_tracker --------------------------------------------------------------------------
    def _load_tracker(self, rr: ResourceRegistrar, req, res) -> None:
        category = req.tracker_category.strip()
        if not category:
            raise TemotoError(ErrorCode.BAD_REQUEST, SUB, 'tracker_category is empty (known: %s)'
                              % ', '.join(self.catalogue.categories()))
        wanted = [kv.key for kv in req.output_topics]
        if any(kv.value for kv in req.output_topics):
            raise TemotoError(ErrorCode.BAD_REQUEST, SUB, 'output topic names cannot be chosen for a tracker '
                              '(they are per pipe); leave the values empty')
        trackers = self.catalogue.ranked(category)
        if not trackers:
            raise TemotoError(ErrorCode.NO_TRACKERS_FOUND, SUB, 'no tracker of category %r (known categories: %s)'
                              % (category, ', '.join(self.catalogue.categories()) or 'none'))
        matching = [t for t in trackers if set(wanted) <= set(t.output_types)]
        if not matching:
            raise TemotoError(ErrorCode.NO_TRACKERS_FOUND, SUB, 'no %r tracker gives %s (they give: %s)'
                              % (category, ', '.join(wanted), '; '.join('%s: %s' % (t.name, ', '.join(t.output_types))
                                                                        for t in trackers)))

        def attempt(tracker):
            pipe = _Pipe(tracker, rr, 'pipe_%d_at_%s' % (next(_pipe_numbers), self.namespace))
            try:
                return pipe, self._build(pipe)
            except TemotoError:
                self._release(pipe, 'rolling back tracker %s' % tracker.name)
                raise
        tracker, (pipe, topics) = first_that_works(
            matching, attempt, what='a %r tracker' % category, subsystem=SUB, code=ErrorCode.NO_TRACKERS_FOUND,
            name=lambda t: t.name, reliability=lambda t: t.reliability,
            on_failure=lambda t: (rospy.logwarn('%s: tracker %s failed: %s', NAME, t.name, t.error),
                                  self._keep_reliabilities()))
        with self._lock:
            self._pipes[(rr.name, res.trr.resource_id)] = pipe
        rr.put_owner_state(PIPE_KEY % res.trr.resource_id, json.dumps(
            {'tracker': tracker.name, 'pipe_id': pipe.pipe_id, 'sub_ids': pipe.sub_ids}))
        res.tracker_name = tracker.name
        res.pipe_id = pipe.pipe_id
        res.output_topics = [KeyValue(t, topics[t]) for t in (wanted or tracker.output_types)]
        rospy.loginfo('%s: tracker %s (%s) running as %s', NAME, tracker.name, category, pipe.pipe_id)

    def _build(self, pipe: _Pipe) -> Dict[str, str]:
        topics: Dict[str, str] = {}
        for index, filt in enumerate(pipe.tracker.filters):
            if filt.kind == 'sensor':
                request = START_SENSOR_TYPE._request_class(sensor_type=filt.type,
                                                    output_topics=[KeyValue(t, '') for t in filt.outputs])
                resp = self._nested(pipe, SENSOR_MANAGER, START_SENSOR, request)
                topics.update({kv.key: kv.value for kv in resp.output_topics})
            else:
                topics.update(self._start_algorithm(pipe, index, filt, topics))
        return topics

    def _start_algorithm(self, pipe: _Pipe, index: int, filt: Filter, topics: Dict[str, str]) -> Dict[str, str]:
        outputs = {t: '/%s/%s/filter_%d/%s' % (self.namespace, pipe.pipe_id, index, t) for t in filt.outputs}
        args = shlex.split(filt.args)
        args += ['%s:=%s' % (name, topics[t]) for t, name in filt.inputs.items()]
        args += ['%s:=%s' % (name, outputs[t]) for t, name in filt.outputs.items()]
        probes = [TopicProbe(topic, 0.0) for topic in outputs.values()]
        try:
            request = LOAD_PROCESS_TYPE._request_class(action='ros_execute', package_name=filt.package,
                                                 executable=filt.executable,
                                                 args=' '.join(shlex.quote(a) for a in args))
            resp = self._nested(pipe, ER_MANAGER, LOAD_PROCESS, request)
            deadline = time.monotonic() + filt.first_data_timeout
            for probe in probes:
                if not probe.first.wait(max(0.0, deadline - time.monotonic())):
                    raise TemotoError(ErrorCode.TIMEOUT, SUB, 'tracker %s: algorithm %s (pid %d) gave no data on %s '
                                      'within %.1f s' % (pipe.tracker.name, filt.type, resp.pid, probe.topic,
                                                         filt.first_data_timeout))
        finally:
            for probe in probes:
                probe.close()
        return outputs

    def _nested(self, pipe: _Pipe, manager: str, server: str, request):
        resp = pipe.rr.call(manager, server, request)
        with self._lock:
            pipe.sub_ids.append(resp.trr.resource_id)
            self._pipe_of_sub[(pipe.rr.name, resp.trr.resource_id)] = pipe
        return resp

    def _release(self, pipe: _Pipe, why: str) -> None:
        with self._lock:
            ids = list(pipe.sub_ids)
            pipe.sub_ids.clear()
            for local_id in ids:
                self._pipe_of_sub.pop((pipe.rr.name, local_id), None)
        for local_id in reversed(ids):
            try:
                pipe.rr.unload(local_id)
            except TemotoError as err:
                rospy.logwarn('%s: %s: %s', NAME, why, err)

    def _unload_tracker(self, rr: ResourceRegistrar, req, res) -> None:
        rr.drop_owner_state(PIPE_KEY % res.trr.resource_id)
        with self._lock:
            pipe = self._pipes.pop((rr.name, res.trr.resource_id), None)
            if pipe is not None:
                for local_id in pipe.sub_ids:
                    self._pipe_of_sub.pop((rr.name, local_id), None)
        # the sub-resources are linked: the registrar unloads them in cascade

    def _on_pipe_status(self, event: StatusEvent) -> None:
        """Owner callback: a sensor or algorithm of a pipe changed; FAILED lowers the tracker's rank."""
        if event.code != ResourceStatus.FAILED:
            return
        with self._lock:
            pipe = next((p for (rr_name, lid), p in self._pipe_of_sub.items() if lid == event.resource_id), None)
        name = pipe.tracker.name if pipe else '?'
        if pipe is not None:
            pipe.tracker.reliability.failure()
            self._keep_reliabilities()
        self.status_log.append({'owner': 'tracker', 'tracker': name, 'from': '%s/%s' % (event.rr_name,
                                                                                       event.server_name),
                                'message': event.message, 'time': time.time()})
        rospy.logerr('%s: tracker %s lost a filter (%s/%s): %s', NAME, name, event.rr_name, event.server_name,
                     event.message)

    # -- track_object --------------------------------------------------------------------------
    def _track_object(self, req, res) -> None:
        name = req.object_name.strip()
        obj = self.catalogue.objects.get(name)
        if obj is None:
            raise TemotoError(ErrorCode.BAD_REQUEST, SUB, 'unknown object %r (known objects: %s)'
                              % (name, ', '.join(sorted(self.catalogue.objects)) or 'none'))
        methods = sorted(obj.detection_methods, key=lambda m: -self._method(name, m).value)

        def attempt(method):
            request = LOAD_TRACKER_TYPE._request_class(tracker_category=method, output_topics=[KeyValue('pose', '')])
            return self.rr.call(TRACKER_RR, LOAD_TRACKER, request, namespace=self.namespace)
        try:
            method, resp = first_that_works(methods, attempt, what='tracking %r' % name, subsystem=SUB,
                                            code=ErrorCode.NO_TRACKERS_FOUND,
                                            reliability=lambda m: self._method(name, m))
        finally:
            self._keep_reliabilities()
        with self._lock:
            self._object_of_tracker[resp.trr.resource_id] = (name, method)
            self._objects[res.trr.resource_id] = (name, method, resp.trr.resource_id)
        self.rr.put_owner_state(OBJECT_KEY % res.trr.resource_id,
                                json.dumps({'object': name, 'method': method, 'tracker_id': resp.trr.resource_id}))
        res.object_name = name
        res.object_topic = next(kv.value for kv in resp.output_topics if kv.key == 'pose')
        res.detection_method = method
        res.tracker_name = resp.tracker_name
        res.pipe_id = resp.pipe_id

    def _untrack_object(self, req, res) -> None:
        self.rr.drop_owner_state(OBJECT_KEY % res.trr.resource_id)
        with self._lock:
            entry = self._objects.pop(res.trr.resource_id, None)
            if entry is not None:
                self._object_of_tracker.pop(entry[2], None)

    def _on_tracker_status(self, event: StatusEvent) -> None:
        """Owner callback: the tracker of an object failed; lower that detection method for the object."""
        if event.code != ResourceStatus.FAILED:
            return
        with self._lock:
            entry = self._object_of_tracker.get(event.resource_id)
        if entry is not None:
            self._method(*entry).failure()
            self._keep_reliabilities()
        self.status_log.append({'owner': 'object', 'object': entry[0] if entry else '?',
                                'from': '%s/%s' % (event.rr_name, event.server_name), 'message': event.message,
                                'time': time.time()})
        rospy.logerr('%s: the tracker of %s failed: %s', NAME, entry[0] if entry else '?', event.message)

    def _on_held_status(self, event: StatusEvent) -> None:
        """The manager's registrar holds objects' trackers and the filters of trackers loaded from it."""
        with self._lock:
            tracker = event.resource_id in self._object_of_tracker
        (self._on_tracker_status if tracker else self._on_pipe_status)(event)

    # -- recovery after a restart ------------------------------------------------------------------
    def _recover_tracker(self, rr: ResourceRegistrar, kept: Dict[str, str], res) -> None:
        """A pipe the previous incarnation loaded: its filters run on in their owners (``resume`` asks)."""
        record = kept.get(PIPE_KEY % res.trr.resource_id)
        tracker = next((t for t in self.catalogue.trackers if t.name == res.tracker_name), None)
        if record is None or tracker is None:
            raise TemotoError(ErrorCode.RESOURCE_FAILED, SUB, 'tracker %s: %s' % (
                res.tracker_name, 'the journal has no record of its pipe' if record is None
                else 'it is not in the catalogue any more'))
        record = json.loads(record)
        pipe = _Pipe(tracker, rr, record['pipe_id'])
        pipe.sub_ids = list(record['sub_ids'])
        with self._lock:
            self._pipes[(rr.name, res.trr.resource_id)] = pipe
            for local_id in pipe.sub_ids:
                self._pipe_of_sub[(rr.name, local_id)] = pipe
        rospy.loginfo('%s: took tracker %s (%s) back after a restart', NAME, tracker.name, pipe.pipe_id)

    def _recover_object(self, kept: Dict[str, str], res) -> None:
        record = kept.get(OBJECT_KEY % res.trr.resource_id)
        if record is None:
            raise TemotoError(ErrorCode.RESOURCE_FAILED, SUB, 'the journal has no record of tracking %s'
                              % res.object_name)
        record = json.loads(record)
        with self._lock:
            self._object_of_tracker[record['tracker_id']] = (record['object'], record['method'])
            self._objects[res.trr.resource_id] = (record['object'], record['method'], record['tracker_id'])

    def _recovered(self, rr: ResourceRegistrar, key: str) -> bool:
        kind, _, number = key.partition('/')
        with self._lock:
            if kind == 'pipe':
                return (rr.name, int(number)) in self._pipes
            return kind == 'object' and int(number) in self._objects

    def _restore_reliabilities(self, kept: Optional[str]) -> None:
        if not kept:
            return
        values = json.loads(kept)
        for tracker in self.catalogue.trackers:
            if tracker.name in values.get('trackers', {}):
                tracker.reliability.restore(values['trackers'][tracker.name])
        for key, samples in values.get('methods', {}).items():
            obj, _, method = key.partition('/')
            self._method(obj, method).restore(samples)

    def _keep_reliabilities(self) -> None:
        if not self.rr.journaled:
            return
        with self._lock:
            methods = {'%s/%s' % k: r.samples() for k, r in self._methods.items()}
        self.rr.put_owner_state(RELIABILITIES_KEY, json.dumps(
            {'trackers': {t.name: t.reliability.samples() for t in self.catalogue.trackers}, 'methods': methods}))

    def _method(self, obj: str, method: str) -> Reliability:
        with self._lock:
            return self._methods.setdefault((obj, method), Reliability())

    # -- introspection and shutdown --------------------------------------------------------------
    def info_json(self) -> str:
        with self._lock:
            methods = {'%s/%s' % k: round(r.value, 6) for k, r in self._methods.items()}
            pipes = [{'registrar': k[0], 'id': k[1], 'tracker': p.tracker.name, 'pipe_id': p.pipe_id}
                     for k, p in self._pipes.items()]
        return json.dumps({'manager': NAME, 'problems': self.catalogue.problems, 'pipes': pipes,
                           'trackers': {t.name: {'category': t.category, 'reliability': round(t.reliability.value, 6),
                                                 'source': t.source} for t in self.catalogue.trackers},
                           'methods': methods, 'status_log': list(self.status_log)}, sort_keys=True)

    def shutdown(self) -> None:
        for rr in (self.rr, self.tracker_rr):   # objects first: their trackers go with them
            try:
                rr.shutdown()
            except Exception as err:
                rospy.logwarn('%s: registrar shutdown: %s', NAME, err)
        self._info_srv.shutdown()
