"""The holder's side of a registrar: ask other registrars for resources, share equal calls, and release.

Equal calls share one *client query* and one remote resource; each call gets its
own local id. A call made while a load runs on the same thread is linked to that
load (``links.py``), unless the caller says ``link=False``.
"""
import threading
from typing import Callable, Dict, Hashable, List, Optional, Tuple

import rospy

from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.msg import RMPRequest
from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.keys import key_of
from temoto_core.rr.links import Links
from temoto_core.rr.messages import clone, legal_name, service_class, shallow_copy
from temoto_core.rr.query import ACTIVE, FAILED, GONE, LOADING, ClientQuery, ServerQuery, Target, target_name
from temoto_core.rr.recorder import Recorder
from temoto_core.rr.status import StatusEvent
from temoto_core.srv import UnloadResource

StatusCallback = Callable[[StatusEvent], None]


class ClientSide:
    def __init__(self, core: RegistrarCore, links: Links, header: RMPRequest, recorder: Recorder) -> None:
        self._core = core
        self._links = links
        self._recorder = recorder
        self._header = header     # the same for every request of this registrar; never mutated
        self.by_key: Dict[Tuple[Target, Hashable], ClientQuery] = {}
        self.by_local: Dict[int, ClientQuery] = {}
        self.by_external: Dict[Tuple[Target, int], ClientQuery] = {}
        self._proxies: Dict[str, List[rospy.ServiceProxy]] = {}
        self._proxies_lock = threading.Lock()
        # set by the status receiver: statuses that overtook the response announcing their resource
        self.take_parked: Callable[[Target, int], list] = lambda target, external_id: []
        self.deliver: Callable[[object], None] = lambda msg: None

    # ------------------------------------------------------------------------------------------ call
    def call(self, rr_name: str, server_name: str, request, status_cb: Optional[StatusCallback],
             namespace: Optional[str], timeout: Optional[float], link: bool):
        core = self._core
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
        return self._call_remote(query, local_id, status_cb, parent, request, timeout)

    def _call_remote(self, query: ClientQuery, local_id: int, status_cb, parent: Optional[ServerQuery], request,
                     timeout: Optional[float]):
        core = self._core
        request = shallow_copy(request)      # the caller's object keeps its own header
        request.trr = self._header
        query.request = request              # what was asked, as sent (for the registry and for reloads)
        service = target_name(query.target)
        error = None
        try:
            response = self.invoke(service, request, timeout)
            if response.trr.code != 0:
                # the remote stack says what failed, once; this hop only adds where it was asked
                error = TemotoError.from_msgs(response.trr.error_stack, response.trr.message,
                                              ErrorCode.RESOURCE_FAILED, core.subsystem)
                error = error.extended(error.code, core.subsystem, '%s refused the request' % service, core.prefix)
        except TemotoError as err:
            error = err
        with core.lock:
            if error is not None:
                query.move(FAILED)
                query.error = error
                if self.by_key.get((query.target, query.key)) is query:
                    del self.by_key[(query.target, query.key)]
                core.notify_change()
                raise error
            query.response = response
            query.external_id = response.trr.resource_id
            query.move(ACTIVE)
            self.by_external[(query.target, query.external_id)] = query
            out = self._attach(query, local_id, status_cb, parent)
            parked = self.take_parked(query.target, query.external_id)
            core.notify_change()
        for msg in parked:
            self.deliver(msg)
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
    def invoke(self, service: str, request, timeout: Optional[float]):
        """One service call on a pooled persistent connection; one retry on a stale one."""
        srv_class = service_class(request)
        for attempt in (1, 2):
            proxy = self._take_proxy(service, srv_class, timeout)
            try:
                response = proxy.call(request)
            except (rospy.ServiceException, rospy.ROSException, OSError) as err:
                proxy.close()
                if attempt == 2 or not _service_exists(service):
                    raise self._core.error(ErrorCode.SERVICE_REQ_FAIL, 'call to %s failed: %s (did the server '
                                           'die?)' % (service, err))
                continue
            with self._proxies_lock:
                self._proxies.setdefault(service, []).append(proxy)
            return response
        raise AssertionError('unreachable')

    def _take_proxy(self, service: str, srv_class, timeout: Optional[float]) -> rospy.ServiceProxy:
        with self._proxies_lock:
            idle = self._proxies.setdefault(service, [])
            if idle:
                return idle.pop()
        try:
            rospy.wait_for_service(service, timeout=timeout if timeout is not None else 3.0)
        except rospy.ROSException:
            raise self._core.error(ErrorCode.SERVICE_REQ_FAIL, 'service %s does not exist: is its manager '
                                   'running?' % service)
        return rospy.ServiceProxy(service, srv_class, persistent=True)

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
        ns, rr_name, server_name = query.target
        request = UnloadResource._request_class(server_name=server_name, resource_id=query.external_id)
        try:
            response = self.invoke('/%s/%s/unload' % (ns, rr_name), request, 1.0)
        except TemotoError as err:
            raise err.extended(ErrorCode.RESOURCE_UNLOAD_FAIL, core.subsystem, 'could not unload %s resource %d'
                               % (target_name(query.target), query.external_id), core.prefix)
        if response.code != 0:
            raise TemotoError.from_msgs(response.error_stack, response.message).extended(
                ErrorCode.RESOURCE_UNLOAD_FAIL, core.subsystem, 'unloading %s resource %d failed'
                % (target_name(query.target), query.external_id), core.prefix)

    def loading_from(self, target: Target) -> bool:
        """Whether a call to ``target`` is still waiting for its response (lock held)."""
        return any(q.target == target and q.state is LOADING for q in self.by_key.values())


def _service_exists(service: str) -> bool:
    try:
        rospy.wait_for_service(service, timeout=0.5)
        return True
    except rospy.ROSException:
        return False
