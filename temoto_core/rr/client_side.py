"""The holder's side of a registrar: ask other registrars for resources, share equal calls, and release.

Equal calls share one *client query* and one remote resource; each call gets its
own local id. A call made while a load runs on the same thread is linked to that
load (``links.py``), unless the caller says ``link=False``.
"""
import json
import threading
import time
import xmlrpc.client
from typing import Callable, Dict, List, Optional, Tuple

import rospy
from rospy.exceptions import TransportException

from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.msg import RMPRequest
from temoto_core.rr.core import RegistrarCore
from temoto_core import service_uris
from temoto_core.rr.deadlines import DEFAULT_DEADLINE, WATCH, connect, load_deadline, unload_deadline
from temoto_core.rr.keys import key_of
from temoto_core.rr.links import Links
from temoto_core.rr.messages import clone, legal_name, service_class, shallow_copy
from temoto_core.rr.owners import OwnerWatch, owned_by
from temoto_core.rr.query import (ACTIVE, FAILED, GONE, LOADING, ClientQuery, HeldQueries, ServerQuery, Target,
                                  target_name)
from temoto_core.rr.recorder import Recorder
from temoto_core.rr.status import StatusEvent
from temoto_core.rr.status_pipeline import StatusPipeline
from temoto_core.srv import GetRegistry, UnloadResource

StatusCallback = Callable[[StatusEvent], None]

# how often a call polls the master for a service that is not registered yet (its manager is starting)
SERVICE_POLL = 0.05
# how long a call to an owner found lost asks it once more before it fails (it may be back since the last check)
RECHECK_BOUND = 0.2
UNKNOWN_SERVICE = 'the master does not know it'


