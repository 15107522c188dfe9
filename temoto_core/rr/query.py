"""The registrar's records, and the one state machine that every query follows.

A *server query* is one resource this registrar owns, shared by every consumer
whose request is equal; a *client query* is one resource this registrar holds
from another, shared by every local caller whose request is equal. Both move
through the same states, and only along the edges in ``TRANSITIONS``: a move
that is not there is a bug in the registrar, and raises at once instead of
leaving a query in a state nobody expects (osrf/capabilities' instances do the
same).
"""
import enum
from typing import Callable, Dict, Hashable, List, Optional, Tuple

from temoto_core.errors import TemotoError
from temoto_core.rr.status import StatusEvent


class QueryState(str, enum.Enum):
    """A query's life. A ``str`` enum, so the registry's JSON keeps the plain names."""
    LOADING = 'loading'        # the load runs; equal requests wait for its outcome
    ACTIVE = 'active'          # loaded; equal requests share it
    FAILED = 'failed'          # its owner reported FAILED; never shared again, released by its holders
    UNLOADING = 'unloading'    # the last consumer left; the unload callback and the cascade run
    GONE = 'gone'              # out of every index

    def __str__(self) -> str:
        return self.value


LOADING, ACTIVE, FAILED, UNLOADING, GONE = (QueryState.LOADING, QueryState.ACTIVE, QueryState.FAILED,
                                            QueryState.UNLOADING, QueryState.GONE)

TRANSITIONS = {
    LOADING: frozenset({ACTIVE, FAILED}),
    ACTIVE: frozenset({FAILED, UNLOADING, GONE}),
    FAILED: frozenset({UNLOADING, GONE}),
    UNLOADING: frozenset({GONE}),
    GONE: frozenset(),
}


class IllegalTransition(RuntimeError):
    """A registrar bug: a query was moved along an edge the state machine does not have."""


class _Query:
    __slots__ = ()

    def move(self, to: QueryState) -> None:
        """Move to ``to`` (with the registrar's lock held); only along an edge of ``TRANSITIONS``."""
        if to not in TRANSITIONS[self.state]:
            raise IllegalTransition('%s: %s -> %s is not a transition of a query' % (self, self.state, to))
        self.state = to


class Consumer:
    """One consumer incarnation: a node is identified by its name *and* its XML-RPC URI, so a node that
    restarts under the same name is a new consumer, and releasing the old one never touches it."""
    __slots__ = ('status_topic', 'client_name', 'namespace', 'uri', 'incarnation')

    def __init__(self, status_topic: str, client_name: str, namespace: str, uri: str = '',
                 incarnation: int = 0) -> None:
        self.status_topic = status_topic
        self.client_name = client_name
        self.namespace = namespace
        self.uri = uri          # '' until resolved at the master, for a client that does not send it
        self.incarnation = incarnation    # > 0: its registrar keeps a journal and may come back to reclaim


class Server:
    """One advertised resource type: its service, its owner's callbacks and its equality."""
    __slots__ = ('name', 'srv_type', 'load_cb', 'unload_cb', 'key', 'service', 'by_key')

    def __init__(self, name: str, srv_type, load_cb: Callable, unload_cb: Callable,
                 key: Callable[[object], Hashable]) -> None:
        self.name = name
        self.srv_type = srv_type
        self.load_cb = load_cb
        self.unload_cb = unload_cb
        self.key = key
        self.service = None
        self.by_key: Dict[Hashable, 'ServerQuery'] = {}   # queries that new equal requests may share


class ServerQuery(_Query):
    __slots__ = ('server', 'key', 'internal_id', 'request', 'response', 'state', 'consumers', 'links', 'failure',
                 'link_failures', 'backup')

    def __init__(self, server: Server, key: Hashable, internal_id: int, request) -> None:
        self.server = server
        self.key = key
        self.internal_id = internal_id
        self.request = request
        self.response = None
        self.state = LOADING
        self.consumers: Dict[int, Consumer] = {}
        self.links: List[int] = []                              # local ids of the client queries it holds
        self.failure: Optional[TemotoError] = None             # why it FAILED (while loading, or since)
        self.link_failures: Dict[int, TemotoError] = {}         # FAILED of a linked sub-resource while loading
        self.backup = ''                                        # the record its consumers keep (backup.py)

    def __repr__(self) -> str:
        return 'server query %s:%d' % (self.server.name, self.internal_id)


Target = Tuple[str, str, str]       # (namespace, registrar, server)


def target_name(target: Target) -> str:
    return '/%s/%s/%s' % target


class ClientQuery(_Query):
    __slots__ = ('target', 'key', 'request', 'response', 'external_id', 'state', 'local_ids', 'error', 'wire')

    def __init__(self, target: Target, key: Hashable, request) -> None:
        self.target = target
        self.key = key
        self.request = request
        self.response = None
        self.external_id = 0
        self.state = LOADING
        self.local_ids: Dict[int, Optional[Callable[[StatusEvent], None]]] = {}
        self.error: Optional[TemotoError] = None
        self.wire: Optional[Tuple[bytes, bytes]] = None     # request and response serialised (recorder.wire_of)

    def __repr__(self) -> str:
        return 'client query %s:%d' % (target_name(self.target), self.external_id)


class HeldQueries:
    """The holder's tables: filled by the client side (``client_side.py``), read by the status pipeline
    (``status_pipeline.py``) to map an arriving status to the local ids that hold its resource. All three
    are read and changed with the registrar's lock held."""
    __slots__ = ('by_key', 'by_local', 'by_external')

    def __init__(self) -> None:
        self.by_key: Dict[Tuple[Target, Hashable], ClientQuery] = {}     # what an equal new call may share
        self.by_local: Dict[int, ClientQuery] = {}                      # each local id held
        self.by_external: Dict[Tuple[Target, int], ClientQuery] = {}    # the owner's id of each resource

    def loading_from(self, target: Target) -> bool:
        """Whether a call to ``target`` is still waiting for its response (lock held)."""
        return any(q.target == target and q.state is LOADING for q in self.by_key.values())
