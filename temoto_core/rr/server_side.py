"""The owner's side of a registrar: serve loads, share equal requests, release consumers, unload in cascade.
An owner's status goes to the consumers through ``status_pipeline.py``.

Each unique request becomes a *server query* with an internal id (what the owner
sees); each consumer gets its own external id (what it holds). An equal request
that arrives while the first is loading waits for the outcome and gets the full
response, never a half-filled one.
"""
import http.client
import xmlrpc.client
from typing import Callable, Dict, Optional, Tuple

import rosgraph
import rospy

from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.master_lookup import lookup_node
from temoto_core.rr.channels import MasterAway, StatusChannels
from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.links import Links
from temoto_core.rr.messages import as_sent, legal_name, node_uri
from temoto_core.rr.query import (ACTIVE, FAILED, GONE, LOADING, UNLOADING, Consumer, Server, ServerQuery)
from temoto_core.rr.recorder import Recorder
from temoto_core.srv import Reclaim


class ServerSide:
    def __init__(self, core: RegistrarCore, links: Links, channels: StatusChannels,
                 release_held: Callable[[int], None], recorder: Recorder,
                 record_of: Optional[Callable[[ServerQuery], str]] = None) -> None:
        self._core = core
        self._links = links
        self._channels = channels
        self.recorder = recorder
        self._release_held = release_held         # the client side's unload: cascade and rollback go through it
        # the record its consumers keep of each resource (backup.record), for a registrar that can come back
        self.record_of: Callable[[ServerQuery], str] = record_of or (lambda query: '')
        self.servers: Dict[str, Server] = {}
        self.by_internal: Dict[int, ServerQuery] = {}
        self.by_external: Dict[Tuple[str, int], ServerQuery] = {}
        # loads being served, by consumer incarnation (its node name and URI): a consumer that gave up on a
        # call reads this before it decides that what the registry says it holds is all it will ever hold
        self.calls_in_flight: Dict[Tuple[str, str], int] = {}
        self._node, self._node_uri = rospy.get_name(), rospy.get_node_uri() or ''   # who answers: see owners.py

    # ------------------------------------------------------------------------------------------ load
    def handle_load(self, server: Server, request):
        core = self._core
        response = server.srv_type._response_class()
        try:
            core.validate_header(request.trr)
        except TemotoError as err:
            return failure_response(response, err)
        consumer = Consumer(request.trr.status_topic, request.trr.client_name, request.trr.temoto_namespace,
                            request.trr.client_uri or self._calling_incarnation(request.trr.client_name),
                            request.trr.incarnation)
        # The consumer's status channel is connected before it is attached to anything: a FAILED raised
        # the moment after it is attached must find a subscriber to go to. Every path below that does not
        # attach the consumer gives the channel back.
        try:
            self._channels.acquire(consumer.status_topic, master_needed=True)
        except MasterAway as err:
            rospy.logwarn('%s: refused a load from %s: %s', core.prefix, consumer.client_name, err)
            return failure_response(response, core.error(ErrorCode.RR_FAIL, str(err)))
        attached = False
        caller = (consumer.client_name, consumer.uri)
        with core.lock:
            self.calls_in_flight[caller] = self.calls_in_flight.get(caller, 0) + 1
        try:
            response = self._serve(server, request, response, consumer)
            attached = response.trr.code == 0
            return response
        finally:
            with core.lock:
                left = self.calls_in_flight.pop(caller) - 1
                if left:
                    self.calls_in_flight[caller] = left
            if not attached:
                self._channels.release(consumer.status_topic)

    def _calling_incarnation(self, client_name: str) -> str:
        """The URI the master has under ``client_name`` now, while it calls: a client that sends no URI (one
        not built on a registrar) is known by the incarnation that made the request. Resolved later, the name
        could already belong to a new incarnation that started under it, which would then be charged with
        the dead one's references, and they would never be released. '' (resolved by the consumer watch)
        when the master does not answer within 0.5 s or does not know the name."""
        if not client_name:
            return ''
        try:
            return lookup_node(rosgraph.get_master_uri(), client_name, timeout=0.5) or ''
        except (OSError, xmlrpc.client.Error, http.client.HTTPException) as err:
            rospy.logdebug('%s: no URI for consumer %s yet: %s', self._core.prefix, client_name, err)
            return ''

    def _serve(self, server: Server, request, response, consumer: Consumer):
        core = self._core
        key = server.key(request)
        with core.lock:
            if core.closed:
                return failure_response(response, core.error(ErrorCode.SHUTDOWN, 'registrar is shutting down'))
            external_id = core.ids.next()
            while True:
                query = server.by_key.get(key)
                if query is None:
                    # rospy deserialised this request for this call alone: it can be kept as it is
                    query = ServerQuery(server, key, core.ids.next(), request)
                    server.by_key[key] = query
                    self.by_internal[query.internal_id] = query
                    break
                if query.state is ACTIVE:
                    return self._attach(query, external_id, consumer)
                # loading: wait for its outcome; unloading: wait until it is gone, then load anew
                shared = query
                while shared.state in (LOADING, UNLOADING):
                    core.wait_for_change()
                if shared.state is FAILED and shared.failure is not None and shared.response is None:
                    return failure_response(response, shared.failure.extended(
                        ErrorCode.RESOURCE_FAILED, core.subsystem, 'shared load of %s failed' % server.name,
                        core.prefix))
        return self._load_new(server, query, external_id, consumer, request, response)

    def _load_new(self, server: Server, query: ServerQuery, external_id: int, consumer: Consumer, request,
                  response):
        core = self._core
        response.trr.resource_id = query.internal_id
        error = None
        with self._links.loading(query):
            try:
                server.load_cb(request, response)
            except TemotoError as err:
                error = err.extended(ErrorCode.RESOURCE_FAILED, core.subsystem, 'loading %s failed' % server.name,
                                     core.prefix)
            except Exception as err:  # an owner bug must not kill the service thread or leave a loading query
                rospy.logerr('%s: load callback of %s raised %r', core.prefix, server.name, err)
                error = TemotoError(ErrorCode.LOAD_CALLBACK, core.subsystem, 'load callback of %s raised %s: %s'
                                    % (server.name, type(err).__name__, err), prefix=core.prefix)
        with core.lock:
            if error is None and query.failure is None:
                # a sub-resource that failed during the load fails it only if the callback still holds it:
                # a callback may release a failed candidate and go on with another
                held = [query.link_failures[i] for i in query.links if i in query.link_failures]
                query.failure = held[0] if held else None
            if error is None and query.failure is not None:
                error = query.failure.extended(ErrorCode.RESOURCE_FAILED, core.subsystem,
                                               'a sub-resource of %s failed while it was loading' % server.name,
                                               core.prefix)
            if error is not None:
                query.move(FAILED)
                query.failure = error
                rollback = list(query.links)
                self._forget(query)
            else:
                response.trr.resource_id = query.internal_id
                response.trr.code = 0
                query.response = response
                query.move(ACTIVE)
                query.backup = self.record_of(query)      # its links are all made: loads link while loading
                rollback = []
            core.notify_change()
            if error is None:
                return self._attach(query, external_id, consumer)
        for local_id in rollback:
            self._release_quietly(local_id, 'rolling back the failed load of %s' % server.name)
        return failure_response(response, error)

    def _attach(self, query: ServerQuery, external_id: int, consumer: Consumer):
        query.consumers[external_id] = consumer
        self.by_external[(query.server.name, external_id)] = query
        self.recorder.attached(query, external_id, consumer)
        return as_sent(query.response, external_id, query.backup, self._node, self._node_uri, self._core.incarnation)

    # ------------------------------------------------------------------------------------------ unload
    def release_consumer(self, server_name: str, external_id: int) -> None:
        """One consumer leaves; the last one out runs the unload callback and the cascade."""
        core = self._core
        with core.lock:
            if server_name not in self.servers:
                raise core.error(ErrorCode.UNKNOWN_SERVER, 'registrar %s has no server %r (servers: %s)'
                                 % (core.name, server_name, ', '.join(sorted(self.servers)) or 'none'))
            query = self.by_external.get((server_name, external_id))
            if query is None:
                raise core.error(ErrorCode.RESOURCE_NOT_FOUND, 'no resource %d on %s/%s: unknown or already '
                                 'unloaded' % (external_id, core.name, server_name))
            consumer = query.consumers.pop(external_id)
            del self.by_external[(server_name, external_id)]
            self.recorder.detached(server_name, external_id)
            self._channels.release(consumer.status_topic)
            if query.consumers:
                return
            query.move(UNLOADING)
        errors = []
        try:
            query.server.unload_cb(query.request, query.response)
        except TemotoError as err:
            errors.append(err)
        except Exception as err:
            rospy.logerr('%s: unload callback of %s raised %r', core.prefix, server_name, err)
            errors.append(core.error(ErrorCode.RESOURCE_UNLOAD_FAIL, 'unload callback raised %r' % err))
        for local_id in list(query.links):
            try:
                self._release_held(local_id)
            except TemotoError as err:
                errors.append(err)
        with core.lock:
            query.move(GONE)
            self._forget(query)
            core.notify_change()
        if errors:
            # the registry is consistent whatever failed; report the first failure
            raise errors[0].extended(ErrorCode.RESOURCE_UNLOAD_FAIL, core.subsystem,
                                     'unloading %s resource %d: %d step(s) failed' % (server_name, external_id,
                                                                                     len(errors)), core.prefix)

    def _forget(self, query: ServerQuery) -> None:
        """Drop a query from every index (lock held)."""
        if query.server.by_key.get(query.key) is query:
            del query.server.by_key[query.key]
        if query.state in (GONE, UNLOADING) or not query.consumers:
            self.by_internal.pop(query.internal_id, None)
        self._links.forget_parent(query)
        if query.state in (GONE, UNLOADING):
            self.recorder.gone(query)
            for ext, consumer in list(query.consumers.items()):
                self.by_external.pop((query.server.name, ext), None)
                self._channels.release(consumer.status_topic)
            query.consumers.clear()

    def _release_quietly(self, local_id: int, why: str) -> None:
        try:
            self._release_held(local_id)
        except TemotoError as err:
            rospy.logwarn('%s: %s: %s', self._core.prefix, why, err)

    def served(self, internal_id: int) -> Optional[ServerQuery]:
        """The query of served resource ``internal_id``, if there is one."""
        with self._core.lock:
            return self.by_internal.get(internal_id)

    # ------------------------------------------------------------------------------------------ reclaim
    def reclaim(self, req):
        """Hand the resources of a holder's previous incarnation to its new one.

        Fenced: refused whole if any of them is held by a *newer* incarnation of that
        holder (the claimant is a stale process). Per id, the answer says whether it
        is still active; one that failed while its holder was down is ``failed``, and
        one this registrar does not know under that holder's name is ``unknown``.
        """
        core = self._core
        if req.incarnation <= 0:
            return Reclaim._response_class(code=1, message='incarnation %d: only a registrar with a journal can '
                                                           'reclaim' % req.incarnation)
        for label, value in (('client_name', req.client_name), ('status_topic', req.status_topic)):
            if not legal_name(value):
                return Reclaim._response_class(code=1, message='%s %r is not a legal ROS name' % (label, value))
        if not node_uri(req.client_uri):
            return Reclaim._response_class(code=1, message='client_uri %r is not a node URI' % req.client_uri)
        response = Reclaim._response_class(code=0, message='')
        moved = []
        with core.lock:
            claims = []
            for external_id in req.resource_ids:
                query = self.by_external.get((req.server_name, external_id))
                consumer = query.consumers.get(external_id) if query is not None else None
                if consumer is None or consumer.client_name != req.client_name:
                    claims.append((external_id, None, None))
                    continue
                if consumer.incarnation > req.incarnation:
                    return Reclaim._response_class(code=1, message='stale incarnation %d of %s: resource %d is held '
                                                   'by its incarnation %d' % (req.incarnation, req.client_name,
                                                                              external_id, consumer.incarnation))
                claims.append((external_id, query, consumer))
            for external_id, query, consumer in claims:
                if consumer is None:
                    response.states.append('unknown')
                    continue
                moved.append((consumer.status_topic, req.status_topic))
                consumer.uri, consumer.status_topic = req.client_uri, req.status_topic
                consumer.incarnation = req.incarnation
                self.recorder.reattached(query, external_id, consumer)
                response.states.append(ACTIVE.value if query.state is ACTIVE else FAILED.value)
        for old, new in moved:
            self._channels.acquire(new)
            self._channels.release(old)
        rospy.loginfo('%s: %s (incarnation %d) reclaimed %d %s resource(s)', core.prefix, req.client_name,
                      req.incarnation, len(moved), req.server_name)
        return response

    def consumer(self, server_name: str, external_id: int) -> Optional[Consumer]:
        with self._core.lock:
            query = self.by_external.get((server_name, external_id))
            return query.consumers.get(external_id) if query is not None else None


def failure_response(response, error: TemotoError):
    response.trr.code = 1
    response.trr.message = str(error)
    response.trr.resource_id = 0
    response.trr.error_stack = error.to_msgs()
    return response
