"""P2P backup: each neighbour keeps the part of a registrar's registry that concerns it, so a registrar
whose journal is lost rebuilds its registry from its neighbours (the paper's section 5).

What each neighbour keeps:

- a **consumer** keeps, for each resource it holds, the owner's response; with it travels the owner's
  *record* of the resource (``trr.backup``, built by :func:`record` when the resource becomes active):
  its internal id, the sub-resources linked to it (their owner, id and the local id they are held under)
  and the owner state kept for it (keys ``<kind>/<internal id>``, such as the ER Manager's pids and start
  times). The consumer keeps the response anyway, and journals it;
- an **owner** keeps its consumer records: who holds what, under which id, with the request and the
  response. That is where a record's links find their bytes again.

Links are made while a resource loads (a sub-resource is loaded inside the load callback, or linked with
``rr.link`` before it returns), so the record is complete when the response leaves.

Every restart asks: :func:`gather` asks every other registrar for its registry and turns what they keep
about this one into the shape of a journal, and :func:`reconcile` merges it with the
local journal. The journal is written behind the registry (``recorder.py``), so its last changes may be
missing after a SIGKILL, and a consumer may have released a resource while its owner was down; a
neighbour that answers knows better than the journal about what it holds:

- a resource a neighbour holds that the journal lacks (its commit was lost) comes back from the neighbour;
- a consumer that answers and no longer holds what the journal says it holds is *stale*: the recovery
  releases it, and the last one out unloads the resource (its process is stopped);
- a consumer record the neighbour gives is fresher than the journal's (a reclaim moved it);
- a neighbour that does not answer, or is recovering itself, leaves the journal's word standing;
- a hold the journal has without its parent (the link was not yet committed) takes the parent the
  record names, so that its FAILED still goes up;
- a linked sub-resource that neither the journal nor its owner gives back fails the resource linking it:
  nobody can vouch for it.

Held resources that no served resource links are released by the recovery that follows (nothing
references them any more). Owner state that is not per resource (the reliabilities) is not backed up:
it is only in the journal, which writes it at once.
"""
import base64
import dataclasses
import json
import threading
import time
from typing import Callable, Dict, List, Optional, Set, Tuple

import rosgraph
import rospy

from temoto_core.rr.deadlines import call_once
from temoto_core.rr.journal import JournalContents, JournaledConsumer, JournaledHold, JournaledServed
from temoto_core.rr.messages import as_sent
from temoto_core.rr.query import ClientQuery, ServerQuery, target_name
from temoto_core.rr.owner_state import OwnerState
from temoto_core.rr.recorder import serialized
from temoto_core.srv import GetRegistry

BACKUP_VERSION = 2    # 2: links are named; their request and response are at their owner
NO_PARENT = -1      # a held resource that no served one links: released by the recovery


def record(query: ServerQuery, by_local: Dict[int, ClientQuery], owner_state: OwnerState) -> str:
    """The owner's record of ``query``, as its consumers keep it (lock held).

    A link is named, not copied: its request and response are what the link's own owner keeps in its consumer
    record, and :func:`gather` takes them from there. Copying them made every record (and every response that
    carries it) grow with the depth of the chain below, and cost a load through three journaling registrars
    about 0.15 ms (``bench_journal.py``)."""
    links = []
    for local_id in sorted(query.links):
        held = by_local.get(local_id)
        if held is None or held.response is None:
            continue
        links.append({'local_id': local_id, 'target': list(held.target), 'external_id': held.external_id})
    return json.dumps({'v': BACKUP_VERSION, 'internal_id': query.internal_id, 'links': links,
                       'owner_state': owner_state.of_resource(query.internal_id)}, separators=(',', ':'))


@dataclasses.dataclass
class Kept:
    """What the neighbours keep about one registrar."""
    contents: JournalContents
    owner_state: Dict[str, str]
    answered: Set[str]       # status topics of the registrars that answered and were not recovering: their word
                             # is final (a node may host several registrars, so a registrar, not a node)
    unfound: List[Tuple[int, tuple, int]] = dataclasses.field(default_factory=list)
    # links a record names that no owner gave back: (internal id of the resource, target, external id)


