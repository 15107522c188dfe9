"""The Sensor Manager's logic: the ``start_sensor`` server over a catalogue, the ER Manager and a stall detector.

Load: rank the matching catalogue entries, and for each in turn start its
driver through ``load_process``, held on the manager's own account, and wait
for the first message on every output topic. The first candidate whose data
flows wins, and only then is its process linked to the sensor query (unloaded
with it, its FAILED forwarded by the registrar); a candidate that fails to
start, crashes, or stays silent is released and the next is tried. Reliability goes up on success
and down on a load failure, a crash, or a stall.

While a sensor is held, its topics are watched (``temoto_core.stall.detector.StallDetector``); a
topic silent for longer than its limit makes this manager send FAILED for the
sensor, exactly as the registrar forwards a crash reported by the ER Manager.
The stalled driver is stopped when the consumer unloads the failed sensor
(the registrar's cascade).

With a journal (``~journal``) the manager survives its own restart: the
registrar brings back the sensors it served, their consumers and the driver
processes linked to them; :meth:`SensorManager._recover` re-creates each
sensor's topic watch, and ``rr.resume()`` asks the ER Manager which drivers
still run. A driver that died meanwhile reaches the consumers as FAILED then;
one that stalled meanwhile is caught by the watch. Reliabilities are kept in
the journal after every change.
"""
import json
import threading
import time
from typing import Dict, List, Optional, Tuple

import rospy
from diagnostic_msgs.msg import KeyValue

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_core.fallback import Tried, first_that_works
from temoto_core.msg import ResourceStatus
from temoto_core.rr import ResourceRegistrar, StatusEvent
from temoto_core.srv import GetRegistry, GetRegistryResponse
from temoto_er_manager.contract import LOAD_PROCESS, LOAD_PROCESS_TYPE, RR_NAME as ER_MANAGER
from temoto_sensor_manager.catalogue import Catalogue, SensorEntry, TopicSpec
from temoto_sensor_manager.contract import CATALOGUE, RR_NAME as NAME, START_SENSOR, START_SENSOR_TYPE
from temoto_sensor_manager.diagnostics import DriverReports, local_node_pid
from temoto_sensor_manager.selection import LaunchPlan, candidates, plan, validate
from temoto_sensor_manager.start_times import StartDeadline, StartTimes
from temoto_core.stall.detector import StallDetector, TopicProbe
from temoto_core.stall.starvation import tree_wait

SUB = Subsystem.SENSOR_MANAGER
# seconds a registered driver may take to start publishing (load its model, connect to the simulation)
# before its rate counts; the VaultBot's simulated drivers need 0.4 to 0.9 s (BENCHMARKS.md, bench_sim.py)
DEFAULT_FIRST_DATA_ALLOWANCE = 4.0
START_LOOK_S = 0.25                   # s between two looks at a starting driver's CPU waiting
RELIABILITIES_KEY = 'reliabilities'   # owner state: {sensor name: reliability samples}
START_TIMES_KEY = 'start_times'       # owner state: {sensor name: seconds from a driver's start to its data}
RHYTHMS_KEY = 'rhythms'               # owner state: {"sensor/topic type": [mean, spread, longest gap]}
SENSOR_KEY = 'sensor/%d'              # owner state: the driver process of a served sensor, by internal id
# seconds beyond its stall limit that a driver already seen stalling (and shared again) gets to show data
# again: the new subscription's connection on a loaded machine; its start-up allowance does not apply
STALLED_RECHECK_S = 1.0


def probe_of(spec: TopicSpec, topic: str, on_first=None, rhythm=None) -> TopicProbe:
    """The watch of ``topic`` as its catalogue entry ``spec`` describes it; ``rhythm``: what an earlier load
    of the device learnt of this topic (``arrivals.ArrivalModel.seed``)."""
    probe = TopicProbe(topic, spec.silence_limit(), on_first=on_first, rate=spec.rate, adaptive=spec.adaptive,
                       key=spec.key)
    if probe.arrivals is not None:
        probe.arrivals.seed(rhythm)
    return probe


