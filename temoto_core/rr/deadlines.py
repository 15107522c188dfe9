"""Deadlines on a registrar's service calls.

rospy has none. A call in flight on a persistent connection whose peer is cut
off by a dead link stays blocked in ``recv`` (still blocked after 20 s, measured
across two network namespaces); a new connection waits for TCP's own connect
timeout, which is minutes, and the master look-up before it waits as long. So
every call a registrar makes runs against a deadline (a ``time.monotonic()``
instant):

- the master look-up and the TCP connect get what is left of it, as XML-RPC and
  socket timeouts (:func:`connect`);
- the call itself is *guarded* (:meth:`CallWatch.guard`): one watch thread per
  process keeps the calls in flight in a heap ordered by deadline, and shuts
  down the socket of a call that outlives its deadline. That wakes the blocked
  ``recv`` (or ``send``) at once; the caller sees that its guard expired, fails
  the call with ``ErrorCode.TIMEOUT`` and drops the connection, so that a late
  answer is never read as the answer to the next call.

The same watch aborts, on request, every call in flight to a peer found
unreachable (:meth:`CallWatch.abort`), so a long load (a sensor may take seconds
to deliver its first data) still ends within the liveness bound when its owner's
host is cut off.

A guard costs a lock and a heap push per call; the watch thread sleeps until
the earliest deadline and does nothing while no call is late.
"""
import contextlib
import heapq
import importlib
import itertools
import socket
import threading
import time
import xmlrpc.client
from typing import Dict, Iterator, List, Optional, Set, Tuple

import rosgraph
import rospy
from rosgraph.network import read_ros_handshake_header
from temoto_core.rospy_internals import TCPROSTransport, parse_rosrpc_uri

from temoto_core import service_uris

# A live service answers the connection header within milliseconds. A stopped process's kernel still accepts
# the TCP connection and then says nothing, so one attempt is bounded by this, and the caller retries while
# its deadline allows (and while the owner is not known to be lost: owners.py).
CONNECT_BOUND = 1.0
# heap entries that finished are dropped lazily; past this many, and four times the live ones, the heap is rebuilt
_COMPACT_AT = 1024


class Guard:
    """One call in flight: its deadline, its socket, and the peer it talks to."""
    __slots__ = ('deadline', 'sock', 'peer', 'expired', 'aborted', 'done')

    def __init__(self, deadline: float, sock: socket.socket, peer: str) -> None:
        self.deadline = deadline
        self.sock = sock
        self.peer = peer
        self.expired = False       # the deadline passed before the answer came
        self.aborted = ''          # why the call was cut short before its deadline (its peer is unreachable)
        self.done = False

    def cut(self) -> None:
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:            # already closed: the call is over anyway
            pass


class CallWatch:
    """The calls in flight of this process, and the thread that cuts the late ones."""

    def __init__(self) -> None:
        self._heap: List[Tuple[float, int, Guard]] = []
        self._live = 0
        self._cond = threading.Condition()
        self._seq = itertools.count()
        self._thread: Optional[threading.Thread] = None

    @contextlib.contextmanager
    def guard(self, sock: socket.socket, deadline: float, peer: str = '') -> Iterator[Guard]:
        """Run the ``with`` body (one service call on ``sock``) against ``deadline``."""
        guard = Guard(deadline, sock, peer)
        with self._cond:
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name='rr-call-deadlines', daemon=True)
                self._thread.start()
            heapq.heappush(self._heap, (deadline, next(self._seq), guard))
            self._live += 1
            if self._heap[0][2] is guard:
                self._cond.notify()
            if len(self._heap) > _COMPACT_AT and len(self._heap) > 4 * self._live:
                self._heap = [entry for entry in self._heap if not entry[2].done]
                heapq.heapify(self._heap)
        try:
            yield guard
        finally:
            with self._cond:
                guard.done = True
                self._live -= 1

    def abort(self, peer: str, why: str) -> int:
        """Cut every call in flight to ``peer`` now; return how many."""
        with self._cond:
            cut = [g for _, _, g in self._heap if g.peer == peer and not g.done]
            for guard in cut:
                guard.aborted = why
        for guard in cut:
            guard.cut()
        return len(cut)

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._heap and self._heap[0][2].done:
                    heapq.heappop(self._heap)
                if not self._heap:
                    self._cond.wait()
                    continue
                wait = self._heap[0][0] - time.monotonic()
                if wait > 0:
                    self._cond.wait(wait)
                    continue
                guard = heapq.heappop(self._heap)[2]
                guard.expired = True
            guard.cut()


WATCH = CallWatch()


def remaining(deadline: float) -> float:
    return deadline - time.monotonic()


