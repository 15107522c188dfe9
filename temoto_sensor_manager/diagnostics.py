"""Errors that drivers report on ``/diagnostics``, pinned to the driver process that sent them.

A real driver that cannot reach its device says so on ``/diagnostics``
(``diagnostic_msgs/DiagnosticArray``, through ``diagnostic_updater``) long before
any silence would: a device missing at start stays silent for good, and waiting
for its first data cost a candidate its whole start-up allowance. So the Sensor
Manager listens there, and a status of level ERROR (or STALE) fails the sensor
whose driver sent it, at once.

Which driver sent it is found from the message's connection header (the
publishing node's name), the master (that node's URI) and the node itself (its
pid, as ``rosnode ping`` asks), then the process tree: a node counts for a driver
process when it is that process or one of its descendants (a launch file's
nodes are roslaunch's children). Only a node on this manager's own host counts:
a pid says nothing across machines. Never by the status's name or hardware id, which
two drivers of one device (a stalled one still running and its successor) share.
Only error statuses are looked up, so a healthy driver's reports cost a parse.
"""
import http.client
import threading
import time
import urllib.parse
import xmlrpc.client
from typing import Callable, Dict, List, Optional, Tuple

import rosgraph
import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from temoto_core.master_lookup import lookup_node, node_pid, parent_pid
from temoto_core.rospy_internals import sender_of

TOPIC = '/diagnostics'      # absolute, as diagnostic_updater publishes it
ANCESTORS = 4               # levels of the process tree searched above a reporting node
KEEP_S = 10.0               # an error of a process not yet watched waits this long for its load to claim it
LOOKUP_TIMEOUT = 0.5


def describe(statuses: List[DiagnosticStatus]) -> str:
    """One line for the error statuses of one report."""
    return '; '.join('%s: %s (level %d%s)' % (s.name, s.message, s.level,
                                               ', hardware %s' % s.hardware_id if s.hardware_id else '')
                     for s in statuses)


class DriverReports:
    """Calls ``on_error(pid, text)`` when a node of the process ``pid`` reports an error.

    Errors of a process nobody watches yet are kept for ``KEEP_S``: a driver that
    reports its missing device before its start is answered is caught by
    :meth:`error_of` once the load knows its pid.
    """

    def __init__(self, on_error: Callable[[int, str], None], topic: str = TOPIC) -> None:
        self._on_error = on_error
        self._lock = threading.Lock()
        self._recent: Dict[int, Tuple[float, str]] = {}     # pid (and its ancestors) -> (when, error)
        self._sub = rospy.Subscriber(topic, DiagnosticArray, self._on_report, queue_size=50)

    def error_of(self, pid: int) -> str:
        """The error a node of ``pid`` reported in the last ``KEEP_S`` seconds, or ''."""
        with self._lock:
            kept = self._recent.get(pid)
        return kept[1] if kept and time.monotonic() - kept[0] < KEEP_S else ''

    def close(self) -> None:
        self._sub.unregister()

    def _on_report(self, msg: DiagnosticArray) -> None:
        errors = [s for s in msg.status if s.level >= DiagnosticStatus.ERROR]
        if not errors:
            return
        node = sender_of(msg)
        chain = self._process_chain(node)
        if not chain:
            return
        text = 'node %s reports on %s: %s' % (node, TOPIC, describe(errors))
        now = time.monotonic()
        with self._lock:
            for pid in [p for p, (t, _) in self._recent.items() if now - t > KEEP_S]:
                del self._recent[pid]
            for pid in chain:
                self._recent[pid] = (now, text)
        for pid in chain:
            self._on_error(pid, text)

    @staticmethod
    def _process_chain(node: str) -> List[int]:
        """The pid of ``node`` and of its ancestors, nearest first; [] if it cannot be found."""
        pid = local_node_pid(node)
        chain = []
        while pid and pid > 1 and len(chain) <= ANCESTORS:
            chain.append(pid)
            pid = parent_pid(pid)
        return chain


def local_node_pid(node: str) -> Optional[int]:
    """The pid of node ``node`` if it runs on this manager's host, else None (a pid says nothing across
    machines; a node that cannot be found is logged)."""
    try:
        uri = lookup_node(rosgraph.get_master_uri(), node, LOOKUP_TIMEOUT) if node else None
    except (OSError, xmlrpc.client.Error, http.client.HTTPException) as err:
        rospy.logwarn('diagnostics: cannot find the node %s: %s', node, err)
        return None
    if not uri or not _same_host(uri, rospy.get_node_uri() or ''):
        return None
    return node_pid(uri, LOOKUP_TIMEOUT)


def _same_host(uri: str, own_uri: str) -> bool:
    """Whether two XML-RPC URIs name the same host (pids are compared only there)."""
    return urllib.parse.urlsplit(uri).hostname == urllib.parse.urlsplit(own_uri).hostname