def driver_wait(pid: int, executable: str):
    """The run-queue seconds of a starting driver's processes (``starvation.tree_wait``), when ``pid`` is that
    driver on this host (its command line names ``executable``); else a reader of nothing (no allowance for load:
    a pid of another host's ER Manager means another process here)."""
    try:
        with open('/proc/%d/cmdline' % pid, 'rb') as f:
            ours = executable.encode() in f.read()
    except OSError:
        ours = False
    return (lambda: tree_wait(pid)) if ours else (lambda: None)


def rhythm_key(entry_name: str, topic_key: str) -> str:
    return '%s/%s' % (entry_name, topic_key)


def _reached(connections: int) -> str:
    return 'no publisher connected' if not connections else 'connected to %d publisher%s' % (
        connections, '' if connections == 1 else 's')


def _gaps(probes: List[TopicProbe]) -> str:
    """The longest gap between messages on each topic, beside its stall limit (to tune the limits)."""
    return 'longest gap between messages: ' + ', '.join(
        '%s %.3f s in %d msgs (limit %.3f s)' % (p.topic, p.max_gap, p.count, p.limit) for p in probes)


class _Attempt:
    """One candidate being started: woken by a first message or by its process failing."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.failure = ''
        self.pid = 0        # the driver's, once the ER Manager has answered

    def wake(self) -> None:
        with self.cond:
            self.cond.notify_all()

    def fail(self, message: str) -> None:
        with self.cond:
            self.failure = message or 'the driver process failed'
            self.cond.notify_all()


class _Held:
    """An active sensor query: what runs it and what watches it."""

    def __init__(self, internal_id: int, entry: SensorEntry, process_id: int, probes: List[TopicProbe],
                 pid: int = 0) -> None:
        self.internal_id = internal_id
        self.entry = entry
        self.process_id = process_id
        self.pid = pid              # the driver's pid (0: not known, a sensor taken back after a restart)
        self.probes = probes
        self.failed = False
        for probe in probes:
            probe.owner = self


class SensorManager:
    """Serves ``/<ns>/temoto_sensor_manager/start_sensor`` and ``.../catalogue`` (JSON)."""

    def __init__(self, catalogue: Catalogue, rr: Optional[ResourceRegistrar] = None, namespace: Optional[str] = None,
                 first_data_timeout: float = 20.0, er_manager: str = ER_MANAGER,
                 first_data_allowance: float = DEFAULT_FIRST_DATA_ALLOWANCE) -> None:
        self.catalogue = catalogue
        self.first_data_timeout = first_data_timeout      # the cap, and the limit of a topic of unknown rate
        self.first_data_allowance = first_data_allowance
        self.start_times = StartTimes(first_data_allowance)
        self._rhythms: Dict[str, list] = {}         # rhythm_key -> [mean, spread, longest]: learnt in earlier loads
        self.er_manager = er_manager
        self.rr = rr or ResourceRegistrar(NAME, namespace=namespace, subsystem=SUB)
        self._lock = threading.Lock()
        self._held: Dict[int, _Held] = {}            # sensor internal id -> held sensor
        self._by_process: Dict[int, _Held] = {}      # load_process local id -> held sensor
        self._attempts: Dict[int, _Attempt] = {}     # load_process local id -> candidate being started
        self._early_failures: Dict[int, str] = {}    # FAILED that overtook our bookkeeping
        # driver pid -> the stall it showed, while it runs and has sent nothing here since: a load that is
        # given that driver again (an equal request shares it) waits its stall limit, not its start-up
        self._stalled: Dict[int, str] = {}
        self.stall_detector = StallDetector(self._on_stall)
        self.reports = DriverReports(self._on_driver_error)
        for problem in catalogue.problems:
            rospy.logerr('%s: catalogue: %s', NAME, problem)
        kept = self.rr.owner_state()
        self._restore_reliabilities(kept.get(RELIABILITIES_KEY))
        if kept.get(START_TIMES_KEY):
            self.start_times.restore(json.loads(kept[START_TIMES_KEY]))
        if kept.get(RHYTHMS_KEY):
            self._rhythms = {k: v for k, v in json.loads(kept[RHYTHMS_KEY]).items() if isinstance(v, list)}
        self._records = {int(k.split('/')[1]): json.loads(v) for k, v in kept.items() if k.startswith('sensor/')}
        # one callback for every driver process held, also those a restart brings back
        self.rr.register_status_callback(self._on_process_status)
        self.rr.add_server(START_SENSOR, START_SENSOR_TYPE, self._load, self._unload, recover=self._recover)
        self._catalogue_srv = rospy.Service('/%s/%s/%s' % (self.rr.namespace, NAME, CATALOGUE), GetRegistry,
                                            lambda _req: GetRegistryResponse(json=self.catalogue_json()))
        for stale in self._records:
            self.rr.drop_owner_state(SENSOR_KEY % stale)
        self._records.clear()
        self.rr.resume()
        rospy.loginfo('%s: ready with %d sensor(s) of type(s) %s', NAME, len(catalogue.entries),
                      ', '.join(catalogue.types()) or 'none')

    # -- load ----------------------------------------------------------------------------------
    def _load(self, req, res) -> None:
        query = validate(req.sensor_type, req.package_name, req.executable,
                         [(kv.key, kv.value) for kv in req.output_topics])

        def attempt(entry: SensorEntry) -> Tuple[LaunchPlan, _Held]:
            launch = plan(entry, query)
            return launch, self._start(entry, launch, res.trr.resource_id)

        def report(tried: Tried) -> None:
            rospy.logwarn('%s: candidate %s for %r failed (reliability now %.3f): %s', NAME, tried.name,
                          query.sensor_type, tried.candidate.reliability.value, tried.error)
        try:
            entry, (launch, held) = first_that_works(
                candidates(self.catalogue, query), attempt, what='a %r sensor' % query.sensor_type, subsystem=SUB,
                code=ErrorCode.SENSOR_NOT_FOUND, name=lambda e: e.name, reliability=lambda e: e.reliability,
                # the ER Manager being away says nothing of the device
                counts_against=lambda err: getattr(err, 'code', None) != ErrorCode.SERVICE_REQ_FAIL,
                on_failure=report)
        finally:
            self._keep_reliabilities()
        self.rr.put_owner_state(SENSOR_KEY % held.internal_id,
                                json.dumps({'process_id': held.process_id, 'sensor': entry.name}))
        for probe in held.probes:
            # the driver's own CPU waiting counts as starvation, not silence (starvation.py); a node on
            # another host, or one that cannot be asked, leaves the machine's and this manager's measures
            pid = local_node_pid(probe.publisher) if probe.publisher else None
            if pid:
                probe.measure_publisher(pid)
        self.stall_detector.arm(held.probes)
        res.sensor_name = entry.name
        res.package_name = entry.package
        res.executable = entry.executable
        res.output_topics = [KeyValue(k, v) for k, v in launch.topics.items()]
        res.input_topics = [KeyValue(k, v) for k, v in sorted(entry.input_topics.items())]
        rospy.loginfo('%s: %r served by %s (%s), data flowing on %s', NAME, query.sensor_type, entry.name,
                      entry.executable, ', '.join(launch.topics.values()))

    def _start(self, entry: SensorEntry, launch: LaunchPlan, internal_id: int) -> _Held:
        """Start one candidate's driver and wait for its first data; then link the process to the sensor.

        The topics are subscribed before the driver starts. A message from a publisher already on a
        topic (another device serving the same name) would count as first data, as it did when the
        subscription came after the start.

        The start is held *unlinked* (``link=False``): a candidate that crashes during
        the wait must not fail the whole sensor load, as a linked sub-resource failing
        mid-load would. Once data flows, the process is linked to the sensor.
        """
        request = LOAD_PROCESS_TYPE._request_class(action='ros_execute', package_name=entry.package,
                                             executable=entry.executable, args=launch.args)
        attempt = _Attempt()
        # Subscribed before the driver starts: the connection to its publishers is made while it starts
        # (not after the ER Manager answers), so its first message is seen as soon as it is sent.
        probes = [probe_of(entry.output_topics[key], topic, on_first=attempt.wake,
                           rhythm=self._rhythms.get(rhythm_key(entry.name, key)))
                  for key, topic in launch.topics.items()]
        try:
            started = self.rr.call(self.er_manager, LOAD_PROCESS, request, link=False)
        except BaseException:
            for probe in probes:
                probe.close()
            raise
        process_id = started.trr.resource_id
        answered = time.monotonic()
        with self._lock:
            attempt.pid = started.pid
            self._attempts[process_id] = attempt
            early = self._early_failures.pop(process_id, None)
        if early is not None:
            attempt.fail(early)
        reported = self.reports.error_of(started.pid)     # the driver told of its device before the answer
        if reported:
            attempt.fail('it reported an error: %s' % reported)
        with self._lock:
            stalled = self._stalled.get(started.pid, '')
        try:
            allowance = self.start_times.allowance(entry.name)
            limit = max(entry.output_topics[key].first_data_limit(allowance, self.first_data_timeout)
                        for key in launch.topics)
            if stalled:
                limit = min(limit, STALLED_RECHECK_S + max(entry.output_topics[key].silence_limit()
                                                           for key in launch.topics))
            # the allowance counts the driver's progress: its CPU waiting on a busy machine is added (a stalled
            # driver gets none: it has shown it runs)
            deadline = StartDeadline(time.monotonic(), limit, limit if stalled else self.first_data_timeout,
                                     driver_wait(started.pid, entry.executable))
            with attempt.cond:
                while not attempt.failure and not all(p.first.is_set() for p in probes):
                    remaining = deadline.remaining(time.monotonic())
                    if remaining <= 0:
                        break
                    attempt.cond.wait(min(remaining, START_LOOK_S))
            if attempt.failure:
                raise TemotoError(ErrorCode.PROCESS_STOPPED, SUB, 'sensor %s: its driver (pid %d) failed before '
                                  'data arrived: %s' % (entry.name, started.pid, attempt.failure))
            # whether the driver's publisher was ever reached tells a silent driver from a lost connection
            silent = ['%s (%s)' % (p.topic, _reached(p.connections())) for p in probes if not p.first.is_set()]
            if silent and stalled:
                raise TemotoError(ErrorCode.TIMEOUT, SUB, 'sensor %s: no data on %s within %.1f s; its driver (pid %d) '
                                  'runs, and has sent nothing since it stalled (%s)' % (
                                      entry.name, ', '.join(silent), limit, started.pid, stalled))
            if silent:
                raise TemotoError(ErrorCode.TIMEOUT, SUB, 'sensor %s: no data on %s within %s after its driver '
                                  '(pid %d) started (%s)' % (entry.name, ', '.join(silent), deadline.describe(),
                                                             started.pid, self.start_times.describe(entry.name)))
            if not stalled:
                self.start_times.add(entry.name, time.monotonic() - answered)
            try:
                self.rr.link(process_id)      # refused if the process failed meanwhile
            except TemotoError as err:
                raise TemotoError(ErrorCode.PROCESS_STOPPED, SUB, 'sensor %s: its driver (pid %d) failed just as '
                                  'its data arrived: %s' % (entry.name, started.pid, attempt.failure or err))
        except BaseException:
            for probe in probes:
                probe.close()
            with self._lock:
                self._attempts.pop(process_id, None)
            self._release(process_id, 'stopping failed candidate %s' % entry.name)
            raise
        held = _Held(internal_id, entry, process_id, probes, pid=started.pid)
        with self._lock:
            # in one step, so a FAILED of the process finds either the attempt or the held sensor
            self._stalled.pop(started.pid, None)        # its data flows again
            self._attempts.pop(process_id, None)
            self._held[internal_id] = held
            self._by_process[process_id] = held
        return held

    def _release(self, local_id: int, why: str) -> None:
        try:
            self.rr.unload(local_id)
        except TemotoError as err:
            rospy.logwarn('%s: %s: %s', NAME, why, err)

    # -- unload --------------------------------------------------------------------------------
    def _unload(self, req, res) -> None:
        with self._lock:
            held = self._held.pop(res.trr.resource_id, None)
            if held is not None:
                self._by_process.pop(held.process_id, None)
                if not any(h.pid == held.pid for h in self._held.values()):
                    self._stalled.pop(held.pid, None)     # its driver goes: a later one is a new process
        self.rr.drop_owner_state(SENSOR_KEY % res.trr.resource_id)
        if held is None:
            return
        for probe in held.probes:
            probe.close()
        self._keep_rhythms(held)
        rospy.loginfo('%s: released %s (its driver goes with it); %s', NAME, held.entry.name, _gaps(held.probes))

    # -- recovery after a restart ------------------------------------------------------------------
    def _recover(self, req, res) -> None:
        """A sensor the previous incarnation served: watch its topics again (a restart of this manager
        leaves the driver running; whether it still runs is asked of the ER Manager in ``resume``)."""
        rid = res.trr.resource_id
        record = self._records.pop(rid, None)
        entry = self.catalogue.get(res.sensor_name)
        if record is None or entry is None:
            raise TemotoError(ErrorCode.RESOURCE_FAILED, SUB, 'sensor %s: %s' % (
                res.sensor_name, 'the journal has no record of its driver' if record is None
                else 'it is not in the catalogue any more'))
        probes = [probe_of(entry.output_topics[kv.key], kv.value,
                           rhythm=self._rhythms.get(rhythm_key(entry.name, kv.key)))
                  for kv in res.output_topics if kv.key in entry.output_topics]
        held = _Held(rid, entry, int(record['process_id']), probes)
        with self._lock:
            self._held[rid] = held
            self._by_process[held.process_id] = held
        # the new subscriptions still connect: data must arrive within the first-data allowance
        self.stall_detector.arm(probes, grace=self.first_data_allowance)
        rospy.loginfo('%s: took %s back after a restart (driver resource %d); watching %s', NAME, entry.name,
                      held.process_id, ', '.join(p.topic for p in probes))

    def _restore_reliabilities(self, kept: Optional[str]) -> None:
        if not kept:
            return
        for name, samples in json.loads(kept).items():
            entry = self.catalogue.get(name)
            if entry is not None:
                entry.reliability.restore(samples)
        rospy.loginfo('%s: reliabilities restored from the journal: %s', NAME, ', '.join(
            '%s %.3f' % (e.name, e.reliability.value) for e in self.catalogue.entries))

    def _keep_rhythms(self, held: _Held) -> None:
        """What this load learnt of each topic's rhythm, for the device's next load (and the journal)."""
        rhythms = [(p.key, p.arrivals.rhythm()) for p in held.probes if p.key and p.arrivals is not None]
        learnt = {rhythm_key(held.entry.name, key): list(rhythm) for key, rhythm in rhythms if rhythm is not None}
        if not learnt:
            return
        with self._lock:
            self._rhythms.update(learnt)
            kept = dict(self._rhythms)
        if self.rr.journaled:
            self.rr.put_owner_state(RHYTHMS_KEY, json.dumps(kept))

    def _keep_reliabilities(self) -> None:
        """Journal what this manager has learnt of its devices: reliabilities and start times."""
        if self.rr.journaled:
            self.rr.put_owner_state(RELIABILITIES_KEY, json.dumps(
                {e.name: e.reliability.samples() for e in self.catalogue.entries}))
            self.rr.put_owner_state(START_TIMES_KEY, json.dumps(self.start_times.samples()))

    # -- failures ------------------------------------------------------------------------------
    def _on_process_status(self, event: StatusEvent) -> None:
        """Owner callback for a driver process; the registrar forwards the FAILED to our consumers itself."""
        if event.code != ResourceStatus.FAILED:
            return
        with self._lock:
            attempt = self._attempts.get(event.resource_id)
            held = self._by_process.get(event.resource_id)
            if attempt is None and held is None:
                self._early_failures[event.resource_id] = event.message
            if held is not None:
                self._stalled.pop(held.pid, None)         # it exited: not a stalled driver any more
        if attempt is not None:
            attempt.fail(event.message)
        if held is not None:
            self._mark_failed(held, 'sensor %s crashed: %s' % (held.entry.name, event.message), report=False)

    def _on_driver_error(self, pid: int, text: str) -> None:
        """A node of the driver process ``pid`` reported an error on /diagnostics (``diagnostics.py``): the
        candidate being started fails at once, and a held sensor is reported FAILED."""
        with self._lock:
            attempts = [a for a in self._attempts.values() if a.pid == pid]
            held = [h for h in self._held.values() if h.pid == pid and not h.failed]
            if held:
                self._stalled[pid] = 'it reported an error: %s' % text
        for attempt in attempts:
            attempt.fail('it reported an error: %s' % text)
        for h in held:
            self._mark_failed(h, 'sensor %s: its driver (pid %d) reported an error: %s' % (h.entry.name, pid, text),
                              report=True)

    def _on_stall(self, probe: TopicProbe, silence: float, limit: float) -> None:
        held = probe.owner
        if held is None:
            return
        message = ('sensor %s stalled: no message on %s for %.3f s (%s)'
                   % (held.entry.name, probe.topic, silence, probe.describe_limit(limit)))
        if held.pid:
            with self._lock:
                self._stalled[held.pid] = message
        self._mark_failed(held, message, report=True)

    def _mark_failed(self, held: _Held, message: str, report: bool) -> None:
        with self._lock:
            if held.failed:
                return
            held.failed = True
        for probe in held.probes:
            probe.close()
        self._keep_rhythms(held)
        value = held.entry.reliability.failure()
        self._keep_reliabilities()
        rospy.logerr('%s: %s (reliability now %.3f); before that, %s', NAME, message, value, _gaps(held.probes))
        if report:
            err = TemotoError(ErrorCode.TIMEOUT, SUB, message)
            try:
                self.rr.send_status(held.internal_id, ResourceStatus.FAILED, message, error_stack=err.stack)
            except TemotoError as e:        # unloaded meanwhile: nobody left to tell
                rospy.logwarn('%s: could not report the stall of %s: %s', NAME, held.entry.name, e)

    # -- introspection and shutdown --------------------------------------------------------------
    def catalogue_json(self) -> str:
        with self._lock:
            active = {h.entry.name: h.internal_id for h in self._held.values() if not h.failed}
            # the limit each held topic is watched with now (adaptive: it follows the rhythm)
            watched: Dict[str, Dict[str, float]] = {}
            # the driver process whose CPU waiting counts as starvation on each held topic (starvation.py)
            drivers: Dict[str, Dict[str, int]] = {}
            for h in self._held.values():
                if not h.failed:
                    watched.setdefault(h.entry.name, {}).update({p.topic: round(p.current_limit(), 4)
                                                                 for p in h.probes})
                    drivers.setdefault(h.entry.name, {}).update({p.topic: p.publisher_pid for p in h.probes
                                                                 if p.publisher_pid})
        rows = [{'name': e.name, 'type': e.type, 'package': e.package, 'executable': e.executable,
                 'reliability': round(e.reliability.value, 6), 'source': e.source, 'active': e.name in active,
                 'output_topics': {k: {'topic': t.topic, 'rate': t.rate, 'stall_limit': t.silence_limit(),
                                       'stall_detection': t.stall_detection}
                                   for k, t in e.output_topics.items()},
                 'watched': watched.get(e.name, {}), 'driver_pids': drivers.get(e.name, {})}
                for e in self.catalogue.entries]
        return json.dumps({'manager': NAME, 'sensors': rows,
                           'problems': [str(p) for p in self.catalogue.problems]}, sort_keys=True)

    def shutdown(self) -> None:
        self.stall_detector.stop()
        self.reports.close()
        try:
            self.rr.shutdown()
        except Exception as err:
            rospy.logwarn('%s: registrar shutdown: %s', NAME, err)
        self._catalogue_srv.shutdown()