class _BoundedHandshake(TCPROSTransport):
    """rospy's transport, whose connection handshake keeps the connect timeout.

    rospy's ``write_header`` and ``read_header`` make the socket blocking, so
    ``connect(timeout=...)`` bounds only the TCP connect: a stopped process
    (whose kernel accepts the connection) then holds the caller in the header
    read for ever. Here the read runs against ``handshake_deadline`` (a
    ``time.monotonic()`` instant); the call that follows is guarded by the watch.
    """
    handshake_deadline = 0.0

    def read_header(self) -> None:
        if self.socket is not None:
            self.socket.settimeout(max(0.01, remaining(self.handshake_deadline)))
            self._validate_header(read_ros_handshake_header(self.socket, self.read_buff, self.protocol.buff_size))


def connect(service: str, srv_class, deadline: float) -> Optional[rospy.ServiceProxy]:
    """A persistent proxy to ``service``, connected within ``deadline``; None if the master does not know the
    service. Raises ``OSError`` or ``rospy.ServiceException`` if it cannot be reached in time.

    rospy's own proxy looks the service up and connects inside its first call, with no timeout on either;
    here both are done first, against the deadline, and the proxy is handed the open connection.
    """
    uri = service_uris.lookup(service, deadline)     # the master, or the URI known when it is out of reach
    if not uri:
        return None
    host, port = parse_rosrpc_uri(uri)
    proxy = rospy.ServiceProxy(service, srv_class, persistent=True)
    transport = _BoundedHandshake(proxy.protocol, proxy.resolved_name)
    transport.buff_size = proxy.buff_size
    bound = max(0.01, min(CONNECT_BOUND, remaining(deadline)))
    transport.handshake_deadline = time.monotonic() + bound
    try:
        transport.connect(host, port, uri, timeout=bound)
    except Exception as err:          # rospy raises TransportInitError, which callers do not know
        transport.close()
        raise rospy.ServiceException('unable to connect to %s at %s: %s' % (service, uri, err)) from err
    proxy.transport = transport
    return proxy


def call_once(service: str, srv_class, request, seconds: float):
    """One call to ``service`` on a connection of its own, connected and answered within ``seconds``.

    For the few reads that are not registrar calls (a manager's catalogue, say) and so have no pooled
    connection. Raises ``rospy.ServiceException`` if the service is unknown, out of reach or late.
    """
    deadline = time.monotonic() + seconds
    try:
        proxy = connect(service, srv_class, deadline)
    except (OSError, xmlrpc.client.Error) as err:
        raise rospy.ServiceException('%s could not be reached within %.2f s: %s' % (service, seconds, err)) from err
    if proxy is None:
        raise rospy.ServiceException('%s is not known to the master' % service)
    guard = None
    try:
        with WATCH.guard(proxy.transport.socket, deadline, '') as guard:
            return proxy.call(request)
    except (rospy.ServiceException, rospy.ROSException, OSError) as err:
        if guard is not None and guard.expired:
            raise rospy.ServiceException('%s did not answer within %.2f s' % (service, seconds)) from err
        raise
    finally:
        proxy.close()


# ---------------------------------------------------------------------------------------------- per type
# Calls with no deadline of their own get DEFAULT_DEADLINE (the node's ``~call_deadline``). A load that
# takes longer by nature (a sensor's first data, RViz starting) is declared by its manager's contract.
DEFAULT_DEADLINE = 1.0
_BY_TYPE: Dict[type, Tuple[float, float]] = {}
_LOOKED_UP: Set[type] = set()


def register_deadlines(request_class: type, load: float, unload: Optional[float] = None) -> None:
    """Declare how long a load (and an unload) of ``request_class`` may take at most, in seconds."""
    if load <= 0 or (unload is not None and unload <= 0):
        raise ValueError('deadlines of %s must be positive: load %r, unload %r' % (request_class.__name__, load,
                                                                                    unload))
    _BY_TYPE[request_class] = (float(load), float(unload if unload is not None else load))


def _declared(request_class: type) -> Optional[Tuple[float, float]]:
    """The deadlines declared for ``request_class``, looking once for its package's contract module.

    A client may use a manager's request type without importing the manager's
    contract (which declares its deadlines): a process load would then get the
    1 s default and fail. So the first call of a type imports
    ``<package of the message>.contract`` if there is one, as the contract's own
    clients do.
    """
    found = _BY_TYPE.get(request_class)
    if found is None and request_class not in _LOOKED_UP:
        _LOOKED_UP.add(request_class)
        package = getattr(request_class, '_type', '').split('/')[0]
        if package:
            try:
                importlib.import_module(package + '.contract')
            except ModuleNotFoundError as err:
                if err.name not in (package, package + '.contract'):
                    raise                    # the contract exists and is broken: say so
            found = _BY_TYPE.get(request_class)
    return found


def load_deadline(request, default: float) -> float:
    return (_declared(type(request)) or (default, default))[0]


def unload_deadline(request, default: float) -> float:
    return (_declared(type(request)) or (default, default))[1]