def gather(namespace: str, name: str, node: str, new_id: Callable[[], int], service_of: Callable,
           timeout: float = 2.0) -> Kept:
    """What the other registrars keep about registrar ``name`` of ``namespace`` (of node ``node``).

    Every registrar of the ROS graph is asked, whatever its TeMoto namespace: a consumer may be the operator's
    station, and an owner another robot's manager."""
    mine = '/%s/%s/registry' % (namespace, name)
    own_topic = '/%s/%s/status' % (namespace, name)
    try:
        services = [s for s, _ in rosgraph.Master(node).getSystemState()[2]]
    except Exception as err:          # no master: nothing to ask
        rospy.logwarn('/%s/%s: cannot list the registrars to rebuild from: %s', namespace, name, err)
        return Kept(JournalContents([], []), {}, set())
    served: Dict[int, JournaledServed] = {}
    named: List[Tuple[int, int, tuple, int]] = []            # (resource, local id, target, external id)
    offered: Dict[Tuple[tuple, int], Tuple[str, bytes, bytes]] = {}   # what owners say this registrar holds
    owner_state: Dict[str, str] = {}
    answered: Set[str] = set()
    wanted = [s for s in services if s.endswith('/registry') and s != mine]
    for snapshot in _registries(wanted, timeout):
        theirs = (snapshot['namespace'], snapshot['name'])
        their_topic = '/%s/%s/status' % theirs
        if not snapshot.get('recovering', False):
            answered.add(their_topic)
        uri = _uri(node, snapshot['node'])
        for query in snapshot['client_queries']:
            ns, rr, server = query['target'].strip('/').split('/', 2)
            if (ns, rr) != (namespace, name) or query['response'] is None:
                continue
            request_type = query['request']['type']
            response = service_of(request_type)._response_class()
            response.deserialize(base64.b64decode(query['response']['data']))
            internal_id, links, state = parse_record(response.trr.backup, their_topic)
            if internal_id is None:
                continue                  # an owner before the backup existed: nothing to rebuild it from
            response.trr.resource_id = internal_id       # the owner keeps its own id, and no copy of the record
            response.trr.backup = ''
            # who answered is stamped on each answer (owners.py), not kept with the resource
            response.trr.owner_node, response.trr.owner_uri, response.trr.owner_incarnation = '', '', 0
            entry = served.get(internal_id)
            if entry is None:
                entry = served[internal_id] = JournaledServed(
                    internal_id, server, query['state'], request_type, base64.b64decode(query['request']['data']),
                    serialized(response), [])
                named.extend((internal_id,) + link for link in links)
                owner_state.update(state)
            entry.consumers.append(JournaledConsumer(query['external_id'], their_topic,
                                                     snapshot['node'], theirs[0], uri,
                                                     int(snapshot.get('incarnation', 0))))
        for query in snapshot['server_queries']:
            for consumer in query['consumers']:
                # the status topic names the registrar: another registrar of the same node is not this one
                if consumer['status_topic'] == own_topic and query['response']:
                    request_type = query['request']['type']
                    stored = service_of(request_type)._response_class()
                    stored.deserialize(base64.b64decode(query['response']['data']))
                    sent = as_sent(stored, consumer['resource_id'], query.get('record', ''), snapshot['node'], uri,
                                   int(snapshot.get('incarnation', 0)))
                    offered[((theirs[0], theirs[1], query['server']), consumer['resource_id'])] = (
                        request_type, base64.b64decode(query['request']['data']), serialized(sent))
    holds: List[JournaledHold] = []
    unfound: List[Tuple[int, tuple, int]] = []
    linked = set()
    for internal_id, local_id, target, external_id in named:
        found = offered.get((target, external_id))
        if found is None:
            unfound.append((internal_id, target, external_id))
            continue
        linked.add((target, external_id))
        holds.append(JournaledHold(local_id, target, external_id, *found, internal_id))
    for (target, external_id), found in offered.items():
        if (target, external_id) not in linked:
            holds.append(JournaledHold(new_id(), target, external_id, *found, NO_PARENT))
    return Kept(JournalContents(sorted(served.values(), key=lambda e: e.internal_id), holds), owner_state, answered,
                unfound)


def parse_record(text: str, keeper: str) -> Tuple[Optional[int], List[Tuple[int, tuple, int]], Dict[str, str]]:
    """(internal id, links as (local id, target, external id), owner state) of a record a consumer kept;
    (None, [], {}) for none. A neighbour's word is checked like any message from the wire."""
    try:
        kept = json.loads(text or '{}')
        internal_id = kept.get('internal_id')
        if not isinstance(internal_id, int) or isinstance(internal_id, bool) or internal_id <= 0:
            return None, [], {}
        links = []
        for link in kept.get('links', []):
            target = tuple(link['target'])
            if (len(target) != 3 or not all(isinstance(part, str) for part in target)
                    or not all(isinstance(link[k], int) for k in ('local_id', 'external_id'))):
                raise ValueError('bad link %r' % (link,))
            links.append((link['local_id'], target, link['external_id']))
        state = {str(k): str(v) for k, v in kept.get('owner_state', {}).items()}
        return internal_id, links, state
    except (ValueError, TypeError, KeyError, AttributeError) as err:
        rospy.logwarn('rebuilding from neighbours: the record %s keeps cannot be read (%s): left out', keeper, err)
        return None, [], {}


