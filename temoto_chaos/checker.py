"""The invariants, checked from outside: registries as the introspection services send them (plain JSON,
read here without the registrar's code), each client's own account, and the processes the kernel lists.

A check reads a snapshot and returns the violations it sees, each a sentence. Some invariants hold only
once the system has settled (a FAILED travels, a killed manager takes its registry back), so the runner
asks again until none is left or its bound passes, and reports what is left then.
"""
from __future__ import annotations

import collections
import dataclasses
import json
import os
import threading
import time
from typing import Callable, Dict, List, Optional, Tuple

import psutil
import rospy

from temoto_core.srv import GetRegistry

# processes that are resources, by the kernel's name (15 characters at most):
# a device's driver, one at most (and the station's screen, one RViz host)
DRIVERS = ('d435_driver', 'hokuyo_driver', 'sick_driver', 'laser_stitcher', 'rviz_host')
CONSUMERS = ('throttle',)                  # the clients' own processes (topic_tools): one per command line
# a tracker's algorithm (color_blob_tracker), one per tracker loaded: a tracker that FAILED keeps its own
# until its holder releases it, and an equal request meanwhile gets a new one
ALGORITHMS = ('color_blob_trac',)
CLIENT_NODE_PREFIX = 'chaos_client_'       # the clients' node names (the runner names each incarnation)
# what a client calls the resources of each server it is a consumer of (its held 'kind')
SERVER_KINDS = {'start_sensor': 'sensor', 'load_process': 'process', 'track_object': 'tracked',
                'load_rviz_plugin': 'display', 'load_robot': 'robot'}
UNDER_WAY = ('loading', 'unloading')        # an owner's entry that is not settled yet: compared once it is


@dataclasses.dataclass(frozen=True)
class Manager:
    """A manager the checker reads: its name in reports, its registrar's path, and the servers whose
    consumers the clients are (server, what it serves)."""
    label: str
    path: str                                  # /<namespace>/<registrar>
    serves: Tuple[Tuple[str, str], ...] = ()
    lists_processes: bool = False              # an ER Manager: its processes are read too


def managers(robot: str, station: Optional[str] = None, robot_manager: bool = False) -> List[Manager]:
    """The managers of the robot's stack, and of the station's when it runs one (history 3 and later); the
    Robot Manager's when the clients hold motion (history 5)."""
    out = [Manager('Sensor Manager', '/%s/temoto_sensor_manager' % robot, (('start_sensor', 'sensor'),)),
           Manager('ER Manager', '/%s/temoto_er_manager' % robot, (('load_process', 'process'),), True)]
    if station:
        out += [Manager('Context Manager', '/%s/temoto_context_manager' % robot, (('track_object', 'tracked object'),)),
                Manager("station's ER Manager", '/%s/temoto_er_manager' % station, (), True),
                Manager('Output Manager', '/%s/temoto_output_manager' % station, (('load_rviz_plugin', 'display'),))]
    if robot_manager:
        out.append(Manager('Robot Manager', '/%s/temoto_robot_manager' % robot, (('load_robot', 'robot'),)))
    return out


READ_TIMEOUT = 2.0
PROCESS_CLOCK_S = 0.02        # a process's start time is known to the kernel's clock tick (10 ms), and rounded
# a call's deadlines, load and unload (the managers' contracts), by the kind of resource a client holds (it
# counts its calls as '<load|unload> <kind>'), and the slack a loaded machine gets before it is a violation
DEADLINES = {'sensor': (40.0, 15.0), 'process': (15.0, 10.0), 'tracked': (70.0, 25.0), 'display': (60.0, 15.0),
             'robot': (90.0, 30.0)}
DEADLINE_SLACK = 2.0
# s an owner has to release what a killed client held: its consumer liveness bound, 2 x (the check period,
# 2 s, + 1 s of ping timeout), with the same slack
KILLED_CLIENT_BOUND = 2 * (2.0 + 1.0) + DEADLINE_SLACK