class ClientSide:
    def __init__(self, core: RegistrarCore, links: Links, held: HeldQueries, header: RMPRequest,
                 recorder: Recorder, pipeline: StatusPipeline, default_deadline: float = DEFAULT_DEADLINE) -> None:
        self._core = core
        self.default_deadline = default_deadline
        self._links = links
        self._recorder = recorder
        # statuses that overtook the response announcing their resource are parked there, and a FAILED found in
        # an owner's registry is handed to it as if its status had arrived
        self._pipeline = pipeline
        self._header = header     # the same for every request of this registrar; never mutated
        self.held = held
        self.by_key, self.by_local, self.by_external = held.by_key, held.by_local, held.by_external
        self._proxies: Dict[str, List[rospy.ServiceProxy]] = {}
        self._proxies_lock = threading.Lock()
        # The one part given after construction: the owner watch needs this side's holdings and its unloads,
        # and this side's calls need the watch's verdicts. The registrar calls watch_owners() right after.
        self.owners: Optional[OwnerWatch] = None

    def watch_owners(self, owners: OwnerWatch) -> None:
        self.owners = owners

    # ------------------------------------------------------------------------------------------ call
    def call(self, rr_name: str, server_name: str, request, status_cb: Optional[StatusCallback],
             namespace: Optional[str], deadline: Optional[float], link: bool):
        core = self._core
        if deadline is not None and not deadline > 0:
            raise core.error(ErrorCode.BAD_REQUEST, 'deadline %r: a call needs a positive deadline in seconds'
                             % (deadline,))
        ns = (namespace if namespace is not None else core.namespace).strip('/')
        for label, value in (('registrar', rr_name), ('server', server_name)):
            if not legal_name(value, base=True):
                raise core.error(ErrorCode.BAD_REQUEST, 'illegal %s name %r' % (label, value))
        if (ns, rr_name) == (core.namespace, core.name):
            raise core.error(ErrorCode.NESTED_CALL, 'registrar %s cannot request a resource from itself (%s); '
                             'the original forbids it and it would deadlock' % (core.name, server_name))
        if not hasattr(request, 'trr'):
            raise core.error(ErrorCode.BAD_REQUEST, 'request %s has no trr header' % type(request).__name__)
        target = (ns, rr_name, server_name)
        key = key_of(request)
        parent = self._links.current() if link else None
        with core.lock:
            if core.closed:
                raise core.error(ErrorCode.SHUTDOWN, 'registrar %s is shut down' % core.name)
            local_id = core.ids.next()
            while True:
                query = self.by_key.get((target, key))
                if query is None:
                    query = ClientQuery(target, key, None)
                    self.by_key[(target, key)] = query
                    break
                if query.state is ACTIVE:
                    return self._attach(query, local_id, status_cb, parent)
                shared = query
                while shared.state is LOADING:
                    core.wait_for_change()
                if shared.state is FAILED and shared.error is not None and shared.response is None:
                    raise shared.error
        seconds = deadline if deadline is not None else load_deadline(request, self.default_deadline)
        return self._call_remote(query, local_id, status_cb, parent, request, seconds)

    def _call_remote(self, query: ClientQuery, local_id: int, status_cb, parent: Optional[ServerQuery], request,
                     seconds: float):
        core = self._core
        request = shallow_copy(request)      # the caller's object keeps its own header
        request.trr = self._header
        query.request = request              # what was asked, as sent (for the registry and for reloads)
        service = target_name(query.target)
        error = None
        try:
            response = self.invoke(service, request, seconds)
            if response.trr.code != 0:
                # the remote stack says what failed, once; this hop only adds where it was asked
                error = TemotoError.from_msgs(response.trr.error_stack, response.trr.message,
                                              ErrorCode.RESOURCE_FAILED, core.subsystem)
                error = error.extended(error.code, core.subsystem, '%s refused the request' % service, core.prefix)
        except TemotoError as err:
            error = err
        with core.lock:
            late = error is None and core.closed
            if late:
                # the registrar shut down while this load was on its way: its shutdown released what it held
                # then, so nothing here would ever release this one (a plugin's failover that outlived its
                # action, docs/failures.md): it is given back at once, and the caller hears why
                query.response, query.external_id = response, response.trr.resource_id
                error = core.error(ErrorCode.SHUTDOWN, 'registrar %s shut down while %s was loading; the resource '
                                   'it answered with is released' % (core.name, service))
            if error is not None:
                query.move(FAILED)
                query.error = error
                if self.by_key.get((query.target, query.key)) is query:
                    del self.by_key[(query.target, query.key)]
                core.notify_change()
            else:
                query.response = response
                query.external_id = response.trr.resource_id
                query.move(ACTIVE)
                self.by_external[(query.target, query.external_id)] = query
                out = self._attach(query, local_id, status_cb, parent)
                parked = self._pipeline.take_parked(query.target, query.external_id)
                core.notify_change()
        if late:
            try:
                self._send_unload(query)
            except TemotoError as err:
                rospy.logwarn('%s: %s', core.prefix, err)
            self.close_proxies()        # the shutdown closed the pool once; the unload's connection goes too
        if error is not None:
            raise error
        if self.owners is not None:
            self.owners.notice(response.trr.owner_node, response.trr.owner_uri, response.trr.owner_incarnation)
        for msg in parked:
            self._pipeline.receive(msg)
        return out

    def _attach(self, query: ClientQuery, local_id: int, status_cb, parent: Optional[ServerQuery]):
        query.local_ids[local_id] = status_cb
        self.by_local[local_id] = query
        if parent is not None:
            self._links.attach(local_id, parent)
        self._recorder.held(local_id, query, parent)
        out = clone(query.response)     # the caller may change it; the shared copy must not change
        out.trr.resource_id = local_id
        return out

    def link(self, local_id: int) -> None:
        """Make held ``local_id`` a sub-resource of the load running on this thread."""
        core = self._core
        parent = self._links.current()
        with core.lock:
            query = self.by_local.get(local_id)
            if query is None:
                raise core.error(ErrorCode.RESOURCE_NOT_FOUND, 'link: %s holds no resource with id %d'
                                 % (core.name, local_id))
            if parent is None:
                raise core.error(ErrorCode.BAD_REQUEST, 'link: no load is running on this thread to link '
                                 'resource %d to' % local_id)
            if self._links.parent_of(local_id) is not None:
                raise core.error(ErrorCode.BAD_REQUEST, 'link: resource %d is already linked' % local_id)
            if query.state is not ACTIVE:
                raise core.error(ErrorCode.RESOURCE_FAILED, 'link: resource %d (%s) is %s'
                                 % (local_id, target_name(query.target), query.state))
            self._links.attach(local_id, parent)
            self._recorder.linked(local_id, parent)

    # ------------------------------------------------------------------------------------------ transport
    def invoke(self, service: str, request, seconds: float, watched: bool = True):
        """One service call on a pooled persistent connection, within ``seconds`` (``deadlines.py``): one
        retry on a connection found stale, if time is left. ``watched``: the owner watch counts the call
        (``owners.py``), which a reconciliation's own reads must not."""
        core = self._core
        deadline = time.monotonic() + seconds
        srv_class = service_class(request)
        registrar = registrar_of(service)
        owners = self.owners if watched else None
        for attempt in (1, 2):
            # counted from before the connection: a stopped owner is found lost (and the connection attempts
            # end) within the liveness bound, not the call's whole deadline
            owner = owners.calling(owners.serving(registrar), registrar) if owners is not None else None
            guard = None
            try:
                proxy = self._take_proxy(service, srv_class, deadline, seconds)
                peer = getattr(proxy.transport, 'callerid_pub', '')   # the node serving it, from the TCPROS header
                if owners is not None and (owner is None or owner.node != peer):
                    owners.done_calling(owner, True)
                    owner = owners.calling(peer, registrar)
                with WATCH.guard(proxy.transport.socket, deadline, peer) as guard:
                    response = proxy.call(request)
            # rospy turns a socket error while sending into TransportTerminated, which is not a ROSException:
            # a pooled connection to an owner that died broke a chaos client's load with it (seed 17, step 1506)
            except (rospy.ServiceException, rospy.ROSException, TransportException, OSError) as err:
                proxy.close()
                if guard is not None and guard.expired:
                    raise core.error(ErrorCode.TIMEOUT, 'no answer from %s within its deadline of %.2f s'
                                     % (service, seconds))
                if guard is not None and guard.aborted:
                    raise core.error(ErrorCode.SERVICE_REQ_FAIL, 'call to %s cut short: %s' % (service, guard.aborted))
                if attempt == 2 or not self._service_exists(service, deadline):
                    raise core.error(ErrorCode.SERVICE_REQ_FAIL, 'call to %s failed: %s (did the server '
                                     'die?)' % (service, err))
                # the other idle connections lead to the same server, so they are as stale as this one (a
                # restarted owner): the retry, and the calls after it, connect afresh
                self._drop_idle(service)
                continue
            finally:
                if owners is not None:
                    # a call that was cut may have been served anyway: the owner is then checked (owners.py)
                    owners.done_calling(owner, guard is None or not (guard.expired or guard.aborted))
            if guard.expired or guard.aborted:      # answered as it was cut: the connection is not reusable
                proxy.close()
            else:
                with self._proxies_lock:
                    self._proxies.setdefault(service, []).append(proxy)
            return response
        raise AssertionError('unreachable')

    def _take_proxy(self, service: str, srv_class, deadline: float, seconds: float) -> rospy.ServiceProxy:
        registrar = registrar_of(service)
        why = UNKNOWN_SERVICE
        while True:                 # a manager that is starting has not registered its service yet
            # an owner known lost is not tried, not even on a connection that is still open
            lost = self.owners.unreachable(registrar) if self.owners is not None else ''
            if lost:
                lost = self.owners.recheck(registrar, max(0.01, min(RECHECK_BOUND, deadline - time.monotonic())))
            if lost:
                raise self._core.error(ErrorCode.SERVICE_REQ_FAIL, 'service %s is not tried: %s' % (service, lost))
            with self._proxies_lock:
                idle = self._proxies.setdefault(service, [])
                if idle:
                    return idle.pop()
            try:
                proxy = connect(service, srv_class, deadline)
            except (OSError, rospy.ServiceException, xmlrpc.client.Error) as err:
                proxy, why = None, str(err)
            if proxy is not None:
                return proxy
            if time.monotonic() + SERVICE_POLL > deadline:
                if why == UNKNOWN_SERVICE:
                    raise self._core.error(ErrorCode.SERVICE_REQ_FAIL, 'service %s does not exist (the master did '
                                           'not know it within %.2f s): is its manager running?' % (service, seconds))
                raise self._core.error(ErrorCode.SERVICE_REQ_FAIL, 'service %s could not be reached within %.2f s '
                                       '(%s): is its manager running?' % (service, seconds, why))
            time.sleep(SERVICE_POLL)

    def _drop_idle(self, service: str) -> None:
        with self._proxies_lock:
            stale = self._proxies.pop(service, [])
        for proxy in stale:
            proxy.close()

    def _service_exists(self, service: str, deadline: float) -> bool:
        try:
            return bool(service_uris.lookup(service, min(deadline, time.monotonic() + 0.5)))
        except (OSError, xmlrpc.client.Error):
            return False

    def close_proxies(self) -> None:
        with self._proxies_lock:
            for proxies in self._proxies.values():
                for proxy in proxies:
                    proxy.close()
            self._proxies.clear()

    # ------------------------------------------------------------------------------------------ unload
    def unload(self, local_id: int, send: bool = True) -> Optional[ClientQuery]:
        """Release ``local_id``; the last local holder out unloads the remote resource (unless ``send`` is
        false: its owner is known to be unreachable)."""
        core = self._core
        with core.lock:
            query = self.by_local.pop(local_id, None)
            if query is None:
                raise core.error(ErrorCode.RESOURCE_NOT_FOUND, '%s holds no resource with id %d (unknown or '
                                 'already unloaded)' % (core.name, local_id))
            del query.local_ids[local_id]
            self._links.detach(local_id)
            self._recorder.released(local_id)
            if query.local_ids:
                return None
            if self.by_key.get((query.target, query.key)) is query:
                del self.by_key[(query.target, query.key)]
            self.by_external.pop((query.target, query.external_id), None)
            query.move(GONE)
            core.notify_change()
        if send:
            self._send_unload(query)
        return query

    def _send_unload(self, query: ClientQuery) -> None:
        core = self._core
        try:
            response = self._unload_remote(query.target, query.external_id, query.request)
            refused = TemotoError.from_msgs(response.error_stack, response.message) if response.code != 0 else None
            if refused is not None and refused.code == ErrorCode.RECOVERING:
                raise refused             # not taken yet: owed, as to an owner out of reach
        except TemotoError as err:
            # not delivered: owed to the owner, and sent again once it answers (owners.py)
            owed = ''
            if self.owners is not None and query.response is not None:
                self.owners.owe(query.response.trr.owner_node, query.target, query.external_id)
                owed = ' now (released here; the unload is sent again when its owner answers)'
            raise err.extended(ErrorCode.RESOURCE_UNLOAD_FAIL, core.subsystem, 'could not unload %s resource %d%s'
                               % (target_name(query.target), query.external_id, owed), core.prefix)
        if refused is not None and any(frame.code == ErrorCode.RESOURCE_NOT_FOUND for frame in response.error_stack):
            # the owner let it go already (a consumer it could not reach, a FAILED it cleaned up during a
            # partition): gone there and here, which is what the unload asked for
            rospy.loginfo('%s: %s resource %d was gone at its owner already: %s', core.prefix,
                          target_name(query.target), query.external_id, response.message)
            return
        if refused is not None:
            raise refused.extended(ErrorCode.RESOURCE_UNLOAD_FAIL, core.subsystem, 'unloading %s resource %d failed'
                                   % (target_name(query.target), query.external_id), core.prefix)

    def _unload_remote(self, target: Target, external_id: int, load_request):
        ns, rr_name, server_name = target
        request = UnloadResource._request_class(server_name=server_name, resource_id=external_id)
        seconds = unload_deadline(load_request, self.default_deadline) if load_request is not None \
            else self.default_deadline
        return self.invoke('/%s/%s/unload' % (ns, rr_name), request, seconds)

    def resend_unload(self, target: Target, external_id: int) -> bool:
        """An owed unload, sent again: True once the owner answered (it may no longer know the resource),
        False if it still cannot be reached, or is still taking its registry back (the resource may be on its
        way back there)."""
        try:
            response = self._unload_remote(target, external_id, None)
        except TemotoError:
            return False
        if response.code != 0 and any(frame.code == ErrorCode.RECOVERING for frame in response.error_stack):
            return False
        if response.code != 0:
            rospy.loginfo('%s: owed unload of %s resource %d: %s', self._core.prefix, target_name(target),
                          external_id, response.message)
        return True

    def reconcile_with(self, registrar: Tuple[str, str], quiet: Callable[[], bool]) -> bool:
        """Release what ``registrar`` says this node incarnation holds there and this side does not know of:
        a load answered after its caller gave up on it, or an unload lost in a partition. Only while
        ``quiet()``: a call in flight may hold an id this side has not seen yet. True once done."""
        core = self._core
        ns, rr_name = registrar
        try:
            snapshot = json.loads(self.invoke('/%s/%s/registry' % registrar, GetRegistry._request_class(),
                                              self.default_deadline, watched=False).json)
        except (TemotoError, ValueError) as err:
            # read again at the owner's next answer; a read that keeps failing leaves what the owner holds for
            # this node unreconciled, so it is told, at most every 5 s (chaos seed 17, step 6429, left a stray
            # reference and, at debug level, no trace of why)
            rospy.logwarn_throttle(5.0, '%s: could not read /%s/%s/registry to reconcile with it: %s'
                                   % (core.prefix, ns, rr_name, err))
            return False
        if snapshot.get('recovering'):
            return False              # its registry is being rebuilt: what failed while it was down shows later
        mine = self._header.client_uri
        in_flight = snapshot.get('calls_in_flight')
        if in_flight is None:         # an owner that does not say: any load there may be one this node gave up on
            in_flight = [[self._header.client_name, mine, 1]] if any(
                query.get('state') == LOADING.value for query in snapshot.get('server_queries', [])) else []
        if any(name == self._header.client_name and uri == mine for name, uri, _ in in_flight):
            # a load this node gave up on is still being served there: later. Only this node's: an owner
            # busy with other consumers' loads (a display waiting for its first frame) is read meanwhile
            return False
        served = [((ns, rr_name, query['server']), consumer['resource_id'], query)
                  for query in snapshot.get('server_queries', []) for consumer in query.get('consumers', [])
                  if consumer.get('client_uri') == mine and consumer.get('client_name') == self._header.client_name]
        with core.lock:
            strays = [(t, e) for t, e, _ in served if (t, e) not in self.by_external]
            unheard = [(t, e, q.get('failure') or '') for t, e, q in served if q.get('state') == FAILED.value
                       and (t, e) in self.by_external and self.by_external[(t, e)].state is not FAILED]
        if not quiet():
            return False
        unreleased = 0
        for target, external_id in strays:
            rospy.logwarn('%s: %s holds resource %d for this node, which does not know of it: releasing it',
                          core.prefix, target_name(target), external_id)
            if not self.resend_unload(target, external_id):
                unreleased += 1
        for target, external_id, why in unheard:
            message = '%s: FAILED at its owner%s; its status never reached this node' % (
                target_name(target), ' (%s)' % why if why else '')
            rospy.logwarn('%s: %s', core.prefix, message)
            self._pipeline.lost(target, external_id, message)
        # a release that did not reach the owner (it died or was cut off meanwhile) is not done: the owner stays
        # to be read again, and the stray is found and released at its next answer
        return unreleased == 0

    def holds_from(self, node: str) -> bool:
        with self._core.lock:
            return any(owned_by(q, node) for q in self.by_external.values())

    def held_from(self, node: str) -> List[Tuple[Target, int]]:
        with self._core.lock:
            return [(q.target, q.external_id) for q in self.by_external.values() if owned_by(q, node)]



def registrar_of(service: str) -> Tuple[str, str]:
    """``(namespace, registrar)`` of a registrar's service ``/<ns>/<rr>/<leaf>``."""
    parts = service.strip('/').split('/')
    return (parts[0], parts[1]) if len(parts) >= 3 else ('', '')
