"""A node's TCPROS server no longer waits for ever on one peer's handshake.

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

``install()`` patches rospy's ``TCPROSServer`` once per process, before its server starts; every TeMoto
node gets it from ``temoto_core.node.init_node``.
"""
from __future__ import annotations

import threading

import rospy.impl.tcpros_base as tcpros_base

# generous beside a handshake (a header is a few hundred bytes, sent right after the connect), short beside
# the deadlines of the calls waiting behind it
HANDSHAKE_S = 5.0

_lock = threading.Lock()
_handshaking = threading.local()
_original_callback = tcpros_base.TCPROSServer._tcp_server_callback
_original_read = tcpros_base.read_ros_handshake_header


def _read_header(sock, buff, buff_size: int) -> dict:
    """rospy's header read; in the accept thread's handshake, within ``HANDSHAKE_S``."""
    if not getattr(_handshaking, 'active', False):
        return _original_read(sock, buff, buff_size)
    previous = sock.gettimeout()
    sock.settimeout(HANDSHAKE_S)
    try:
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


def install() -> None:
    """Bound the handshakes of every TCPROS server this process starts from now on."""
    with _lock:
        tcpros_base.read_ros_handshake_header = _read_header
        tcpros_base.TCPROSServer._tcp_server_callback = _accepted


def installed() -> bool:
    return tcpros_base.TCPROSServer._tcp_server_callback is _accepted