class RegistryReader:
    """Reads GetRegistry-typed services (registries, process lists), all asked at once, over connections
    kept open from one read to the next.

    A check reads about fourteen services, several checks a second. A new connection per read cost a master
    lookup and a TCP handshake per service: about 0.03 s of a check's 0.07 s (profiled, history 4). A kept
    connection that broke (its node died, or a new incarnation took its name) is closed, and that read made
    again once on a new connection, so an answer is never older than the read."""

    def __init__(self) -> None:
        self._proxies: Dict[str, rospy.ServiceProxy] = {}
        self._busy: Dict[str, threading.Lock] = collections.defaultdict(threading.Lock)
        self._guard = threading.Lock()

    def read_all(self, services: List[str], timeout: float = READ_TIMEOUT) -> Dict[str, Optional[dict]]:
        """Each service's JSON, or None for one that does not answer within ``timeout`` (a snapshot closer
        to one moment, in the slowest answer's time rather than the sum). A thread is left behind only when
        a server hangs, which the caller then reports."""
        boxes: Dict[str, Dict[str, object]] = {service: {} for service in services}
        deadline = time.monotonic() + timeout
        threads = [threading.Thread(target=self._read, args=(service, box, deadline), daemon=True,
                                    name='chaos-read') for service, box in boxes.items()]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(max(0.0, deadline - time.monotonic()))
        return {service: box.get('json') for service, box in boxes.items()}

    def read_json(self, service: str, timeout: float = READ_TIMEOUT) -> Optional[dict]:
        """One service's JSON (see :meth:`read_all`)."""
        return self.read_all([service], timeout)[service]

    def keep_only(self, services: List[str]) -> None:
        """Close the connections to every other service (a killed client's registry is never read again)."""
        with self._guard:
            gone = [name for name in self._proxies if name not in services]
            proxies = [self._proxies.pop(name) for name in gone]
            # and their locks (a history kills a client every 40 steps or so: each incarnation left one);
            # a lock a read still holds stays, so that read is still the only one on its service
            for name in [n for n, lock in self._busy.items() if n not in services and not lock.locked()]:
                del self._busy[name]
        for proxy in proxies:
            proxy.close()

    def close(self) -> None:
        self.keep_only([])

    def _read(self, service: str, box: Dict[str, object], deadline: float) -> None:
        with self._guard:
            busy = self._busy[service]
        # one call at a time per connection: a read still hung on a stopped server counts as no answer
        if not busy.acquire(timeout=max(0.0, deadline - time.monotonic())):
            box['error'] = TimeoutError('an earlier read of %s has not ended' % service)
            return
        try:
            with self._guard:
                kept = self._proxies.pop(service, None)
            if kept is not None:
                try:
                    box['json'] = self._ask(kept, service)
                    return
                except Exception:      # stale: its node is gone or was replaced; read again on a new connection
                    kept.close()
            try:
                box['json'] = self._ask(rospy.ServiceProxy(service, GetRegistry, persistent=True), service)
            except Exception as e:     # not up, refused, stopped: the caller reports no answer
                box['error'] = e
        finally:
            busy.release()

    def _ask(self, proxy: rospy.ServiceProxy, service: str) -> dict:
        try:
            answer = json.loads(proxy().json)
        except Exception:
            proxy.close()
            raise
        with self._guard:
            self._proxies[service] = proxy
        return answer


@dataclasses.dataclass
class Snapshot:
    managers: List[Manager]
    registries: Dict[str, Optional[dict]]    # manager label -> its registry (None: no answer)
    processes: Dict[str, Optional[dict]]     # an ER Manager's label -> its process list
    clients: Dict[int, dict]                 # client index -> its state (the socket's answer)
    client_registries: Dict[int, Optional[dict]]
    resources: Dict[int, Tuple[str, str]]    # live resource process pid -> (its name, its command line)
    # when each resource process started (the kernel's clock), and when the registries were read: a process
    # started after the read, or while an ER Manager was starting a resource, may not be in its list yet
    created: Dict[int, float] = dataclasses.field(default_factory=dict)
    read_at: float = float('inf')
    # client incarnations the nemesis killed, by node name (without namespace): seconds since the kill
    killed: Dict[str, float] = dataclasses.field(default_factory=dict)


def resource_name(name: str, cmdline: List[str]) -> Optional[str]:
    """Which driver or consumer a process is, if any: by the kernel's name (a node forked from the ER
    Manager's zygote is named after its script, and shows the zygote's command line), else by the program
    or script its command line runs (a plain start is named after its interpreter)."""
    candidates = [name] + [os.path.basename(arg)[:15] for arg in cmdline[:2]]
    return next((c for c in candidates if c in DRIVERS + CONSUMERS + ALGORITHMS), None)


def resource_processes(pids: List[int]) -> Dict[int, Tuple[str, str]]:
    """Of ``pids``, the drivers and consumer processes: pid -> (which one, the command line). Read from /proc
    directly: psutil read each process's files several times over, a seventh of a check's time."""
    found = {}
    for pid in pids:
        try:
            with open('/proc/%d/comm' % pid, 'rb') as f:
                name = f.read().decode('utf-8', 'replace').rstrip('\n')
            with open('/proc/%d/cmdline' % pid, 'rb') as f:
                cmdline = f.read().decode('utf-8', 'replace').split('\0')
        except OSError:          # gone meanwhile
            continue
        if cmdline and not cmdline[-1]:
            cmdline.pop()
        which = resource_name(name, cmdline)
        if which is not None:
            found[pid] = (which, ' '.join(cmdline))
    return found


