"""The one door to rospy's internals: everything TeMoto takes from rospy beyond its public API.

Written against rospy 1.15.15 (Debian 12's ``python3-rospy``; ``tests/test_rospy_internals.py`` pins it).
At import, every internal symbol used here is looked up, and a rospy that lacks one stops the process at
once with an ImportError naming it: an upgrade that moved one fails loudly instead of breaking a guarantee
silently. Nothing else in TeMoto imports ``rospy.impl`` or ``rospy.core``.

What is taken, and why:

- ``rospy.core.is_shutdown_requested``: a node's loop must see a shutdown that is under way, before
  ``is_shutdown()`` turns true (``node.py``);
- ``rospy.core.is_initialized`` and the topic and service managers of ``rospy.impl.registration``: a
  master that restarted is given every registration of the node again (``master_rejoin.py``);
- the parameter cache of ``rospy.impl.paramserver``: a log call must not ask the master (``node.py``);
- ``rospy.core.parse_rosrpc_uri`` and ``TCPROSTransport`` of ``rospy.impl.tcpros_service``: a service call
  with a bounded handshake (``rr/deadlines.py``, the RViz host's client);
- ``rospy.impl.tcpros_base``: the TCPROS server's handshake read, bounded (below);
- a received message's ``_connection_header``: who published it (the Sensor Manager's driver reports and
  stall detector), and what type it is (the navigator's obstacle sources);
- a publisher's open connections (``Publisher.impl.connections``, each with its socket and the
  subscriber's name): which subscribers are alive now, not after rospy's next failed write
  (the navigator watches a goal's client so);
- ``rospy.impl.masterslave.ROSHandler.shutdown``: a master's shutdown meant for another node is refused
  (below, the shutdown guard);
- ``rospy.impl.tcpros_pubsub.QueuedConnection``'s queue: a node's last words (a goal's end, said as it is
  stopped) have left for the socket before rospy's shutdown closes it (``wait_sent``).

The bounded handshake. A node's TCPROS server no longer waits for ever on one peer's handshake.

rospy's TCPROS server accepts every topic and service connection to a node in one thread, and reads each
new connection's handshake header in that same thread, with no timeout. So one peer that connects and never
sends its header holds up every later connection to the node (every subscriber, every service call) for as
long as it stays silent:

- a process SIGSTOPped between its ``connect`` and its header (a stopped manager, in the chaos history);
- a host cut off or powered off mid-handshake: nothing ever closes the connection at this end;
- in a clean clone's suite, the simulation's accept thread was found in ``read_ros_handshake_header`` on one
  connection while a test's service call waited behind it, until pytest-timeout ended the test (the peer
  was not found).

Here the header must arrive within ``HANDSHAKE_S``; a peer that is late gets its connection closed, with
rospy's own warning, and the connections behind it wait that long at most. The header read is the only
thing bounded: once the handshake is done, the socket is as rospy left it.

The handshakes stay in rospy's one accept thread, in the order they came. A thread per handshake was tried
and broke rospy: a subscriber that connects twice to one publisher (rospy's subscriber side races so) keeps
the later connection, and so does the publisher, which closes the other; handled in parallel, the two ends
could keep different ones and close each other's, leaving none. An action's status channel was lost so,
and its FAILED with it, twice in one day's clean-clone suites.

``install_bounded_handshake()`` patches rospy's ``TCPROSServer`` once per process, before its server starts; every TeMoto
node gets it from ``temoto_core.node.init_node``.

The shutdown guard. When a node registers under a name the master already knows at another URI, the master
tells that URI to shut down, naming the node it means ("[/name] Reason: new node registered with same
name"). If the earlier node died and its port went to another process, that process is shut down instead:
any node of any master on the host. ``clear_stale_registration`` removes most such leftovers first, but not
all (a node that unregistered its topics as it died leaves only its parameter subscriptions, and cannot be
told from a live one by them). A clean-clone suite lost a Sensor Manager so: another test's master, replacing
its ``/temoto_action_engine``, shut down the Sensor Manager that had been given the dead engine's port. With
``install_shutdown_guard()``, a node refuses such a request when it names another node, and logs it. Every
other shutdown request (``rosnode kill``, or the master's for this node's own name) is obeyed as before.
"""
from __future__ import annotations