@dataclasses.dataclass
class Reconciled:
    contents: JournalContents         # what to recover
    stale: List[Tuple[str, int]]      # (server, external id): consumers that answered and hold it no more
    added_served: int                 # served resources the journal lacked
    added_holds: int                  # held resources the journal lacked
    lost: Dict[int, str] = dataclasses.field(default_factory=dict)
    # internal id -> why: resources a sub-resource of which neither the journal nor its owner gave back


def reconcile(journal: JournalContents, kept: Kept) -> Reconciled:
    """The journal, corrected by what the neighbours keep (see the module docstring)."""
    given = {entry.internal_id: entry for entry in kept.contents.served}
    served: List[JournaledServed] = []
    stale: List[Tuple[str, int]] = []
    for entry in journal.served:
        theirs = given.pop(entry.internal_id, None)
        fresher = {c.external_id: c for c in theirs.consumers} if theirs is not None else {}
        consumers = []
        for consumer in entry.consumers:
            if consumer.external_id in fresher:
                consumers.append(fresher.pop(consumer.external_id))
                continue
            if consumer.status_topic in kept.answered:
                stale.append((entry.server, consumer.external_id))
            consumers.append(consumer)       # a stale one too: the recovery releases it the normal way
        consumers.extend(fresher.values())   # attached, but the journal lost it
        served.append(dataclasses.replace(entry, consumers=consumers))
    added_served = list(given.values())
    # a hold made unlinked and linked before the load returned (``rr.link``) is journaled in two changes;
    # a SIGKILL between their commits leaves the journal's hold without its parent, and the record names it
    linked_by = {(hold.target, hold.external_id): hold.parent for hold in kept.contents.holds
                 if hold.parent not in (None, NO_PARENT)}
    holds = [dataclasses.replace(hold, parent=linked_by[(hold.target, hold.external_id)])
             if hold.parent is None and (hold.target, hold.external_id) in linked_by else hold
             for hold in journal.holds]
    known = {(hold.target, hold.external_id) for hold in journal.holds}
    added_holds = [hold for hold in kept.contents.holds if (hold.target, hold.external_id) not in known]
    lost: Dict[int, str] = {}
    for internal_id, target, external_id in kept.unfound:
        if (target, external_id) not in known:
            lost.setdefault(internal_id, 'its sub-resource %s %d could not be recovered: the journal lacks it and '
                                         'its owner did not give it back' % (target_name(target), external_id))
    contents = JournalContents(sorted(served + added_served, key=lambda e: e.internal_id),
                               holds + added_holds)
    return Reconciled(contents, stale, len(added_served), len(added_holds), lost)


def _registries(services: List[str], timeout: float) -> List[dict]:
    """The registries behind ``services``, asked all at once; one that does not answer within ``timeout`` is
    left out. A registration left by a dead registrar is refused at once, so it costs nothing."""
    found: Dict[str, dict] = {}

    def ask(service: str) -> None:
        try:
            # bounded as a whole, so that a stopped neighbour does not keep this thread for ever
            found[service] = json.loads(call_once(service, GetRegistry, GetRegistry._request_class(), timeout).json)
        except Exception as err:       # gone, refused, not a registry: nothing to rebuild from there
            rospy.logdebug('rebuilding from neighbours: %s did not answer (%s)', service, err)
    threads = [threading.Thread(target=ask, args=(s,), daemon=True, name='rr-backup-ask') for s in services]
    for thread in threads:
        thread.start()
    deadline = time.monotonic() + timeout
    for thread in threads:
        thread.join(max(0.0, deadline - time.monotonic()))
    late = [s for s, t in zip(services, threads) if t.is_alive()]
    if late:
        rospy.logwarn('rebuilding from neighbours: no answer within %.1f s from %s', timeout, ', '.join(late))
    answered = dict(found)             # a late thread may still write: read one copy
    return [answered[s] for s in services if s in answered]


def _uri(caller: str, node: str) -> str:
    try:
        return rosgraph.Master(caller).lookupNode(node)
    except Exception:                 # gone meanwhile: its liveness watch finds it dead
        return ''
