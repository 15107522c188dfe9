"""Recovery: a restarted registrar rebuilds its registry from its journal, corrected by what its
neighbours keep (``backup.py``; the neighbours alone if the journal is lost), checks it against reality,
and takes back from its neighbours what its previous incarnation held.

Three steps, in the owner's order:

1. At construction, the resources it *held* come back as active client queries,
   under the same local ids.
2. ``add_server(..., recover=cb)`` brings back that server's resources, their
   consumers and their links. ``cb(request, response)`` checks each against
   reality (is the process still there?) and raises ``TemotoError`` if it is
   gone; then the resource's consumers hear FAILED with the reason. Nothing that
   still runs is restarted. A server without ``recover`` cannot check, so its
   resources are reported FAILED. A consumer that answered the neighbours' roll
   call and no longer holds its resource is released, as an unload would.
3. ``resume()`` asks each owner of a held resource to hand it over to this
   incarnation (``/<ns>/<rr>/reclaim``): the owner points the consumer record
   at the new node URI and status topic, and says which resources are still
   active. One that failed, or was released, while this registrar was down is
   handled as a FAILED that arrives now: forwarded up the links and handed to
   the callbacks. A held resource whose parent did not come back is released.
"""
import importlib
import threading
import time
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import rospy

from temoto_core.errors import ErrorCode, ErrorFrame, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_core.rr.channels import StatusChannels
from temoto_core.rr.client_side import ClientSide
from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.journal import JournalContents, JournaledServed
from temoto_core.rr.keys import key_of
from temoto_core.rr.links import Links
from temoto_core.rr.query import ACTIVE, FAILED, ClientQuery, Consumer, Server, ServerQuery, Target, target_name
from temoto_core.rr.server_side import ServerSide
from temoto_core.rr.status_pipeline import StatusPipeline
from temoto_core.srv import Reclaim

RecoverCallback = Callable[[object, object], None]

# How long resume() keeps asking an owner that does not answer (it may be restarting too) before it gives
# up and reports what it held there FAILED.
RECLAIM_PATIENCE = 10.0


def service_of(request_type: str):
    """The service class of a request type name (``pkg/NameRequest``)."""
    package, name = request_type.split('/')
    return getattr(importlib.import_module(package + '.srv'), name[:-len('Request')])