def take(reader: RegistryReader, read: List[Manager], client_namespace: str,
         client_states: Callable[[], Dict[int, dict]], session_processes: Callable[[], List[int]]) -> Snapshot:
    """Everything as near one moment as a system that keeps working allows: the managers' registries (and
    ER Managers' processes), the clients' registries (their registrars are in ``client_namespace``), then
    the resource processes the kernel has.

    The clients are asked for their state before the registries are read and again after, so that a call
    that began or ended meanwhile counts as under way, and only what a client held all along is held. A
    resource process started after the registries were read is not expected in them yet."""
    before = client_states()
    clients = {i: '/%s/%s/registry' % (client_namespace.strip('/'), s['registrar']) for i, s in before.items()}
    services = [m.path + '/registry' for m in read] + [m.path + '/processes' for m in read if m.lists_processes]
    read_at = time.time()
    answers = reader.read_all(services + list(clients.values()))
    reader.keep_only(list(answers))
    after = client_states()
    resources = resource_processes(session_processes())
    return Snapshot(read, {m.label: answers[m.path + '/registry'] for m in read},
                    {m.label: answers[m.path + '/processes'] for m in read if m.lists_processes},
                    _held_throughout(before, after), {i: answers[c] for i, c in clients.items()}, resources,
                    _created(resources), read_at)


def _held_throughout(before: Dict[int, dict], after: Dict[int, dict]) -> Dict[int, dict]:
    """Each client's state as the checker may hold it to: held (and heard FAILED) in both answers, and every
    call under way in either. A client that started again meanwhile is left out until the next look."""
    out = {}
    for i, first in before.items():
        second = after.get(i)
        if second is None or second['node'] != first['node']:
            continue
        state = dict(second)
        state['held'] = {lid: info for lid, info in second['held'].items() if lid in first['held']}
        state['pending'] = first.get('pending', []) + second.get('pending', [])
        out[i] = state
    return out


def _created(pids) -> Dict[int, float]:
    out = {}
    for pid in pids:
        try:
            out[pid] = psutil.Process(pid).create_time()
        except psutil.Error:
            continue
    return out


def _maybe_unlisted_yet(snap: Snapshot, pid: int) -> bool:
    """Whether ``pid`` may be missing from every ER Manager's list only because it started too late to be
    in it: after the lists were read, or while an ER Manager was still starting a resource (the manager
    lists a process once the start returns)."""
    created = snap.created.get(pid)
    if created is None:
        return False
    starting = [row['started'] for procs in snap.processes.values() for row in procs['processes']
                if row['state'] == 'starting']
    return created >= snap.read_at - PROCESS_CLOCK_S or any(created >= t - PROCESS_CLOCK_S for t in starting)


def _settled(snap: Snapshot) -> List[str]:
    out = []
    for name, reg in snap.registries.items():
        if reg is None:
            out.append('the %s does not answer' % name)
        elif reg.get('recovering'):
            out.append('the %s is still recovering' % name)
    return out


def check(snap: Snapshot) -> List[str]:
    """Every violation this snapshot shows (an unsettled system is reported as such, not checked)."""
    unsettled = _settled(snap) + ['the %s does not list its processes' % name
                                  for name, procs in snap.processes.items() if procs is None]
    if unsettled:
        return unsettled
    out: List[str] = []
    listed = {p['pid']: (name, row, p) for name, procs in snap.processes.items()
              for row in procs['processes'] for p in row['processes']}
    # every live resource process belongs to a registry entry, and none runs twice: a driver is one per
    # device (a forked driver shows its zygote's command line), a consumer one per command line; a tracker's
    # algorithm runs once per tracker entry (the entry is what is checked)
    same: Dict[str, List[int]] = {}
    for pid, (name, cmdline) in snap.resources.items():
        if pid not in listed and not _maybe_unlisted_yet(snap, pid):
            out.append('%s (pid %d) runs, but no ER Manager entry has it' % (name, pid))
        if name not in ALGORITHMS:
            same.setdefault(name if name in DRIVERS else cmdline, []).append(pid)
    for what, pids in sorted(same.items()):
        if len(pids) > 1:
            out.append('%s runs %d times: %s' % (what, len(pids), sorted(pids)))
    # every ER entry is alive or FAILED: a process the kernel no longer has is known to have exited, and the
    # resource of a process that exited is FAILED (or gone) in the ER Manager's registry
    for pid, (name, row, proc) in listed.items():
        if not psutil.pid_exists(pid) and proc['state'] != 'exited':
            out.append('the %s lists %s (pid %d) as %s, but it is gone' % (name, row['label'], pid, proc['state']))
    for name, procs in snap.processes.items():
        active = {q['internal_id'] for q in snap.registries[name]['server_queries'] if q['state'] == 'active'}
        for row in procs['processes']:
            if row['state'] == 'exited' and row['resource_id'] in active:
                out.append('the %s\'s %s exited, but its resource is still active' % (name, row['label']))
    out += _holders(snap)
    out += _deadlines(snap)
    return out


