"""The invariants, checked from outside: registries as the introspection services send them (plain JSON,
read here without the registrar's code), each client's own account, and the processes the kernel lists.

A check reads a snapshot and returns the violations it sees, each a sentence. Some invariants hold only
once the system has settled (a FAILED travels, a killed manager takes its registry back), so the runner
asks again until none is left or its bound passes, and reports what is left then.
"""
from __future__ import annotations

import dataclasses
import json
import threading
import time
from typing import Callable, Dict, List, Optional, Tuple

import psutil
import rospy

from temoto_core.srv import GetRegistry

DRIVERS = ('d435_driver', 'hokuyo_driver', 'sick_driver', 'laser_stitcher')
CONSUMERS = ('throttle',)                  # the clients' own processes (topic_tools), by the kernel's name
CLIENT_NODE_PREFIX = 'chaos_client_'       # the clients' node names (the runner names each incarnation)
# the servers whose consumers the clients are: (owner, server, what it serves)
SERVED = (('sensor_manager', 'start_sensor', 'sensor'), ('er_manager', 'load_process', 'process'))
READ_TIMEOUT = 2.0
# a call's deadline (the managers' contracts) and the slack a loaded machine gets before it is a violation
DEADLINES = {'load': 40.0, 'unload': 15.0}
DEADLINE_SLACK = 2.0


def read_all(services: List[str], timeout: float = READ_TIMEOUT) -> Dict[str, Optional[dict]]:
    """Each GetRegistry-typed service's JSON, all asked at once (a snapshot closer to one moment, and the
    slowest answer's time rather than the sum), or None for one that does not answer within ``timeout``.
    A thread is left behind only when a server hangs, which the caller then reports."""
    boxes: Dict[str, Dict[str, object]] = {service: {} for service in services}

    def ask(service: str, box: Dict[str, object]) -> None:
        try:
            box['json'] = json.loads(rospy.ServiceProxy(service, GetRegistry)().json)
        except Exception as e:        # not up, refused, stopped: the caller reports no answer
            box['error'] = e
    threads = [threading.Thread(target=ask, args=item, daemon=True, name='chaos-read') for item in boxes.items()]
    for thread in threads:
        thread.start()
    deadline = time.monotonic() + timeout
    for thread in threads:
        thread.join(max(0.0, deadline - time.monotonic()))
    return {service: box.get('json') for service, box in boxes.items()}


def read_json(service: str, timeout: float = READ_TIMEOUT) -> Optional[dict]:
    """One GetRegistry-typed service's JSON (see :func:`read_all`)."""
    return read_all([service], timeout)[service]


@dataclasses.dataclass
class Snapshot:
    sensor_manager: Optional[dict]
    er_manager: Optional[dict]
    er_processes: Optional[dict]
    clients: Dict[int, dict]                 # client index -> its state (the socket's answer)
    client_registries: Dict[int, Optional[dict]]
    resources: Dict[int, Tuple[str, str]]    # live resource process pid -> (its name, its command line)


def resource_processes(pids: List[int]) -> Dict[int, Tuple[str, str]]:
    """Of ``pids``, the drivers and consumer processes: pid -> (the kernel's name, the command line)."""
    found = {}
    for pid in pids:
        try:
            proc = psutil.Process(pid)
            name = proc.name()
            if name in DRIVERS or name in CONSUMERS:
                found[pid] = (name, ' '.join(proc.cmdline()))
        except psutil.Error:
            continue
    return found


def take(namespace: str, client_states: Dict[int, dict], session_processes: Callable[[], List[int]]) -> Snapshot:
    base = '/%s' % namespace.strip('/')
    resources = resource_processes(session_processes())
    managers = [base + '/temoto_sensor_manager/registry', base + '/temoto_er_manager/registry',
                base + '/temoto_er_manager/processes']
    clients = {i: '%s/%s/registry' % (base, s['registrar']) for i, s in client_states.items()}
    read = read_all(managers + list(clients.values()))
    return Snapshot(*(read[m] for m in managers), client_states, {i: read[c] for i, c in clients.items()}, resources)