class Recovery:
    def __init__(self, core: RegistrarCore, contents: JournalContents, server: ServerSide, client: ClientSide,
                 links: Links, channels: StatusChannels, pipeline: StatusPipeline, header,
                 stale: Sequence[Tuple[str, int]] = (), lost: Optional[Dict[int, str]] = None) -> None:
        self._core = core
        self._server = server
        self._client = client
        self._links = links
        self._channels = channels
        self._pipeline = pipeline
        self._header = header
        self._served: Dict[str, List[JournaledServed]] = {}
        for entry in contents.served:
            self._served.setdefault(entry.server, []).append(entry)
        self._stale: Dict[str, List[int]] = {}   # server -> external ids whose consumers hold them no more
        for server_name, external_id in stale:
            self._stale.setdefault(server_name, []).append(external_id)
        self._lost = dict(lost or {})             # internal id -> why it cannot be vouched for (backup.reconcile)
        self._parents: Dict[int, int] = {}       # held local id -> internal id of the served resource it belongs to
        self.restored_holds = self._restore_holds(contents.holds)

    # ------------------------------------------------------------------------------------------ 1. held
    def _restore_holds(self, holds) -> int:
        client = self._client
        by_external: Dict[Tuple[Target, int], ClientQuery] = {}
        with self._core.lock:
            for hold in holds:
                query = by_external.get((hold.target, hold.external_id))
                if query is None:
                    srv = service_of(hold.request_type)
                    request = srv._request_class()
                    request.deserialize(hold.request)
                    response = srv._response_class()
                    response.deserialize(hold.response)
                    query = ClientQuery(hold.target, key_of(request), request)
                    query.response, query.external_id = response, hold.external_id
                    query.move(ACTIVE)
                    by_external[(hold.target, hold.external_id)] = query
                    client.by_key.setdefault((hold.target, query.key), query)
                    client.by_external[(hold.target, hold.external_id)] = query
                query.local_ids[hold.local_id] = None
                client.by_local[hold.local_id] = query
                if hold.parent is not None:
                    self._parents[hold.local_id] = hold.parent
        return len(holds)

    # ------------------------------------------------------------------------------------------ 2. served
    def restore_server(self, server: Server, recover: Optional[RecoverCallback]) -> None:
        core, side = self._core, self._server
        restored: List[ServerQuery] = []
        with core.lock:
            for entry in self._served.pop(server.name, []):
                request = server.srv_type._request_class()
                request.deserialize(entry.request)
                response = server.srv_type._response_class()
                response.deserialize(entry.response)
                query = ServerQuery(server, server.key(request), entry.internal_id, request)
                query.response = response
                query.move(ACTIVE)
                for c in entry.consumers:
                    query.consumers[c.external_id] = Consumer(c.status_topic, c.client_name, c.namespace, c.uri,
                                                              c.incarnation)
                    side.by_external[(server.name, c.external_id)] = query
                side.by_internal[query.internal_id] = query
                if entry.state == ACTIVE.value:
                    server.by_key.setdefault(query.key, query)
                else:
                    query.move(FAILED)
                    query.failure = core.error(ErrorCode.RESOURCE_FAILED, 'failed before this incarnation started: %s'
                                               % (entry.reason or 'no reason was journaled'))
                for local_id, parent in list(self._parents.items()):
                    if parent == query.internal_id and local_id in self._client.by_local:
                        self._links.attach(local_id, query)
                        del self._parents[local_id]
                query.backup = side.record_of(query)
                restored.append(query)
        self._channels.acquire_all([c.status_topic for q in restored for c in q.consumers.values()])
        # Consumers that no longer hold their resource leave first, so that no FAILED is announced to them;
        # a resource left with none of its consumers is checked like the others (its process adopted), then
        # unloaded as the last one out would.
        stale = set(self._stale.pop(server.name, []))
        unheld = []
        for query in restored:
            leaving = [external_id for external_id in query.consumers if external_id in stale]
            if leaving and len(leaving) == len(query.consumers):
                unheld.append((query, leaving))
                continue
            for external_id in leaving:
                self._release_stale(server.name, external_id)
        unheld_ids = {query.internal_id for query, _ in unheld}
        for query in restored:
            if query.state is not ACTIVE:
                continue
            why = self._why_lost(query, server, recover)
            if why is not None and query.internal_id not in unheld_ids:
                message = 'lost while %s was down: %s' % (core.prefix, why)
                rospy.logwarn('%s: %s resource %d %s', core.prefix, server.name, query.internal_id, message)
                self._pipeline.forward(query, ResourceStatus.FAILED, message,
                                       [ErrorFrame(ErrorCode.RESOURCE_FAILED, core.subsystem, message, core.prefix)])
        for _query, leaving in unheld:
            for external_id in leaving:
                self._release_stale(server.name, external_id)
        if restored:
            rospy.loginfo('%s: recovered %d %s resource(s)', core.prefix, len(restored), server.name)

    def _why_lost(self, query: ServerQuery, server: Server, recover: Optional[RecoverCallback]) -> Optional[str]:
        """Why restored ``query`` cannot be vouched for, or None if it still runs. The callback runs in any case:
        it adopts what still runs, so that an unload stops it."""
        why = None
        if recover is None:
            why = '%s cannot check its %s resources after a restart' % (self._core.prefix, server.name)
        else:
            try:
                recover(query.request, query.response)
            except TemotoError as err:
                why = str(err)
            except Exception as err:   # an owner bug: the resource cannot be vouched for
                rospy.logerr('%s: recover callback of %s raised %r', self._core.prefix, server.name, err)
                why = 'recover callback of %s raised %r' % (server.name, err)
        # a sub-resource that is unaccounted for fails the resource, whatever its own process says
        return self._lost.pop(query.internal_id, why)

    def _release_stale(self, server_name: str, external_id: int) -> None:
        core, side = self._core, self._server
        consumer = side.consumer(server_name, external_id)
        rospy.logwarn('%s: %s no longer holds %s resource %d: releasing it', core.prefix,
                      consumer.client_name if consumer is not None else '?', server_name, external_id)
        try:
            side.release_consumer(server_name, external_id)
        except TemotoError as err:
            rospy.logwarn('%s: releasing stale %s resource %d: %s', core.prefix, server_name, external_id, err)

    # ------------------------------------------------------------------------------------------ 3. neighbours
    def resume(self) -> None:
        """Reclaim what this registrar held; report what died meanwhile; release what lost its parent."""
        core, client = self._core, self._client
        with core.lock:
            orphans = [local_id for local_id in self._parents if local_id in client.by_local]
            self._parents.clear()
            groups: Dict[Target, List[ClientQuery]] = {}
            for query in {id(q): q for q in client.by_local.values()}.values():
                groups.setdefault(query.target, []).append(query)
        for local_id in orphans:
            try:
                client.unload(local_id)
            except TemotoError as err:
                rospy.logwarn('%s: releasing held resource %d, whose parent is gone: %s', core.prefix, local_id, err)
        threads = [threading.Thread(target=self._reclaim, args=(target, queries), daemon=True,
                                    name='rr-%s-reclaim' % core.name) for target, queries in groups.items()]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()

    def _reclaim(self, target: Target, queries: List[ClientQuery]) -> None:
        core = self._core
        ns, rr_name, server_name = target
        service = '/%s/%s/reclaim' % (ns, rr_name)
        ids = [q.external_id for q in queries]
        request = Reclaim._request_class(client_name=self._header.client_name, client_uri=self._header.client_uri,
                                         status_topic=self._header.status_topic, incarnation=core.incarnation,
                                         server_name=server_name, resource_ids=ids)
        deadline = time.monotonic() + RECLAIM_PATIENCE
        answer, why = None, ''
        while answer is None and time.monotonic() < deadline:
            try:
                rospy.wait_for_service(service, timeout=max(0.1, deadline - time.monotonic()))
                answer = rospy.ServiceProxy(service, Reclaim)(request)
            except (rospy.ROSException, rospy.ServiceException, OSError) as err:
                why = str(err)
        if answer is None:
            states = ['unknown'] * len(ids)
            why = '%s did not answer within %.0f s (%s)' % (service, RECLAIM_PATIENCE, why)
        elif answer.code != 0:
            states = ['unknown'] * len(ids)
            why = '%s refused: %s' % (service, answer.message)
        else:
            states = list(answer.states)
        for query, state in zip(queries, states):
            if state == ACTIVE.value:
                continue
            message = '%s resource %d was %s when %s came back%s' % (
                target_name(target), query.external_id, 'failed' if state == FAILED.value else 'gone', core.prefix,
                ': ' + why if why else '')
            self._pipeline.lost(target, query.external_id, message)
