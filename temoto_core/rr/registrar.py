"""The Resource Registrar: serve resources, share equal requests, record which resource depends on which,
unload in cascade, and carry status up every chain.

One registrar is embedded per subsystem (a manager node, or one action instance).
``ResourceRegistrar`` is a thin front over the parts, each in its own module:

======================  ================================================================================
``query.py``            the records, and the state machine every query follows
``server_side.py``      the owner's side: load, share, release, unload in cascade
``client_side.py``      the holder's side: call, share equal calls, release
``links.py``            which held resource belongs to which served one
``status_pipeline.py``  a status's way: sent by an owner, forwarded to consumers, received, delivered
``channels.py``         the status topics this registrar publishes to (a pool of publishers)
``liveness.py``         consumers that died without unloading
``owners.py``           owners cut off, stopped or dead: what is held from them fails, owed unloads wait
``deadlines.py``        every call's deadline, and the watch that cuts late calls
``keys.py``             request equality
``journal.py``          the crash-safe local record (SQLite); ``recorder.py`` writes every change to it
``recovery.py``         a restarted registrar: journal, reality, neighbours
======================  ================================================================================

A FAILED from a driver's exit travels through ``status_pipeline`` in each registrar
on its way: the ER Manager's ``send_status`` forwards it to each consumer of the
process; the Sensor Manager receives it, maps it to its own id, forwards it through
the link (``links``) to the sensor's consumers, and so on up to the action's callback.

The parts are built in dependency order, each given its collaborators: the holder's
tables (``HeldQueries``), the status pipeline that reads them, the client side, the
server side, the watches. One edge goes back: the client side and the owner watch
need each other (``ClientSide.watch_owners``).
"""
from typing import Callable, Dict, Optional

import rospy

from temoto_core import master_rejoin, watchdog
from temoto_core.master_reach import MasterReach
from temoto_core.errors import ErrorCode, ErrorFrame, Subsystem, TemotoError
from temoto_core.node import prime_log_parameter
from temoto_core.params import ParamError
from temoto_core.msg import RMPRequest, ResourceStatus
from temoto_core.rr import backup
from temoto_core.rr.channels import StatusChannels
from temoto_core.rr.client_side import ClientSide, StatusCallback
from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.keys import key_function, register_key
from temoto_core.rr.links import Links
from temoto_core.rr.journal import Journal, JournalContents
from temoto_core.rr.liveness import ConsumerWatch
from temoto_core.rr.messages import legal_name
from temoto_core.rr.owner_state import OwnerState
from temoto_core.rr.owners import OwnerWatch
from temoto_core.rr.query import ACTIVE, HeldQueries, Server, target_name
from temoto_core.rr.recorder import Recorder
from temoto_core.rr.recovery import RecoverCallback, Recovery, service_of
from temoto_core.rr.registry import ClientEntry, ConsumerEntry, RegistrySnapshot, ServerEntry, encode_message, readable
from temoto_core.rr.server_side import ServerSide
from temoto_core.rr.settings import RegistrarSettings
from temoto_core.rr.status_pipeline import StatusPipeline
from temoto_core.srv import GetRegistry, GetRegistryResponse, Reclaim, UnloadResource, UnloadResourceResponse

RESERVED_LEAVES = ('unload', 'status', 'registry', 'reclaim')


