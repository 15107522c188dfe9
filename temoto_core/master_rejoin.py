"""A master that came back: register this node with it again.

rospy registers a node's publishers, subscribers and services with the master once, at start (roscpp
too). When the master's host dies and a new master starts at the same address (the robot rebooted: the
master runs on the robot), the new master knows nothing of the nodes that outlived the old one on other
hosts. Their services cannot be looked up, and a publisher that registers now is never connected to their
subscribers. Nothing raises: a status the returned robot's registrar publishes to the operator's registrar
simply reaches nobody, and the robot's restart finds nobody to rebuild its registry from.

:class:`MasterRejoin` asks the master, once per period, whether it knows this node, and which run it is
(its ``/run_id``, which roscore draws afresh at every start): one XML-RPC round trip with a timeout. When
the master does not know the node, or is a new run, it registers everything this process has, as rospy
does at start, and connects each subscriber to the publishers the master names. A master that does not
answer is left alone: what a cut-off host means for the resources held there is the owner watch's to report.

Knowing the node is not enough. A publisher or service this process makes while the master is down waits
in rospy's own registration loop, which registers that one name the moment the new master answers. The
new master then knows the node, with one registration out of many: every other service of the node could
not be looked up, and an unload owed to it was never delivered (chaos seed 17, step 4669: two displays
leaked at the station's Output Manager after the robot lost power twice in 25 steps).

A process may hold a second node that rospy knows nothing of: librviz starts a roscpp node of its own
(``/rviz_<number>``) in the RViz host, whose subscriptions carry the robot's transforms to the operator's
screen. roscpp never registers again, so after the robot's reboot RViz never heard the new robot's ``/tf``:
every display in the robot's frames lost its transform while the host still listed it as shown. Such a
node is *adopted* (:func:`nodes_of_processes`, :meth:`MasterRejoin.adopt`): its topics are read from its own
XML-RPC API at the time they are registered again, its services are learnt once when it is adopted. The
ER Manager adopts the nodes of the processes it runs the same way (a roscpp throttle on the station of a
robot's topic would go quiet otherwise), and disowns each when its process exits.
"""
import dataclasses
import http.client
import threading
import urllib.parse
import xmlrpc.client
from typing import Dict, Iterable, List, Optional, Tuple

import psutil
import rosgraph
import rospy

from temoto_core import params, rospy_internals
from temoto_core.xmlrpc_util import proxy

DEFAULT_PERIOD = 1.0      # s between two checks: a returned master has everything again within about this
CALL_TIMEOUT = 1.0        # s for one XML-RPC call to the master or to this node
MASTER_CALLER_ID = '/master'   # how the master signs the publisherUpdate it sends to a subscriber

XMLRPC_ERRORS = (OSError, xmlrpc.client.Error, http.client.HTTPException)

Registrations = Tuple[List[Tuple[str, str]], List[Tuple[str, str]], List[Tuple[str, str]]]


@dataclasses.dataclass(frozen=True)
class ProcessNode:
    """A node this one speaks for to a master that restarted, because it registers once and never again
    (librviz's roscpp node in the RViz host; a node of a process the ER Manager runs): its name, its XML-RPC
    URI and its services, as (name, rosrpc URI)."""
    name: str
    uri: str
    services: Tuple[Tuple[str, str], ...] = ()


def nodes_of_processes(pids: Iterable[int], timeout: float = CALL_TIMEOUT) -> List[ProcessNode]:
    """The nodes the processes ``pids`` serve, as the master knows them now, this process's rospy node left
    out: a node whose XML-RPC address is a port one of them listens on, on this node's host. Nothing is
    asked of the nodes themselves (a stopped process would make each question last its timeout), and a name
    needs no guessing (librviz's and roscpp's anonymous nodes). Raises an XML-RPC or socket error when the
    master does not answer."""
    ports = _listening_ports(pids)
    if not ports:
        return []
    own_host = urllib.parse.urlsplit(rospy.get_node_uri() or '').hostname
    state = system_state(timeout)
    names = sorted({node for _, nodes in state[0] + state[1] + state[2] for node in nodes} - {rospy.get_name()})
    calls = xmlrpc.client.MultiCall(proxy(rosgraph.get_master_uri(), timeout))
    for name in names:
        calls.lookupNode(rospy.get_name(), name)
    found = []
    for name, (code, _, uri) in zip(names, tuple(calls()) if names else ()):
        address = urllib.parse.urlsplit(uri) if code == 1 else None
        if address is not None and address.hostname == own_host and address.port in ports:
            found.append(ProcessNode(name, uri, _services_of(name, state, timeout)))
    return found


def _listening_ports(pids: Iterable[int]) -> set:
    ports = set()
    for pid in pids:
        try:
            ports.update(c.laddr.port for c in psutil.Process(pid).net_connections('tcp')
                         if c.status == psutil.CONN_LISTEN)
        except psutil.Error:
            continue                          # gone: it serves nothing
    return ports