def _settled(snap: Snapshot) -> List[str]:
    out = []
    for name, reg in (('Sensor Manager', snap.sensor_manager), ('ER Manager', snap.er_manager)):
        if reg is None:
            out.append('the %s does not answer' % name)
        elif reg.get('recovering'):
            out.append('the %s is still recovering' % name)
        elif any(q['state'] in ('loading', 'unloading') for q in reg['server_queries']):
            out.append('the %s has a load or unload under way' % name)
    return out


def check(snap: Snapshot) -> List[str]:
    """Every violation this snapshot shows (an unsettled system is reported as such, not checked)."""
    unsettled = _settled(snap)
    if unsettled or snap.er_processes is None:
        return unsettled or ['the ER Manager does not list its processes']
    out: List[str] = []
    listed = {p['pid']: (row, p) for row in snap.er_processes['processes'] for p in row['processes']}
    # every live driver or consumer process belongs to a registry entry, and none runs twice: a driver is one
    # per device (a forked driver shows its zygote's command line), a consumer one per command line
    same: Dict[str, List[int]] = {}
    for pid, (name, cmdline) in snap.resources.items():
        if pid not in listed:
            out.append('%s (pid %d) runs, but no ER Manager entry has it' % (name, pid))
        same.setdefault(name if name in DRIVERS else cmdline, []).append(pid)
    for what, pids in sorted(same.items()):
        if len(pids) > 1:
            out.append('%s runs %d times: %s' % (what, len(pids), sorted(pids)))
    # every ER entry is alive or FAILED: a process the kernel no longer has is known to have exited, and the
    # resource of a process that exited is FAILED (or gone) in the ER Manager's registry
    active_er = {q['internal_id'] for q in snap.er_manager['server_queries'] if q['state'] == 'active'}
    for pid, (row, proc) in listed.items():
        if not psutil.pid_exists(pid) and proc['state'] != 'exited':
            out.append('the ER Manager lists %s (pid %d) as %s, but it is gone' % (row['label'], pid, proc['state']))
    for row in snap.er_processes['processes']:
        if row['state'] == 'exited' and row['resource_id'] in active_er:
            out.append('the ER Manager\'s %s exited, but its resource is still active' % row['label'])
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
        for lid, info in state['held'].items():
            if int(lid) not in local:
                out.append('client %d: acknowledged load %s (%s) is not in its registry: lost'
                           % (i, lid, info['sensor']))
    for owner, server, what in SERVED:
        out += _served_holders(snap, getattr(snap, owner), server, what)
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
    for i, state in snap.clients.items():
        reg = snap.client_registries.get(i)
        if reg is None:
            continue
        heard_failed = {int(lid) for lid in state['failed_heard']}
        for cq in reg['client_queries']:
            if not cq['target'].endswith('/' + server):
                continue
            key = (state['node'], cq['external_id'])
            held[key] = cq
            q = served.get(key)
            if q is None:
                if cq['state'] != 'failed':
                    out.append('client %d holds %s id %d, which is not served to it: lost' % (i, what, key[1]))
            elif q['state'] == 'failed' and not any(lid in heard_failed for lid in cq['local_ids']):
                out.append('client %d never heard the FAILED of its %s %s (%s)' % (
                    i, what, q['summary'].get('sensor_type') or q['summary'].get('executable', '?'),
                    q.get('failure', '')[:120]))
    for key, q in served.items():
        if key not in held:
            out.append('%s id %d of %s is counted as held by %s, which holds nothing of it: a leaked reference'
                       % (what, key[1], server, key[0]))
    return out


def _deadlines(snap: Snapshot) -> List[str]:
    out = []
    for i, state in snap.clients.items():
        for op, seen in sorted(state['calls'].items()):
            limit = DEADLINES.get(op, 1.0) + DEADLINE_SLACK
            if seen['max_s'] > limit:
                out.append('client %d: a %s took %.1f s, past its deadline' % (i, op, seen['max_s']))
        for text in state.get('unexpected', []):
            out.append('client %d: a call failed with no TemotoError: %s' % (i, text[:300]))
    return out