class ResourceRegistrar:
    """See the module docstring. ``rospy.init_node`` must have run in this process."""

    def __init__(self, name: str, namespace: Optional[str] = None, subsystem: int = Subsystem.CORE,
                 consumer_check_period: Optional[float] = None, status_connect_timeout: float = 2.0,
                 journal: Optional[str] = None, recovery_grace: Optional[float] = None,
                 call_deadline: Optional[float] = None, journal_pause: Optional[float] = None) -> None:
        """``journal``: the path of this registrar's journal (default: the ``~journal`` parameter; '' for none).
        With one, a restart of the node recovers the registry (``recovery.py``); ``resume()`` completes it.
        ``recovery_grace``: how long the resources of a dead consumer that keeps a journal are kept for it
        to come back (default: ``~recovery_grace``, 10 s).
        ``call_deadline``: the deadline of a call whose request type declares none (default:
        ``~call_deadline``, 1 s).
        ``journal_pause``: how long the journal's writer waits between two commits under a burst (default:
        ``~journal_pause``, ``recorder.COMMIT_PAUSE``); a longer pause costs less CPU and lags further."""
        prefix = '%s/%s' % (rospy.get_name(), name)
        try:
            # every setting read and checked before anything is built: opening the journal starts a new
            # incarnation, and a bad value must not cost one
            settings = self.settings = RegistrarSettings.read(namespace, journal, recovery_grace, call_deadline,
                                                              journal_pause, consumer_check_period)
        except ParamError as err:
            raise TemotoError(ErrorCode.BAD_REQUEST, subsystem, str(err), prefix=prefix)
        # a registrar warns when its owners' host is cut off, and then the master is often out of reach too:
        # its log calls must not ask the master (whatever started rospy in this process: node.py)
        prime_log_parameter()
        journal = self.journal_path = settings.journal
        try:
            master_rejoin.ensure_started()
        except ValueError as err:
            raise TemotoError(ErrorCode.BAD_REQUEST, subsystem, str(err), prefix=prefix)
        self._journal = Journal(journal, run_id=str(rospy.get_param('/run_id', ''))) if journal else None
        core = self._core = RegistrarCore(
            name, settings.namespace, subsystem, incarnation=self._journal.incarnation if self._journal else 0,
            id_floor=self._journal.id_floor if self._journal else 0)
        self.name, self.namespace, self.subsystem, self.prefix = core.name, core.namespace, core.subsystem, core.prefix
        self.status_topic = core.topic('status')
        self.incarnation = core.incarnation
        self._links = Links()
        held = HeldQueries()
        self._owner_state = OwnerState(self._journal.owner_state() if self._journal is not None else None)
        self._channels = StatusChannels(core.prefix, status_connect_timeout, MasterReach())
        recorder = self._recorder = Recorder(self._journal, settings.journal_pause)
        self._pipeline = StatusPipeline(core, self._links, held, self._channels, recorder, self.status_topic)
        header = RMPRequest(status_topic=self.status_topic, temoto_namespace=core.namespace,
                            client_name=rospy.get_name(), client_uri=rospy.get_node_uri() or '',
                            incarnation=core.incarnation)
        self._client = ClientSide(core, self._links, held, header, recorder, self._pipeline, settings.call_deadline)
        # only a registrar that can come back needs its neighbours to keep its records
        record_of = (lambda query: backup.record(query, held.by_local, self._owner_state)) \
            if self._journal is not None else None
        self._server = ServerSide(core, self._links, self._channels, self._client.unload, recorder, record_of)
        self._watch = ConsumerWatch(core, self._server, self._channels, self._pipeline,
                                    settings.consumer_check_period, settings.recovery_grace)
        try:
            self._owners = OwnerWatch(core, self._client.holds_from, self._client.held_from, self._pipeline.lost,
                                      self._client.resend_unload, self._client.reconcile_with,
                                      settings.owner_check_period, settings.owner_liveness_bound,
                                      settings.recovery_grace, settings.owner_busy_bound,
                                      hears_from=self._hears_from, hear_again=self._hear_again)
        except ValueError as err:
            raise core.error(ErrorCode.BAD_REQUEST, str(err))
        self._client.watch_owners(self._owners)
        self._recovery = None
        if self._journal is not None:
            reconciled = self._reconcile_with_neighbours(self._journal.contents())
            self._recovery = Recovery(core, reconciled.contents, self._server, self._client, self._links,
                                      self._channels, self._pipeline, header, stale=reconciled.stale,
                                      lost=reconciled.lost)
        # with a journal, the registry is being recovered until resume() is done (the registry says so)
        self._recovering = self._journal is not None
        self._status_sub = rospy.Subscriber(self.status_topic, ResourceStatus, self._pipeline.receive,
                                            queue_size=1000, tcp_nodelay=True)
        self._registry_srv = rospy.Service(core.topic('registry'), GetRegistry,
                                           lambda _req: GetRegistryResponse(json=self.registry().to_json()))
        self._unload_srv = None
        self._reclaim_srv = None
        watchdog.watch('the lock of registrar %s' % core.prefix, core.lock)

    def _hears_from(self, node: str) -> bool:
        """Whether this registrar's status subscriber has a connection from ``node`` (the node that published
        on it, as its TCPROS header names it)."""
        impl = getattr(getattr(self, '_status_sub', None), 'impl', None)
        if impl is None:
            return True                  # starting (nothing is held yet) or shut down: nothing to hear
        return any(getattr(c, 'callerid_pub', '') == node for c in impl.connections)

    def _hear_again(self) -> None:
        master_rejoin.refresh_subscription(self.status_topic, ResourceStatus._type)

    @property
    def journaled(self) -> bool:
        """This registrar keeps a journal, so its node recovers after a restart."""
        return self._journal is not None

    def _reconcile_with_neighbours(self, journal: JournalContents) -> backup.Reconciled:
        """The journal, checked against what the neighbours keep about this registrar (``backup.py``): the
        journal is written behind the registry, and consumers may have released what they held while this
        registrar was down. With an empty journal (a first start, or a lost journal), the neighbours' copies
        alone rebuild the registry; on a first start they keep nothing."""
        core = self._core
        kept = backup.gather(core.namespace, core.name, rospy.get_name(), core.ids.next, service_of)
        reconciled = backup.reconcile(journal, kept)
        if reconciled.added_served or reconciled.added_holds or reconciled.stale:
            rospy.logwarn('%s: the neighbours gave back %d served and %d held resource(s) the journal lacked, '
                          'and %d consumer(s) no longer hold what the journal says', core.prefix,
                          reconciled.added_served, reconciled.added_holds, len(reconciled.stale))
        for key, value in kept.owner_state.items():
            if key not in self._owner_state:
                self.put_owner_state(key, value)
        return reconciled

    # ------------------------------------------------------------------------------------------ owner state
    def owner_state(self) -> Dict[str, str]:
        """What the owner kept (:meth:`put_owner_state`), as the journal or the neighbours gave it back."""
        return self._owner_state.as_dict()

    def put_owner_state(self, key: str, value: str) -> None:
        """Keep ``value`` across a crash of this node: in the journal, and, for a key ``<kind>/<internal id>``,
        with that resource's record at its consumers (``backup.py``)."""
        self._owner_state[key] = value
        if self._journal is not None:
            self._journal.put_owner_state(key, value)

    def drop_owner_state(self, key: str) -> None:
        self._owner_state.pop(key)
        if self._journal is not None:
            self._journal.drop_owner_state(key)

    @property
    def consumer_check_period(self) -> float:
        return self._watch.period

    # ------------------------------------------------------------------------------------------ serving
    def add_server(self, server_name: str, srv_type, load_cb: Callable, unload_cb: Callable,
                   key: Optional[Callable] = None, recover: Optional[RecoverCallback] = None) -> None:
        """Advertise ``/<ns>/<rr>/<server_name>`` serving resources of ``srv_type``.

        ``load_cb(request, response)`` fills the response (``response.trr.resource_id``
        is preset to the owner's internal id) or raises :class:`TemotoError`.
        ``unload_cb(request, response)`` gets the stored pair when the last consumer
        leaves. ``key(request)`` replaces the default equality, for clients of this type
        too (``keys.register_key``); a manager's contract module normally registers it.
        ``recover(request, response)``, with a journal: checks a resource recorded by the
        previous incarnation against reality, and raises :class:`TemotoError` if it is gone.
        """
        core = self._core
        if not legal_name(server_name, base=True) or server_name in RESERVED_LEAVES:
            raise core.error(ErrorCode.BAD_REQUEST, 'illegal server name %r' % server_name)
        if key is not None:
            register_key(srv_type._request_class, key)
        with core.lock:
            if server_name in self._server.servers:
                raise core.error(ErrorCode.BAD_REQUEST, 'server %r already exists in registrar %r'
                                 % (server_name, core.name))
            server = Server(server_name, srv_type, load_cb, unload_cb, key_function(srv_type._request_class))
            self._server.servers[server_name] = server
            if self._unload_srv is None:
                self._unload_srv = rospy.Service(core.topic('unload'), UnloadResource, self._handle_unload)
                self._reclaim_srv = rospy.Service(core.topic('reclaim'), Reclaim, self._server.reclaim)
                self._watch.start()
        if self._recovery is not None:
            self._recovery.restore_server(server, recover)
        server.service = rospy.Service(core.topic(server_name), srv_type,
                                       lambda req: self._server.handle_load(server, req))

    def resume(self) -> None:
        """After a restart with a journal, once every server is added: take back from their owners the
        resources the previous incarnation held, and report FAILED whatever died meanwhile. A no-op
        without a journal."""
        if self._recovery is not None:
            self._recovery.resume()
        self._recovering = False

    def _handle_unload(self, req) -> UnloadResourceResponse:
        try:
            if self._recovering:
                # its servers are added one by one and their resources come back with them: an unload now may
                # name a server or a resource that is not back yet, and "unknown" would settle it for good while
                # the resource comes back a moment later (chaos seed 17, step 1098: a tracked object leaked so)
                raise self._core.error(ErrorCode.RECOVERING, 'registrar %s is taking its registry back after a '
                                       'restart: send the unload again' % self._core.name)
            self._server.release_consumer(req.server_name, req.resource_id)
        except TemotoError as err:
            return UnloadResourceResponse(code=1, message=str(err), error_stack=err.to_msgs())
        return UnloadResourceResponse(code=0, message='unloaded')

    def send_status(self, internal_id: int, code: int, message: str, error_stack=None) -> None:
        """Owner side: report a change of resource ``internal_id`` to all its consumers.

        FAILED marks the resource failed (it is no longer shared) and, if its load
        callback is still running, makes that load fail.
        """
        self._pipeline.send(self._server.served(internal_id), internal_id, code, message, error_stack)

    # ------------------------------------------------------------------------------------------ holding
    def call(self, rr_name: str, server_name: str, request, status_cb: Optional[StatusCallback] = None,
             namespace: Optional[str] = None, deadline: Optional[float] = None, link: bool = True):
        """Ask registrar ``rr_name`` for a resource; return the response with your local id in ``trr.resource_id``.

        Equal calls share one query and one remote resource. With ``link`` (the
        default), a call made inside a load callback becomes a sub-resource of the
        resource being loaded: released with it, and its FAILED forwarded to that
        resource's consumers. ``link=False`` holds it on this registrar's own account
        (``link`` attaches it later).

        ``deadline`` (seconds) bounds the whole call, from looking the service up to
        its answer: past it the call raises ``ErrorCode.TIMEOUT`` (``deadlines.py``).
        Default: the deadline the request type's contract declares, else the node's
        ``~call_deadline`` (1 s).
        """
        return self._client.call(rr_name, server_name, request, status_cb, namespace, deadline, link)

    def link(self, resource_id: int) -> None:
        """Make held ``resource_id`` (from ``call(..., link=False)``) a sub-resource of the load running on this
        thread. Raises if it has failed meanwhile: a load must not take on a dead sub-resource."""
        self._client.link(resource_id)

    def unload(self, resource_id: int) -> None:
        """Release this registrar's local id; the remote resource goes when its last holder leaves."""
        self._client.unload(resource_id)

    def register_status_callback(self, callback: StatusCallback) -> None:
        """``callback(event)`` runs for every status that reaches any client query of this registrar."""
        self._pipeline.add_callback(callback)

    # ------------------------------------------------------------------------------------------ introspection
    def registry(self) -> RegistrySnapshot:
        core, server, client = self._core, self._server, self._client
        with core.lock:
            servers = [ServerEntry(
                server=q.server.name, internal_id=q.internal_id, state=q.state.value,
                consumers=[ConsumerEntry(ext, c.status_topic, c.client_name, c.namespace, c.uri)
                           for ext, c in sorted(q.consumers.items())],
                links=list(q.links), request=encode_message(q.request),
                response=encode_message(q.response) if q.response is not None else None,
                summary={k: v for k, v in readable(q.request).items() if k != 'trr'},
                details={k: v for k, v in readable(q.response).items() if k != 'trr'} if q.response is not None
                else {},
                failure=str(q.failure) if q.failure else '', record=q.backup)
                for q in list(server.by_internal.values())]
            clients = []
            for q in {id(q): q for q in client.by_local.values()}.values():
                parents = (self._links.parent_of(i) for i in q.local_ids)
                clients.append(ClientEntry(
                    target=target_name(q.target), external_id=q.external_id, state=q.state.value,
                    local_ids=sorted(q.local_ids), linked_to=sorted({p.internal_id for p in parents if p is not None}),
                    request=encode_message(q.request),
                    response=encode_message(q.response) if q.response is not None else None,
                    summary={k: v for k, v in readable(q.request).items() if k != 'trr'}))
            in_flight = [[name, uri, n] for (name, uri), n in sorted(server.calls_in_flight.items())]
            return RegistrySnapshot(name=core.name, namespace=core.namespace, node=rospy.get_name(),
                                    servers=sorted(server.servers), server_queries=servers, client_queries=clients,
                                    recovering=self._recovering, incarnation=core.incarnation,
                                    calls_in_flight=in_flight)

    # ------------------------------------------------------------------------------------------ lifetime
    def shutdown(self) -> None:
        """Unload everything this registrar holds, tell consumers its resources are gone, unregister."""
        core, server, client = self._core, self._server, self._client
        with core.lock:
            if core.closed:
                return
            core.closed = True
            local_ids = list(client.by_local)
            served = list(server.by_internal.values())
        watchdog.unwatch('the lock of registrar %s' % core.prefix, core.lock)
        self._watch.stop()
        self._owners.stop()
        # consumers learn first that the resources are going away, so they can fail over
        why = '%s is shutting down' % core.prefix
        for query in served:
            if query.state is ACTIVE:
                self._pipeline.forward(query, ResourceStatus.FAILED, why,
                                       [ErrorFrame(ErrorCode.SHUTDOWN, core.subsystem, why, core.prefix)])
        for query in served:
            for external_id in list(query.consumers):
                try:
                    server.release_consumer(query.server.name, external_id)
                except TemotoError as err:
                    rospy.logwarn('%s: shutdown: %s', core.prefix, err)
        unreachable = set()   # registrars that did not answer: drop what they hold without waiting again
        for local_id in local_ids:
            query = client.by_local.get(local_id)
            if query is None:
                continue
            try:
                client.unload(local_id, send=query.target[:2] not in unreachable)
            except TemotoError as err:
                rospy.logwarn('%s: shutdown: %s', core.prefix, err)
                if any(f.code in (ErrorCode.SERVICE_REQ_FAIL, ErrorCode.TIMEOUT) for f in err.stack):
                    unreachable.add(query.target[:2])
        for srv in [s.service for s in server.servers.values()] + [self._unload_srv, self._reclaim_srv,
                                                                    self._registry_srv]:
            if srv is not None:
                srv.shutdown('registrar shutdown')
        self._status_sub.unregister()
        self._channels.close()
        client.close_proxies()
        self._pipeline.close()
        self._recorder.close()
        if self._journal is not None:
            self._journal.close()