def _is_client(node: str) -> bool:
    return node.rsplit('/', 1)[-1].startswith(CLIENT_NODE_PREFIX)


def _holders(snap: Snapshot) -> List[str]:
    """Acknowledged loads, references and FAILED deliveries, between the managers and the clients."""
    out = []
    for i, state in snap.clients.items():
        reg = snap.client_registries.get(i)
        if reg is None:
            out.append('client %d (%s) does not answer for its registry' % (i, state['node']))
            continue
        local = {lid for cq in reg['client_queries'] for lid in cq['local_ids']}
        unloading = {p['id'] for p in state.get('pending', []) if p['op'] == 'unload'}
        for lid, info in state['held'].items():
            if int(lid) not in local and int(lid) not in unloading:
                out.append('client %d: acknowledged load %s (%s) is not in its registry: lost'
                           % (i, lid, info['what']))
    for manager in snap.managers:
        for server, what in manager.serves:
            out += _served_holders(snap, snap.registries[manager.label], server, what)
    return out


def _served_holders(snap: Snapshot, registry: dict, server: str, what: str) -> List[str]:
    """One server's references to the clients, against what each client holds of it."""
    out = []
    served = {}          # (client node, external id) -> the owner's entry
    for q in registry['server_queries']:
        if q['server'] != server:
            continue
        for c in q['consumers']:
            if _is_client(c['client_name']):
                served[(c['client_name'], c['resource_id'])] = q
    held = {}            # (client node, external id) -> (client index, local ids, the client's entry state)
    busy = set()         # the clients with a call of this server's under way: their references are in flux
    for i, state in snap.clients.items():
        reg = snap.client_registries.get(i)
        if reg is None:
            continue
        if any(p['kind'] == SERVER_KINDS.get(server) for p in state.get('pending', [])):
            busy.add(state['node'])
        heard_failed = {int(lid) for lid in state['failed_heard']}
        for cq in reg['client_queries']:
            if not cq['target'].endswith('/' + server):
                continue
            key = (state['node'], cq['external_id'])
            held[key] = cq
            q = served.get(key)
            if q is None:
                if cq['state'] != 'failed' and state['node'] not in busy:
                    out.append('client %d holds %s id %d, which is not served to it: lost' % (i, what, key[1]))
            elif q['state'] == 'failed' and not any(lid in heard_failed for lid in cq['local_ids']):
                out.append('client %d never heard the FAILED of its %s %s (%s)' % (
                    i, what, _describe(q['summary']), q.get('failure', '')[:120]))
    for key, q in served.items():
        if key not in held and key[0] not in busy and q['state'] not in UNDER_WAY \
                and snap.killed.get(key[0].rsplit('/', 1)[-1], KILLED_CLIENT_BOUND) >= KILLED_CLIENT_BOUND:
            out.append('%s id %d of %s is counted as held by %s, which holds nothing of it: a leaked reference'
                       % (what, key[1], server, key[0]))
    return out


def _describe(summary: dict) -> str:
    for key in ('sensor_type', 'executable', 'object_name', 'topic', 'type', 'robot_name', 'features'):
        if summary.get(key):
            return str(summary[key])
    return '?'


def _deadlines(snap: Snapshot) -> List[str]:
    out = []
    for i, state in snap.clients.items():
        for op, seen in sorted(state['calls'].items()):
            verb, _, kind = op.partition(' ')
            load, unload = DEADLINES.get(kind, (1.0, 1.0))
            limit = (load if verb == 'load' else unload) + DEADLINE_SLACK
            if seen['max_s'] > limit:
                out.append('client %d: a %s took %.1f s, past its deadline' % (i, op, seen['max_s']))
        for text in state.get('unexpected', []):
            out.append('client %d: a call failed with no TemotoError: %s' % (i, text[:300]))
    return out