import re
import socket
import struct
import threading
import time
from typing import Callable, Dict, Optional, Set, Tuple

import rospy
import rospy.core
import rospy.impl.masterslave
import rospy.impl.paramserver
import rospy.impl.registration
import rospy.impl.tcpros_base as tcpros_base
import rospy.impl.tcpros_pubsub
import rospy.impl.tcpros_service
from rosgraph.network import ROSHandshakeException

WRITTEN_FOR = '1.15.15'     # the rospy these internals were read in

# every internal symbol TeMoto uses: (module, name)
USED = [(rospy.core, 'is_shutdown_requested'), (rospy.core, 'is_initialized'), (rospy.core, 'parse_rosrpc_uri'),
        (rospy.impl.paramserver, 'get_param_server_cache'), (rospy.impl.registration, 'get_topic_manager'),
        (rospy.impl.registration, 'get_service_manager'), (rospy.impl.tcpros_service, 'TCPROSTransport'),
        (tcpros_base, 'TCPROSServer'), (tcpros_base, 'read_ros_handshake_header'),
        (rospy.impl.masterslave, 'ROSHandler'), (rospy.impl.tcpros_pubsub, 'QueuedConnection')]


def missing(used=USED) -> list:
    """The internal symbols of ``used`` that rospy lacks, as 'module.name'."""
    return ['%s.%s' % (module.__name__, name) for module, name in used if not hasattr(module, name)]


_missing = missing()
if _missing or not hasattr(tcpros_base.TCPROSServer, '_tcp_server_callback'):
    raise ImportError('temoto_core.rospy_internals: this rospy lacks %s; TeMoto was written against rospy %s'
                      % (', '.join(_missing) or 'TCPROSServer._tcp_server_callback', WRITTEN_FOR))

is_shutdown_requested: Callable[[], bool] = rospy.core.is_shutdown_requested
is_initialized: Callable[[], bool] = rospy.core.is_initialized
TCPROSTransport = rospy.impl.tcpros_service.TCPROSTransport


def parse_rosrpc_uri(uri: str) -> Tuple[str, int]:
    """(host, port) of a ``rosrpc://`` service URI."""
    return rospy.core.parse_rosrpc_uri(uri)


def cache_param(key: str, value) -> None:
    """Put ``value`` in rospy's parameter cache under ``key``."""
    rospy.impl.paramserver.get_param_server_cache().set(key, value)


def registrations() -> Tuple[list, list, list]:
    """This node's (publications, subscriptions, services), as rospy's registration managers list them:
    [[name, type], ...] for the topics, [[name, uri], ...] for the services."""
    topics = rospy.impl.registration.get_topic_manager()
    services = rospy.impl.registration.get_service_manager()
    return topics.get_publications(), topics.get_subscriptions(), services.get_services()


def connection_header(msg) -> Dict[str, str]:
    """The TCPROS header of the connection ``msg`` came on (rospy puts it on every message it hands to a
    callback: ``callerid``, ``type``, ``topic``, ...); {} if unknown."""
    return getattr(msg, '_connection_header', None) or {}


def sender_of(msg) -> str:
    """The name of the node that published ``msg``; '' if unknown."""
    return connection_header(msg).get('callerid', '')


def _open(conn) -> bool:
    """Whether a TCPROS connection's peer still holds its end: a peek that reads an end of file says it
    closed (its process died, and its kernel closed the socket), before rospy has noticed."""
    sock = getattr(conn, 'socket', None)
    if sock is None:
        return False
    try:
        if sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b'':
            return False                        # the peer closed its end
    except BlockingIOError:
        pass                                    # nothing to read: open
    except OSError:                             # reset, or closed at this end
        return False
    return True


