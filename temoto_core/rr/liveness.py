"""Consumer liveness: release the references of consumer incarnations that died without unloading.

A consumer is a node incarnation: its name and its XML-RPC URI. A node killed
with SIGKILL stays registered at the master, and a node restarted under the same
name gets a new URI, so liveness is asked of the incarnation's own URI
(``getPid``, as ``rosnode ping`` does), never of whatever the master now has
under the name. A refused connection, or another pid answering at the URI, is
death; a ping that times out is death only the second time in a row (a loaded
machine). Bound: 2 x (``consumer_check_period`` + 1 s of ping timeout).
Unused status channels are unregistered on the same beat.

A consumer whose registrar keeps a journal (it sent an incarnation) may come
back and reclaim what it held (``recovery.py``): its references are kept for
``recovery_grace`` more seconds after it is found dead, and released only if no
new incarnation has claimed them by then.
"""
import errno
import socket
import threading
import time
import urllib.parse
import xmlrpc.client
from typing import Dict, List, Optional, Tuple

import rosgraph
import rospy

from temoto_core.errors import ErrorCode, ErrorFrame, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_core.rr.channels import CHANNEL_GRACE, StatusChannels
from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.server_side import ServerSide
from temoto_core.rr.status_pipeline import StatusPipeline
from temoto_core.xmlrpc_util import proxy as xmlrpc_proxy


UNREACHABLE = frozenset({errno.EHOSTUNREACH, errno.ENETUNREACH, errno.ENETDOWN, errno.EHOSTDOWN, errno.ETIMEDOUT})


class ConsumerWatch:
    def __init__(self, core: RegistrarCore, server: ServerSide, channels: StatusChannels, pipeline: StatusPipeline,
                 period: float, recovery_grace: float) -> None:
        self._core = core
        self._server = server
        self._channels = channels
        self._pipeline = pipeline
        self.period = period
        self.recovery_grace = recovery_grace
        self._dead_since: Dict[str, float] = {}    # URI of a dead consumer that may come back -> when found dead
        self._pids: Dict[str, int] = {}     # consumer URI -> the pid that first answered there
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    def start(self) -> None:
        if self.period > 0 and self._thread is None:
            self._thread = threading.Thread(target=self._run, name='rr-%s-watch' % self._core.name, daemon=True)
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        master = xmlrpc_proxy(rosgraph.get_master_uri(), 1.0)
        strikes: Dict[str, int] = {}
        while not self._stop.wait(self.period):
            self._channels.reap_idle(max(CHANNEL_GRACE, self.period))
            self._resolve_uris(master)
            with self._core.lock:
                holders: Dict[Tuple[str, str], List[Tuple[str, int]]] = {}
                returning = set()        # URIs of consumers whose registrar may come back for its resources
                for (server_name, external_id), query in self._server.by_external.items():
                    consumer = query.consumers[external_id]
                    if consumer.client_name and consumer.uri:
                        holders.setdefault((consumer.client_name, consumer.uri), []).append(
                            (server_name, external_id))
                        if consumer.incarnation > 0:
                            returning.add(consumer.uri)
            live_uris = {uri for _, uri in holders}
            for table in (self._pids, strikes, self._dead_since):
                for uri in [u for u in table if u not in live_uris]:
                    del table[uri]
            for (node, uri), refs in holders.items():
                verdict = self._alive(uri)
                if verdict is None:
                    strikes[uri] = strikes.get(uri, 0) + 1
                    if strikes[uri] < 2:
                        continue
                elif verdict:
                    strikes.pop(uri, None)
                    continue
                strikes.pop(uri, None)
                if uri in returning:
                    since = self._dead_since.setdefault(uri, time.monotonic())
                    if time.monotonic() - since < self.recovery_grace:
                        continue
                self._release_dead(node, uri, refs)

    def _release_dead(self, node: str, uri: str, refs: List[Tuple[str, int]]) -> None:
        core = self._core
        rospy.logwarn('%s: consumer %s (%s) died; releasing its %d reference(s)', core.prefix, node, uri, len(refs))
        reason = 'released by %s: its consumer %s at %s is gone' % (core.prefix, node, uri)
        for server_name, external_id in refs:
            consumer = self._server.consumer(server_name, external_id)
            if consumer is None or consumer.uri != uri:
                continue
            # a release the holder did not ask for is announced to it (a new incarnation listening on the
            # same status topic hears of an id it never held, and ignores it)
            self._pipeline.announce(consumer, server_name, external_id, ResourceStatus.FAILED, reason,
                                    [ErrorFrame(ErrorCode.RESOURCE_FAILED, core.subsystem, reason, core.prefix)])
            try:
                self._server.release_consumer(server_name, external_id)
            except TemotoError as err:
                rospy.logwarn('%s: releasing %s:%d of dead consumer %s: %s', core.prefix, server_name,
                              external_id, node, err)

    def _resolve_uris(self, master) -> None:
        """A client that sent no URI (one not built on this registrar) is taken to be the incarnation the
        master has under its name when first checked."""
        core = self._core
        with core.lock:
            names = {c.client_name for q in self._server.by_internal.values() for c in q.consumers.values()
                     if c.client_name and not c.uri}
        for name in names:
            try:
                code, _, uri = master.lookupNode(core.prefix, name)
            except (OSError, xmlrpc.client.Error):
                return    # master unreachable: no verdict now
            with core.lock:
                for query in self._server.by_internal.values():
                    for consumer in query.consumers.values():
                        if consumer.client_name == name and not consumer.uri:
                            # a name the master no longer knows is dead: a URI no node answers at says so
                            consumer.uri = uri if code == 1 else 'http://unregistered%s/' % name

    def _alive(self, uri: str) -> Optional[bool]:
        """True: the incarnation at ``uri`` answers; False: it is gone; None: no verdict (timed out)."""
        verdict, pid = ping(uri, 1.0, self._core.prefix)
        if not verdict:
            return verdict
        first = self._pids.setdefault(uri, pid)
        return first == pid     # another process now listening on a reused port is another incarnation


def ping(uri: str, timeout: float, caller: str) -> Tuple[Optional[bool], int]:
    """Ask the node at XML-RPC ``uri`` for its pid, as ``rosnode ping`` does: (True, pid) if it answers,
    (False, 0) if it is gone (refused, or not a node), (None, 0) if it did not answer within ``timeout``
    (a partition, a dead host, a stopped or overloaded process: no verdict)."""
    try:
        code, _, pid = xmlrpc_proxy(uri, timeout).getPid(caller)
    except socket.timeout:
        return None, 0
    except OSError as err:
        # a refused or reset connection: the host answers, the process is gone; no route: no verdict
        return (None, 0) if err.errno in UNREACHABLE else (False, 0)
    except (xmlrpc.client.Error, ValueError):
        return False, 0
    return (True, int(pid)) if code == 1 else (False, 0)


def accepts(uri: str, timeout: float) -> bool:
    """Whether the node at XML-RPC ``uri`` takes a TCP connection within ``timeout``: its host is reachable
    and a process holds the port, though it may be too busy (or stopped) to answer."""
    parsed = urllib.parse.urlsplit(uri)
    try:
        with socket.create_connection((parsed.hostname, parsed.port), timeout):
            return True
    except (OSError, ValueError, TypeError):
        return False