def _services_of(name: str, state: list, timeout: float) -> Tuple[Tuple[str, str], ...]:
    """(service, rosrpc URI) of every service node ``name`` offers, per the master's system state."""
    services = sorted(s for s, nodes in state[2] if name in nodes)
    if not services:
        return ()
    calls = xmlrpc.client.MultiCall(proxy(rosgraph.get_master_uri(), timeout))
    for service in services:
        calls.lookupService(rospy.get_name(), service)
    return tuple((service, uri) for service, (code, _, uri) in zip(services, tuple(calls())) if code == 1)


def system_state(timeout: float = CALL_TIMEOUT) -> list:
    """The master's [publishers, subscribers, services]. Raises an XML-RPC or socket error when it does not
    answer, or refuses."""
    code, message, state = proxy(rosgraph.get_master_uri(), timeout).getSystemState(rospy.get_name())
    if code != 1:
        raise xmlrpc.client.Fault(code, 'getSystemState: %s' % message)
    return state


def refresh_subscription(topic: str, msg_type: str, timeout: float = CALL_TIMEOUT) -> int:
    """Ask the master again for the publishers of ``topic``, which this node subscribes to, and hand them to
    rospy as the master's own update would: a publisher the master told this node of in an update that never
    arrived (sent across a link that went down a moment later) is connected now. Returns how many publishers
    the master names. Raises an XML-RPC or socket error when the master or this node does not answer."""
    own_uri = rospy.get_node_uri()
    code, message, publishers = proxy(rosgraph.get_master_uri(), timeout).registerSubscriber(
        rospy.get_name(), topic, msg_type, own_uri)
    if code != 1:
        raise xmlrpc.client.Fault(code, 'registerSubscriber %s: %s' % (topic, message))
    proxy(own_uri, timeout).publisherUpdate(MASTER_CALLER_ID, topic, publishers)
    return len(publishers)