def live_subscribers(publisher: rospy.Publisher, unreachable_s: Optional[float] = None) -> Set[str]:
    """The names of ``publisher``'s subscribers whose connection is open now.

    A subscriber that dies has its socket closed by its kernel at once; here that reads as an end of
    file (a TCPROS subscriber sends nothing after its handshake, so a peek takes nothing from the
    stream). rospy itself drops the connection only when a later write to it fails: the second write
    after the death, 0.4 s for an action's 5 Hz status.

    A subscriber cut off (a link down, its host gone) closes nothing: TCP retransmits for minutes. With
    ``unreachable_s``, a subscriber whose kernel has acknowledged nothing for that long while this end has
    had to retransmit (``unreachable``) is left out too: a publisher that sends regularly (an action's
    status) tells a subscriber out of reach within about that bound. The connection itself is kept, so it
    carries on once the link is back (dropped, the subscriber would not know for a minute: rospy's
    keepalive)."""
    conns = list(publisher.impl.connections)
    return {conn.endpoint_id for conn in conns
            if _open(conn) and (unreachable_s is None or not unreachable(conn, unreachable_s))}


def wait_sent(publishers, timeout: float) -> bool:
    """Wait until what was published on ``publishers`` has left rospy's queues for the sockets; True when it
    has within ``timeout``. A publisher with a ``queue_size`` hands each message to a writer thread per
    subscriber (``QueuedConnection``); rospy's shutdown closes the connections without waiting for it, and a
    goal's end said by a node as it stops was lost (its client waited 90 s: CI at dda811a). The writer thread
    has still to finish the socket write of the last batch it took: a bounded poll cannot see that, and a
    write under way when the socket closes is lost (microseconds, unless the thread is starved then)."""
    deadline = time.monotonic() + timeout
    while any(getattr(conn, '_queue', None) for pub in publishers for conn in list(pub.impl.connections)):
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.002)
    return True


# struct tcp_info (linux/tcp.h): 8 bytes of state, then u32s: rto, ato, snd_mss, rcv_mss, unacked, sacked, lost,
# retrans, fackets, last_data_sent, last_ack_sent, last_data_recv, last_ack_recv (ms ago), ...
_TCP_INFO = struct.Struct('8B13I')
_RETRANSMITS, _LAST_ACK_RECV = 2, 8 + 12


def unreachable(conn, seconds: float) -> bool:
    """Whether a connection's peer has acknowledged nothing for ``seconds`` while this end had to retransmit
    (its retransmission timer, 0.2 s at least, fired): the peer is out of reach, though not gone. A healthy
    peer's kernel acknowledges within milliseconds, whatever its process does (stopped, busy)."""
    sock = getattr(conn, 'socket', None)
    if sock is None:
        return False
    try:
        info = _TCP_INFO.unpack_from(sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, _TCP_INFO.size))
    except (OSError, struct.error):         # closed meanwhile, or not TCP: _open says which
        return False
    return info[_RETRANSMITS] > 0 and info[_LAST_ACK_RECV] >= seconds * 1000.0


def live_publishers(subscriber: rospy.Subscriber) -> Set[str]:
    """The publishers of ``subscriber``'s topic whose connection is open now.

    rospy's receive thread drops a connection when it reads the end of file, but that thread may not have
    run yet when another callback asks (a goal that arrives right after the publisher died). A peek sees the
    end of file as soon as the kernel closed the socket. A publisher with a message still unread reads as
    open; for a latched topic sent once, that message was read long ago."""
    return {conn.endpoint_id for conn in list(subscriber.impl.connections) if _open(conn)}


def live_publisher_nodes(subscriber: rospy.Subscriber) -> Set[str]:
    """As :func:`live_publishers`, by the publishing nodes' names (their connection header's ``callerid``), for
    a reason an operator can read."""
    return {(getattr(conn, 'header', None) or {}).get('callerid', conn.endpoint_id)
            for conn in list(subscriber.impl.connections) if _open(conn)}


# generous beside a handshake (a header is a few hundred bytes, sent right after the connect), short beside
# the deadlines of the calls waiting behind it
HANDSHAKE_S = 5.0
# a TCPROS header's length, first 4 bytes little-endian: a topic's carries its message definition, a few KB at
# most. An HTTP request read so ("POST" is 1.4 GB, "GET " 0.5 GB) is an XML-RPC call to a node that had this
# port before: rospy would wait for the rest of that "header" until the handshake's bound
MAX_HEADER_BYTES = 1 << 20

