"""A peer that connects to a node's TCPROS port and never sends its handshake is closed after ``HANDSHAKE_S``,
and the connections behind it are served then (temoto_core/rospy_internals.py). Against a real node process;
rospy alone served every later connection to the node behind that peer, for as long as it stayed silent."""
import json
import socket

import rosgraph
import rospy

from temoto_core import rospy_internals
from temoto_core.rr.deadlines import call_once
from temoto_test_nodes.srv import Control
from rr_helpers import RegistrarNode

HANG = 10.0          # generous: catches a connection that waits behind the silent peer


def _tcpros_address(service: str):
    uri = rosgraph.Master('/test_bounded_handshake').lookupService(service)
    return rospy.core.parse_rosrpc_uri(uri)


def _counts(service: str) -> dict:
    return json.loads(call_once(service, Control, Control._request_class(json.dumps({'op': 'counts'})), HANG).result)


def test_a_peer_silent_in_its_handshake_is_closed_and_the_connections_behind_it_are_served(rospy_client, procs):
    node = RegistrarNode(procs, 'rr_silent_peer')
    service = '/rr_silent_peer/control'
    # a persistent connection made before the silent peer: it must keep working long after the handshake bound
    kept = rospy.ServiceProxy(service, Control, persistent=True)
    assert 'unloads' in json.loads(kept(json.dumps({'op': 'counts'})).result)
    silent = socket.create_connection(_tcpros_address(service), timeout=HANG)
    try:
        # the node gives up on the silent peer: the connection is closed from its end
        silent.settimeout(rospy_internals.HANDSHAKE_S + HANG)
        assert silent.recv(1) == b''
        for _ in range(3):                       # new connections, after the silent one, each bounded
            assert 'unloads' in _counts(service)
    finally:
        silent.close()
    # the connection made before it, idle all that time, is not bounded by the handshake's limit
    assert 'unloads' in json.loads(kept(json.dumps({'op': 'counts'})).result)
    kept.close()
    assert node.process.proc.poll() is None


def test_an_xmlrpc_call_that_lands_on_a_tcpros_port_is_closed_at_once(rospy_client, procs):
    """A dead node's XML-RPC port, reused by this node's TCPROS server: a call meant for the dead node is
    closed at once, not read as a 1.4 GB header until the handshake's bound with every connection waiting
    behind it (a Context Manager's services timed out for 30 s so in a clean-clone suite)."""
    RegistrarNode(procs, 'rr_port_reused')
    service = '/rr_port_reused/control'
    misdirected = socket.create_connection(_tcpros_address(service), timeout=HANG)
    try:
        misdirected.sendall(b'POST /RPC2 HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: text/xml\r\n'
                            b'Content-Length: 120\r\n\r\n')   # the call's body never comes, as a slow caller's
        # closed from the node's end well before the handshake's bound, which would otherwise run out first
        misdirected.settimeout(rospy_internals.HANDSHAKE_S / 2)
        try:
            assert misdirected.recv(1) == b''
        except ConnectionResetError:
            pass                                   # closed with the request unread: the kernel resets it
        assert 'unloads' in _counts(service)
    finally:
        misdirected.close()