class MasterRejoin:
    """Registers this process's node again with a master that does not know it (see the module docstring)."""

    def __init__(self, period: float = DEFAULT_PERIOD, timeout: float = CALL_TIMEOUT) -> None:
        if not period > 0:
            raise ValueError('master_check_period %r: it must be a positive number of seconds' % (period,))
        self.period = period
        self.timeout = timeout
        self._master_uri = rosgraph.get_master_uri()
        self._caller_id = rospy.get_name()
        self._stop = threading.Event()
        self._warned_other: Dict[str, str] = {}      # node name: the other URI the master gave it, warned once
        self._adopted: Dict[str, ProcessNode] = {}
        self._adopted_lock = threading.Lock()
        # the run of the master this node last registered everything with ('' when it has no /run_id)
        self._run_id: Optional[str] = None
        self._thread = threading.Thread(target=self._run, name='temoto-master-rejoin', daemon=True)

    def start(self) -> 'MasterRejoin':
        try:
            self._run_id = self._ask()[1]      # the master this node registered with at start
        except XMLRPC_ERRORS:
            pass                               # no master now: the first check learns its run
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        while not self._stop.wait(self.period) and not rospy.is_shutdown():
            try:
                self.check()
            except XMLRPC_ERRORS as err:      # the master went away mid-way: the next period tries again
                rospy.logdebug('%s: registering again with %s failed: %s', self._caller_id, self._master_uri, err)

    def adopt(self, node: ProcessNode) -> None:
        """Register ``node`` again too whenever the master does not know it or is a new run."""
        with self._adopted_lock:
            self._adopted[node.name] = node

    def disown(self, name: str) -> None:
        """No longer speak for node ``name`` (its process is gone: registering it would bring it back)."""
        with self._adopted_lock:
            self._adopted.pop(name, None)

    def check(self) -> bool:
        """Register again if the master does not know this node (or an adopted one), or is a new run; True
        when it did. Raises an XML-RPC or socket error when the master stops answering half-way."""
        own_uri = rospy.get_node_uri()
        if not own_uri or not rospy_internals.is_initialized():
            return False                      # rospy is still registering for the first time
        with self._adopted_lock:
            adopted = list(self._adopted.values())
        try:
            known, run_id = self._ask()
            new_run = bool(run_id) and self._run_id is not None and run_id != self._run_id
            # an adopted node is asked about only when the run cannot tell whether the master knows it (a
            # master with no /run_id), or on a new run (whose answer guards a name another process took):
            # the check that runs every second stays two questions, however many nodes are adopted
            asked = adopted and (new_run or not run_id or self._run_id is None)
            adopted_known = self._lookup_nodes(adopted) if asked else {node.name: node.uri for node in adopted}
        except XMLRPC_ERRORS:
            return False                      # no master (yet): nothing to register with
        registered = False
        if self._may_register(self._caller_id, own_uri, known) and (known != own_uri or new_run):
            self._register(self._caller_id, own_uri, self._own_registrations(), new_run and known == own_uri)
            registered = True
        for node in adopted:
            if self._may_register(node.name, node.uri, adopted_known[node.name]) and (
                    adopted_known[node.name] != node.uri or new_run):
                registrations = self._node_registrations(node)
                if registrations is not None:
                    self._register(node.name, node.uri, registrations, new_run and adopted_known[node.name] == node.uri)
                    registered = True
        # reached only when every registration was made: a pass that raised half-way is redone at the next period
        if registered or run_id or self._run_id is None:
            self._run_id = run_id
        return registered

    def _may_register(self, name: str, uri: str, known: Optional[str]) -> bool:
        """False when the master names another process ``name``: registering would shut that process down."""
        if known is None or known == uri:
            return True
        if self._warned_other.get(name) != known:
            self._warned_other[name] = known
            rospy.logwarn('%s: the master names another node %s at %s; not registering it again',
                          self._caller_id, name, known)
        return False

    def _ask(self) -> Tuple[Optional[str], str]:
        """(this node's URI at the master or None, the master's /run_id or '') in one round trip."""
        calls = xmlrpc.client.MultiCall(proxy(self._master_uri, self.timeout))
        calls.lookupNode(self._caller_id, self._caller_id)
        calls.getParam(self._caller_id, '/run_id')
        (code, _, uri), (run_code, _, run_id) = tuple(calls())
        return (uri if code == 1 else None), (str(run_id) if run_code == 1 else '')

    def _lookup_nodes(self, nodes: List[ProcessNode]) -> Dict[str, Optional[str]]:
        """Each node's URI at the master, or None, in one round trip."""
        calls = xmlrpc.client.MultiCall(proxy(self._master_uri, self.timeout))
        for node in nodes:
            calls.lookupNode(self._caller_id, node.name)
        return {node.name: (value if code == 1 else None) for node, (code, _, value) in zip(nodes, tuple(calls()))}

    @staticmethod
    def _own_registrations() -> Registrations:
        publications, subscriptions, services = rospy_internals.registrations()
        return list(publications), list(subscriptions), list(services)

    def _node_registrations(self, node: ProcessNode) -> Optional[Registrations]:
        """An adopted node's topics, from its own API now (RViz subscribes and unsubscribes as displays come
        and go), and its services as adopted; None when it does not answer."""
        api = proxy(node.uri, self.timeout)
        try:
            publications = self._ok(api.getPublications(self._caller_id), 'the publications of', node.name)
            subscriptions = self._ok(api.getSubscriptions(self._caller_id), 'the subscriptions of', node.name)
        except ConnectionRefusedError:
            # nobody listens at its address: its process is gone, and registering it would bring it back
            rospy.logwarn('%s: %s is gone; no longer registering it again', self._caller_id, node.name)
            self.disown(node.name)
            return None
        except XMLRPC_ERRORS as err:
            # stopped or busy: the rest is registered now, this one at the next new run
            rospy.logwarn('%s: %s did not say what it registers: %s', self._caller_id, node.name, err)
            return None
        return ([tuple(p) for p in publications or []], [tuple(s) for s in subscriptions or []],
                list(node.services))

    def _register(self, name: str, uri: str, registrations: Registrations, partly_known: bool) -> None:
        publications, subscriptions, offered = registrations
        master = proxy(self._master_uri, self.timeout)
        node = proxy(uri, self.timeout)
        for topic, msg_type in publications:
            self._ok(master.registerPublisher(name, topic, msg_type, uri), 'publisher', topic)
        for topic, msg_type in subscriptions:
            publishers = self._ok(master.registerSubscriber(name, topic, msg_type, uri), 'subscriber', topic)
            if publishers:
                node.publisherUpdate(MASTER_CALLER_ID, topic, publishers)
        for service, service_uri in offered:
            self._ok(master.registerService(name, service, service_uri, uri), 'service', service)
        rospy.logwarn('%s: the master at %s %s (it restarted): registered %d publisher(s), %d subscriber(s) and '
                      '%d service(s) of %s again', self._caller_id, self._master_uri,
                      'is a new run that knew only part of %s' % name if partly_known else 'did not know %s' % name,
                      len(publications), len(subscriptions), len(offered), name)

    def _ok(self, answer, kind: str, name: str):
        code, message, value = answer
        if code != 1:
            rospy.logerr('%s: the master refused %s %s: %s', self._caller_id, kind, name, message)
            return None
        return value


_started: Optional[MasterRejoin] = None
_decided = False                  # the parameter was read: a check that is off is not asked for again
_start_lock = threading.Lock()


def ensure_started() -> Optional[MasterRejoin]:
    """This process's watch, started on the first call with ``~master_check_period`` (s; 0 turns it off);
    None when off. Raises ValueError naming the parameter when it is not a number of seconds. Only the first
    call asks the master (later ones may come while it is down)."""
    global _started, _decided
    with _start_lock:
        if not _decided:
            period = params.seconds('master_check_period', DEFAULT_PERIOD)
            if period > 0:
                _started = MasterRejoin(period).start()
            _decided = True
        return _started