_lock = threading.Lock()
_handshaking = threading.local()
_original_callback = tcpros_base.TCPROSServer._tcp_server_callback
_original_read = tcpros_base.read_ros_handshake_header


def _refuse_misdirected(sock) -> None:
    """Raise at once if the connection's first 4 bytes, read as a header's length, cannot be one.

    Ports are reused: a node that dies leaves its XML-RPC URI at masters and in peers' caches, and the port
    may go to another node's TCPROS server. An XML-RPC call to the dead node (a master's update, a
    registrar's liveness ping) then lands here, and rospy read its "POST" as the length of a header it
    waited to receive in full, for the handshake's whole bound, with every connection behind it waiting in
    the one accept thread. A clean-clone suite had a Context Manager's services time out for 30 s so, one
    "Inbound TCP/IP connection failed: timed out" every 5 s (two masters' nodes on one host).
    """
    first = sock.recv(4, socket.MSG_PEEK | socket.MSG_WAITALL)
    if len(first) < 4:
        return                                   # closed early: rospy's read says so
    (size,) = struct.unpack('<I', first)
    if size > MAX_HEADER_BYTES:
        what = 'an HTTP request (%r...)' % first if first.isalpha() or first[:3].isalpha() else \
            'a header of %d bytes' % size
        raise ROSHandshakeException('%s, not a TCPROS handshake: closed at once (a call meant for a node that '
                                    'had this port before?)' % what)


def _read_header(sock, buff, buff_size: int) -> dict:
    """rospy's header read; in the accept thread's handshake, within ``HANDSHAKE_S``, and refusing at once what
    cannot be a header (``_refuse_misdirected``)."""
    if not getattr(_handshaking, 'active', False):
        return _original_read(sock, buff, buff_size)
    previous = sock.gettimeout()
    sock.settimeout(HANDSHAKE_S)
    try:
        _refuse_misdirected(sock)
        return _original_read(sock, buff, buff_size)
    finally:
        sock.settimeout(previous)


def _accepted(server, sock, client_addr) -> None:
    """The accept thread's handler: rospy's, with the header read bounded."""
    _handshaking.active = True
    try:
        _original_callback(server, sock, client_addr)     # it catches, logs and closes whatever fails
    finally:
        _handshaking.active = False


def install_bounded_handshake() -> None:
    """Bound the handshakes of every TCPROS server this process starts from now on."""
    with _lock:
        tcpros_base.read_ros_handshake_header = _read_header
        tcpros_base.TCPROSServer._tcp_server_callback = _accepted


def bounded_handshake_installed() -> bool:
    return tcpros_base.TCPROSServer._tcp_server_callback is _accepted


_original_shutdown = rospy.impl.masterslave.ROSHandler.shutdown
_BUMPED = re.compile(r'^\[(?P<name>[^\]]+)\] Reason: new node registered with same name$')  # rosmaster's words


def bumped_node(msg: str) -> Optional[str]:
    """The node a master's "new node registered with same name" shutdown means; None for any other request."""
    found = _BUMPED.match(msg or '')
    return found.group('name') if found else None


def _guarded_shutdown(handler, caller_id, msg=''):
    """rospy's slave-API ``shutdown``, refusing a master's request that names another node."""
    meant = bumped_node(msg)
    if meant is not None and meant != rospy.get_name():
        rospy.logwarn('refused a shutdown from %s meant for %s (this is %s): that node is gone, and its port '
                      'is now this node\'s', caller_id, meant, rospy.get_name())
        return 0, 'this is %s, not %s' % (rospy.get_name(), meant), 0
    return _original_shutdown(handler, caller_id, msg)


def install_shutdown_guard() -> None:
    """Refuse, from now on, a master's shutdown request that names another node (see the module's doc)."""
    rospy.impl.masterslave.ROSHandler.shutdown = _guarded_shutdown


def shutdown_guard_installed() -> bool:
    return rospy.impl.masterslave.ROSHandler.shutdown is _guarded_shutdown
